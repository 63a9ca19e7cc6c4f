//! A property test over a simulated clock: the whole pipeline's timing
//! rules (reader, supervisor's ledger, workers' queues, SLAM's frame rule)
//! wired as the services wire them, with messages delayed at random (in
//! order per link, as iceoryx2 delivers), random work times, random kills
//! (restarted, or given up on for good) and both clock modes. Whatever
//! happens: every frame is recorded exactly once, no frame waits on a dead
//! worker (the run completes), and lockstep never drops a frame.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::time::{Duration, Instant};

use scheduling::ledger::{Arrival, Input, Ledger};
use scheduling::source::{Backlog, LockstepCursor, Publish, SourceCommand};
use scheduling::tracking::{frame_ready, next_frame};
use scheduling::worker::{Next, WorkQueue};
use scheduling::{Availability, ClockMode, RoutingConfig};
use shared_types::{MaskSource, RouteKind, ServiceKind};

/// Frames a process keeps borrowed (the frames topic's limit).
const HELD: usize = 3;
/// The watchdog's timeout in the simulation.
const STALL: Duration = Duration::from_secs(2);

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
enum Proc {
    Reader,
    Supervisor,
    Segmenter,
    Propagator,
    Slam,
}

impl Proc {
    fn kind(self) -> ServiceKind {
        match self {
            Proc::Reader => ServiceKind::CameraReader,
            Proc::Segmenter => ServiceKind::Segmenter,
            Proc::Propagator => ServiceKind::Propagator,
            Proc::Slam => ServiceKind::Slam,
            Proc::Supervisor => unreachable!("the supervisor is not a service"),
        }
    }
    fn of(kind: ServiceKind) -> Proc {
        match kind {
            ServiceKind::Segmenter => Proc::Segmenter,
            ServiceKind::Propagator => Proc::Propagator,
            ServiceKind::Slam => Proc::Slam,
            _ => Proc::Reader,
        }
    }
}

#[derive(Debug, Clone, Copy)]
enum Msg {
    /// A frame (`left_out`: header only; `end`: the end of the stream).
    Frame {
        seq: u64,
        left_out: bool,
        end: bool,
    },
    Route {
        seq: u64,
        kind: RouteKind,
    },
    Masks {
        seq: u64,
        source: MaskSource,
        gone: bool,
    },
    Track {
        seq: u64,
        keyframe_next: bool,
    },
    Replay(u64),
    ForgetBacklog,
    Ready {
        kind: ServiceKind,
        restart: bool,
    },
}

/// Messages in flight, delivered in order per link after a random delay.
struct Bus {
    rng: fastrand::Rng,
    max_delay_ms: u64,
    queue: BTreeMap<(u64, u64), (Proc, Msg)>,
    last_on_link: HashMap<(Proc, Proc), u64>,
    counter: u64,
}

impl Bus {
    fn send(&mut self, now: u64, from: Proc, to: Proc, msg: Msg) {
        let delay = self.rng.u64(0..=self.max_delay_ms);
        let last = self.last_on_link.get(&(from, to)).copied().unwrap_or(0);
        let at = (now + delay).max(last);
        self.last_on_link.insert((from, to), at);
        self.counter += 1;
        self.queue.insert((at, self.counter), (to, msg));
    }
    fn publish(&mut self, now: u64, from: Proc, to: &[Proc], msg: Msg) {
        for &p in to {
            self.send(now, from, p, msg);
        }
    }
    fn due(&mut self, now: u64) -> Vec<(Proc, Msg)> {
        let mut out = Vec::new();
        while let Some(entry) = self.queue.first_entry() {
            if entry.key().0 > now {
                break;
            }
            out.push(entry.remove());
        }
        out
    }
}

/// A mask worker process.
struct Worker {
    source: MaskSource,
    queue: WorkQueue<u64>,
    held: VecDeque<u64>,
    busy_until: Option<(u64, u64)>,
    work_ms: (u64, u64),
}

impl Worker {
    fn new(source: MaskSource, mode: ClockMode, work_ms: (u64, u64)) -> Self {
        Self {
            source,
            queue: WorkQueue::new(mode),
            held: VecDeque::new(),
            busy_until: None,
            work_ms,
        }
    }
    fn mine(&self, kind: RouteKind) -> bool {
        match self.source {
            MaskSource::Segmenter => kind.segments(),
            _ => kind.propagates(),
        }
    }
}

