//! The supervisor's run loop: start the services, route every frame, record
//! every Track, restart what dies, stop everything in order, write outputs.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use anyhow::{anyhow, bail, Result};
use pipeline::clock::now_ns;
use pipeline::config::{PipelineConfig, SourceKind};
use pipeline::transport::{cleanup_dead_nodes, remove_run_files, run_files};
use pipeline::views::MasksView;
use shared_types::names::{RunNames, Topic};
use shared_types::{
    frame_flags, mask_flags, read_error_text, Control, FrameHeader, Lifecycle, MaskSource,
    MasksHeader, Route, RouteKind, ServiceKind, Track, TrackState,
};

mod processes;
mod watch;
use processes::{clean_previous, Service, SvcState};
use watch::MasksSample;

use crate::children::{service_program, RestartPolicy};
use crate::external::ExternalStream;
use run_folder::latency;
use run_folder::mask_record::MaskRecorder;
use run_folder::outputs::{write_tum, FrameLog, FrameRow};
use run_folder::run_dir;
use scheduling::ledger::{Arrival, Dropped, Input, Ledger};

pub use run_folder::run_dir::{CORRECTED_TRAJECTORY_FILE, LOOPS_FILE, MAP_FILE};

/// How a run ended.
#[derive(Debug, Clone)]
pub struct RunSummary {
    /// The run folder.
    pub run_dir: PathBuf,
    /// The report's figures (None when it could not be written).
    pub report: Option<evaluation::report::ReportSummary>,
    /// Frames recorded.
    pub frames: u64,
    /// Frames tracked.
    pub tracked: u64,
    /// Real time: frames dropped because a newer one was tracked first.
    pub dropped: u64,
    /// Service restarts.
    pub restarts: u64,
    /// Stopped by a signal before the input ended.
    pub interrupted: bool,
    /// Why the run is degraded (a mask worker given up on: frames after it
    /// went unmasked); empty for a run that had everything it was asked for.
    pub degraded: Vec<String>,
    /// The latency table (per stage, p50 / p99), as printed at the end.
    pub latency_table: String,
}

/// What the supervisor keeps with a pending frame (its ledger holds the
/// rest): copied into the frame's Route and `frames.csv` row.
#[derive(Debug, Clone, Copy)]
struct FrameExtra {
    timestamp: f64,
    stamps: shared_types::StageStamps,
}

struct Supervisor {
    config: PipelineConfig,
    names: RunNames,
    run_dir: PathBuf,
    services: Vec<Service>,
    log: FrameLog,
    /// Every frame from its arrival to its row in `frames.csv`: the
    /// timing, routing and drop decisions (the scheduling crate's).
    ledger: Ledger<FrameExtra>,
    restarts: u64,
    status_dirty: bool,
    fatal: Option<String>,
    /// The newest tracked frames, oldest first: a restarted SLAM resumes
    /// its motion model from them (`--resume-poses`).
    recent_tracked: RecentTracked,
    /// `source.kind = "external"`: the outside publisher's stream (no
    /// camera-reader runs).
    external: Option<ExternalStream>,
}

impl Supervisor {
    /// Writes the row of a frame whose fate the ledger has settled.
    fn write_row(&mut self, row: FrameRow) -> Result<()> {
        self.log.append(&row)?;
        self.recent_tracked.offer(&row);
        self.status_dirty = true;
        Ok(())
    }

    /// Writes the row of a frame the ledger dropped.
    fn write_dropped(&mut self, d: Dropped<FrameExtra>) -> Result<()> {
        self.write_row(FrameRow {
            seq: d.seq,
            timestamp: d.frame.as_ref().map_or(0.0, |p| p.extra.timestamp),
            state: "dropped".into(),
            route: d
                .frame
                .and_then(|p| p.route)
                .map_or("none", |r| r.as_str())
                .into(),
            mask_source: "none".into(),
            mask_origin: "none".into(),
            note: d.why,
            ..Default::default()
        })
    }

