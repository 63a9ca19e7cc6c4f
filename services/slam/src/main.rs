//! SLAM service: frames + masks in, Track out.
//!
//! A frame is tracked once its route is known and, unless the route is
//! Skip, its masks have arrived. Lockstep tracks frames in order; real-time
//! tracks the newest ready frame and leaves older ones (the supervisor counts
//! them as dropped). A frame seen again (a replay after some other service
//! restarted) is not tracked twice: its Track is published again.

use std::collections::{HashMap, VecDeque};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Result;
use clap::Parser;
use iceoryx2::sample::Sample;
use pipeline::clock::now_ns;
use pipeline::config::ClockMode;
use pipeline::runtime::{run_service, InputError, ServiceArgs, ServiceContext};
use pipeline::service_loop::{self, Drain, Event, Flow, Service};
use pipeline::transport::{attach, qos, waitset, Receiver, Sender, Svc};
use pipeline::views::{FrameView, MasksView};
use scheduling::{tracking, KeyframeFacts};
use shared_types::names::Topic;
use shared_types::{
    control_kind, frame_flags, mask_flags, Control, FrameHeader, MaskSource, MasksHeader, Pose,
    Route, RouteKind, ServiceKind, SlamCommand, StageStamps, Track, TrackState,
};
use slam_backend::bridge_link::BridgeLink;
use slam_backend::rgbd_tracker::{MapFiles, RgbdTracker};
use slam_backend::scripted::ScriptedTracker;
use slam_backend::tracker::{TrackInput, Tracker};
use slam_core::io::ply::write_ply;
use slam_core::KeyframeTiming;

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

/// What the service writes besides its messages.
struct Outputs {
    map: Option<std::path::PathBuf>,
    loops: Option<std::path::PathBuf>,
    corrected_trajectory: Option<std::path::PathBuf>,
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
    run_service(kind, &args.service, move |ctx| run(ctx, &outputs, files))
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

type FrameSample = Sample<Svc, [u8], FrameHeader>;
type MasksSample = Sample<Svc, [u8], MasksHeader>;

struct HeldFrame {
    sample: FrameSample,
    received_ns: u64,
}

/// What the service remembers between wake-ups.
#[derive(Default)]
struct State {
    frames: VecDeque<HeldFrame>,
    masks: VecDeque<MasksSample>,
    routes: HashMap<u64, Route>,
    last: Option<Track>,
    /// Real time: the frame whose keyframe waits for its segmenter masks.
    pending_keyframe: Option<u64>,
    /// Real time: the newest frame the segmenter answered for.
    last_segmented: Option<u64>,
    /// Real time: the segmenter's newest answer found no object (and did
    /// not fail).
    segmented_empty: bool,
    /// Real time: the newest frame on which the propagator saw something
    /// move that it does not follow ([`mask_flags::SEGMENT_WANTED`]).
    last_moved: Option<u64>,
}

impl State {
    /// Nothing dynamic in view as far as the masks tell: the segmenter's
    /// newest answer was empty and nothing moved since.
    fn scene_empty(&self) -> bool {
        self.segmented_empty
            && self
                .last_moved
                .is_none_or(|m| self.last_segmented.is_some_and(|s| m < s))
    }
}

/// A map of at most this many keyframes is young (the core's measure: lost,
/// it is started again): in real time a frame the keyframe rule picks goes
/// in now with the masks it was tracked with, instead of waiting for (or
/// leaving the keyframe to) segmenter masks. On a loaded machine the niced
/// segmenter may take a second or more to answer: at 60 fps with two busy
/// processes 3 of 6 runs lost tracking for good after the first keyframe
/// without this rule, 0 of 8 with it.
const YOUNG_MAP_KEYFRAMES: u32 = slam_core::system::YOUNG_MAP_KEYFRAMES as u32;

fn run(ctx: ServiceContext, outputs: &Outputs, files: MapFiles) -> Result<()> {
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

/// What arrives for the SLAM, in the order a wake-up drains it.
enum Arrival {
    Frame(FrameSample),
    Masks(MasksSample),
    Route(Route),
    Control(Control),
}

/// The receivers the SLAM (and its standby) drain, the Tracks sender a
/// replayed frame is answered on, and how many frames and masks may be held
/// (within the topics' borrow limits).
struct Ports<'a> {
    frames: &'a Receiver<[u8], FrameHeader>,
    masks: &'a Receiver<[u8], MasksHeader>,
    routes: &'a Receiver<Route, ()>,
    tracks: &'a Sender<Track, ()>,
    max_frames: usize,
    max_masks: usize,
}

impl Ports<'_> {
    /// The next arrival of this wake-up: frames, then masks, then routes,
    /// then (a standby's) commands. Room for a frame or masks is made
    /// before it is taken: the oldest held goes.
    fn next(
        &self,
        drain: &mut Drain,
        st: &mut State,
        control: Option<&Receiver<Control, ()>>,
    ) -> Result<Option<Arrival>> {
        loop {
            let entering = drain.entering();
            let next = match drain.stage() {
                0 => {
                    if entering {
                        self.frames.clear_wakeups();
                    }
                    if !self.frames.has_samples()? {
                        None
                    } else {
                        if st.frames.len() >= self.max_frames {
                            st.frames.pop_front();
                        }
                        self.frames.next_sample()?.map(Arrival::Frame)
                    }
                }
                1 => {
                    if entering {
                        self.masks.clear_wakeups();
                    }
                    if !self.masks.has_samples()? {
                        None
                    } else {
                        if st.masks.len() >= self.max_masks {
                            st.masks.pop_front();
                        }
                        self.masks.next_sample()?.map(Arrival::Masks)
                    }
                }
                2 => {
                    if entering {
                        self.routes.clear_wakeups();
                    }
                    self.routes.next()?.map(Arrival::Route)
                }
                3 => match control {
                    Some(control) => {
                        if entering {
                            control.clear_wakeups();
                        }
                        control.next()?.map(Arrival::Control)
                    }
                    None => None,
                },
                _ => return Ok(None),
            };
            if next.is_some() {
                return Ok(next);
            }
            drain.advance();
        }
    }
}

