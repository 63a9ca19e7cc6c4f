//! The robot's end: a [`MaskModel`] whose masks come from a worker on
//! another machine. It stands in the segmenter's place in the run (the
//! `mask-link` binary runs the usual mask-worker loop with it), so the
//! supervisor, the propagator and SLAM see no difference.
//!
//! A frame goes to a live worker (Zenoh liveliness) as one query; the
//! answer is awaited up to `remote.timeout_ms`, and given up as soon as the
//! worker's token vanishes (a killed worker, a dead link). A frame no worker
//! answered goes to the local model (`fallback = "local"`) or is told
//! [`Unavailable`] (`fallback = "none"`: real time carries the propagator's
//! masks, lockstep goes on unmasked).

use std::collections::BTreeSet;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use pipeline::config::PipelineConfig;
use pipeline::mask_worker::{MaskModel, Unavailable};
use pipeline::views::{FrameView, MasksView};
use shared_types::{mask_flags, Instance};
use zenoh::query::{ConsolidationMode, QueryTarget};
use zenoh::sample::SampleKind;
use zenoh::{Session, Wait};

use crate::session::{frames_key, open, workers_key, Endpoints};
use crate::wire::{decode_reply, encode_request, ImageEncoding};

/// How often a waiting frame looks whether its worker is still alive.
const LIVELINESS_POLL: Duration = Duration::from_millis(10);

/// Counts for the summary line and the bench.
#[derive(Debug, Default, Clone)]
pub struct LinkStats {
    /// Frames answered by a remote worker.
    pub remote: u64,
    /// Frames the local model made masks for (no worker answered).
    pub fallback: u64,
    /// Frames nobody made masks for (`fallback = "none"`).
    pub unavailable: u64,
    /// Frames not answered within `timeout_ms`.
    pub timeouts: u64,
    /// Frames whose worker vanished while they waited.
    pub vanished: u64,
    /// Replies that were not a valid answer (dropped with a warning).
    pub bad_replies: u64,
    /// Frames the worker's model failed on.
    pub worker_failures: u64,
    /// Requests sent, and their bytes.
    pub sent: u64,
    /// See `sent`.
    pub bytes_sent: u64,
    /// Round trip of each answered frame (milliseconds).
    pub round_trips_ms: Vec<f64>,
}

/// Why a frame got no remote masks.
enum NoAnswer {
    NoWorker,
    Vanished,
    Timeout,
    Failed(String),
}

impl NoAnswer {
    fn describe(&self) -> String {
        match self {
            Self::NoWorker => "no remote worker is alive".into(),
            Self::Vanished => "the remote worker went away while the frame waited".into(),
            Self::Timeout => "no remote worker answered in time".into(),
            Self::Failed(why) => format!("the remote worker failed on it: {why}"),
        }
    }
}

/// The remote segmenter as a mask model.
pub struct RemoteSegmenter {
    session: Session,
    run: String,
    key: String,
    /// Key expressions of the live workers' tokens.
    workers: Arc<Mutex<BTreeSet<String>>>,
    _liveliness: zenoh::pubsub::Subscriber<()>,
    fallback: Option<Box<dyn MaskModel>>,
    encoding: ImageEncoding,
    with_depth: bool,
    timeout: Duration,
    /// `mask_flags` of the masks made last.
    origin: u32,
    /// Frames in a row without remote masks (said once when it starts and
    /// once when it ends, not per frame).
    streak: u64,
    stats: LinkStats,
}

impl RemoteSegmenter {
    /// Opens the session of `[remote]`, watches the run's workers and loads
    /// the fallback model (`fallback = "local"`). With no fallback, waits
    /// up to `remote.startup_wait_s` for a worker.
    pub fn connect(config: &PipelineConfig) -> Result<Self> {
        let fallback = match config.services.segmenter.fallback.as_str() {
            "local" => Some(segmentation::models::load(config)?),
            _ => None,
        };
        Self::with_fallback(config, fallback)
    }