    fn on_track(&mut self, t: Track) -> Result<()> {
        let received = now_ns();
        let state = TrackState::from_u32(t.state);
        let skipped = state == Some(TrackState::Skipped);
        let next_keyframe = t.next_needs_keyframe != 0;
        let Some(tracked) = self
            .ledger
            .on_track(t.seq, skipped, next_keyframe, Instant::now())
        else {
            return Ok(());
        };
        for d in tracked.dropped {
            self.write_dropped(d)?;
        }
        let pending = tracked.frame;
        let route = pending
            .as_ref()
            .and_then(|p| p.route)
            .map(|r| r.as_str())
            .unwrap_or("none");
        let first_tracked = !self.slam_has_tracked() && state.is_some_and(|s| s.is_tracked());
        self.write_row(FrameRow {
            seq: t.seq,
            timestamp: t.source_timestamp,
            state: state.map(|s| s.as_str()).unwrap_or("invalid").to_string(),
            route: route.to_string(),
            mask_source: MaskSource::from_u32(t.mask_source)
                .unwrap_or(MaskSource::None)
                .as_str()
                .to_string(),
            mask_origin: mask_origin(&t).into(),
            keyframe: t.keyframe_inserted != 0,
            next_keyframe: t.next_needs_keyframe != 0,
            pose: t.pose,
            features: t.counts.features,
            features_masked: t.counts.features_masked,
            features_moving: t.counts.features_moving,
            inliers: t.counts.inliers,
            map_points: t.counts.map_points,
            keyframes: t.counts.keyframes,
            extract_us: t.counts.extract_us,
            mapping_us: t.counts.mapping_us,
            tracked_by_flow: t.counts.tracked_by_flow != 0,
            stamps: t.stamps,
            track_received_ns: received,
            note: pending.map(|p| p.note).unwrap_or_default(),
        })?;
        if first_tracked {
            self.apply_niceness();
        }
        Ok(())
    }

    /// Real time: a worker will not make masks for `h.seq` (the frame was
    /// replaced before its turn); the ledger may drop the frame.
    fn on_masks_gone(&mut self, h: &MasksHeader) -> Result<()> {
        let Some(source) = MaskSource::from_u32(h.source) else {
            return Ok(());
        };
        match self.ledger.on_masks_gone(h.seq, source, Instant::now()) {
            Some(d) => self.write_dropped(d),
            None => Ok(()),
        }
    }

    /// Notes a frame (or its replay); the ledger decides its route
    /// ([`Self::route_ready`]), or that it is dropped, or that a replay
    /// gets its first route again. `problem`: why an external frame cannot
    /// be tracked (recorded as bad input, routed Refuse).
    fn on_frame(
        &mut self,
        h: &FrameHeader,
        problem: Option<String>,
        routes: &pipeline::transport::Sender<Route, ()>,
    ) -> Result<()> {
        tracing::debug!(seq = h.seq, flags = h.flags, "frame");
        let now = Instant::now();
        if h.has(frame_flags::END_OF_STREAM) {
            if self.ledger.on_end_of_stream(h.seq, now) {
                tracing::info!(frames = h.seq, "end of stream");
            }
            self.status_dirty = true;
            return Ok(());
        }
        let input = match problem {
            Some(why) => Input::Refused(why),
            None if h.has(frame_flags::BAD_INPUT) => Input::Bad(read_error_text(&h.error)),
            None => Input::Good,
        };
        let extra = FrameExtra {
            timestamp: h.source_timestamp,
            stamps: h.stamps,
        };
        let left_out = h.has(frame_flags::DROPPED_AT_SOURCE);
        match self.ledger.on_frame(h.seq, input, left_out, extra, now) {
            Arrival::AlreadyRecorded => {
                if let Some(external) = &mut self.external {
                    external.repeated(h);
                }
                Ok(())
            }
            Arrival::Dropped(d) => self.write_dropped(d),
            Arrival::Resend(kind) => {
                send_route(routes, h.seq, kind, h.stamps, h.has(frame_flags::REPLAY))
            }
            Arrival::Waiting => Ok(()),
        }
    }