/// The SLAM process.
struct Slam {
    mode: ClockMode,
    frames: VecDeque<u64>,
    routes: HashMap<u64, RouteKind>,
    masks: Vec<u64>,
    last: Option<u64>,
    busy_until: Option<(u64, u64)>,
    work_ms: (u64, u64),
}

struct Service {
    alive: bool,
    given_up: bool,
    restarts: u32,
    back_at: Option<u64>,
}

struct Sim {
    mode: ClockMode,
    total: u64,
    bus: Bus,
    rng: fastrand::Rng,
    t0: Instant,
    ledger: Ledger<()>,
    /// Each frame's recorded fates (must end with exactly one each).
    fates: HashMap<u64, Vec<String>>,
    reader_cursor: LockstepCursor,
    backlog: Backlog,
    next_due: u64,
    end_sent: bool,
    seg: Worker,
    prop: Worker,
    slam: Slam,
    services: BTreeMap<Proc, Service>,
    kills: Vec<(u64, Proc, bool)>,
}

const FRAME_PATH: [Proc; 4] = [
    Proc::Supervisor,
    Proc::Segmenter,
    Proc::Propagator,
    Proc::Slam,
];

impl Sim {
    fn new(seed: u64) -> Self {
        let mut rng = fastrand::Rng::with_seed(seed);
        let mode = if rng.bool() {
            ClockMode::Lockstep
        } else {
            ClockMode::Realtime
        };
        let total = rng.u64(10..50);
        let span = total * 40;
        let mut kills: Vec<(u64, Proc, bool)> = (0..rng.usize(0..5))
            .map(|_| {
                let p = [Proc::Segmenter, Proc::Propagator, Proc::Slam][rng.usize(0..3)];
                let for_good = p != Proc::Slam && rng.u8(0..10) < 3;
                (rng.u64(0..span), p, for_good)
            })
            .collect();
        kills.sort_by_key(|k| std::cmp::Reverse(k.0));
        let t0 = Instant::now();
        let services = [Proc::Reader, Proc::Segmenter, Proc::Propagator, Proc::Slam]
            .into_iter()
            .map(|p| {
                let s = Service {
                    alive: true,
                    given_up: false,
                    restarts: 0,
                    back_at: None,
                };
                (p, s)
            })
            .collect();
        let seg_ms = (rng.u64(5..40), rng.u64(40..150));
        let prop_ms = (rng.u64(1..10), rng.u64(10..40));
        let slam_ms = (rng.u64(1..10), rng.u64(10..40));
        Sim {
            mode,
            total,
            bus: Bus {
                rng: fastrand::Rng::with_seed(seed ^ 0x5eed),
                max_delay_ms: rng.u64(0..20),
                queue: BTreeMap::new(),
                last_on_link: HashMap::new(),
                counter: 0,
            },
            rng,
            t0,
            ledger: Ledger::new(mode, RoutingConfig::default(), [], t0),
            fates: HashMap::new(),
            reader_cursor: LockstepCursor::new(0, total),
            backlog: Backlog::default(),
            next_due: 0,
            end_sent: false,
            seg: Worker::new(MaskSource::Segmenter, mode, seg_ms),
            prop: Worker::new(MaskSource::Propagator, mode, prop_ms),
            slam: Slam {
                mode,
                frames: VecDeque::new(),
                routes: HashMap::new(),
                masks: Vec::new(),
                last: None,
                busy_until: None,
                work_ms: slam_ms,
            },
            services,
            kills,
        }
    }

    fn instant(&self, now: u64) -> Instant {
        self.t0 + Duration::from_millis(now)
    }

    fn alive(&self, p: Proc) -> bool {
        p == Proc::Supervisor || self.services[&p].alive
    }

    fn fate(&mut self, seq: u64, what: &str) {
        self.fates.entry(seq).or_default().push(what.to_string());
    }

    fn availability(&self) -> Availability {
        Availability {
            segmenter: !self.services[&Proc::Segmenter].given_up,
            propagator: !self.services[&Proc::Propagator].given_up,
        }
    }

    fn publish_frame(&mut self, now: u64, seq: u64, left_out: bool) {
        let end = seq >= self.total;
        let msg = Msg::Frame { seq, left_out, end };
        self.bus.publish(now, Proc::Reader, &FRAME_PATH, msg);
    }