/// Routes a standby keeps: those of the newest frames (a route may come
/// before its frame).
const STANDBY_ROUTES: usize = 16;

/// The warm standby: holds the newest frames, masks and routes (bounded as
/// the active SLAM holds them) without tracking, until the supervisor's
/// PROMOTE for this process.
struct Standby<'a> {
    st: &'a mut State,
    ports: &'a Ports<'a>,
    control: &'a Receiver<Control, ()>,
    /// The first frame it may track, once promoted.
    promoted_from: Option<u64>,
    drain: Drain,
}

impl Service for Standby<'_> {
    type Event = Arrival;

    fn woke(&mut self) {
        self.drain.restart();
    }

    fn next_event(&mut self) -> Result<Option<Arrival>> {
        self.ports
            .next(&mut self.drain, self.st, Some(self.control))
    }

    fn handle(&mut self, event: Event<Arrival>) -> Result<Flow> {
        match event {
            Event::Arrived(Arrival::Frame(sample)) => {
                take_frame(self.st, sample, self.ports.tracks)?
            }
            Event::Arrived(Arrival::Masks(sample)) => take_masks(self.st, sample, None),
            Event::Arrived(Arrival::Route(r)) => {
                self.st.routes.insert(r.seq, r);
                // The newest routes stay (trimmed as they come: the same
                // ones as trimming after the wake-up's last).
                while self.st.routes.len() > STANDBY_ROUTES {
                    let oldest = *self.st.routes.keys().min().expect("not empty");
                    self.st.routes.remove(&oldest);
                }
            }
            Event::Arrived(Arrival::Control(c)) => {
                if c.kind == control_kind::PROMOTE && c.pid == std::process::id() {
                    self.promoted_from = Some(c.seq);
                    return Ok(Flow::Stop);
                }
            }
            Event::Tick | Event::Shutdown => {}
        }
        Ok(Flow::Continue)
    }
}

/// The active SLAM: tracks the frames it holds as their routes and masks
/// come, serves the bridge, and at shutdown writes its files.
struct Slam<'a> {
    st: State,
    tracker: Box<dyn Tracker>,
    bridge: Option<BridgeLink>,
    commands: Option<&'a Receiver<SlamCommand, ()>>,
    ports: &'a Ports<'a>,
    poses: &'a Sender<Pose, ()>,
    outputs: &'a Outputs,
    mode: ClockMode,
    drain: Drain,
}

