//! The supervisor's run loop: start the services, route every frame, record
//! every Track, restart what dies, stop everything in order, write outputs.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::Child;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Result};
use pipeline::clock::now_ns;
use pipeline::config::{PipelineConfig, SourceKind};
use pipeline::progress::Progress;
use pipeline::transport::{
    attach, cleanup_dead_nodes, remove_run_files, run_files, wait, waitset, Transport, Wake,
};
use pipeline::views::MasksView;
use shared_types::names::{RunNames, Topic};
use shared_types::{
    frame_flags, mask_flags, read_error_text, Control, FrameHeader, Lifecycle, MaskSource,
    MasksHeader, Route, RouteKind, ServiceKind, Track, TrackState,
};

use crate::children::{
    describe_exit, is_input_error, process_matches, renice, service_program, signal, spawn,
    RestartDecision, RestartPolicy,
};
use crate::external::ExternalStream;
use crate::latency;
use crate::mask_record::MaskRecorder;
use crate::outputs::{write_tum, FrameLog, FrameRow};
use crate::run_dir::{self, ChildStatus, Status};
use scheduling::ledger::{Arrival, Dropped, Input, Ledger};
use scheduling::routing::Availability;

/// The SLAM service writes its map here (in the run folder) when stopped.
pub const MAP_FILE: &str = "map.ply";
/// Loop closures, one row each (written by the SLAM service as they happen).
pub const LOOPS_FILE: &str = "loops.csv";
/// The SLAM's trajectory with its loop corrections applied (written at
/// stop when a loop closed; `trajectory.txt` has the poses as published).
pub const CORRECTED_TRAJECTORY_FILE: &str = "trajectory_loop_corrected.txt";

/// How a run ended.
#[derive(Debug, Clone)]
pub struct RunSummary {
    pub run_dir: PathBuf,
    /// The report's figures (None when it could not be written).
    pub report: Option<crate::report::ReportSummary>,
    pub frames: u64,
    pub tracked: u64,
    /// Real time: frames dropped because a newer one was tracked first.
    pub dropped: u64,
    pub restarts: u64,
    pub interrupted: bool,
    /// Why the run is degraded (a mask worker given up on: frames after it
    /// went unmasked); empty for a run that had everything it was asked for.
    pub degraded: Vec<String>,
    pub latency_table: String,
}

#[derive(Debug, Clone, PartialEq)]
enum SvcState {
    NotStarted,
    Starting {
        since: Instant,
    },
    Ready,
    Backoff {
        until: Instant,
    },
    Failed {
        reason: String,
    },
    Stopped,
    /// `source.kind = "external"`: an outside program publishes the frames.
    External,
}

struct Service {
    kind: ServiceKind,
    program: Vec<String>,
    child: Option<Child>,
    state: SvcState,
    policy: RestartPolicy,
    started: Instant,
    restarts: u64,
    /// Last error line the service printed (shown when it is given up on).
    last_error: Arc<Mutex<String>>,
    /// The thread forwarding the running process's stderr.
    stderr_forwarder: Option<std::thread::JoinHandle<()>>,
}

impl Service {
    fn pid(&self) -> Option<u32> {
        self.child.as_ref().map(|c| c.id())
    }
    fn state_name(&self) -> &'static str {
        match self.state {
            SvcState::NotStarted => "not_started",
            SvcState::Starting { .. } => "starting",
            SvcState::Ready => "ready",
            SvcState::Backoff { .. } => "backoff",
            SvcState::Failed { .. } => "failed",
            SvcState::Stopped => "stopped",
            SvcState::External => "external",
        }
    }
    fn failed(&self) -> bool {
        matches!(self.state, SvcState::Failed { .. })
    }
}

/// What the supervisor keeps with a pending frame (its ledger holds the
/// rest): copied into the frame's Route and `frames.csv` row.
#[derive(Debug, Clone, Copy)]
struct FrameExtra {
    timestamp: f64,
    stamps: shared_types::StageStamps,
}