    fn kill(&mut self, now: u64, p: Proc, for_good: bool) {
        let svc = self.services.get_mut(&p).expect("a service");
        if !svc.alive {
            return;
        }
        svc.alive = false;
        svc.given_up = for_good;
        svc.back_at = (!for_good).then(|| now + 50 + now % 250);
        match p {
            Proc::Segmenter => {
                self.seg = Worker::new(MaskSource::Segmenter, self.mode, self.seg.work_ms)
            }
            Proc::Propagator => {
                self.prop = Worker::new(MaskSource::Propagator, self.mode, self.prop.work_ms)
            }
            Proc::Slam => {
                self.slam.frames.clear();
                self.slam.routes.clear();
                self.slam.masks.clear();
                self.slam.last = None;
                self.slam.busy_until = None;
            }
            _ => {}
        }
        // The supervisor sees the death at once (its watch period aside).
        self.ledger.on_worker_lost();
        for (r, _) in self.ledger.reroute_orphans(self.availability()) {
            self.bus.publish(
                now,
                Proc::Supervisor,
                &[Proc::Segmenter, Proc::Propagator, Proc::Slam],
                Msg::Route {
                    seq: r.seq,
                    kind: r.kind,
                },
            );
        }
    }

    fn step_services_lifecycle(&mut self, now: u64) {
        while self.kills.last().is_some_and(|k| k.0 <= now) {
            let (_, p, for_good) = self.kills.pop().expect("a kill");
            self.kill(now, p, for_good);
        }
        for p in [Proc::Segmenter, Proc::Propagator, Proc::Slam] {
            let svc = self.services.get_mut(&p).expect("a service");
            if svc.back_at.is_some_and(|t| t <= now) {
                svc.back_at = None;
                svc.alive = true;
                svc.restarts += 1;
                let msg = Msg::Ready {
                    kind: p.kind(),
                    restart: true,
                };
                self.bus.send(now, p, Proc::Supervisor, msg);
            }
        }
    }

    fn step_reader(&mut self, now: u64) {
        if self.mode == ClockMode::Realtime {
            let period = 33;
            while self.next_due < self.total && self.next_due * period <= now {
                let seq = self.next_due;
                let left_out = self.backlog.full(now * 1_000_000);
                if !left_out {
                    self.backlog.published(seq, now * 1_000_000);
                }
                self.publish_frame(now, seq, left_out);
                self.next_due += 1;
            }
            if self.next_due == self.total && !self.end_sent {
                self.end_sent = true;
                self.publish_frame(now, self.total, false);
            }
        }
    }

    fn on_reader(&mut self, now: u64, msg: Msg) {
        match msg {
            Msg::Track { seq, .. } => {
                self.backlog.on_track(seq);
                if self.mode == ClockMode::Lockstep {
                    if let Some(Publish::Next(next)) = self.reader_cursor.on_tracks([seq]) {
                        self.publish_frame(now, next, false);
                    }
                }
            }
            Msg::Replay(seq) if self.mode == ClockMode::Lockstep => {
                if let Some(Publish::Replay(s)) = self.reader_cursor.on_replay(seq) {
                    self.publish_frame(now, s, false);
                }
            }
            Msg::ForgetBacklog => self.backlog.forget(),
            _ => {}
        }
    }

    fn on_supervisor(&mut self, now: u64, msg: Msg) {
        let at = self.instant(now);
        match msg {
            Msg::Frame { seq, end: true, .. } => {
                self.ledger.on_end_of_stream(seq, at);
            }
            Msg::Frame { seq, left_out, .. } => {
                match self.ledger.on_frame(seq, Input::Good, left_out, (), at) {
                    Arrival::Dropped(d) => self.fate(d.seq, &d.why),
                    Arrival::Resend(kind) => self.send_route(now, seq, kind),
                    Arrival::AlreadyRecorded | Arrival::Waiting => {}
                }
            }
            Msg::Track { seq, keyframe_next } => {
                if let Some(t) = self.ledger.on_track(seq, false, keyframe_next, at) {
                    for d in t.dropped {
                        self.fate(d.seq, &d.why);
                    }
                    self.fate(seq, "tracked");
                }
            }
            Msg::Masks { seq, source, gone } => {
                if gone {
                    if let Some(d) = self.ledger.on_masks_gone(seq, source, at) {
                        self.fate(d.seq, &d.why);
                    }
                } else {
                    let wanted = source == MaskSource::Propagator && self.rng.u8(0..20) == 0;
                    self.ledger.on_masks(seq, source, wanted);
                }
            }
            Msg::Ready { kind, restart } => match self.ledger.on_service_ready(kind, restart, at) {
                Some(SourceCommand::Replay(seq)) => {
                    self.bus
                        .send(now, Proc::Supervisor, Proc::Reader, Msg::Replay(seq))
                }
                Some(SourceCommand::ForgetBacklog) => {
                    self.bus
                        .send(now, Proc::Supervisor, Proc::Reader, Msg::ForgetBacklog)
                }
                None => {}
            },
            _ => {}
        }
    }