    /// [`Self::connect`] with the fallback model given.
    pub fn with_fallback(
        config: &PipelineConfig,
        fallback: Option<Box<dyn MaskModel>>,
    ) -> Result<Self> {
        let r = &config.remote;
        let session = open(&Endpoints {
            zenoh_config: r.zenoh_config.as_deref(),
            mode: &r.mode,
            listen: &r.listen,
            connect: &r.connect,
        })?;
        let workers: Arc<Mutex<BTreeSet<String>>> = Arc::default();
        let seen = workers.clone();
        let liveliness = session
            .liveliness()
            .declare_subscriber(format!("{}/*", workers_key(&r.run)))
            .history(true)
            .callback(move |sample| {
                let key = sample.key_expr().to_string();
                let mut live = seen.lock().unwrap_or_else(|p| p.into_inner());
                match sample.kind() {
                    SampleKind::Put => {
                        if live.insert(key.clone()) {
                            tracing::info!("remote worker up: {key}");
                        }
                    }
                    SampleKind::Delete => {
                        if live.remove(&key) {
                            tracing::warn!("remote worker gone: {key}");
                        }
                    }
                }
            })
            .wait()
            .map_err(|e| anyhow::anyhow!("cannot watch the remote workers: {e}"))?;
        let link = Self {
            session,
            run: r.run.clone(),
            key: frames_key(&r.run),
            workers,
            _liveliness: liveliness,
            fallback,
            encoding: ImageEncoding::from_config(&r.encoding, r.jpeg_quality),
            with_depth: r.depth,
            timeout: Duration::from_millis(r.timeout_ms),
            origin: 0,
            streak: 0,
            stats: LinkStats::default(),
        };
        tracing::info!(
            "remote segmenter: run '{}' on {} (fallback {}); {} worker(s) alive",
            link.run,
            link.key,
            config.services.segmenter.fallback,
            link.alive()
        );
        if link.fallback.is_none() {
            let wait = Duration::from_secs_f64(r.startup_wait_s);
            if !link.wait_for_worker(Instant::now() + wait) {
                bail!(
                    "no remote segmenter worker for run '{}' appeared within {:.0} s (fallback = \"none\"); start one with: dynslam worker segmenter --run {} --connect <this machine's endpoint>",
                    link.run,
                    r.startup_wait_s,
                    link.run
                );
            }
        }
        Ok(link)
    }

    /// Live workers now.
    pub fn alive(&self) -> usize {
        self.workers.lock().map(|w| w.len()).unwrap_or(0)
    }

    /// Waits until a worker is alive or `deadline` passes.
    pub fn wait_for_worker(&self, deadline: Instant) -> bool {
        while self.alive() == 0 {
            if Instant::now() >= deadline {
                return false;
            }
            std::thread::sleep(LIVELINESS_POLL);
        }
        true
    }

    /// What the link has done so far.
    pub fn stats(&self) -> &LinkStats {
        &self.stats
    }

    /// One frame to a remote worker and its masks back into `labels`.
    fn ask(
        &mut self,
        frame: &FrameView,
        previous: Option<&MasksView>,
        labels: &mut [u8],
    ) -> Result<Vec<Instance>, NoAnswer> {
        let start = Instant::now();
        let deadline = start + self.timeout;
        // Without a fallback a frame may wait for a worker to come back.
        let found = match self.fallback {
            Some(_) => self.alive() > 0,
            None => self.wait_for_worker(deadline),
        };
        if !found {
            return Err(NoAnswer::NoWorker);
        }
        let request = encode_request(&self.run, frame, previous, self.encoding, self.with_depth)
            .map_err(|e| NoAnswer::Failed(format!("{e:#}")))?;
        self.stats.sent += 1;
        self.stats.bytes_sent += request.len() as u64;
        let replies = self
            .session
            .get(&self.key)
            .payload(request)
            .target(QueryTarget::BestMatching)
            .consolidation(ConsolidationMode::None)
            .timeout(deadline.saturating_duration_since(Instant::now()))
            .wait()
            .map_err(|e| NoAnswer::Failed(format!("cannot send the frame: {e}")))?;
        let seq = frame.header.seq;
        let size = (frame.header.width, frame.header.height);
        loop {
            let reply = match replies.recv_timeout(LIVELINESS_POLL) {
                Ok(Some(reply)) => reply,
                Ok(None) if Instant::now() >= deadline => return Err(NoAnswer::Timeout),
                Ok(None) if self.alive() == 0 => return Err(NoAnswer::Vanished),
                Ok(None) => continue,
                // The query is over without a usable answer.
                Err(_) if Instant::now() >= deadline => return Err(NoAnswer::Timeout),
                Err(_) => return Err(NoAnswer::Vanished),
            };
            let sample = match reply.result() {
                Ok(sample) => sample,
                Err(e) => {
                    let why = String::from_utf8_lossy(&e.payload().to_bytes()).into_owned();
                    if why.contains("Timeout") {
                        return Err(NoAnswer::Timeout);
                    }
                    return Err(NoAnswer::Failed(why));
                }
            };
            match decode_reply(&sample.payload().to_bytes(), &self.run, seq, size, labels) {
                Ok(Ok((instances, _model_ns))) => {
                    self.stats
                        .round_trips_ms
                        .push(start.elapsed().as_secs_f64() * 1e3);
                    return Ok(instances);
                }
                Ok(Err(why)) => return Err(NoAnswer::Failed(why)),
                Err(e) => {
                    // Dropped; a good reply may still come.
                    self.stats.bad_replies += 1;
                    if self.stats.bad_replies <= 10 {
                        tracing::warn!(seq, "dropped a reply that is not valid: {e:#}");
                    }
                }
            }
        }
    }
}

