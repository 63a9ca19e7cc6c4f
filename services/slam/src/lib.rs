//! SLAM service: frames + masks in, Track out.
//!
//! A frame is tracked once its route is known and, unless the route is
//! Skip, its masks have arrived. Lockstep tracks frames in order; real-time
//! tracks the newest ready frame and leaves older ones (the supervisor counts
//! them as dropped). A frame seen again (a replay after some other service
//! restarted) is not tracked twice: its Track is published again.
//!
//! The service's loops run [`pipeline::service_loop`]: `active` (the
//! SLAM), `standby` (the warm standby), `held` (what both hold and how a
//! wake-up drains into it). `main.rs` is the command line.

#![deny(missing_docs)]

mod active;
mod held;
mod standby;

use std::time::Duration;

use anyhow::Result;
use pipeline::runtime::{InputError, ServiceContext};
use pipeline::service_loop::{self, Drain};
use pipeline::transport::{attach, qos, waitset};
use shared_types::names::Topic;
use shared_types::{Control, FrameHeader, MasksHeader, Pose, Route, ServiceKind, Track};
use slam_backend::bridge_link::BridgeLink;
use slam_backend::rgbd_tracker::{MapFiles, RgbdTracker};
use slam_backend::scripted::ScriptedTracker;
use slam_backend::tracker::Tracker;

use active::Slam;
use held::{Ports, State};
use standby::Standby;

/// What the service writes besides its messages.
pub struct Outputs {
    /// The map (PLY), written at stop.
    pub map: Option<std::path::PathBuf>,
    /// `loops.csv`: each loop closure appended as it happens.
    pub loops: Option<std::path::PathBuf>,
    /// The trajectory as the final map stands (TUM), written at stop when a
    /// loop closed.
    pub corrected_trajectory: Option<std::path::PathBuf>,
}

fn tracker_from_config(ctx: &ServiceContext, files: MapFiles) -> Result<Box<dyn Tracker>> {
    let cfg = &ctx.config.services.slam;
    match cfg.backend.as_str() {
        "scripted" => Ok(Box::new(ScriptedTracker::new(
            if cfg.keyframe_every == 0 {
                5
            } else {
                cfg.keyframe_every
            },
            Duration::from_millis(cfg.work_ms),
            cfg.seen_log.clone(),
        ))),
        "orb-rgbd" => {
            let files = MapFiles {
                load: cfg.load_map.clone(),
                save: cfg.save_map.clone(),
                ..files
            };
            let tracker =
                RgbdTracker::new(&ctx.config, &files).map_err(|e| InputError(e.to_string()))?;
            Ok(Box::new(tracker))
        }
        other => Err(InputError(format!(
            "key `services.slam.backend`: unknown backend '{other}' (known: orb-rgbd, scripted)"
        ))
        .into()),
    }
}

/// The service: the SLAM (or, as `ServiceKind::SlamStandby`, its warm
/// standby until promoted) until stopped; `files` are the map files it goes
/// on from.
pub fn run(ctx: ServiceContext, outputs: &Outputs, files: MapFiles) -> Result<()> {
    let standby = ctx.kind == ServiceKind::SlamStandby;
    // The ports first: a restarted SLAM holds the frames that come while
    // it reads its map, and tracks the newest of them at once.
    let frames = ctx.transport.slice_receiver::<FrameHeader>(Topic::Frames)?;
    let masks = ctx.transport.slice_receiver::<MasksHeader>(Topic::Masks)?;
    let routes = ctx.transport.receiver::<Route>(Topic::Routes)?;
    let tracks = ctx.transport.sender::<Track>(Topic::Tracks)?;
    let poses = ctx.transport.sender::<Pose>(Topic::Poses)?;
    let control = standby
        .then(|| ctx.transport.receiver::<Control>(Topic::Control))
        .transpose()?;
    let ws = waitset()?;
    let _a = attach(&ws, &frames)?;
    let _b = attach(&ws, &masks)?;
    let _c = attach(&ws, &routes)?;
    let control_attached = control.as_ref().map(|c| attach(&ws, c)).transpose()?;
    let ports = Ports {
        frames: &frames,
        masks: &masks,
        routes: &routes,
        tracks: &tracks,
        max_frames: qos(Topic::Frames).borrowed - 1,
        max_masks: qos(Topic::Masks).borrowed - 1,
    };
    let mut st = State::default();
    // A standby reads the map when promoted (the newest checkpoint then).
    let mut tracker = (!standby)
        .then(|| tracker_from_config(&ctx, files.clone()))
        .transpose()?;
    if standby {
        ctx.announce_ready()?;
        tracing::info!("slam standing by");
        let mut standby = Standby {
            st: &mut st,
            ports: &ports,
            control: control
                .as_ref()
                .expect("a standby listens to the supervisor"),
            promoted_from: None,
            drain: Drain::default(),
        };
        service_loop::run(&ws, &mut standby)?;
        let Some(from) = standby.promoted_from else {
            return Ok(()); // stopped while standing by: nothing to write
        };
        // The supervisor's later commands are the reader's: left unread
        // they would wake this loop for ever.
        drop(control_attached);
        drop(control);
        // The promoted process goes on from the newest checkpoint and the
        // last poses the dead one gave (the supervisor wrote them first).
        let started = std::time::Instant::now();
        tracker = Some(tracker_from_config(&ctx, files)?);
        st.frames.retain(|f| f.sample.user_header().seq >= from);
        st.masks.retain(|m| m.user_header().seq >= from);
        st.routes.retain(|&s, _| s >= from);
        tracing::info!(
            from,
            held = st.frames.len(),
            map_ms = started.elapsed().as_millis() as u64,
            "promoted: the standby is the SLAM now"
        );
    }
    let tracker = tracker.expect("built above or at promotion");
    let (bridge, commands) = BridgeLink::open(&ctx)?.unzip();
    let _d = commands.as_ref().map(|c| attach(&ws, c)).transpose()?;
    if !standby {
        ctx.announce_ready()?;
    }
    tracing::info!("slam ready with tracker '{}'", tracker.name());
    service_loop::run(
        &ws,
        &mut Slam {
            st,
            tracker,
            bridge,
            commands: commands.as_ref(),
            ports: &ports,
            poses: &poses,
            outputs,
            mode: ctx.config.run.mode,
            drain: Drain::default(),
        },
    )
}
