//! mask-link: the segmenter's place in a run whose segmenter is remote
//! (`services.segmenter.location = "remote"`): the usual mask-worker loop
//! over iceoryx2, with masks made by a worker on another machine (and the
//! local fallback).

use std::process::ExitCode;

use clap::Parser;
use pipeline::mask_worker;
use pipeline::runtime::{run_service, ServiceArgs};
use remote::link::RemoteSegmenter;
use shared_types::{MaskSource, ServiceKind};

#[derive(Debug, Parser)]
#[command(about = "dynslam mask-link: a remote segmenter's stand-in in the run")]
struct Args {
    #[command(flatten)]
    service: ServiceArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    pipeline::runtime::init_logging_with(remote::LOG_FILTER);
    run_service(ServiceKind::Segmenter, &args.service, |ctx| {
        let model = RemoteSegmenter::connect(&ctx.config)?;
        mask_worker::run(ctx, MaskSource::Segmenter, Box::new(model))
    })
}
