//! The `bridge` service: reads the run's pose stream and Tracks (iceoryx2)
//! and publishes them as ROS 2 topics over Zenoh. Started by the supervisor
//! when `[bridge] enabled = true` (or `dynslam run --ros2`); off the frame
//! path: tracking never waits for it and goes on when it dies.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use pipeline::runtime::{run_service, ServiceArgs};
use shared_types::ServiceKind;

#[derive(Parser, Debug)]
#[command(about = "dynslam's ROS 2 bridge (rmw_zenoh wire format)")]
struct Args {
    #[command(subcommand)]
    role: Role,
}

#[derive(Subcommand, Debug)]
enum Role {
    /// The run as ROS 2 topics (the supervisor starts it with --ros2).
    Publish {
        #[command(flatten)]
        service: ServiceArgs,
        /// The run folder: the supervisor's status.json is read for the
        /// diagnostics, the bridge's own record is kept there.
        #[arg(long)]
        run_dir: PathBuf,
    },
    /// A ROS 2 camera's topics as the run's frames, in the camera-reader's
    /// place (`source.kind = "ros2"`).
    CameraIn {
        #[command(flatten)]
        service: ServiceArgs,
        /// Number of the first frame (a restarted stream goes on).
        #[arg(long, default_value_t = 0)]
        start_seq: u64,
    },
    /// Prints the `[camera]` section the configured CameraInfo topic gives
    /// (the supervisor asks before a `source.kind = "ros2"` run starts).
    CameraInfo {
        /// The pipeline configuration.
        #[arg(long)]
        config: PathBuf,
    },
}

fn main() -> ExitCode {
    match Args::parse().role {
        Role::Publish { service, run_dir } => run_service(ServiceKind::Bridge, &service, |ctx| {
            bridge::publish::serve(ctx, &run_dir)
        }),
        Role::CameraIn { service, start_seq } => {
            run_service(ServiceKind::CameraReader, &service, |ctx| {
                bridge::camera_in::serve(ctx, start_seq)
            })
        }
        Role::CameraInfo { config } => camera_info(&config),
    }
}

/// `bridge camera-info`: the `[camera]` section on stdout, or the reason on
/// stderr (exit 2: a restart cannot help).
fn camera_info(config: &std::path::Path) -> ExitCode {
    pipeline::runtime::init_logging();
    let result = pipeline::config::PipelineConfig::load(config)
        .map_err(anyhow::Error::from)
        .and_then(|c| bridge::camera_in::camera_section(&c));
    match result {
        Ok(section) => {
            print!("{section}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(pipeline::runtime::exit_code::INPUT)
        }
    }
}
