//! The supervisor's ledger of frames: every frame it has seen, from its
//! arrival until its fate is recorded (`frames.csv`), exactly once.
//!
//! It decides when a waiting frame is routed (lockstep: once the previous
//! frame's Track is recorded; real time: the newest first, while fewer than
//! [`REALTIME_IN_FLIGHT`] frames are in flight), which frames are dropped
//! and why, which routes must be replaced because their worker was given up
//! on, which frame a restarted service gets again, and which stage holds a
//! stalled run. The supervisor does the I/O (routes sent, rows written);
//! every decision is here, driven by the instants it passes in.

use std::collections::{BTreeMap, BTreeSet};
use std::time::{Duration, Instant};

use shared_types::{MaskSource, RouteKind, ServiceKind};

use crate::mode::ClockMode;
use crate::routing::{Availability, Router, RoutingConfig};
use crate::source::SourceCommand;

/// Real time: frames at most between their route and their Track (one
/// being tracked, one being masked). The propagator then masks only
/// frames SLAM will track, instead of burning the cores SLAM needs on
/// frames a newer one replaces.
pub const REALTIME_IN_FLIGHT: usize = 2;

/// Real time: a route older than this no longer counts as in flight: its
/// worker died, or the frame was replaced in the worker before its turn
/// under load (with 1 s, 60 fps under load stalled for a second at a time:
/// end-to-end p99 1.05 s).
pub const REALTIME_FLIGHT_TIMEOUT: Duration = Duration::from_millis(300);

/// Real time: after the end of the stream, how long the last frames are
/// given to be tracked before they are recorded dropped.
pub const END_OF_STREAM_GRACE: Duration = Duration::from_secs(2);

/// Why a frame is dropped (the note of its `frames.csv` row).
pub mod why {
    /// A newer frame was tracked first (real time).
    pub const NEWER_TRACKED: &str = "a newer frame was tracked first";
    /// The camera-reader did not decode it (real time).
    pub const LEFT_OUT_AT_SOURCE: &str =
        "left out by the camera-reader: the pipeline was busy with older frames";
    /// The segmenter took a newer frame before this one's turn.
    pub const REPLACED_IN_SEGMENTER: &str = "replaced in the segmenter before its turn";
    /// The propagator took a newer frame before this one's turn.
    pub const REPLACED_IN_PROPAGATOR: &str = "replaced in the propagator before its turn";
    /// Still untracked when the end-of-stream grace ran out.
    pub const END_OF_STREAM: &str = "not tracked before the end of the stream";
}

/// Which frames `frames.csv` holds, without holding their rows: a long
/// run's memory stays flat (the rows are read back from the file for the
/// outputs at the end). Frames are recorded nearly in order, so a
/// contiguous prefix plus the few recorded ahead of it is all there is.
#[derive(Debug, Default, Clone)]
pub struct RecordedFrames {
    /// Every frame below this one is recorded.
    prefix: u64,
    ahead: BTreeSet<u64>,
    newest: Option<u64>,
}

impl RecordedFrames {
    /// The set holding `seqs`.
    pub fn from_seqs(seqs: impl IntoIterator<Item = u64>) -> Self {
        let mut r = Self::default();
        for s in seqs {
            r.insert(s);
        }
        r
    }

    /// Whether `seq` is recorded.
    pub fn contains(&self, seq: u64) -> bool {
        seq < self.prefix || self.ahead.contains(&seq)
    }

    /// Notes `seq` as recorded; false if it already was.
    pub fn insert(&mut self, seq: u64) -> bool {
        if self.contains(seq) {
            return false;
        }
        self.ahead.insert(seq);
        while self.ahead.remove(&self.prefix) {
            self.prefix += 1;
        }
        self.newest = Some(self.newest.map_or(seq, |n| n.max(seq)));
        true
    }

    /// How many frames are recorded.
    pub fn len(&self) -> u64 {
        self.prefix + self.ahead.len() as u64
    }

    /// No frame recorded yet.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The first frame not recorded yet.
    pub fn first_missing(&self) -> u64 {
        self.prefix
    }

