//! propagator service: mask propagation to ordinary frames.
//!
//! A thin shell: the worker loop is `pipeline::mask_worker`; the backend
//! named in `[services.propagator]` comes from `propagation::models`.

use std::process::ExitCode;

use clap::Parser;
use pipeline::mask_worker;
use pipeline::runtime::{run_service, ServiceArgs};
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
        let model = propagation::models::load(&ctx.config)?;
        mask_worker::run(ctx, MaskSource::Propagator, model)
    })
}
