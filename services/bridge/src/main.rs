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
use clap::Parser;
use pipeline::runtime::{run_service, ServiceArgs, ServiceContext};
use pipeline::transport::{attach, wait, waitset, Wake};
use shared_types::names::Topic;
use shared_types::{Pose, ServiceKind, Track};

#[derive(Parser, Debug)]
#[command(about = "dynslam's ROS 2 bridge (rmw_zenoh wire format)")]
struct Args {
    #[command(flatten)]
    service: ServiceArgs,
    /// The run folder: the supervisor's status.json is read for the
    /// diagnostics, the bridge's own record is kept there.
    #[arg(long)]
    run_dir: PathBuf,
}

/// How long the bridge sleeps at most between its periodic publications.
const TICK: Duration = Duration::from_millis(50);
/// A node with no router for this long tells the user (once).
const ROUTER_WARNING_AFTER: Duration = Duration::from_secs(3);

fn main() -> ExitCode {
    let args = Args::parse();
    run_service(ServiceKind::Bridge, &args.service, |ctx| {
        serve(ctx, &args.run_dir)
    })
}

fn serve(ctx: ServiceContext, run_dir: &std::path::Path) -> Result<()> {
    let cfg = &ctx.config.bridge;
    let poses = ctx.transport.receiver::<Pose>(Topic::Poses)?;
    let tracks = ctx.transport.receiver::<Track>(Topic::Tracks)?;
    let mut node = RosNode::open(cfg)?;
    let mut outputs = Outputs::new(&mut node, cfg, run_dir)?;
    // The robot's odom -> base arrives on tf (REP-105).
    let tf_in = if cfg.odom_frame.is_empty() {
        None
    } else {
        Some(node.subscriber(&cfg.tf_topic)?)
    };
    let ws = waitset()?;
    let _p = attach(&ws, &poses)?;
    let _t = attach(&ws, &tracks)?;
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
        tracks.clear_wakeups();
        while let Some(t) = tracks.next()? {
            outputs.on_track(&t);
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