    /// The highest recorded frame.
    pub fn newest(&self) -> Option<u64> {
        self.newest
    }
}

/// What the supervisor knows of an arriving frame's pixels.
#[derive(Debug, Clone, PartialEq)]
pub enum Input {
    /// Usable as far as anyone checked.
    Good,
    /// The camera-reader marked it bad (why): routed as the router says
    /// for bad input, SLAM skips it.
    Bad(String),
    /// The supervisor found an external frame unusable (why): routed
    /// [`RouteKind::Refuse`], SLAM does not read its pixels.
    Refused(String),
}

/// A frame seen but whose fate is not recorded yet; `T` is what the
/// supervisor keeps with it (its timestamp and stage stamps).
#[derive(Debug, Clone)]
pub struct Pending<T> {
    /// The supervisor's own data for the frame.
    pub extra: T,
    /// Bad input (marked by the reader, or refused).
    pub bad: bool,
    /// Refused by the supervisor (see [`Input::Refused`]).
    pub refused: bool,
    /// Decided (and sent) route; `None` while it waits for its turn.
    pub route: Option<RouteKind>,
    /// When the route was decided (real time bounds the frames in flight).
    pub routed_at: Option<Instant>,
    /// A set of masks for the frame was published (the watchdog's clue).
    pub masks_seen: bool,
    /// Why the frame went as it did (its `frames.csv` note).
    pub note: String,
}

/// A frame whose fate is decided: dropped (`why`), its pending state if it
/// had one (a frame never seen has none).
#[derive(Debug, Clone)]
pub struct Dropped<T> {
    /// The frame.
    pub seq: u64,
    /// The note of its row.
    pub why: String,
    /// What was known of it.
    pub frame: Option<Pending<T>>,
}

/// What to do about an arriving frame.
#[derive(Debug, Clone)]
pub enum Arrival<T> {
    /// Its fate is already recorded (a replay after a restart, or an
    /// external publisher's repeat): nothing to do.
    AlreadyRecorded,
    /// Record it dropped now.
    Dropped(Dropped<T>),
    /// A replay of a frame already routed: send its route again.
    Resend(RouteKind),
    /// It waits for its route ([`Ledger::route_ready`]).
    Waiting,
}

/// A route decided now: send it.
#[derive(Debug, Clone)]
pub struct Routed<T> {
    /// The frame.
    pub seq: u64,
    /// Its route.
    pub kind: RouteKind,
    /// The supervisor's data for it.
    pub extra: T,
}

/// A Track's frame: the frames it makes dropped (real time, older ones;
/// record them first) and what was pending of it.
#[derive(Debug, Clone)]
pub struct Tracked<T> {
    /// Older frames dropped because this one was tracked.
    pub dropped: Vec<Dropped<T>>,
    /// The frame's pending state (None: it arrived before the supervisor's
    /// restart or was never seen).
    pub frame: Option<Pending<T>>,
}

/// What a standby SLAM's promotion means ([`Ledger::on_slam_promoted`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Promotion {
    /// The first frame the promoted SLAM may track.
    pub from: u64,
    /// What the reader is told.
    pub reader: Option<SourceCommand>,
}

/// Which stage holds the oldest unrecorded frame of a stalled run.
#[derive(Debug, Clone, PartialEq)]
pub struct Stall {
    /// The oldest pending frame (None: no frame is pending: the source).
    pub seq: Option<u64>,
    /// Its route, if decided.
    pub route: Option<RouteKind>,
    /// The service to restart (None: none explains it).
    pub held_by: Option<ServiceKind>,
    /// What the frame waits for, in words.
    pub stage: &'static str,
}

/// The ledger (see the module docs).
#[derive(Debug, Clone)]
pub struct Ledger<T> {
    mode: ClockMode,
    no_masks: bool,
    router: Router,
    pending: BTreeMap<u64, Pending<T>>,
    recorded: RecordedFrames,
    /// The number of frames in the stream, once its end was seen.
    total: Option<u64>,
    end_seen_at: Option<Instant>,
    /// When a frame was last recorded (or a service last came up): the
    /// watchdog's clock.
    last_progress: Instant,
    /// The newest frame SLAM answered for (a Track) in this supervisor's
    /// life.
    newest_answered: Option<u64>,
}

