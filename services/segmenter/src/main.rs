//! segmenter service: keyframe instance segmentation.
//!
//! A thin shell: the worker loop is `pipeline::mask_worker`; the backend
//! named in `[services.segmenter]` comes from `segmentation::models`.

use std::process::ExitCode;

use clap::Parser;
use pipeline::mask_worker;
use pipeline::runtime::{run_service, ServiceArgs};
use shared_types::{MaskSource, ServiceKind};

#[derive(Debug, Parser)]
#[command(about = "dynslam segmenter: keyframe instance segmentation")]
struct Args {
    #[command(flatten)]
    service: ServiceArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    run_service(ServiceKind::Segmenter, &args.service, |ctx| {
        let model = segmentation::models::load(&ctx.config)?;
        mask_worker::run(ctx, MaskSource::Segmenter, model)
    })
}