impl Service for Slam<'_> {
    type Event = Arrival;

    fn patience(&self) -> Duration {
        // A map being saved for the bridge is answered soon after it is
        // written.
        match &self.bridge {
            Some(b) if b.busy() => Duration::from_millis(50),
            _ => Duration::from_secs(1),
        }
    }

    fn woke(&mut self) {
        self.drain.restart();
    }

    fn next_event(&mut self) -> Result<Option<Arrival>> {
        self.ports.next(&mut self.drain, &mut self.st, None)
    }

    fn handle(&mut self, event: Event<Arrival>) -> Result<Flow> {
        let st = &mut self.st;
        match event {
            Event::Arrived(Arrival::Frame(sample)) => take_frame(st, sample, self.ports.tracks)?,
            Event::Arrived(Arrival::Masks(sample)) => {
                take_masks(st, sample, Some(&mut *self.tracker))
            }
            Event::Arrived(Arrival::Route(r)) => {
                st.routes.insert(r.seq, r);
            }
            Event::Arrived(Arrival::Control(_)) => {}
            Event::Tick => self.tick()?,
            Event::Shutdown => {
                if let Some(b) = &mut self.bridge {
                    b.finish()?;
                }
                finish(&mut *self.tracker, self.outputs)?;
            }
        }
        Ok(Flow::Continue)
    }
}

impl Slam<'_> {
    /// Tracks the frames that are ready (a promoted standby holds some),
    /// serves the bridge, and lets a keyframe that waited too long for its
    /// segmenter masks go in without them.
    fn tick(&mut self) -> Result<()> {
        let (st, tracker) = (&mut self.st, &mut *self.tracker);
        while let Some(track) = track_next_ready(st, tracker, self.mode)? {
            self.ports.tracks.send(track)?;
            self.poses.send(Pose::of(&track))?;
            record_loops(tracker, self.outputs.loops.as_deref())?;
        }
        if let (Some(b), Some(commands)) = (&mut self.bridge, self.commands) {
            b.publish_map(tracker)?;
            if b.serve(commands, tracker)?.reset {
                st.pending_keyframe = None;
            }
        }
        if let (Some(waiting), Some(last)) = (st.pending_keyframe, st.last) {
            if tracking::keyframe_waited_too_long(waiting, last.seq) {
                tracing::warn!(
                    seq = waiting,
                    "no segmenter masks for this keyframe; inserted with its propagated ones"
                );
                tracker.complete_keyframe(None);
                st.pending_keyframe = None;
            }
        }
        Ok(())
    }
}

/// At stop: the tracker's files (a keyframe still waiting for its masks
/// goes in), the loops, the loop-corrected trajectory and the map.
fn finish(tracker: &mut dyn Tracker, outputs: &Outputs) -> Result<()> {
    tracker.finish().map_err(anyhow::Error::msg)?;
    record_loops(tracker, outputs.loops.as_deref())?;
    if let Some(path) = &outputs.corrected_trajectory {
        if let Some(trajectory) = tracker.corrected_trajectory() {
            std::fs::write(path, trajectory.to_tum())
                .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
            tracing::info!("loop-corrected trajectory written to {}", path.display());
        }
    }
    if let Some(path) = &outputs.map {
        let points = tracker.map_points();
        write_ply(path, &points)
            .map_err(|e| anyhow::anyhow!("cannot write the map to {}: {e}", path.display()))?;
        tracing::info!(points = points.len(), "map written to {}", path.display());
    }
    Ok(())
}

/// A frame published since the last wake-up, held; a replayed frame
/// already tracked gets its Track again.
fn take_frame(st: &mut State, sample: FrameSample, tracks: &Sender<Track, ()>) -> Result<()> {
    let h = *sample.user_header();
    if h.has(frame_flags::END_OF_STREAM) || h.has(frame_flags::DROPPED_AT_SOURCE) {
        return Ok(());
    }
    if let Some(last) = st.last.filter(|l| h.seq <= l.seq) {
        if h.seq == last.seq {
            tracks.send(last)?; // replayed frame: answer again
        }
        return Ok(());
    }
    st.frames.retain(|f| f.sample.user_header().seq != h.seq);
    st.frames.push_back(HeldFrame {
        sample,
        received_ns: now_ns(),
    });
    Ok(())
}