impl<T: Clone> Ledger<T> {
    /// A ledger for a run in `mode`, with the frames `recorded` before (a
    /// resumed run); `now` starts the watchdog's clock.
    pub fn new(
        mode: ClockMode,
        routing: RoutingConfig,
        recorded: impl IntoIterator<Item = u64>,
        now: Instant,
    ) -> Self {
        let no_masks = routing.no_masks;
        let router = match mode {
            ClockMode::Lockstep => Router::new(routing),
            ClockMode::Realtime => Router::realtime(routing),
        };
        Self {
            mode,
            no_masks,
            router,
            pending: BTreeMap::new(),
            recorded: RecordedFrames::from_seqs(recorded),
            total: None,
            end_seen_at: None,
            last_progress: now,
            newest_answered: None,
        }
    }

    /// A resumed run: the router goes on from the last recorded row's
    /// keyframe flag and the newest segmented frame.
    pub fn resume(&mut self, next_needs_keyframe: bool, last_segment: Option<u64>) {
        self.router.resume(next_needs_keyframe, last_segment);
    }

    /// The router (its counters).
    pub fn router(&self) -> &Router {
        &self.router
    }

    /// The frames recorded.
    pub fn recorded(&self) -> &RecordedFrames {
        &self.recorded
    }

    /// The first frame whose fate is not recorded: where a restarted reader
    /// starts and what a lockstep replay asks for.
    pub fn next_seq(&self) -> u64 {
        self.recorded.first_missing()
    }

    /// The stream's length, once its end was seen.
    pub fn total(&self) -> Option<u64> {
        self.total
    }

    /// Every frame of the stream is recorded.
    pub fn complete(&self) -> bool {
        self.total.is_some_and(|t| self.next_seq() >= t)
    }

    /// The pending state of `seq`.
    pub fn pending(&self, seq: u64) -> Option<&Pending<T>> {
        self.pending.get(&seq)
    }

    /// Something moved the run on (a service came up): the watchdog waits
    /// a full period again.
    pub fn note_progress(&mut self, now: Instant) {
        self.last_progress = now;
    }

    /// Marks `seq` recorded and takes its pending state; None when it
    /// already was recorded.
    fn settle(&mut self, seq: u64, now: Instant) -> Option<Option<Pending<T>>> {
        if !self.recorded.insert(seq) {
            return None;
        }
        self.last_progress = now;
        Some(self.pending.remove(&seq))
    }

    fn drop_frame(&mut self, seq: u64, why: &str, now: Instant) -> Option<Dropped<T>> {
        self.settle(seq, now).map(|frame| Dropped {
            seq,
            why: why.to_string(),
            frame,
        })
    }

    /// The end of the stream: `total` frames. True the first time (or when
    /// the count changed).
    pub fn on_end_of_stream(&mut self, total: u64, now: Instant) -> bool {
        self.end_seen_at.get_or_insert(now);
        let new = self.total != Some(total);
        self.total = Some(total);
        new
    }

    /// A frame (or its replay) arrived: `left_out` when the reader did not
    /// decode it. Its route is decided by [`Self::route_ready`]; a replayed
    /// frame gets its first route again.
    pub fn on_frame(
        &mut self,
        seq: u64,
        input: Input,
        left_out: bool,
        extra: T,
        now: Instant,
    ) -> Arrival<T> {
        if self.recorded.contains(seq) {
            return Arrival::AlreadyRecorded;
        }
        let (bad, refused, note) = match input {
            Input::Good => (false, false, String::new()),
            Input::Bad(why) => (true, false, format!("bad input: {why}")),
            Input::Refused(why) => (true, true, format!("bad input: {why}")),
        };
        let entry = self.pending.entry(seq).or_insert_with(|| Pending {
            extra: extra.clone(),
            bad,
            refused,
            route: None,
            routed_at: None,
            masks_seen: false,
            note,
        });
        entry.extra = extra;
        if left_out {
            return self.dropped(seq, why::LEFT_OUT_AT_SOURCE, now);
        }
        if let Some(kind) = entry.route {
            return Arrival::Resend(kind);
        }
        // Real time: SLAM only moves forward, so a frame older than a
        // tracked one that reaches us late is already dropped.
        let late = self.mode.is_realtime() && self.recorded.newest().is_some_and(|n| n > seq);
        if late {
            return self.dropped(seq, why::NEWER_TRACKED, now);
        }
        Arrival::Waiting
    }