    /// Sends the routes the ledger decides for waiting frames.
    fn route_ready(&mut self, routes: &pipeline::transport::Sender<Route, ()>) -> Result<()> {
        for r in self.ledger.route_ready(self.availability(), Instant::now()) {
            send_route(routes, r.seq, r.kind, r.extra.stamps, false)?;
        }
        Ok(())
    }

    /// Frames routed to a mask worker that has been given up on go on
    /// unmasked: a second Route (Skip) replaces the first.
    fn reroute_orphans(&mut self, routes: &pipeline::transport::Sender<Route, ()>) -> Result<()> {
        for (r, worker) in self.ledger.reroute_orphans(self.availability()) {
            tracing::warn!(
                seq = r.seq,
                "the {worker} was given up on with this frame routed to it; it goes on unmasked"
            );
            send_route(routes, r.seq, r.kind, r.extra.stamps, false)?;
        }
        Ok(())
    }
}

impl Supervisor {
    /// A service announced it is up (`msg`); the reader is told what a
    /// restart means for it ([`Ledger::on_service_ready`]).
    fn on_ready(
        &mut self,
        msg: Lifecycle,
        control: &pipeline::transport::Sender<Control, ()>,
    ) -> Result<()> {
        let Some(kind) = ServiceKind::from_u32(msg.service) else {
            return Ok(());
        };
        let Some(svc) = self.services.iter_mut().find(|s| s.kind == kind) else {
            return Ok(());
        };
        if svc.pid() != Some(msg.pid) {
            return Ok(());
        }
        let was_restart = svc.restarts > 0;
        svc.state = SvcState::Ready;
        svc.ready_since = Some(Instant::now());
        self.status_dirty = true;
        tracing::info!("{} ready (pid {})", kind.as_str(), msg.pid);
        if let Some(command) = self
            .ledger
            .on_service_ready(kind, was_restart, Instant::now())
        {
            control.send(command.to_control())?;
        }
        Ok(())
    }

    /// The source starts once the services that consume it are up (or given
    /// up on); an external publisher is told where to publish instead.
    fn start_source_when_ready(&mut self) {
        if self.svc(ServiceKind::CameraReader).state != SvcState::NotStarted {
            return;
        }
        let up = |k| {
            matches!(
                self.services.iter().find(|s| s.kind == k).map(|s| &s.state),
                Some(SvcState::Ready) | Some(SvcState::Failed { .. })
            )
        };
        // The bridge, when there is one, sees the first poses too; one
        // given up on (no router library, a bad Zenoh file) holds nothing.
        let bridge_up = up(ServiceKind::Bridge) || !self.config.bridge.enabled;
        let consumers_up = up(ServiceKind::Slam)
            && up(ServiceKind::Segmenter)
            && up(ServiceKind::Propagator)
            && bridge_up;
        if !consumers_up {
            return;
        }
        if self.external.is_some() {
            self.svc(ServiceKind::CameraReader).state = SvcState::External;
            self.status_dirty = true;
            tracing::info!(
                "ready for frames from an external publisher: iceoryx2 service {}, file prefix {} (README \"Frames in\")",
                self.names.service(Topic::Frames),
                self.names.file_prefix()
            );
        } else {
            self.start(ServiceKind::CameraReader);
        }
    }

    /// A set of masks published since the last wake-up: noted by the
    /// ledger (and the router), recorded (and scored) by `recorder`.
    fn on_masks(&mut self, sample: MasksSample, recorder: &mut MaskRecorder) -> Result<()> {
        let h = *sample.user_header();
        if h.has(mask_flags::GONE) {
            if h.has(mask_flags::UNAVAILABLE) {
                let source = MaskSource::from_u32(h.source).unwrap_or(MaskSource::None);
                recorder.record_unavailable(h.seq, source);
            }
            return self.on_masks_gone(&h);
        }
        match MasksView::new(sample.user_header(), sample.payload()) {
            Ok(view) => {
                let segment_wanted = view.header.has(mask_flags::SEGMENT_WANTED);
                self.ledger
                    .on_masks(view.header.seq, view.source(), segment_wanted);
                recorder.record(&view)
            }
            Err(e) => tracing::warn!("not recording masks: {e:#}"),
        }
        Ok(())
    }

