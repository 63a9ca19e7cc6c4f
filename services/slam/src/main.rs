//! SLAM service: frames + masks in, Track out (the library's
//! [`slam::run`] does it; this is its command line).

use std::process::ExitCode;

use clap::Parser;
use pipeline::runtime::{run_service, ServiceArgs};
use shared_types::ServiceKind;
use slam::Outputs;
use slam_backend::rgbd_tracker::MapFiles;

#[derive(Debug, Parser)]
#[command(about = "dynslam slam: tracks frames with dynamic-object masks")]
struct Args {
    #[command(flatten)]
    service: ServiceArgs,
    /// Write the map here (PLY) when the service is stopped.
    #[arg(long)]
    map_out: Option<std::path::PathBuf>,
    /// The run's map checkpoint: gone on from if it exists, written every
    /// `services.slam.checkpoint_every_keyframes` keyframes and at stop.
    #[arg(long)]
    checkpoint: Option<std::path::PathBuf>,
    /// The last poses the previous SLAM process gave (TUM format): a
    /// restart resumes its motion model from them.
    #[arg(long)]
    resume_poses: Option<std::path::PathBuf>,
    /// Append each loop closure here as it happens (CSV; the header is
    /// written when the file is new): a killed process loses none.
    #[arg(long)]
    loops_out: Option<std::path::PathBuf>,
    /// At stop, when a loop closed: write the trajectory as the final map
    /// stands (every frame moved with its keyframe by the loop corrections)
    /// here (TUM format).
    #[arg(long)]
    corrected_trajectory_out: Option<std::path::PathBuf>,
    /// Start as the warm standby: hold the newest frames, masks and routes
    /// without tracking them until the supervisor promotes this process
    /// (then read the checkpoint and the resume poses, and track).
    #[arg(long)]
    standby: bool,
}

fn main() -> ExitCode {
    let args = Args::parse();
    let outputs = Outputs {
        map: args.map_out.clone(),
        loops: args.loops_out.clone(),
        corrected_trajectory: args.corrected_trajectory_out.clone(),
    };
    let files = MapFiles {
        checkpoint: args.checkpoint.clone(),
        resume_poses: args.resume_poses.clone(),
        ..MapFiles::default()
    };
    let kind = if args.standby {
        ServiceKind::SlamStandby
    } else {
        ServiceKind::Slam
    };
    run_service(kind, &args.service, move |ctx| {
        slam::run(ctx, &outputs, files)
    })
}