    fn dropped(&mut self, seq: u64, why: &str, now: Instant) -> Arrival<T> {
        match self.drop_frame(seq, why, now) {
            Some(d) => Arrival::Dropped(d),
            None => Arrival::AlreadyRecorded,
        }
    }

    /// Decides the routes of waiting frames. Lockstep: a frame is routed
    /// only once the previous frame's Track is recorded (its keyframe flag
    /// decides the route, and iceoryx2 does not order deliveries across
    /// services: the reader may publish frame n+1 before Track(n) reaches
    /// the supervisor). Real time: the newest frame first, and only while
    /// fewer than [`REALTIME_IN_FLIGHT`] masked frames are between routing
    /// and their Track; the frames passed over are dropped when a newer
    /// one is tracked.
    pub fn route_ready(&mut self, workers: Availability, now: Instant) -> Vec<Routed<T>> {
        let lockstep = self.mode == ClockMode::Lockstep;
        let mut waiting: Vec<u64> = self
            .pending
            .iter()
            .filter(|(_, p)| p.route.is_none())
            .map(|(&s, _)| s)
            .collect();
        let mut room = usize::MAX;
        if !lockstep {
            waiting.reverse();
            let in_flight = self
                .pending
                .values()
                .filter(|p| {
                    p.route.is_some_and(RouteKind::makes_masks)
                        && p.routed_at.is_some_and(|t| {
                            now.saturating_duration_since(t) < REALTIME_FLIGHT_TIMEOUT
                        })
                })
                .count();
            room = REALTIME_IN_FLIGHT.saturating_sub(in_flight);
        }
        let mut routed = Vec::new();
        for seq in waiting {
            if lockstep && seq > 0 && !self.recorded.contains(seq - 1) {
                break;
            }
            if room == 0 {
                break;
            }
            let p = self
                .pending
                .get_mut(&seq)
                .expect("waiting frame is pending");
            let kind = if p.refused {
                RouteKind::Refuse
            } else if let Some(kind) = self.router.route(seq, p.bad, workers) {
                kind
            } else {
                continue; // real time: waits for the first segmenter result
            };
            p.route = Some(kind);
            p.routed_at = Some(now);
            if kind == RouteKind::Skip && !p.bad && !self.no_masks {
                p.note = "unmasked: no mask service available".into();
            }
            if self.router.last_was_request() {
                p.note =
                    "segmented early: the propagator saw something move that it does not follow"
                        .into();
            }
            routed.push(Routed {
                seq,
                kind,
                extra: p.extra.clone(),
            });
            if kind.makes_masks() {
                room = room.saturating_sub(1);
            }
        }
        routed
    }

    /// A Track for `seq` (`skipped`: SLAM did not track it, bad input);
    /// None when its fate is already recorded.
    pub fn on_track(
        &mut self,
        seq: u64,
        skipped: bool,
        next_needs_keyframe: bool,
        now: Instant,
    ) -> Option<Tracked<T>> {
        self.newest_answered = self.newest_answered.max(Some(seq));
        if self.recorded.contains(seq) {
            return None;
        }
        let mut dropped = Vec::new();
        if self.mode.is_realtime() {
            // Frames older than a tracked one will never be tracked.
            let older: Vec<u64> = self.pending.range(..seq).map(|(&s, _)| s).collect();
            for s in older {
                dropped.extend(self.drop_frame(s, why::NEWER_TRACKED, now));
            }
        }
        // A skipped (bad) frame was not tracked: it has no opinion on keyframes.
        if !skipped {
            self.router.on_track(next_needs_keyframe);
        }
        let frame = self.settle(seq, now).flatten();
        Some(Tracked { dropped, frame })
    }

