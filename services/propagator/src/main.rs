//! propagator service: mask propagation to ordinary frames.
//!
//! A thin shell: the worker loop is `pipeline::mask_worker`; this binary
//! only picks the model backend named in `[services.propagator]`.

use std::process::ExitCode;

use clap::Parser;
use pipeline::mask_worker::{self, model_from_config, ModelFactory};
use pipeline::runtime::{run_service, ServiceArgs};
use propagator::newcomers::NewcomerCheck;
use propagator::propagate::{LkPropagator, PropagatorParams};
use propagator::sam2::{Sam2Propagator, Sam2Settings};
use shared_types::{MaskSource, ServiceKind};

#[derive(Debug, Parser)]
#[command(about = "dynslam propagator: mask propagation to ordinary frames")]
struct Args {
    #[command(flatten)]
    service: ServiceArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    run_service(ServiceKind::Propagator, &args.service, |ctx| {
        let lk: &ModelFactory = &|config| {
            let mut lk = LkPropagator::new(PropagatorParams::default());
            let routing = &config.routing;
            if routing.early_segment_requests {
                let mode = config.run.mode;
                if mode.is_realtime() && routing.unseen_view_share > 0.0 {
                    tracing::debug!(
                        "routing.unseen_view_share applies to lockstep runs: in real time the segmenter would be busy on every frame it can take, at the tracking's expense"
                    );
                }
                lk = lk.with_newcomer_check(NewcomerCheck::for_pipeline(
                    &config.camera,
                    routing,
                    mode,
                ));
            }
            Ok(Box::new(lk))
        };
        let sam2: &ModelFactory = &|config| {
            let settings = Sam2Settings::from_config(&config.services.propagator)?;
            let env = onnx_runtime::init_runtime(&config.onnxruntime)?;
            Ok(Box::new(Sam2Propagator::load(env, settings)?))
        };
        let model = model_from_config(ctx.kind, &ctx.config, &[("lk", lk), ("sam2", sam2)])?;
        mask_worker::run(ctx, MaskSource::Propagator, model)
    })
}