    /// Reaps dead services; services only fail when one dies, so what
    /// follows from it (routes around a worker given up on, a required
    /// worker's loss, a dead reader or SLAM) is decided then.
    fn on_deaths(
        &mut self,
        routes: &pipeline::transport::Sender<Route, ()>,
        control: &pipeline::transport::Sender<Control, ()>,
        tracks: &pipeline::transport::Receiver<Track, ()>,
    ) -> Result<()> {
        let reaped = self.watch_children(false)?;
        if let Some(standby) = reaped.promoted {
            self.finish_promotion(standby, control, tracks)?;
        }
        if reaped.any {
            self.ledger.on_worker_lost();
            self.reroute_orphans(routes)?;
            if self.config.run.require_masks {
                if let Some(reason) = self.degraded().first() {
                    self.fatal = Some(format!(
                        "{reason}; run.require_masks (--require-masks) makes this a failure"
                    ));
                }
            }
        }
        for kind in [ServiceKind::CameraReader, ServiceKind::Slam] {
            if let SvcState::Failed { reason } = &self.svc(kind).state {
                self.fatal = Some(reason.clone());
            }
        }
        Ok(())
    }
}

impl Supervisor {
    /// The standby (pid `standby`) took the dead SLAM's place: the dead
    /// one's last Tracks are recorded first, the resume poses written, then
    /// the standby is told from which frame to track and the reader what a
    /// SLAM restart means for it ([`Ledger::on_slam_promoted`]).
    fn finish_promotion(
        &mut self,
        standby: u32,
        control: &pipeline::transport::Sender<Control, ()>,
        tracks: &pipeline::transport::Receiver<Track, ()>,
    ) -> Result<()> {
        for t in tracks.drain()? {
            self.on_track(t)?;
        }
        // The standby was started with the resume poses' path.
        self.prepare_slam_start(true);
        let promotion = self.ledger.on_slam_promoted(Instant::now());
        control.send(Control {
            kind: shared_types::control_kind::PROMOTE,
            pid: standby,
            seq: promotion.from,
        })?;
        if let Some(command) = promotion.reader {
            control.send(command.to_control())?;
        }
        Ok(())
    }
}

fn send_route(
    routes: &pipeline::transport::Sender<Route, ()>,
    seq: u64,
    kind: RouteKind,
    mut stamps: shared_types::StageStamps,
    replay: bool,
) -> Result<()> {
    stamps.routed_ns = now_ns();
    routes.send(Route {
        seq,
        kind: kind as u32,
        replay: replay as u32,
        stamps,
    })
}

/// The last few tracked frames by sequence number, oldest first: as many
/// as the SLAM's motion model and rolling-shutter correction use.
#[derive(Debug, Default)]
struct RecentTracked {
    rows: Vec<FrameRow>,
}

impl RecentTracked {
    const KEEP: usize = slam_core::tracking::MOTION_HISTORY;

    fn from_rows(rows: &[FrameRow]) -> Self {
        let mut recent = Self::default();
        for r in rows {
            recent.offer(r);
        }
        recent
    }

    /// Keeps `row` if it is tracked and among the newest.
    fn offer(&mut self, row: &FrameRow) {
        if !row.is_tracked() {
            return;
        }
        let at = self.rows.partition_point(|r| r.seq < row.seq);
        self.rows.insert(at, row.clone());
        if self.rows.len() > Self::KEEP {
            self.rows.remove(0);
        }
    }
}