    /// A set of masks for `seq` was published (`segment_wanted`: the
    /// propagator saw something move that it does not follow). Lockstep
    /// stays deterministic: the masks of frame N are published before
    /// SLAM's Track N, which frame N+1's route waits for.
    pub fn on_masks(&mut self, seq: u64, source: MaskSource, segment_wanted: bool) {
        if source == MaskSource::Segmenter {
            self.router.on_segmenter_result(seq);
        }
        if source == MaskSource::Propagator && segment_wanted {
            self.router.on_segment_wanted();
        }
        if let Some(p) = self.pending.get_mut(&seq) {
            p.masks_seen = true;
        }
    }

    /// Real time: a worker will not make masks for `seq` (the frame was
    /// replaced before its turn). A frame tracked by those masks is dropped
    /// now, which frees its place among the frames in flight; a background
    /// segment frees the segmenter.
    pub fn on_masks_gone(
        &mut self,
        seq: u64,
        source: MaskSource,
        now: Instant,
    ) -> Option<Dropped<T>> {
        let route = self.pending.get(&seq).and_then(|p| p.route);
        match source {
            MaskSource::Segmenter => {
                self.router.on_segment_gone(seq);
                if route == Some(RouteKind::Segment) {
                    self.drop_frame(seq, why::REPLACED_IN_SEGMENTER, now)
                } else {
                    None
                }
            }
            MaskSource::Propagator if route.is_some_and(|r| r.propagates()) => {
                self.drop_frame(seq, why::REPLACED_IN_PROPAGATOR, now)
            }
            _ => None,
        }
    }

    /// A mask worker died (restarting or given up on): the router forgets
    /// what it had at the segmenter.
    pub fn on_worker_lost(&mut self) {
        self.router.on_worker_lost();
    }

    /// Frames routed to a mask worker that has been given up on never get
    /// their masks: they go on unmasked, told to SLAM by a second Route
    /// (Skip, which replaces the first), so a lockstep run never waits for
    /// them. Returned with the worker's name.
    pub fn reroute_orphans(&mut self, workers: Availability) -> Vec<(Routed<T>, &'static str)> {
        let mut orphans = Vec::new();
        for (&seq, p) in self.pending.iter_mut() {
            let worker = match p.route {
                Some(RouteKind::Segment) if !workers.segmenter => "segmenter",
                // Tracked with the propagator's masks; the segmenter's only
                // re-prompt the propagator.
                Some(RouteKind::Propagate | RouteKind::SegmentBehind) if !workers.propagator => {
                    "propagator"
                }
                _ => continue,
            };
            p.route = Some(RouteKind::Skip);
            p.note =
                format!("unmasked: the {worker} was given up on while this frame was routed to it");
            let routed = Routed {
                seq,
                kind: RouteKind::Skip,
                extra: p.extra.clone(),
            };
            orphans.push((routed, worker));
        }
        orphans
    }

    /// Real time, once the end of the stream was seen
    /// [`END_OF_STREAM_GRACE`] ago: the frames still unrecorded will never
    /// be tracked and are dropped. Lockstep waits for every frame.
    pub fn on_tick(&mut self, now: Instant) -> Vec<Dropped<T>> {
        let (Some(total), Some(seen)) = (self.total, self.end_seen_at) else {
            return Vec::new();
        };
        if !self.mode.is_realtime() || now.saturating_duration_since(seen) <= END_OF_STREAM_GRACE {
            return Vec::new();
        }
        (self.next_seq()..total)
            .filter_map(|seq| self.drop_frame(seq, why::END_OF_STREAM, now))
            .collect()
    }

