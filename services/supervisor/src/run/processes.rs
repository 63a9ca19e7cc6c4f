//! The run's processes: each service's state, starting it, reaping and
//! restarting it, stopping all in order, the watchdog's kill.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::Child;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use pipeline::transport::{cleanup_dead_nodes, remove_run_files};
use scheduling::routing::Availability;
use shared_types::names::RunNames;
use shared_types::ServiceKind;

use super::{Supervisor, CORRECTED_TRAJECTORY_FILE, LOOPS_FILE, MAP_FILE};
use crate::children::{
    describe_exit, is_input_error, process_matches, renice, signal, spawn, RestartDecision,
    RestartPolicy,
};
use run_folder::outputs::write_tum;
use run_folder::run_dir::{self, ChildStatus, Status};

/// What [`Supervisor::watch_children`] found.
pub(super) struct Reaped {
    /// A service died.
    pub(super) any: bool,
    /// The standby (its pid) took the dead SLAM's place.
    pub(super) promoted: Option<u32>,
}

#[derive(Debug, Clone, PartialEq)]
pub(super) enum SvcState {
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

pub(super) struct Service {
    pub(super) kind: ServiceKind,
    pub(super) program: Vec<String>,
    pub(super) child: Option<Child>,
    pub(super) state: SvcState,
    pub(super) policy: RestartPolicy,
    pub(super) started: Instant,
    /// When the running process announced it was ready.
    pub(super) ready_since: Option<Instant>,
    pub(super) restarts: u64,
    /// Last error line the service printed (shown when it is given up on).
    pub(super) last_error: Arc<Mutex<String>>,
    /// The thread forwarding the running process's stderr.
    pub(super) stderr_forwarder: Option<std::thread::JoinHandle<()>>,
}

impl Service {
    pub(super) fn pid(&self) -> Option<u32> {
        self.child.as_ref().map(|c| c.id())
    }
    pub(super) fn state_name(&self) -> &'static str {
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
    pub(super) fn failed(&self) -> bool {
        matches!(self.state, SvcState::Failed { .. })
    }
}

/// Kills what a previous supervisor of this run left behind and removes the
/// run's stale shared memory, so that a resumed run starts clean.
pub(super) fn clean_previous(run_dir: &Path, names: &RunNames) -> Result<()> {
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
pub(super) fn forward_stderr(
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
pub(super) fn last_error_of(svc: &mut Service) -> String {
    if let Some(forwarder) = svc.stderr_forwarder.take() {
        let deadline = Instant::now() + Duration::from_millis(500);
        while !forwarder.is_finished() && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(5));
        }
    }
    svc.last_error.lock().map(|s| s.clone()).unwrap_or_default()
}

impl Supervisor {
    pub(super) fn svc(&mut self, kind: ServiceKind) -> &mut Service {
        self.services
            .iter_mut()
            .find(|s| s.kind == kind)
            .expect("every kind has a service")
    }