/// Runs (or resumes) the run in `run_dir` to its end.
pub fn execute(run_dir: &Path) -> Result<RunSummary> {
    let (info, config) = run_dir::open(run_dir)?;
    run_dir::keep_private(&config);
    let names = RunNames::new(&info.run_id).map_err(|e| anyhow!(e))?;
    let run_dir = run_dir.to_path_buf();
    // Held until this function returns (or the process dies).
    let _lock = run_dir::RunLock::acquire(names.run_id())?;
    clean_previous(&run_dir, &names)?;
    let (log, old_rows) = FrameLog::open(&run_dir)?;
    let mut ledger = Ledger::new(
        config.run.mode,
        config.routing.clone(),
        old_rows.iter().map(|r| r.seq),
        Instant::now(),
    );
    if let Some(last) = old_rows.last() {
        let last_segment = old_rows
            .iter()
            .rev()
            .find(|r| {
                r.route == RouteKind::Segment.as_str()
                    || r.route == RouteKind::SegmentBehind.as_str()
            })
            .map(|r| r.seq);
        ledger.resume(last.next_keyframe, last_segment);
        tracing::info!(frames = old_rows.len(), "resuming run {}", info.run_id);
        if config.services.slam.backend == "orb-rgbd" {
            match crate::map_files::checkpoint(&run_dir) {
                Some(c) => tracing::info!(
                    "the resumed SLAM goes on from its checkpoint {} in the same world frame",
                    c.display()
                ),
                None => tracing::warn!(
                    "no map checkpoint in the run folder: the resumed SLAM starts an empty map, poses from frame {} on are in a new world frame (the report says so)",
                    last.seq + 1
                ),
            }
        }
        run_dir::log_resume(&run_dir, last.seq + 1)?;
    }
    let services = services_of(&config)?;
    let mut sup = Supervisor {
        names: names.clone(),
        run_dir: run_dir.clone(),
        services,
        log,
        ledger,
        restarts: run_dir::restart_count(&run_dir),
        status_dirty: true,
        fatal: None,
        recent_tracked: RecentTracked::from_rows(&old_rows),
        external: (config.source.kind == SourceKind::External).then(ExternalStream::default),
        config,
    };
    drop(old_rows);
    if let Err(e) = pipeline::transport::check_shm_capacity(&sup.config) {
        return Err(fail_run(&mut sup, &names, e));
    }

    let interrupted = match watch::supervise(&mut sup) {
        Ok(i) => i,
        Err(e) => {
            // An error path cleans up like the normal one: the services
            // stopped, the status says why, nothing left in /dev/shm.
            sup.stop_all();
            if let Err(w) = sup.watch_children(true) {
                tracing::warn!("while stopping the services: {w:#}");
            }
            return Err(fail_run(&mut sup, &names, e));
        }
    };
    let (requests, routed) = sup.ledger.router().requests();
    if requests > 0 {
        tracing::info!(
            "early segmenter requests from the propagator: {requests} ({routed} had a frame segmented for them; the rest came with a keyframe anyway)"
        );
    }
    let degraded = sup.degraded();
    let (state, error) = if let Some(fatal) = &sup.fatal {
        ("failed", Some(fatal.clone()))
    } else if interrupted {
        ("interrupted", None)
    } else if !degraded.is_empty() {
        ("degraded", Some(degraded.join("; ")))
    } else {
        ("completed", None)
    };
    if let Err(e) = remove_shared_memory(&names) {
        return Err(fail_run(&mut sup, &names, e));
    }
    let summary = match finish_outputs(&sup, interrupted, degraded) {
        Ok(s) => s,
        Err(e) => return Err(fail_run(&mut sup, &names, e)),
    };
    // Written last: `completed` means the outputs are on disk.
    sup.write_status(state, error);
    if let Some(fatal) = sup.fatal {
        bail!("{fatal}");
    }
    Ok(summary)
}

