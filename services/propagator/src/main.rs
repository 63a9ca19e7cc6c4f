//! propagator service: mask propagation to ordinary frames.
//!
//! A thin shell: the worker loop is `pipeline::mask_worker`; this binary
//! only picks the model backend named in `[services.propagator]`.

use std::process::ExitCode;

use clap::Parser;
use pipeline::mask_worker::{self, model_from_config, ModelFactory};
use pipeline::runtime::{run_service, ServiceArgs};
use propagator::propagate::{LkPropagator, PropagatorParams};
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
        let lk: &ModelFactory =
            &|_ctx| Ok(Box::new(LkPropagator::new(PropagatorParams::default())));
        let model = model_from_config(&ctx, &[("lk", lk)])?;
        mask_worker::run(ctx, MaskSource::Propagator, model)
    })
}
