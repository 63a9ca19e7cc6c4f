//! camera-reader service: plays a source into the `frames` topic (the
//! library's [`camera_reader::run`] does it; this is its command line).

use std::process::ExitCode;

use clap::Parser;
use pipeline::runtime::{run_service, ServiceArgs};
use shared_types::ServiceKind;

#[derive(Debug, Parser)]
#[command(about = "dynslam camera-reader: plays frames into shared memory")]
struct Args {
    #[command(flatten)]
    service: ServiceArgs,
    /// First frame to publish (the supervisor resumes interrupted runs here).
    #[arg(long, default_value_t = 0)]
    start_seq: u64,
}

fn main() -> ExitCode {
    let args = Args::parse();
    run_service(ServiceKind::CameraReader, &args.service, |ctx| {
        camera_reader::run(ctx, args.start_seq)
    })
}