/// The run's services: every kind a run has, the bridge when it is
/// enabled, the standby SLAM when the run has one; none started yet.
fn services_of(config: &PipelineConfig) -> Result<Vec<Service>> {
    let bridge = config.bridge.enabled.then_some(ServiceKind::Bridge);
    let standby = config
        .services
        .slam
        .has_standby(config.run.mode)
        .then_some(ServiceKind::SlamStandby);
    ServiceKind::ALL
        .into_iter()
        .chain(bridge)
        .chain(standby)
        .map(|kind| {
            Ok(Service {
                kind,
                program: service_program(config, kind)?,
                child: None,
                state: SvcState::NotStarted,
                policy: RestartPolicy::new(&config.supervisor),
                started: Instant::now(),
                ready_since: None,
                restarts: 0,
                last_error: Arc::new(Mutex::new(String::new())),
                stderr_forwarder: None,
            })
        })
        .collect()
}

/// Every process of the run is gone: nothing of it may stay in /dev/shm.
fn remove_shared_memory(names: &RunNames) -> Result<()> {
    cleanup_dead_nodes(names)?;
    let left = run_files(names);
    if !left.is_empty() {
        // Normally only iceoryx2's global management segment, which outlives
        // the last node by design; anything else is a killed process's.
        tracing::debug!(files = ?left, "removing the run's remaining iceoryx2 files");
        remove_run_files(names)?;
    }
    Ok(())
}

/// Ends a run on `error` (its services already stopped): `status.json`
/// says `failed` with the error, the run's shared memory is removed.
fn fail_run(sup: &mut Supervisor, names: &RunNames, error: anyhow::Error) -> anyhow::Error {
    sup.write_status("failed", Some(format!("{error:#}")));
    if let Err(e) = remove_shared_memory(names) {
        tracing::warn!("cannot remove the run's shared memory: {e:#}");
    }
    error
}

/// Trajectories, latency summary and trace, derived from `frames.csv`.
fn finish_outputs(
    sup: &Supervisor,
    interrupted: bool,
    degraded: Vec<String>,
) -> Result<RunSummary> {
    let dir = &sup.run_dir;
    let rows = run_folder::outputs::read_rows(dir)?;
    let tracked = write_tum(&dir.join("trajectory.txt"), &rows, FrameRow::is_tracked)?;
    write_tum(&dir.join("keyframes.txt"), &rows, |r| {
        r.keyframe && r.is_tracked()
    })?;
    let summary = latency::summarize(&rows);
    std::fs::write(
        dir.join("latency_summary.json"),
        serde_json::to_string_pretty(&serde_json::json!({
            "frames": rows.len(),
            "stages": summary,
        }))?,
    )?;
    std::fs::write(
        dir.join("trace.json"),
        latency::trace_json(&rows).to_string(),
    )?;
    let table = latency::format_table(&summary);
    // The report never fails a run whose outputs are written.
    let report = match evaluation::report::write(dir, &sup.config, &rows, &degraded) {
        Ok(r) => Some(r),
        Err(e) => {
            tracing::warn!("cannot write the report: {e:#}");
            None
        }
    };
    Ok(RunSummary {
        report,
        run_dir: dir.clone(),
        frames: rows.len() as u64,
        tracked: tracked as u64,
        dropped: rows.iter().filter(|r| r.state == "dropped").count() as u64,
        restarts: sup.restarts,
        interrupted,
        degraded,
        latency_table: table,
    })
}

/// Where the masks a frame was tracked with were made (`mask_flags::origin`).
fn mask_origin(t: &Track) -> &'static str {
    if t.mask_source == MaskSource::None as u32 {
        "none"
    } else {
        mask_flags::origin(t.mask_flags)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(seq: u64, state: &str) -> FrameRow {
        FrameRow {
            seq,
            timestamp: seq as f64 / 30.0,
            state: state.into(),
            ..FrameRow::default()
        }
    }

    #[test]
    fn recent_tracked_keeps_the_newest_tracked_frames_in_order() {
        let mut recent = RecentTracked::from_rows(&[row(0, "ok"), row(1, "lost"), row(2, "ok")]);
        for r in [
            row(5, "relocalised"),
            row(4, "ok"),
            row(6, "skipped"),
            row(3, "ok"),
        ] {
            recent.offer(&r);
        }
        let seqs: Vec<u64> = recent.rows.iter().map(|r| r.seq).collect();
        assert_eq!(seqs, [3, 4, 5]);
    }
}