    fn send_route(&mut self, now: u64, seq: u64, kind: RouteKind) {
        let to = [Proc::Segmenter, Proc::Propagator, Proc::Slam];
        self.bus
            .publish(now, Proc::Supervisor, &to, Msg::Route { seq, kind });
    }

    fn step_supervisor(&mut self, now: u64) {
        let at = self.instant(now);
        for r in self.ledger.route_ready(self.availability(), at) {
            self.send_route(now, r.seq, r.kind);
        }
        for d in self.ledger.on_tick(at) {
            self.fate(d.seq, &d.why);
        }
        let settled = self.services.values().all(|s| s.alive || s.given_up);
        if let Some(stall) = self.ledger.stall(STALL, settled, at) {
            match stall.held_by.map(Proc::of) {
                Some(p) if p != Proc::Reader => {
                    self.kill(now, p, false);
                    self.ledger.note_progress(at);
                }
                _ => panic!("a stall nobody explains: {stall:?} (mode {:?})", self.mode),
            }
        }
    }

    fn on_worker(&mut self, which: Proc, msg: Msg) {
        let w = if which == Proc::Segmenter {
            &mut self.seg
        } else {
            &mut self.prop
        };
        match msg {
            Msg::Frame {
                seq,
                left_out: false,
                end: false,
            } => {
                w.held.retain(|&s| s != seq);
                w.held.push_back(seq);
                while w.held.len() > HELD {
                    w.held.pop_front();
                }
            }
            Msg::Route { seq, kind } if w.mine(kind) => w.queue.on_route(seq, seq),
            _ => {}
        }
    }

    fn step_worker(&mut self, now: u64, which: Proc) {
        let mut out = Vec::new();
        let (w, rng) = if which == Proc::Segmenter {
            (&mut self.seg, &mut self.rng)
        } else {
            (&mut self.prop, &mut self.rng)
        };
        if let Some((until, seq)) = w.busy_until {
            if until > now {
                return;
            }
            w.busy_until = None;
            out.push((seq, false));
        }
        for seq in w.queue.keep_newest() {
            out.push((seq, true));
        }
        loop {
            let held = w.held.clone();
            match w.queue.next(|s| held.contains(&s), held.front().copied()) {
                Next::Work(seq) => {
                    w.busy_until = Some((now + rng.u64(w.work_ms.0..=w.work_ms.1), seq));
                    break;
                }
                Next::PassOver { route, tell_gone } => {
                    if tell_gone {
                        out.push((route, true));
                    }
                }
                Next::Wait => break,
            }
        }
        let source = w.source;
        for (seq, gone) in out {
            let msg = Msg::Masks { seq, source, gone };
            self.bus
                .publish(now, which, &[Proc::Supervisor, Proc::Slam], msg);
        }
    }

    fn on_slam(&mut self, now: u64, msg: Msg) {
        let s = &mut self.slam;
        match msg {
            Msg::Frame {
                seq,
                left_out: false,
                end: false,
            } => {
                if let Some(last) = s.last.filter(|&l| seq <= l) {
                    if seq == last {
                        // A replayed frame: its Track again.
                        let msg = Msg::Track {
                            seq,
                            keyframe_next: false,
                        };
                        self.bus
                            .publish(now, Proc::Slam, &[Proc::Supervisor, Proc::Reader], msg);
                    }
                    return;
                }
                s.frames.retain(|&f| f != seq);
                s.frames.push_back(seq);
                while s.frames.len() > HELD {
                    s.frames.pop_front();
                }
            }
            Msg::Route { seq, kind } => {
                s.routes.insert(seq, kind);
            }
            Msg::Masks {
                seq, gone: false, ..
            } if s.last.is_none_or(|l| seq > l) => s.masks.push(seq),
            _ => {}
        }
    }