/// Kills what a previous supervisor of this run left behind and removes the
/// run's stale shared memory, so that a resumed run starts clean.
fn clean_previous(run_dir: &Path, names: &RunNames) -> Result<()> {
    if let Some(status) = run_dir::read_status(run_dir) {
        if status.supervisor_pid != std::process::id()
            && process_matches(status.supervisor_pid, run_dir.to_string_lossy().as_ref())
            && status.state == "running"
        {
            bail!(
                "run {} is still supervised by pid {}; stop it first",
                run_dir.display(),
                status.supervisor_pid
            );
        }
        let deadline = Instant::now() + Duration::from_secs(3);
        for c in status.children.iter().filter_map(|c| c.pid) {
            while process_matches(c, names.run_id()) {
                signal(c, libc::SIGKILL);
                if Instant::now() > deadline {
                    bail!("process {c} of run {} does not die", names.run_id());
                }
                std::thread::sleep(Duration::from_millis(10));
            }
        }
    }
    let report = cleanup_dead_nodes(names)?;
    let removed = remove_run_files(names)?;
    if report.dead_nodes_removed > 0 || removed > 0 {
        tracing::info!(
            dead_nodes = report.dead_nodes_removed,
            files = removed,
            "removed stale resources of a previous supervisor"
        );
    }
    Ok(())
}

/// Forwards a child's stderr to ours and remembers its last error line;
/// the thread ends when the child's stderr closes.
fn forward_stderr(
    child: &mut Child,
    last_error: Arc<Mutex<String>>,
) -> Option<std::thread::JoinHandle<()>> {
    child.stderr.take().map(|stderr| {
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                eprintln!("{line}");
                if line.contains("ERROR") {
                    if let Ok(mut l) = last_error.lock() {
                        *l = line;
                    }
                }
            }
        })
    })
}

