//! Where loop closing runs: inline after each keyframe's local mapping
//! (no mapping thread: repeatable runs), or split between the mapping
//! thread and a thread of its own (ORB-SLAM2's third thread). Candidate
//! detection, a keyframe-database query of well under a millisecond, stays
//! where the map is, after each keyframe's local mapping; only when it
//! finds consistent candidates is the map copied (a copy costs about 3 ms
//! on the shared sequence: made after every keyframe it slowed the frame
//! path on 2 cores) and handed to the loop-closing thread, which verifies
//! the candidates, corrects the copy and adjusts it globally. Its
//! corrections come back as updates that local mapping merges at the start
//! of its next keyframe, or when the system asks for everything to be
//! finished ([`LoopClosing::flush`]).

use std::sync::mpsc::{channel, Receiver, Sender};
use std::thread::JoinHandle;

use super::{LoopCloser, LoopReport};
use crate::camera::Camera;
use crate::map::Map;
use crate::params::SlamParams;

/// Loop closing as the system runs it.
pub enum LoopClosing {
    /// No loop closing.
    Off,
    /// On the mapping thread, after each keyframe's mapping.
    Inline(LoopCloser),
    /// On its own thread, on snapshots of the map.
    OnThread(LoopClosingThread),
}

impl LoopClosing {
    /// As `params` asks (`loop_closing`, `global_bundle_adjustment`); on a
    /// thread when `on_thread` (and the thread starts; else inline).
    pub fn new(params: &SlamParams, camera: Camera, on_thread: bool) -> Self {
        if !params.loop_closing {
            return Self::Off;
        }
        let closer = LoopCloser::new(camera, params.sensor, params.global_bundle_adjustment);
        if !on_thread {
            return Self::Inline(closer);
        }
        match LoopClosingThread::spawn(closer) {
            Ok(thread) => Self::OnThread(thread),
            Err(e) => {
                tracing::warn!("loop closing thread not started ({e}): closing loops inline");
                Self::Inline(LoopCloser::new(
                    camera,
                    params.sensor,
                    params.global_bundle_adjustment,
                ))
            }
        }
    }

    /// Before local mapping of a keyframe: the corrections that are ready
    /// merged into `map`, and the reports that came with them.
    pub fn merge_ready(&mut self, map: &mut Map) -> Vec<LoopReport> {
        match self {
            Self::OnThread(thread) => thread.merge_ready(map),
            _ => Vec::new(),
        }
    }

    /// After local mapping of keyframe `id`: inline, look for a loop and
    /// merge its correction now; with the thread, look for candidates and
    /// hand the thread a snapshot if there are any.
    pub fn after_keyframe(&mut self, map: &mut Map, id: usize) -> Vec<LoopReport> {
        match self {
            Self::Off => Vec::new(),
            Self::Inline(closer) => {
                let outcome = closer.process(map, id);
                if let Some(update) = &outcome.update {
                    map.merge_loop(update);
                }
                vec![outcome.report]
            }
            Self::OnThread(thread) => {
                let t = std::time::Instant::now();
                let candidates = thread.detector.detect(map, id);
                if !candidates.is_empty() {
                    thread.submit(map, id, candidates);
                }
                vec![LoopReport {
                    keyframe: id,
                    detect_ms: t.elapsed().as_secs_f64() * 1e3,
                    ..Default::default()
                }]
            }
        }
    }

    /// Waits until every snapshot handed over is processed and merges
    /// what came of them (the end of a run, a map to save).
    pub fn flush(&mut self, map: &mut Map) -> Vec<LoopReport> {
        match self {
            Self::OnThread(thread) => thread.flush(map),
            _ => Vec::new(),
        }
    }
}

enum Request {
    /// A snapshot after keyframe `id`'s local mapping, its loop
    /// `candidates`, taken when `merged` of the thread's corrections had
    /// been merged.
    Keyframe {
        map: Map,
        id: usize,
        candidates: Vec<usize>,
        merged: usize,
    },
    /// Answer once everything before is processed.
    Flush(Sender<()>),
}