/// Masks published since the last wake-up, held (a frame's segmenter
/// masks beat its propagated ones); segmenter masks complete the keyframe
/// waiting for them (`tracker`: None for a standby).
fn take_masks(st: &mut State, sample: MasksSample, tracker: Option<&mut dyn Tracker>) {
    if sample.user_header().has(mask_flags::GONE) {
        return; // that frame will not be tracked (the supervisor drops it)
    }
    let header = sample.user_header();
    let seq = header.seq;
    let segmented = from_segmenter(&sample);
    if header.has(mask_flags::SEGMENT_WANTED) {
        st.last_moved = st.last_moved.max(Some(seq));
    }
    if segmented {
        if st.last_segmented.is_none_or(|s| seq > s) {
            st.segmented_empty = header.num_instances == 0 && !header.has(mask_flags::FAILED);
            st.last_segmented = Some(seq);
        }
        let waiting = st
            .pending_keyframe
            .filter(|&k| tracking::completes_waiting_keyframe(k, seq));
        // A standby has no tracker and no keyframe waiting.
        if let (Some(waiting), Some(tracker)) = (waiting, tracker) {
            // The pending keyframe's own masks (or a newer frame's:
            // its own will not come) complete it.
            let own = waiting == seq;
            let view = MasksView::new(sample.user_header(), sample.payload());
            let failed = sample.user_header().has(mask_flags::FAILED);
            let masks = view.ok().filter(|_| own && !failed);
            tracker.complete_keyframe(masks.as_ref());
            st.pending_keyframe = None;
            tracing::debug!(seq = waiting, own, "pending keyframe inserted");
        }
    }
    if st.last.is_some_and(|l| seq <= l.seq) {
        // Real time: the segmenter's result for a frame already
        // tracked with propagated masks (the propagator takes it as
        // its prompt), or a propagator's after the segmenter's.
        return;
    }
    let segmented_held = |m: &MasksSample| m.user_header().seq == seq && from_segmenter(m);
    if !segmented && st.masks.iter().any(segmented_held) {
        return; // a frame's segmenter masks beat its propagated ones
    }
    st.masks.retain(|m| m.user_header().seq != seq);
    st.masks.push_back(sample);
}

/// Tracks one ready frame ([`tracking::next_frame`]: oldest first in
/// lockstep, newest in real time).
fn track_next_ready(
    st: &mut State,
    tracker: &mut dyn Tracker,
    mode: ClockMode,
) -> Result<Option<Track>> {
    let ready: Vec<bool> = st
        .frames
        .iter()
        .map(|f| {
            let seq = f.sample.user_header().seq;
            let route = st
                .routes
                .get(&seq)
                .and_then(|r| RouteKind::from_u32(r.kind));
            tracking::frame_ready(route, st.masks.iter().any(|m| m.user_header().seq == seq))
        })
        .collect();
    let index = tracking::next_frame(mode, &ready);
    let Some(index) = index else { return Ok(None) };
    let timing = keyframe_timing(st, index, mode.is_realtime());
    let (track, waiting) = make_track(st, index, tracker, timing)?;
    // Everything up to this frame is consumed.
    let seq = track.seq;
    match waiting {
        WaitingKeyframe::ThisFrame => st.pending_keyframe = Some(seq),
        WaitingKeyframe::InsertedWithout => st.pending_keyframe = None,
        WaitingKeyframe::Unchanged => {}
    }
    st.last = Some(track);
    st.frames.retain(|f| f.sample.user_header().seq > seq);
    st.masks.retain(|m| m.user_header().seq > seq);
    st.routes.retain(|&s, _| s > seq);
    Ok(Some(track))
}

/// Appends the loops the tracker closed since the last call to `path`
/// (`loops.csv`; the SLAM core logs each one as it closes).
fn record_loops(tracker: &mut dyn Tracker, path: Option<&std::path::Path>) -> Result<()> {
    let loops = tracker.take_loops();
    match path {
        Some(path) if !loops.is_empty() => run_folder::loops_csv::append(path, &loops)
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display())),
        _ => Ok(()),
    }
}

fn from_segmenter(m: &MasksSample) -> bool {
    m.user_header().source == MaskSource::Segmenter as u32
}