/// The last error line of a service that has exited: its stderr forwarder
/// is given up to half a second to read what the process wrote last (the
/// exit can be seen before the pipe is drained; a grandchild holding the
/// pipe open must not stall the supervisor).
fn last_error_of(svc: &mut Service) -> String {
    if let Some(forwarder) = svc.stderr_forwarder.take() {
        let deadline = Instant::now() + Duration::from_millis(500);
        while !forwarder.is_finished() && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(5));
        }
    }
    svc.last_error.lock().map(|s| s.clone()).unwrap_or_default()
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
    fn svc(&mut self, kind: ServiceKind) -> &mut Service {
        self.services
            .iter_mut()
            .find(|s| s.kind == kind)
            .expect("every kind has a service")
    }

    fn start(&mut self, kind: ServiceKind) {
        let run_dir = self.run_dir.clone();
        let mut args = vec![
            "--run-id".to_string(),
            self.names.run_id().to_string(),
            "--config".to_string(),
            run_dir
                .join(run_dir::CONFIG_FILE)
                .to_string_lossy()
                .into_owned(),
        ];
        if kind == ServiceKind::Bridge {
            args.push("--run-dir".into());
            args.push(run_dir.to_string_lossy().into_owned());
        }
        if kind == ServiceKind::CameraReader {
            args.push("--start-seq".into());
            args.push(self.ledger.next_seq().to_string());
        }
        if kind == ServiceKind::Slam {
            args.push("--map-out".into());
            args.push(run_dir.join(MAP_FILE).to_string_lossy().into_owned());
            args.push("--loops-out".into());
            args.push(run_dir.join(LOOPS_FILE).to_string_lossy().into_owned());
            args.push("--corrected-trajectory-out".into());
            let corrected = run_dir.join(CORRECTED_TRAJECTORY_FILE);
            args.push(corrected.to_string_lossy().into_owned());
            args.push("--checkpoint".into());
            let checkpoint = run_dir.join(crate::map_files::CHECKPOINT_FILE);
            args.push(checkpoint.to_string_lossy().into_owned());
            if self.ledger.next_seq() > 0 {
                // A restart (or a resume): does it go on in the map?
                let from = if checkpoint.is_file() {
                    let poses = run_dir.join(crate::map_files::RESUME_POSES_FILE);
                    match write_tum(&poses, &self.recent_tracked.rows, |_| true) {
                        Ok(_) => {
                            args.push("--resume-poses".into());
                            args.push(poses.to_string_lossy().into_owned());
                        }
                        Err(e) => tracing::warn!(
                            "the restarted SLAM relocalises instead of resuming its motion: {e:#}"
                        ),
                    }
                    "checkpoint"
                } else {
                    "empty"
                };
                if let Err(e) = run_dir::log_slam_start(&run_dir, self.ledger.next_seq(), from) {
                    tracing::warn!("cannot record the SLAM start: {e:#}");
                }
            }
        }
        let nice = self
            .config
            .process(kind)
            .nice
            .filter(|_| self.slam_has_tracked());
        let svc = self.svc(kind);
        let program = svc.program.clone();
        match spawn(&program, &args, nice) {
            Ok(mut child) => {
                svc.stderr_forwarder = forward_stderr(&mut child, svc.last_error.clone());
                tracing::info!(pid = child.id(), "started {}", kind.as_str());
                svc.child = Some(child);
                svc.state = SvcState::Starting {
                    since: Instant::now(),
                };
                svc.started = Instant::now();
            }
            Err(e) => {
                svc.state = SvcState::Failed {
                    reason: format!("{e:#}"),
                };
            }
        }
        self.status_dirty = true;
    }

    fn availability(&self) -> Availability {
        let ok = |k: ServiceKind| !self.services.iter().any(|s| s.kind == k && s.failed());
        Availability {
            segmenter: ok(ServiceKind::Segmenter),
            propagator: ok(ServiceKind::Propagator),
        }
    }

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
            note: d.why,
            ..Default::default()
        })
    }

    /// The SLAM has tracked a frame (in this run or, resumed, before it).
    /// From then on services run at their configured niceness
    /// (`services.*.nice`); until then at the supervisor's: the first
    /// segmenter masks are what every stage waits for at the start, and a
    /// niced segmenter on a busy machine took 0.5 s for them (at 60 fps with
    /// two busy processes the first 32-40 frames went untracked).
    fn slam_has_tracked(&self) -> bool {
        !self.recent_tracked.rows.is_empty()
    }

    /// Every running service with a `nice` key gets it.
    fn apply_niceness(&self) {
        for svc in &self.services {
            let (Some(nice), Some(child)) = (self.config.process(svc.kind).nice, &svc.child) else {
                continue;
            };
            match renice(child.id(), nice) {
                Ok(()) => tracing::info!("{} now runs at niceness {nice}", svc.kind.as_str()),
                Err(e) => tracing::warn!("cannot set the niceness of {}: {e}", svc.kind.as_str()),
            }
        }
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

    /// Reaps dead children and decides on restarts.
    fn watch_children(&mut self, stopping: bool) -> Result<bool> {
        let mut someone_died = false;
        let now = Instant::now();
        let timeout = Duration::from_secs(self.config.supervisor.ready_timeout_s);
        for i in 0..self.services.len() {
            let svc = &mut self.services[i];
            let Some(child) = svc.child.as_mut() else {
                continue;
            };
            let status = match child.try_wait()? {
                Some(s) => s,
                None => {
                    if let SvcState::Starting { since } = svc.state {
                        if now.duration_since(since) > timeout {
                            tracing::error!(
                                "{} not ready after {timeout:?}; killing it",
                                svc.kind.as_str()
                            );
                            signal(child.id(), libc::SIGKILL);
                        }
                    }
                    continue;
                }
            };
            let pid = child.id();
            svc.child = None;
            someone_died = true;
            self.status_dirty = true;
            if stopping {
                svc.state = SvcState::Stopped;
                continue;
            }
            let how = describe_exit(status);
            let kind = svc.kind;
            if is_input_error(status) {
                let msg = last_error_of(svc);
                svc.state = SvcState::Failed {
                    reason: format!("{} stopped on bad input ({how}): {msg}", kind.as_str()),
                };
                tracing::error!(
                    "{} stopped on bad input ({how}); not restarting it",
                    kind.as_str()
                );
                continue;
            }
            match svc.policy.on_death(now.duration_since(svc.started)) {
                RestartDecision::RestartAfter(delay) => {
                    tracing::warn!(
                        pid,
                        "{} died ({how}); restarting in {delay:?}",
                        kind.as_str()
                    );
                    svc.state = SvcState::Backoff { until: now + delay };
                    svc.restarts += 1;
                    self.restarts += 1;
                    run_dir::log_restart(
                        &self.run_dir,
                        &format!(
                            "{} pid {pid} {how} next_seq {}",
                            kind.as_str(),
                            self.ledger.next_seq()
                        ),
                    )?;
                }
                RestartDecision::GiveUp { deaths_in_a_row } => {
                    let msg = last_error_of(svc);
                    let reason = format!(
                        "{} died {deaths_in_a_row} times in a row, each within {} s of starting (last: {how}); giving up on it. Its last error: {msg}",
                        kind.as_str(),
                        self.config.supervisor.restart_backoff_reset_s
                    );
                    tracing::error!("{reason}");
                    svc.state = SvcState::Failed { reason };
                }
            }
        }
        if someone_died {
            // iceoryx2 dead-node detection: free the dead process's ports.
            let report = cleanup_dead_nodes(&self.names)?;
            if report.dead_nodes_removed > 0 {
                tracing::debug!(
                    nodes = report.dead_nodes_removed,
                    "cleaned dead iceoryx2 nodes"
                );
            }
        }
        if !stopping {
            let kinds: Vec<ServiceKind> = self.services.iter().map(|s| s.kind).collect();
            for kind in kinds {
                if let SvcState::Backoff { until } = self.svc(kind).state {
                    if now >= until {
                        self.start(kind);
                    }
                }
            }
        }
        Ok(someone_died)
    }

    /// The mask workers given up on, in words (a degraded run).
    fn degraded(&self) -> Vec<String> {
        self.services
            .iter()
            .filter(|s| matches!(s.kind, ServiceKind::Segmenter | ServiceKind::Propagator))
            .filter_map(|s| match &s.state {
                SvcState::Failed { reason } => Some(format!(
                    "{reason} (the frames after it were tracked without its masks)"
                )),
                _ => None,
            })
            .collect()
    }

    fn write_status(&mut self, state: &str, error: Option<String>) {
        let status = Status {
            run_id: self.names.run_id().to_string(),
            supervisor_pid: std::process::id(),
            restarts: self.restarts,
            frames_done: self.ledger.recorded().len(),
            frames_total: self.ledger.total(),
            children: self
                .services
                .iter()
                .map(|s| ChildStatus {
                    service: s.kind.as_str().to_string(),
                    pid: s.pid(),
                    state: s.state_name().to_string(),
                    restarts: s.restarts,
                })
                .collect(),
            state: state.to_string(),
            error,
        };
        if let Err(e) = run_dir::write_status(&self.run_dir, &status) {
            tracing::warn!("cannot write status: {e:#}");
        }
        self.status_dirty = false;
    }

    /// Stops the services in order: the source first, the SLAM last.
    fn stop_all(&mut self) {
        let grace = Duration::from_millis(self.config.supervisor.stop_timeout_ms);
        // The bridge last: it publishes the SLAM's last poses.
        for kind in [
            ServiceKind::CameraReader,
            ServiceKind::Segmenter,
            ServiceKind::Propagator,
            ServiceKind::Slam,
            ServiceKind::Bridge,
        ] {
            let Some(svc) = self.services.iter_mut().find(|s| s.kind == kind) else {
                continue; // no bridge in this run
            };
            let Some(mut child) = svc.child.take() else {
                // A service given up on stays `failed` (the run's outcome says why).
                if !svc.failed() {
                    svc.state = SvcState::Stopped;
                }
                continue;
            };
            signal(child.id(), libc::SIGTERM);
            let deadline = Instant::now() + grace;
            loop {
                match child.try_wait() {
                    Ok(Some(_)) => break,
                    Ok(None) if Instant::now() < deadline => {
                        std::thread::sleep(Duration::from_millis(5))
                    }
                    _ => {
                        tracing::warn!(
                            "{} ignored SIGTERM for {grace:?}; killing it",
                            kind.as_str()
                        );
                        let _ = child.kill();
                        let _ = child.wait();
                        break;
                    }
                }
            }
            svc.state = SvcState::Stopped;
        }
        self.status_dirty = true;
    }

    /// The watchdog: every service is up, frames are due, yet none has been
    /// recorded for `supervisor.stall_timeout_s`. The oldest pending frame
    /// says which stage holds it ([`Ledger::stall`]); that service is killed
    /// (and restarted like a crash, so lockstep replays the frame), with the
    /// stage in the log. A stall no service explains fails the run with the
    /// same words.
    fn check_stall(&mut self) {
        let timeout = self.config.supervisor.stall_timeout_s;
        // An external publisher may start whenever it likes.
        let waiting_for_publisher = self.external.as_ref().is_some_and(|e| e.frames_seen() == 0);
        let settled = !waiting_for_publisher
            && self.services.iter().all(|s| {
                matches!(
                    s.state,
                    SvcState::Ready | SvcState::Failed { .. } | SvcState::External
                )
            });
        let now = Instant::now();
        let Some(stall) = self
            .ledger
            .stall(Duration::from_secs(timeout), settled, now)
        else {
            return;
        };
        let what = match stall.seq {
            None if self.external.is_some() => format!(
                "the external publisher sent no frame after {} (and no end of stream)",
                self.ledger.next_seq()
            ),
            None => format!(
                "no frame after {} reached the supervisor",
                self.ledger.next_seq()
            ),
            Some(seq) => {
                let route = stall.route.map_or("not routed", |r| r.as_str());
                format!("frame {seq} (route {route}) is {}", stall.stage)
            }
        };
        let why = format!("no frame recorded for {timeout} s (supervisor.stall_timeout_s): {what}");
        match stall
            .held_by
            .and_then(|k| self.svc(k).pid().map(|pid| (k, pid)))
        {
            Some((k, pid)) => {
                tracing::error!(
                    "stalled: {why}; killing {} (pid {pid}) to restart it",
                    k.as_str()
                );
                signal(pid, libc::SIGKILL);
                self.ledger.note_progress(now);
            }
            None => self.fatal = Some(format!("the run stalled: {why}")),
        }
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
    let mut services = Vec::new();
    let bridge = config.bridge.enabled.then_some(ServiceKind::Bridge);
    for kind in ServiceKind::ALL.into_iter().chain(bridge) {
        services.push(Service {
            kind,
            program: service_program(&config, kind)?,
            child: None,
            state: SvcState::NotStarted,
            policy: RestartPolicy::new(&config.supervisor),
            started: Instant::now(),
            restarts: 0,
            last_error: Arc::new(Mutex::new(String::new())),
            stderr_forwarder: None,
        });
    }
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

    let interrupted = match supervise(&mut sup) {
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

/// Every process of the run is gone: nothing of it may stay in /dev/shm.
fn remove_shared_memory(names: &RunNames) -> Result<()> {
    cleanup_dead_nodes(names)?;
    let left = run_files(names)?;
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

/// The event loop; returns true when interrupted by SIGINT/SIGTERM.
fn supervise(sup: &mut Supervisor) -> Result<bool> {
    let transport = Transport::open(&sup.names, "supervisor")?;
    if sup.config.run.private {
        // The supervisor's node made the run's management file; the services
        // create theirs under the inherited umask.
        let changed = pipeline::transport::make_run_files_private(&sup.names)?;
        tracing::debug!(changed, "run's shared memory made owner-only");
    }
    let frames = transport.slice_receiver::<FrameHeader>(Topic::Frames)?;
    let tracks = transport.receiver::<Track>(Topic::Tracks)?;
    let masks = transport.slice_receiver::<MasksHeader>(Topic::Masks)?;
    // The source's frames, listed once: the progress bar's length and the
    // timestamps the ground-truth masks are looked up by.
    let listed = camera_reader::source::configured_frames(&sup.config.source).ok();
    let expected = listed.as_ref().map_or(0, |f| f.len() as u64);
    let truth = match (
        camera_reader::source::MaskList::open(&sup.config.source.path),
        listed,
    ) {
        (Ok(Some(masks)), Some(frames)) => Some(crate::mask_record::Truth {
            masks,
            timestamps: frames.iter().map(|f| f.timestamp).collect(),
            ignore: crate::ignore::IgnoreRegions::open(&sup.config.source.path)?,
        }),
        _ => None,
    };
    let mut recorder = MaskRecorder::start(&sup.run_dir, sup.config.run.save_masks, truth)?;
    let lifecycle = transport.receiver::<Lifecycle>(Topic::Lifecycle)?;
    let routes = transport.sender::<Route>(Topic::Routes)?;
    let control = transport.sender::<Control>(Topic::Control)?;
    let ws = waitset()?;
    let _a = attach(&ws, &frames)?;
    let _b = attach(&ws, &tracks)?;
    let _c = attach(&ws, &lifecycle)?;
    let _d = attach(&ws, &masks)?;
    let period = Duration::from_millis(sup.config.supervisor.watch_period_ms);

    let kinds: Vec<ServiceKind> = sup
        .services
        .iter()
        .map(|s| s.kind)
        .filter(|k| *k != ServiceKind::CameraReader)
        .collect();
    for kind in kinds {
        sup.start(kind);
    }
    // A progress bar over the frames the source will play (known up front
    // from its lists; the reader announces the exact end of the stream).
    let mut progress = Progress::new("frames", expected);
    let mut shown = 0u64;
    let mut last_sweep = Instant::now();
    let mut interrupted = false;
    loop {
        if wait(&ws, period)? == Wake::Terminate {
            tracing::warn!("termination requested; stopping the services");
            interrupted = true;
            break;
        }
        for msg in lifecycle.drain()? {
            let Some(kind) = ServiceKind::from_u32(msg.service) else {
                continue;
            };
            let Some(svc) = sup.services.iter_mut().find(|s| s.kind == kind) else {
                continue;
            };
            if svc.pid() != Some(msg.pid) {
                continue;
            }
            let was_restart = svc.restarts > 0;
            svc.state = SvcState::Ready;
            sup.status_dirty = true;
            tracing::info!("{} ready (pid {})", kind.as_str(), msg.pid);
            // Lockstep recovery: the in-flight frame may have been lost with
            // the dead process; the reader publishes it again.
            if let Some(replay_seq) = sup.ledger.replay_for(kind, was_restart, Instant::now()) {
                control.send(Control { replay_seq })?;
            }
        }
        // The source starts once the services that consume it are up.
        if sup.svc(ServiceKind::CameraReader).state == SvcState::NotStarted {
            let up = |k| {
                matches!(
                    sup.services.iter().find(|s| s.kind == k).map(|s| &s.state),
                    Some(SvcState::Ready) | Some(SvcState::Failed { .. })
                )
            };
            // The bridge, when there is one, sees the first poses too; one
            // given up on (no router library, a bad Zenoh file) holds nothing.
            let bridge_up = up(ServiceKind::Bridge) || !sup.config.bridge.enabled;
            if up(ServiceKind::Slam)
                && up(ServiceKind::Segmenter)
                && up(ServiceKind::Propagator)
                && bridge_up
            {
                if sup.external.is_some() {
                    sup.svc(ServiceKind::CameraReader).state = SvcState::External;
                    sup.status_dirty = true;
                    tracing::info!(
                        "ready for frames from an external publisher: iceoryx2 service {}, file prefix {} (README \"Frames in\")",
                        sup.names.service(Topic::Frames),
                        sup.names.file_prefix()
                    );
                } else {
                    sup.start(ServiceKind::CameraReader);
                }
            }
        }
        for t in tracks.drain()? {
            sup.on_track(t)?;
        }
        masks.clear_wakeups();
        while let Some(sample) = masks.next_sample()? {
            let h = *sample.user_header();
            if h.has(mask_flags::GONE) {
                sup.on_masks_gone(&h)?;
                continue;
            }
            match MasksView::new(sample.user_header(), sample.payload()) {
                Ok(view) => {
                    let segment_wanted = view.header.has(mask_flags::SEGMENT_WANTED);
                    sup.ledger
                        .on_masks(view.header.seq, view.source(), segment_wanted);
                    recorder.record(&view)
                }
                Err(e) => tracing::warn!("not recording masks: {e:#}"),
            }
        }
        frames.clear_wakeups();
        while let Some(sample) = frames.next_sample()? {
            let header = *sample.user_header();
            let problem = match &mut sup.external {
                Some(stream) => stream
                    .check(&header, sample.payload().len(), &sup.config)
                    .err(),
                None => None,
            };
            drop(sample);
            sup.on_frame(&header, problem, &routes)?;
        }
        sup.route_ready(&routes)?;
        // Services only fail when one dies: what follows from it is decided then.
        if sup.watch_children(false)? {
            sup.ledger.on_worker_lost();
            sup.reroute_orphans(&routes)?;
            if sup.config.run.require_masks {
                if let Some(reason) = sup.degraded().first() {
                    sup.fatal = Some(format!(
                        "{reason}; run.require_masks (--require-masks) makes this a failure"
                    ));
                }
            }
        }
        for kind in [ServiceKind::CameraReader, ServiceKind::Slam] {
            if let SvcState::Failed { reason } = &sup.svc(kind).state {
                sup.fatal = Some(reason.clone());
            }
        }
        sup.check_stall();
        if sup.fatal.is_some() {
            break;
        }
        if last_sweep.elapsed() > Duration::from_secs(1) {
            cleanup_dead_nodes(&sup.names)?;
            last_sweep = Instant::now();
        }
        if expected > 0 && sup.ledger.recorded().len() != shown {
            shown = sup.ledger.recorded().len();
            progress.set(shown);
        }
        if sup.ledger.complete() {
            break;
        }
        // Real time: the last frames may never be tracked; they get a moment.
        for d in sup.ledger.on_tick(Instant::now()) {
            sup.write_dropped(d)?;
        }

        if sup.status_dirty {
            sup.write_status("running", None);
        }
    }
    progress.finish();
    sup.stop_all();
    sup.watch_children(true)?;
    let skipped = recorder.finish()?;
    if skipped > 0 {
        tracing::warn!("{skipped} sets of masks were not recorded (the writer fell behind)");
    }
    Ok(interrupted)
}

/// Trajectories, latency summary and trace, derived from `frames.csv`.
fn finish_outputs(
    sup: &Supervisor,
    interrupted: bool,
    degraded: Vec<String>,
) -> Result<RunSummary> {
    let dir = &sup.run_dir;
    let rows = crate::outputs::read_rows(dir)?;
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
    let report = match crate::report::write(dir, &sup.config, &rows, &degraded) {
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