/// The loop-closing thread, its channels, and the detection state that
/// stays on the caller's side.
pub struct LoopClosingThread {
    detector: LoopCloser,
    requests: Option<Sender<Request>>,
    outcomes: Receiver<super::LoopOutcome>,
    worker: Option<JoinHandle<()>>,
    /// Corrections merged into the live map so far.
    merged: usize,
}

impl LoopClosingThread {
    /// Starts the thread (named `loop-closing`); `closer` detects here, a
    /// copy of it verifies and corrects there.
    pub fn spawn(closer: LoopCloser) -> std::io::Result<Self> {
        let verifier = closer.clone();
        let (requests, inbox) = channel::<Request>();
        let (outbox, outcomes) = channel();
        let worker = std::thread::Builder::new()
            .name("loop-closing".into())
            .spawn(move || {
                lower_priority();
                let mut corrections = 0;
                for request in inbox {
                    match request {
                        // A snapshot from before the last correction was
                        // merged shows the uncorrected map: nothing to
                        // look for in it.
                        Request::Keyframe { merged, .. } if merged < corrections => {}
                        Request::Keyframe {
                            map,
                            id,
                            candidates,
                            ..
                        } => {
                            let outcome = verifier.close(&map, id, &candidates);
                            corrections += usize::from(outcome.update.is_some());
                            if outbox.send(outcome).is_err() {
                                break;
                            }
                        }
                        Request::Flush(done) => {
                            let _ = done.send(());
                        }
                    }
                }
            })?;
        Ok(Self {
            detector: closer,
            requests: Some(requests),
            outcomes,
            worker: Some(worker),
            merged: 0,
        })
    }

    /// Hands a snapshot of `map` after keyframe `id`, with its loop
    /// candidates, to the thread.
    fn submit(&mut self, map: &Map, id: usize, candidates: Vec<usize>) {
        let request = Request::Keyframe {
            map: map.clone(),
            id,
            candidates,
            merged: self.merged,
        };
        if self
            .requests
            .as_ref()
            .is_some_and(|r| r.send(request).is_err())
        {
            tracing::error!("loop closing thread gone: no more loop closing");
            self.requests = None;
        }
    }

    fn merge_ready(&mut self, map: &mut Map) -> Vec<LoopReport> {
        let mut reports = Vec::new();
        while let Ok(outcome) = self.outcomes.try_recv() {
            if let Some(update) = &outcome.update {
                // Counted either way: the thread waits for this one.
                self.merged += 1;
                self.detector.loop_closed(update.closure.keyframe);
                if !map.merge_loop(update) {
                    tracing::warn!("a loop correction did not fit the map: left out");
                }
            }
            reports.push(outcome.report);
        }
        reports
    }

    fn flush(&mut self, map: &mut Map) -> Vec<LoopReport> {
        let (done, wait) = channel();
        if let Some(requests) = &self.requests {
            if requests.send(Request::Flush(done)).is_ok() {
                let _ = wait.recv();
            }
        }
        self.merge_ready(map)
    }
}

/// Nice value of the loop-closing thread: a global bundle adjustment
/// takes seconds and must yield the cores to feature extraction and
/// tracking when they are busy (measured on 2 cores: at normal priority it
/// raised the frame path's p99 by a quarter).
const NICE: i32 = 10;

/// Lowers the calling thread's priority (Linux schedules threads by their
/// own nice value); elsewhere, or if refused, it keeps its priority.
fn lower_priority() {
    #[cfg(target_os = "linux")]
    // SAFETY: plain system calls on the calling thread's id; no memory is
    // shared with them.
    unsafe {
        let tid = libc::gettid();
        if libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, NICE) != 0 {
            tracing::debug!("loop closing thread keeps its priority (setpriority refused)");
        }
    }
}

impl Drop for LoopClosingThread {
    fn drop(&mut self) {
        self.requests.take();
        if let Some(worker) = self.worker.take() {
            let _ = worker.join();
        }
    }
}
