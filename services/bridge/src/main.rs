//! The `bridge` service: reads the run's pose stream and Tracks (iceoryx2)
//! and publishes them as ROS 2 topics over Zenoh. Started by the supervisor
//! when `[bridge] enabled = true` (or `dynslam run --ros2`); off the frame
//! path: tracking never waits for it and goes on when it dies.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::Result;
use bridge::node::RosNode;
use bridge::outputs::Outputs;
use bridge::services::MapServices;
use clap::{Parser, Subcommand};
use pipeline::runtime::{run_service, ServiceArgs, ServiceContext};
use pipeline::transport::{attach, wait, waitset, Wake};
use shared_types::names::Topic;
use shared_types::{MapHeader, MasksHeader, Pose, ServiceKind, Track};

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

/// How long the bridge sleeps at most between its periodic publications.
const TICK: Duration = Duration::from_millis(50);
/// A node with no router for this long tells the user (once).
const ROUTER_WARNING_AFTER: Duration = Duration::from_secs(3);

fn main() -> ExitCode {
    match Args::parse().role {
        Role::Publish { service, run_dir } => {
            run_service(ServiceKind::Bridge, &service, |ctx| serve(ctx, &run_dir))
        }
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

fn serve(ctx: ServiceContext, run_dir: &std::path::Path) -> Result<()> {
    let cfg = &ctx.config.bridge;
    let poses = ctx.transport.receiver::<Pose>(Topic::Poses)?;
    let tracks = ctx.transport.receiver::<Track>(Topic::Tracks)?;
    // Only with mask_image: the label images are read in shared memory.
    let masks = if cfg.mask_image {
        Some(ctx.transport.slice_receiver::<MasksHeader>(Topic::Masks)?)
    } else {
        None
    };
    // The map as local mapping leaves it (the SLAM sends it with a bridge).
    let map = ctx.transport.slice_receiver::<MapHeader>(Topic::Map)?;
    let mut node = RosNode::open(cfg)?;
    let mut outputs = Outputs::new(&mut node, cfg, run_dir)?;
    let (mut services, replies) = if cfg.services {
        Some(MapServices::open(&mut node, &ctx.transport)?).unzip()
    } else {
        (None, None)
    };
    // The robot's odom -> base arrives on tf (REP-105).
    let tf_in = if cfg.odom_frame.is_empty() {
        None
    } else {
        Some(node.subscriber(&cfg.tf_topic)?)
    };
    let ws = waitset()?;
    let _p = attach(&ws, &poses)?;
    let _t = attach(&ws, &tracks)?;
    let _m = masks.as_ref().map(|m| attach(&ws, m)).transpose()?;
    let _map = attach(&ws, &map)?;
    let _r = replies.as_ref().map(|r| attach(&ws, r)).transpose()?;
    ctx.announce_ready()?;
    tracing::info!(
        zid = node.zid(),
        domain = cfg.domain_id,
        namespace = %cfg.namespace,
        "ROS 2 node {} on Zenoh ({})",
        cfg.node_name,
        cfg.zenoh_config
            .as_ref()
            .map_or_else(|| format!("{} {:?}", cfg.mode, cfg.connect), |f| f.display().to_string())
    );
    let started = Instant::now();
    let mut router_checked = false;
    loop {
        let stopping = wait(&ws, TICK)? == Wake::Terminate;
        // Masks before Tracks: a frame's masks come before its Track.
        if let Some(m) = &masks {
            m.clear_wakeups();
            while let Some(sample) = m.next_sample()? {
                outputs.on_masks(sample.user_header(), sample.payload());
            }
        }
        tracks.clear_wakeups();
        while let Some(t) = tracks.next()? {
            // Masks that came after the loop above, for this Track.
            if let Some(m) = &masks {
                while outputs.awaits_masks_for(&t) {
                    let Some(sample) = m.next_sample()? else {
                        break;
                    };
                    outputs.on_masks(sample.user_header(), sample.payload());
                }
            }
            outputs.on_track(&t)?;
        }
        if let Some(tf) = &tf_in {
            while let Some((dds, payload)) = tf.next() {
                outputs.on_tf_sample(&dds, &payload);
            }
        }
        poses.clear_wakeups();
        while let Some(p) = poses.next()? {
            outputs.on_pose(&p)?;
        }
        map.clear_wakeups();
        while let Some(sample) = map.next_sample()? {
            outputs.on_map(sample.user_header(), sample.payload())?;
        }
        if let (Some(s), Some(replies)) = (&mut services, &replies) {
            outputs.refused += s.poll(replies, Instant::now())?;
        }
        if stopping {
            // The supervisor stops the bridge after the SLAM: what the SLAM
            // said last is out, the path complete.
            return outputs.finish();
        }
        outputs.tick(Instant::now())?;
        if !router_checked && started.elapsed() > ROUTER_WARNING_AFTER {
            router_checked = true;
            if cfg.zenoh_config.is_none() && node.routers() == 0 {
                tracing::warn!(
                    "no Zenoh router reached at {:?} yet: ROS 2 nodes will not see dynslam until one runs (on the robot: ros2 run rmw_zenoh_cpp rmw_zenohd); the bridge keeps trying",
                    cfg.connect
                );
            }
        }
    }
}