impl MaskModel for RemoteSegmenter {
    fn name(&self) -> &str {
        "remote"
    }

    fn infer(&mut self, frame: &FrameView, labels: &mut [u8]) -> Result<Vec<Instance>> {
        self.infer_after(frame, None, labels)
    }

    fn infer_after(
        &mut self,
        frame: &FrameView,
        previous: Option<&MasksView>,
        labels: &mut [u8],
    ) -> Result<Vec<Instance>> {
        let why = match self.ask(frame, previous, labels) {
            Ok(instances) => {
                if self.streak > 0 {
                    tracing::info!(
                        "remote masks again after {} frames without them",
                        self.streak
                    );
                    self.streak = 0;
                }
                self.stats.remote += 1;
                self.origin = mask_flags::REMOTE;
                return Ok(instances);
            }
            Err(why) => why,
        };
        if self.streak == 0 {
            let instead = match self.fallback {
                Some(_) => "the local model makes the masks until it answers again",
                None => "frames go without segmenter masks until it answers again",
            };
            tracing::warn!(seq = frame.header.seq, "{}: {instead}", why.describe());
        }
        self.streak += 1;
        match &why {
            NoAnswer::Timeout => self.stats.timeouts += 1,
            NoAnswer::Vanished => self.stats.vanished += 1,
            NoAnswer::Failed(_) => self.stats.worker_failures += 1,
            NoAnswer::NoWorker => {}
        }
        let seq = frame.header.seq;
        labels.fill(0);
        match &mut self.fallback {
            Some(model) => {
                tracing::debug!(seq, "{}: the local model makes its masks", why.describe());
                self.stats.fallback += 1;
                self.origin = mask_flags::FALLBACK;
                model.infer_after(frame, previous, labels)
            }
            None => {
                self.stats.unavailable += 1;
                self.origin = 0;
                Err(Unavailable(format!("frame {seq}: {}", why.describe())).into())
            }
        }
    }

    fn origin_flags(&self) -> u32 {
        self.origin
    }

    fn summary(&self) -> Option<String> {
        let s = &self.stats;
        let mut trips = s.round_trips_ms.clone();
        trips.sort_by(f64::total_cmp);
        let p50 = trips.get(trips.len() / 2).copied().unwrap_or(0.0);
        Some(format!(
            "remote: {} frames masked by remote workers, {} by the local fallback, {} without masks; {} timed out, {} lost with their worker, {} failed there, {} bad replies dropped; {} frames sent, {:.0} KB each, round trip p50 {p50:.1} ms",
            s.remote,
            s.fallback,
            s.unavailable,
            s.timeouts,
            s.vanished,
            s.worker_failures,
            s.bad_replies,
            s.sent,
            s.bytes_sent as f64 / 1024.0 / s.sent.max(1) as f64,
        ))
    }
}