    pub(super) fn start(&mut self, kind: ServiceKind) {
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
        if matches!(kind, ServiceKind::Slam | ServiceKind::SlamStandby) {
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
            if kind == ServiceKind::SlamStandby {
                // Written when it is promoted (`finish_promotion`).
                let poses = run_dir.join(crate::map_files::RESUME_POSES_FILE);
                args.push("--resume-poses".into());
                args.push(poses.to_string_lossy().into_owned());
            } else if self.ledger.next_seq() > 0 {
                // A restart (or a resume): it goes on in the map if there is one.
                if let Some(poses) = self.prepare_slam_start(false) {
                    args.push("--resume-poses".into());
                    args.push(poses.to_string_lossy().into_owned());
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
                svc.ready_since = None;
            }
            Err(e) => {
                svc.state = SvcState::Failed {
                    reason: format!("{e:#}"),
                };
            }
        }
        self.status_dirty = true;
    }

    /// A SLAM start after the run's first frame (a restart, a resume, or
    /// the standby's promotion): with a checkpoint to go on in, the last
    /// tracked poses are written for it to resume its motion from (their
    /// file is returned; None without a checkpoint or when they cannot be
    /// written); the start is recorded in `slam-starts.log`.
    pub(super) fn prepare_slam_start(&self, promoted: bool) -> Option<PathBuf> {
        let run_dir = &self.run_dir;
        let in_map = crate::map_files::checkpoint(run_dir).is_some();
        let poses = run_dir.join(crate::map_files::RESUME_POSES_FILE);
        let written = in_map
            && match write_tum(&poses, &self.recent_tracked.rows, |_| true) {
                Ok(_) => true,
                Err(e) => {
                    tracing::warn!("the SLAM relocalises instead of resuming its motion: {e:#}");
                    false
                }
            };
        let map = if in_map { "checkpoint" } else { "empty" };
        let from = if promoted {
            format!("{map} (standby)")
        } else {
            map.to_string()
        };
        if let Err(e) = run_dir::log_slam_start(run_dir, self.ledger.next_seq(), &from) {
            tracing::warn!("cannot record the SLAM start: {e:#}");
        }
        written.then_some(poses)
    }

    pub(super) fn availability(&self) -> Availability {
        let ok = |k: ServiceKind| !self.services.iter().any(|s| s.kind == k && s.failed());
        Availability {
            segmenter: ok(ServiceKind::Segmenter),
            propagator: ok(ServiceKind::Propagator),
        }
    }

    /// The SLAM has tracked a frame (in this run or, resumed, before it).
    /// From then on services run at their configured niceness
    /// (`services.*.nice`); until then at the supervisor's: the first
    /// segmenter masks are what every stage waits for at the start, and a
    /// niced segmenter on a busy machine took 0.5 s for them (at 60 fps with
    /// two busy processes the first 32-40 frames went untracked).
    pub(super) fn slam_has_tracked(&self) -> bool {
        !self.recent_tracked.rows.is_empty()
    }

    /// Every running service with a `nice` key gets it.
    pub(super) fn apply_niceness(&self) {
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

    /// Reaps dead children and decides on restarts; a dead SLAM with a
    /// ready standby is replaced by it at once ([`Self::promote_standby`]).
    pub(super) fn watch_children(&mut self, stopping: bool) -> Result<Reaped> {
        let mut someone_died = false;
        let mut promoted = None;
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
            let ready_for = svc.ready_since.map(|r| now.duration_since(r));
            let decision = svc
                .policy
                .on_death(now.duration_since(svc.started), ready_for);
            if let (ServiceKind::Slam, RestartDecision::RestartAfter(_)) = (kind, decision) {
                if let Some(standby) = self.promote_standby(i, pid, &how, now)? {
                    promoted = Some(standby);
                    continue;
                }
            }
            let svc = &mut self.services[i];
            match decision {
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
                            "{} pid {pid} {how} next_seq {} at_ns {}",
                            kind.as_str(),
                            self.ledger.next_seq(),
                            pipeline::clock::now_ns()
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
        Ok(Reaped {
            any: someone_died,
            promoted,
        })
    }

    /// The SLAM (`self.services[slam]`, pid `dead`) died and the restart
    /// policy allows a restart: a ready standby takes its place at once
    /// (its process becomes the SLAM's, counted as the SLAM's restart) and
    /// a new standby is started behind it. Returns the standby's pid (it is
    /// told by [`Supervisor::finish_promotion`]); None without a ready
    /// standby (the SLAM is restarted cold).
    fn promote_standby(
        &mut self,
        slam: usize,
        dead: u32,
        how: &str,
        now: Instant,
    ) -> Result<Option<u32>> {
        let Some(j) = self.services.iter().position(|s| {
            s.kind == ServiceKind::SlamStandby && s.state == SvcState::Ready && s.child.is_some()
        }) else {
            return Ok(None);
        };
        let standby = &mut self.services[j];
        let child = standby.child.take().expect("a ready standby has a process");
        let forwarder = standby.stderr_forwarder.take();
        let last_error = std::mem::take(&mut standby.last_error);
        standby.state = SvcState::Backoff { until: now };
        let pid = child.id();
        let svc = &mut self.services[slam];
        svc.child = Some(child);
        svc.stderr_forwarder = forwarder;
        svc.last_error = last_error;
        svc.state = SvcState::Ready;
        svc.started = now;
        svc.ready_since = Some(now);
        svc.restarts += 1;
        self.restarts += 1;
        tracing::warn!(
            dead,
            "slam died ({how}); the standby (pid {pid}) takes over"
        );
        run_dir::log_restart(
            &self.run_dir,
            &format!(
                "slam pid {dead} {how} next_seq {} at_ns {} promoted standby pid {pid}",
                self.ledger.next_seq(),
                pipeline::clock::now_ns()
            ),
        )?;
        Ok(Some(pid))
    }

    /// The mask workers given up on, in words (a degraded run).
    pub(super) fn degraded(&self) -> Vec<String> {
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

    pub(super) fn write_status(&mut self, state: &str, error: Option<String>) {
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
    pub(super) fn stop_all(&mut self) {
        let grace = Duration::from_millis(self.config.supervisor.stop_timeout_ms);
        // The bridge last: it publishes the SLAM's last poses.
        for kind in [
            ServiceKind::CameraReader,
            ServiceKind::Segmenter,
            ServiceKind::Propagator,
            ServiceKind::SlamStandby,
            ServiceKind::Slam,
            ServiceKind::Bridge,
        ] {
            let Some(svc) = self.services.iter_mut().find(|s| s.kind == kind) else {
                continue; // no bridge or standby in this run
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
    pub(super) fn check_stall(&mut self) {
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