    /// A service came up (`was_restart`: not for the first time): what the
    /// reader is told. Lockstep recovery: the frame in flight may have been
    /// lost with the dead process, so the reader publishes the first
    /// unrecorded one again (the reader itself starts from it, and the
    /// bridge is off the frame path). Real time: a restarted SLAM never gets
    /// the frames published or routed before it, so neither the reader nor
    /// the in-flight limit waits for their Tracks.
    pub fn on_service_ready(
        &mut self,
        kind: ServiceKind,
        was_restart: bool,
        now: Instant,
    ) -> Option<SourceCommand> {
        self.note_progress(now);
        if !was_restart || self.complete() {
            return None;
        }
        match self.mode {
            ClockMode::Lockstep => {
                // The reader starts from it itself; the bridge is off the
                // frame path, and a standby SLAM holds frames without
                // tracking them.
                let on_frame_path = matches!(
                    kind,
                    ServiceKind::Segmenter | ServiceKind::Propagator | ServiceKind::Slam
                );
                on_frame_path.then(|| SourceCommand::Replay(self.next_seq()))
            }
            ClockMode::Realtime if kind == ServiceKind::Slam => {
                // Nor does it get their routes: the frames routed so far
                // no longer hold the in-flight limit (the newer frames it
                // tracks drop them).
                for p in self.pending.values_mut() {
                    p.routed_at = None;
                }
                Some(SourceCommand::ForgetBacklog)
            }
            ClockMode::Realtime => None,
        }
    }

    /// The active SLAM died and the warm standby takes over (the
    /// supervisor recorded the dead one's last Tracks first): it tracks
    /// from the frame after the newest one SLAM answered, so the two never
    /// answer for the same frame; the reader is told as after a restart
    /// ([`Self::on_service_ready`]: the standby may not hold every frame).
    pub fn on_slam_promoted(&mut self, now: Instant) -> Promotion {
        Promotion {
            from: self.newest_answered.map_or(0, |s| s + 1),
            reader: self.on_service_ready(ServiceKind::Slam, true, now),
        }
    }

    /// The watchdog: with every service settled (up or given up on) and
    /// frames due, none recorded for `timeout` (zero: never). The oldest
    /// pending frame says which stage holds it.
    pub fn stall(&self, timeout: Duration, settled: bool, now: Instant) -> Option<Stall> {
        if timeout.is_zero()
            || !settled
            || self.complete()
            || now.saturating_duration_since(self.last_progress) < timeout
        {
            return None;
        }
        let Some((&seq, p)) = self.pending.iter().next() else {
            return Some(Stall {
                seq: None,
                route: None,
                held_by: Some(ServiceKind::CameraReader),
                stage: "waiting for the source",
            });
        };
        let held_by = match p.route {
            // Real time routes nothing before the first segmenter result.
            None if self.mode.is_realtime() => Some(ServiceKind::Segmenter),
            None => None,
            Some(RouteKind::Skip | RouteKind::Refuse) => Some(ServiceKind::Slam),
            Some(_) if p.masks_seen => Some(ServiceKind::Slam),
            Some(RouteKind::Segment) => Some(ServiceKind::Segmenter),
            Some(_) => Some(ServiceKind::Propagator),
        };
        let stage = match held_by {
            Some(ServiceKind::Slam) => "waiting for its Track from slam",
            Some(ServiceKind::Segmenter) => "waiting for its masks from the segmenter",
            Some(ServiceKind::Propagator) => "waiting for its masks from the propagator",
            _ => "waiting for its route",
        };
        Some(Stall {
            seq: Some(seq),
            route: p.route,
            held_by,
            stage,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recorded_frames_keep_a_prefix_and_the_few_ahead_of_it() {
        let mut r = RecordedFrames::from_seqs([0, 1, 2, 5]);
        assert_eq!((r.len(), r.first_missing(), r.newest()), (4, 3, Some(5)));
        assert!(r.contains(1) && r.contains(5) && !r.contains(3) && !r.contains(6));
        assert!(!r.insert(5), "recorded once");
        assert!(r.insert(4) && r.insert(3));
        assert_eq!((r.len(), r.first_missing()), (6, 6));
        assert!(r.ahead.is_empty(), "nothing held once contiguous");
        assert!(r.insert(2_000_000));
        assert_eq!((r.len(), r.newest()), (7, Some(2_000_000)));
    }
}