    fn step_slam(&mut self, now: u64) {
        let s = &mut self.slam;
        if let Some((until, seq)) = s.busy_until {
            if until > now {
                return;
            }
            s.busy_until = None;
            s.last = Some(seq);
            s.frames.retain(|&f| f > seq);
            s.masks.retain(|&m| m > seq);
            s.routes.retain(|&f, _| f > seq);
            let keyframe_next = self.rng.u8(0..8) == 0;
            let msg = Msg::Track { seq, keyframe_next };
            self.bus
                .publish(now, Proc::Slam, &[Proc::Supervisor, Proc::Reader], msg);
        }
        let s = &mut self.slam;
        let ready: Vec<bool> = s
            .frames
            .iter()
            .map(|f| frame_ready(s.routes.get(f).copied(), s.masks.contains(f)))
            .collect();
        if let Some(i) = next_frame(s.mode, &ready) {
            let seq = s.frames[i];
            s.busy_until = Some((now + self.rng.u64(s.work_ms.0..=s.work_ms.1), seq));
        }
    }

    /// Runs until the ledger has every frame or `limit_ms` passes.
    fn run(&mut self, limit_ms: u64) -> u64 {
        if self.mode == ClockMode::Lockstep {
            self.publish_frame(0, 0, false);
        }
        for now in 0..limit_ms {
            self.step_services_lifecycle(now);
            self.step_reader(now);
            for (to, msg) in self.bus.due(now) {
                if !self.alive(to) {
                    continue; // lost with the dead process
                }
                match to {
                    Proc::Reader => self.on_reader(now, msg),
                    Proc::Supervisor => self.on_supervisor(now, msg),
                    Proc::Segmenter | Proc::Propagator => self.on_worker(to, msg),
                    Proc::Slam => self.on_slam(now, msg),
                }
            }
            self.step_supervisor(now);
            for w in [Proc::Segmenter, Proc::Propagator] {
                if self.alive(w) {
                    self.step_worker(now, w);
                }
            }
            if self.alive(Proc::Slam) {
                self.step_slam(now);
            }
            if self.ledger.complete() {
                return now;
            }
        }
        limit_ms
    }
}

#[test]
fn every_frame_is_recorded_once_no_frame_waits_on_a_dead_worker_and_lockstep_never_drops() {
    let mut by_mode = HashMap::new();
    let (mut restarts, mut given_up, mut dropped) = (0, 0, 0);
    for seed in 0..300u64 {
        let mut sim = Sim::new(seed);
        let limit = sim.total * 1000 + 60_000;
        let ended = sim.run(limit);
        let context = format!(
            "seed {seed}: {:?}, {} frames, delay <= {} ms",
            sim.mode, sim.total, sim.bus.max_delay_ms
        );
        assert!(
            sim.ledger.complete(),
            "{context}: not complete after {limit} ms ({} of {} recorded)",
            sim.ledger.recorded().len(),
            sim.total
        );
        for seq in 0..sim.total {
            let fates = sim.fates.get(&seq).cloned().unwrap_or_default();
            assert_eq!(fates.len(), 1, "{context}: frame {seq}: {fates:?}");
            if sim.mode == ClockMode::Lockstep {
                assert_eq!(fates[0], "tracked", "{context}: frame {seq}");
            }
        }
        assert_eq!(
            sim.fates.len() as u64,
            sim.total,
            "{context}: fates beyond the stream"
        );
        *by_mode.entry(sim.mode).or_insert(0) += 1;
        assert!(ended < limit);
        restarts += sim.services.values().map(|s| s.restarts).sum::<u32>();
        given_up += sim.services.values().filter(|s| s.given_up).count();
        dropped += sim.fates.values().filter(|f| f[0] != "tracked").count();
    }
    // The timelines went through what they are meant to exercise.
    assert!(
        by_mode.values().all(|&n| n > 100),
        "both modes covered: {by_mode:?}"
    );
    assert!(
        restarts > 100 && given_up > 20 && dropped > 500,
        "restarts {restarts}, workers given up {given_up}, frames dropped {dropped}"
    );
}