/// When the frame at `index` may become a keyframe
/// ([`scheduling::keyframe_timing`]), from what this service knows of its masks.
fn keyframe_timing(st: &State, index: usize, realtime: bool) -> KeyframeTiming {
    let seq = st.frames[index].sample.user_header().seq;
    // At most one masks sample per frame is held (a frame's segmenter
    // masks replace its propagated ones).
    let own_masks = st.masks.iter().find(|m| m.user_header().seq == seq);
    slam_backend::convert::keyframe_timing(scheduling::keyframe_timing(KeyframeFacts {
        realtime,
        route: st
            .routes
            .get(&seq)
            .and_then(|r| RouteKind::from_u32(r.kind)),
        segmented: own_masks.is_some_and(from_segmenter),
        young_map: st
            .last
            .is_some_and(|t| (1..=YOUNG_MAP_KEYFRAMES).contains(&t.counts.keyframes)),
        segmenter_alive: tracking::segmenter_alive(seq, st.last_segmented),
        scene_empty: st.scene_empty()
            && own_masks.is_some_and(|m| m.user_header().num_instances == 0),
        asked_before: st.last.is_some_and(|t| t.next_needs_keyframe != 0),
    }))
}

/// The Track of the ready frame at `index`: tracked with its masks, or
/// skipped when the reader marked it bad (answered only once routed, so the
/// supervisor has the reason on file); with it, what became of the keyframe
/// waiting for the segmenter's masks.
fn make_track(
    st: &State,
    index: usize,
    tracker: &mut dyn Tracker,
    keyframe: KeyframeTiming,
) -> Result<(Track, WaitingKeyframe)> {
    let held = &st.frames[index];
    let header = held.sample.user_header();
    let seq = header.seq;
    let route = st.routes[&seq];
    let mut stamps = route.stamps;
    // Refused: the supervisor found an external frame unusable (recorded
    // why); its pixels are not read.
    if header.has(frame_flags::BAD_INPUT)
        || RouteKind::from_u32(route.kind) == Some(RouteKind::Refuse)
    {
        return Ok((skipped_track(header, stamps), WaitingKeyframe::Unchanged));
    }
    // Not refused yet malformed (the supervisor missed a frame?): skipped
    // with a warning, this process stays up.
    let frame = match FrameView::new(header, held.sample.payload()) {
        Ok(frame) => frame,
        Err(e) => {
            tracing::warn!(seq, "not tracking a malformed frame: {e:#}");
            return Ok((skipped_track(header, stamps), WaitingKeyframe::Unchanged));
        }
    };
    let masks_sample = st.masks.iter().find(|m| m.user_header().seq == seq);
    let masks_view = match masks_sample {
        Some(m) if RouteKind::from_u32(route.kind) != Some(RouteKind::Skip) => {
            stamps = m.user_header().stamps;
            let failed = m.user_header().has(mask_flags::FAILED);
            (!failed)
                .then(|| MasksView::new(m.user_header(), m.payload()))
                .transpose()?
        }
        _ => None,
    };
    stamps.slam_received_ns = held.received_ns;
    stamps.track_start_ns = now_ns();
    let outcome = tracker.track(&TrackInput {
        seq,
        frame: &frame,
        masks: masks_view.as_ref(),
        keyframe,
    });
    stamps.track_done_ns = now_ns();
    let track = Track {
        seq,
        source_timestamp: header.source_timestamp,
        pose: outcome.pose,
        state: outcome.state as u32,
        keyframe_inserted: outcome.keyframe_inserted as u32,
        next_needs_keyframe: outcome.next_needs_keyframe as u32,
        mask_source: masks_view.map(|m| m.source() as u32).unwrap_or(0),
        mask_flags: masks_view.map(|m| m.header.flags).unwrap_or(0),
        counts: outcome.counts,
        stamps,
    };
    let waiting = if outcome.keyframe_pending {
        WaitingKeyframe::ThisFrame
    } else if outcome.waiting_keyframe_inserted {
        WaitingKeyframe::InsertedWithout
    } else {
        WaitingKeyframe::Unchanged
    };
    Ok((track, waiting))
}

/// What tracking a frame did to the keyframe waiting for segmenter masks.
enum WaitingKeyframe {
    Unchanged,
    /// This frame's keyframe waits for them now.
    ThisFrame,
    /// The waiting one went in without them (tracking weakened).
    InsertedWithout,
}

fn skipped_track(h: &FrameHeader, mut stamps: StageStamps) -> Track {
    stamps.track_done_ns = now_ns();
    Track {
        seq: h.seq,
        source_timestamp: h.source_timestamp,
        state: TrackState::Skipped as u32,
        stamps,
        ..Default::default()
    }
}
