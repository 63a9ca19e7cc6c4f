//! Frame timelines as the README and docs/design.md tell them, one table or
//! story per test: what each service decides, step by step, on a simulated
//! clock (no processes, no IPC).

use std::time::{Duration, Instant};

use scheduling::ledger::{why, Arrival, Input, Ledger, Stall, END_OF_STREAM_GRACE};
use scheduling::mode::{segmenter_input_size, unseen_view_share};
use scheduling::source::{
    due_ns, Backlog, LockstepCursor, Publish, SourceCommand, BACKLOG_TIMEOUT_NS,
};
use scheduling::tracking::{
    completes_waiting_keyframe, frame_ready, keyframe_waited_too_long, next_frame, segmenter_alive,
    FlowPace, SEGMENTER_PATIENCE,
};
use scheduling::worker::{Next, WorkQueue};
use scheduling::{Availability, ClockMode, RoutingConfig};
use shared_types::{MaskSource, RouteKind, ServiceKind};

const BOTH: Availability = Availability {
    segmenter: true,
    propagator: true,
};

/// A simulated clock: instants `ms` after a fixed origin.
struct Clock(Instant);

impl Clock {
    fn new() -> Self {
        Clock(Instant::now())
    }
    fn at(&self, ms: u64) -> Instant {
        self.0 + Duration::from_millis(ms)
    }
}

fn ledger(mode: ClockMode, clock: &Clock) -> Ledger<()> {
    Ledger::new(mode, RoutingConfig::default(), [], clock.at(0))
}

fn arrive(l: &mut Ledger<()>, seq: u64, clock: &Clock, ms: u64) -> Arrival<()> {
    l.on_frame(seq, Input::Good, false, (), clock.at(ms))
}

/// The routes decided now, as (seq, kind).
fn routes(l: &mut Ledger<()>, clock: &Clock, ms: u64) -> Vec<(u64, RouteKind)> {
    l.route_ready(BOTH, clock.at(ms))
        .into_iter()
        .map(|r| (r.seq, r.kind))
        .collect()
}

fn track(l: &mut Ledger<()>, seq: u64, keyframe_next: bool, clock: &Clock, ms: u64) -> Vec<u64> {
    l.on_track(seq, false, keyframe_next, clock.at(ms))
        .expect("not recorded before")
        .dropped
        .into_iter()
        .map(|d| d.seq)
        .collect()
}

// ---- the supervisor's ledger, lockstep ----

#[test]
fn lockstep_routes_a_frame_only_after_the_previous_frames_track() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Lockstep, &c);
    assert!(matches!(arrive(&mut l, 0, &c, 0), Arrival::Waiting));
    assert!(matches!(arrive(&mut l, 1, &c, 1), Arrival::Waiting));
    // Frame 1 reached the supervisor before Track 0: it waits.
    assert_eq!(routes(&mut l, &c, 2), [(0, RouteKind::Segment)]);
    assert!(routes(&mut l, &c, 3).is_empty());
    track(&mut l, 0, false, &c, 30);
    assert_eq!(routes(&mut l, &c, 31), [(1, RouteKind::Propagate)]);
}

#[test]
fn lockstep_follows_the_keyframe_flag_of_the_previous_track() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Lockstep, &c);
    let mut kinds = Vec::new();
    // SLAM asks for a keyframe with Track 2: frame 3 is segmented.
    for seq in 0..5u64 {
        arrive(&mut l, seq, &c, seq * 33);
        kinds.extend(routes(&mut l, &c, seq * 33).into_iter().map(|r| r.1));
        track(&mut l, seq, seq == 2, &c, seq * 33 + 20);
    }
    use RouteKind::*;
    assert_eq!(kinds, [Segment, Propagate, Propagate, Segment, Propagate]);
}

#[test]
fn lockstep_segments_again_when_the_last_segment_is_too_old() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Lockstep, &c);
    let age = RoutingConfig::default().max_segment_age;
    let mut segmented = Vec::new();
    for seq in 0..=2 * age + 2 {
        arrive(&mut l, seq, &c, seq);
        for (s, k) in routes(&mut l, &c, seq) {
            if k == RouteKind::Segment {
                segmented.push(s);
            }
        }
        track(&mut l, seq, false, &c, seq);
    }
    assert_eq!(segmented, [0, age + 1, 2 * age + 2]);
}

#[test]
fn lockstep_never_drops_a_frame_when_a_newer_one_is_tracked() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Lockstep, &c);
    arrive(&mut l, 0, &c, 0);
    arrive(&mut l, 1, &c, 0);
    routes(&mut l, &c, 0);
    // A Track out of order (a replay answered late): nothing is dropped.
    let tracked = l.on_track(1, false, false, c.at(5)).unwrap();
    assert!(tracked.dropped.is_empty());
    assert!(l.pending(0).is_some(), "frame 0 still waits for its Track");
    assert!(
        l.on_tick(c.at(10_000)).is_empty(),
        "lockstep waits for every frame"
    );
}

#[test]
fn a_replayed_frame_gets_its_first_route_again() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Lockstep, &c);
    arrive(&mut l, 0, &c, 0);
    routes(&mut l, &c, 0);
    assert!(matches!(
        arrive(&mut l, 0, &c, 500),
        Arrival::Resend(RouteKind::Segment)
    ));
}

#[test]
fn a_frame_seen_again_after_its_track_is_not_recorded_twice() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Lockstep, &c);
    arrive(&mut l, 0, &c, 0);
    routes(&mut l, &c, 0);
    track(&mut l, 0, false, &c, 10);
    assert!(matches!(
        arrive(&mut l, 0, &c, 20),
        Arrival::AlreadyRecorded
    ));
    assert!(l.on_track(0, false, false, c.at(30)).is_none());
    assert_eq!(l.recorded().len(), 1);
}

#[test]
fn a_restarted_frame_path_service_gets_the_first_unrecorded_frame_replayed_in_lockstep() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Lockstep, &c);
    for seq in 0..3 {
        arrive(&mut l, seq, &c, seq);
        routes(&mut l, &c, seq);
        track(&mut l, seq, false, &c, seq);
    }
    arrive(&mut l, 3, &c, 3);
    routes(&mut l, &c, 3);
    for kind in [
        ServiceKind::Segmenter,
        ServiceKind::Propagator,
        ServiceKind::Slam,
    ] {
        assert_eq!(
            l.on_service_ready(kind, true, c.at(100)),
            Some(SourceCommand::Replay(3)),
            "{kind:?}"
        );
        assert_eq!(
            l.on_service_ready(kind, false, c.at(100)),
            None,
            "first start"
        );
    }
    // The reader restarts from the first unrecorded frame by itself, and
    // the bridge is off the frame path.
    assert_eq!(
        l.on_service_ready(ServiceKind::CameraReader, true, c.at(100)),
        None
    );
    assert_eq!(
        l.on_service_ready(ServiceKind::Bridge, true, c.at(100)),
        None
    );
}

#[test]
fn real_time_replays_nothing_after_a_restart_and_a_restarted_slam_clears_the_readers_backlog() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Realtime, &c);
    arrive(&mut l, 0, &c, 0);
    assert_eq!(
        l.on_service_ready(ServiceKind::Slam, true, c.at(100)),
        Some(SourceCommand::ForgetBacklog)
    );
    assert_eq!(
        l.on_service_ready(ServiceKind::Slam, false, c.at(100)),
        None,
        "first start"
    );
    for kind in [
        ServiceKind::Segmenter,
        ServiceKind::Propagator,
        ServiceKind::CameraReader,
        ServiceKind::Bridge,
    ] {
        assert_eq!(l.on_service_ready(kind, true, c.at(100)), None, "{kind:?}");
    }
}

/// A SLAM killed with three frames in the reader's backlog: without the
/// supervisor's word the reader leaves out every frame until the backlog
/// times out (a second of frames without a pose); with it, the next frame
/// is published.
#[test]
fn a_restarted_slam_does_not_leave_the_reader_waiting_for_the_dead_ones_tracks() {
    let ms = 1_000_000;
    let mut b = Backlog::default();
    b.published(0, 0);
    b.on_track(0);
    for seq in 1..=3 {
        b.published(seq, seq * 33 * ms);
    }
    // SLAM killed here; the new one is up 100 ms later.
    assert!(b.full(200 * ms), "three frames in flight: left out");
    assert!(
        b.full(900 * ms),
        "still waiting for the dead process's Tracks"
    );
    let mut told = b.clone();
    told.forget();
    assert!(!told.full(200 * ms), "told: the next frame goes out");
}

#[test]
fn a_completed_run_replays_nothing() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Lockstep, &c);
    arrive(&mut l, 0, &c, 0);
    routes(&mut l, &c, 0);
    track(&mut l, 0, false, &c, 1);
    assert!(l.on_end_of_stream(1, c.at(2)));
    assert!(!l.on_end_of_stream(1, c.at(3)), "said once");
    assert!(l.complete());
    assert_eq!(l.on_service_ready(ServiceKind::Slam, true, c.at(4)), None);
}

#[test]
fn a_bad_frame_goes_unmasked_with_its_reason_and_its_track_says_nothing_of_keyframes() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Lockstep, &c);
    arrive(&mut l, 0, &c, 0);
    routes(&mut l, &c, 0);
    track(&mut l, 0, false, &c, 1);
    l.on_frame(1, Input::Bad("truncated PNG".into()), false, (), c.at(2));
    assert_eq!(routes(&mut l, &c, 2), [(1, RouteKind::Skip)]);
    assert_eq!(l.pending(1).unwrap().note, "bad input: truncated PNG");
    // Skipped: its (meaningless) keyframe flag is not taken.
    l.on_track(1, true, true, c.at(3)).unwrap();
    arrive(&mut l, 2, &c, 4);
    assert_eq!(routes(&mut l, &c, 4), [(2, RouteKind::Propagate)]);
}

#[test]
fn a_refused_external_frame_is_routed_refuse() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Realtime, &c);
    l.on_frame(0, Input::Refused("2 bytes".into()), false, (), c.at(0));
    assert_eq!(routes(&mut l, &c, 0), [(0, RouteKind::Refuse)]);
    assert_eq!(l.pending(0).unwrap().note, "bad input: 2 bytes");
}

#[test]
fn with_no_mask_worker_left_frames_go_unmasked_and_say_so() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Lockstep, &c);
    arrive(&mut l, 0, &c, 0);
    let none = Availability {
        segmenter: false,
        propagator: false,
    };
    let routed = l.route_ready(none, c.at(0));
    assert_eq!(routed[0].kind, RouteKind::Skip);
    assert_eq!(
        l.pending(0).unwrap().note,
        "unmasked: no mask service available"
    );
}

#[test]
fn the_no_masks_ablation_skips_every_frame_without_a_note() {
    let c = Clock::new();
    let routing = RoutingConfig {
        no_masks: true,
        ..RoutingConfig::default()
    };
    let mut l: Ledger<()> = Ledger::new(ClockMode::Lockstep, routing, [], c.at(0));
    arrive(&mut l, 0, &c, 0);
    assert_eq!(routes(&mut l, &c, 0), [(0, RouteKind::Skip)]);
    assert_eq!(l.pending(0).unwrap().note, "");
}

#[test]
fn frames_routed_to_a_worker_given_up_on_go_on_unmasked() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Lockstep, &c);
    arrive(&mut l, 0, &c, 0);
    routes(&mut l, &c, 0); // Segment
    let no_segmenter = Availability {
        segmenter: false,
        propagator: true,
    };
    let orphans = l.reroute_orphans(no_segmenter);
    assert_eq!(orphans.len(), 1);
    assert_eq!((orphans[0].0.seq, orphans[0].0.kind), (0, RouteKind::Skip));
    assert_eq!(orphans[0].1, "segmenter");
    assert!(l
        .pending(0)
        .unwrap()
        .note
        .contains("segmenter was given up on"));
    // Already re-routed: not again.
    assert!(l.reroute_orphans(no_segmenter).is_empty());
}

#[test]
fn a_propagated_frame_is_re_routed_when_the_propagator_is_given_up_on() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Lockstep, &c);
    arrive(&mut l, 0, &c, 0);
    routes(&mut l, &c, 0);
    track(&mut l, 0, false, &c, 1);
    arrive(&mut l, 1, &c, 2);
    assert_eq!(routes(&mut l, &c, 2), [(1, RouteKind::Propagate)]);
    let no_propagator = Availability {
        segmenter: true,
        propagator: false,
    };
    assert!(l.reroute_orphans(BOTH).is_empty());
    let orphans = l.reroute_orphans(no_propagator);
    assert_eq!(orphans[0].1, "propagator");
}

#[test]
fn a_frame_left_out_at_the_source_is_recorded_dropped_in_either_mode() {
    for mode in [ClockMode::Lockstep, ClockMode::Realtime] {
        let c = Clock::new();
        let mut l = ledger(mode, &c);
        match l.on_frame(4, Input::Good, true, (), c.at(0)) {
            Arrival::Dropped(d) => assert_eq!(d.why, why::LEFT_OUT_AT_SOURCE),
            other => panic!("{mode:?}: {other:?}"),
        }
        assert!(l.recorded().contains(4));
    }
}

// ---- the supervisor's ledger, real time ----

#[test]
fn real_time_waits_for_the_first_segmenter_result_then_propagates() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Realtime, &c);
    arrive(&mut l, 0, &c, 0);
    assert_eq!(routes(&mut l, &c, 0), [(0, RouteKind::Segment)]);
    arrive(&mut l, 1, &c, 33);
    arrive(&mut l, 2, &c, 66);
    assert!(
        routes(&mut l, &c, 66).is_empty(),
        "nothing to propagate yet"
    );
    l.on_masks(0, MaskSource::Segmenter, false);
    // The newest first: frame 2 (frame 1 is passed over), propagated, and
    // segmented behind: SLAM has not yet answered that it has a keyframe.
    assert_eq!(routes(&mut l, &c, 70), [(2, RouteKind::SegmentBehind)]);
    l.on_track(2, false, false, c.at(90)).unwrap();
    arrive(&mut l, 3, &c, 99);
    assert_eq!(routes(&mut l, &c, 99), [(3, RouteKind::Propagate)]);
}

#[test]
fn real_time_routes_the_newest_frames_first_and_at_most_two_in_flight() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Realtime, &c);
    arrive(&mut l, 0, &c, 0);
    routes(&mut l, &c, 0);
    l.on_masks(0, MaskSource::Segmenter, false);
    track(&mut l, 0, false, &c, 10);
    for seq in 1..=4 {
        arrive(&mut l, seq, &c, 10 + seq);
    }
    let r = routes(&mut l, &c, 20);
    assert_eq!(r, [(4, RouteKind::Propagate), (3, RouteKind::Propagate)]);
    assert!(routes(&mut l, &c, 21).is_empty(), "two in flight");
    // Track 4 drops the older frames and frees both places.
    let dropped = track(&mut l, 4, false, &c, 40);
    assert_eq!(dropped, [1, 2, 3]);
}

#[test]
fn a_route_older_than_the_flight_timeout_no_longer_holds_a_place() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Realtime, &c);
    arrive(&mut l, 0, &c, 0);
    routes(&mut l, &c, 0);
    l.on_masks(0, MaskSource::Segmenter, false);
    track(&mut l, 0, false, &c, 1);
    arrive(&mut l, 1, &c, 2);
    arrive(&mut l, 2, &c, 3);
    assert_eq!(routes(&mut l, &c, 3).len(), 2);
    arrive(&mut l, 3, &c, 100);
    assert!(routes(&mut l, &c, 299).is_empty());
    assert_eq!(routes(&mut l, &c, 304), [(3, RouteKind::Propagate)]);
}

/// The frames routed to a SLAM that died never reach its successor: once
/// the new one is up they hold no place, and the next frame is routed at
/// once instead of after the flight timeout (300 ms: 9 frames at 30 fps).
#[test]
fn a_restarted_slam_frees_the_places_of_the_frames_routed_before_it() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Realtime, &c);
    arrive(&mut l, 0, &c, 0);
    routes(&mut l, &c, 0);
    l.on_masks(0, MaskSource::Segmenter, false);
    track(&mut l, 0, false, &c, 1);
    arrive(&mut l, 1, &c, 2);
    arrive(&mut l, 2, &c, 3);
    assert_eq!(routes(&mut l, &c, 3).len(), 2);
    // SLAM killed with frames 1 and 2 in flight; up again at 60 ms.
    arrive(&mut l, 3, &c, 40);
    assert!(routes(&mut l, &c, 40).is_empty(), "two in flight");
    assert_eq!(
        l.on_service_ready(ServiceKind::Slam, true, c.at(60)),
        Some(SourceCommand::ForgetBacklog)
    );
    assert_eq!(routes(&mut l, &c, 60), [(3, RouteKind::Propagate)]);
    assert_eq!(track(&mut l, 3, false, &c, 90), [1, 2]);
}

/// A promoted standby tracks from the frame after the newest answered one
/// (a duplicate or skipped answer counts: SLAM answered it), and the reader
/// is told as after a SLAM restart.
#[test]
fn a_promoted_standby_tracks_after_the_newest_answered_frame() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Realtime, &c);
    let p = l.on_slam_promoted(c.at(0));
    assert_eq!(p.from, 0, "nothing answered yet");
    arrive(&mut l, 0, &c, 0);
    routes(&mut l, &c, 0);
    l.on_masks(0, MaskSource::Segmenter, false);
    track(&mut l, 0, false, &c, 1);
    arrive(&mut l, 1, &c, 2);
    arrive(&mut l, 2, &c, 3);
    routes(&mut l, &c, 3);
    l.on_track(2, true, false, c.at(4)).unwrap();
    let p = l.on_slam_promoted(c.at(5));
    assert_eq!(p.from, 3);
    assert_eq!(p.reader, Some(SourceCommand::ForgetBacklog));
    let mut lockstep = ledger(ClockMode::Lockstep, &c);
    arrive(&mut lockstep, 0, &c, 0);
    routes(&mut lockstep, &c, 0);
    let p = lockstep.on_slam_promoted(c.at(1));
    assert_eq!((p.from, p.reader), (0, Some(SourceCommand::Replay(0))));
}

#[test]
fn a_frame_reaching_the_supervisor_after_a_newer_track_is_dropped_in_real_time() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Realtime, &c);
    arrive(&mut l, 5, &c, 0);
    routes(&mut l, &c, 0);
    track(&mut l, 5, false, &c, 10);
    match arrive(&mut l, 3, &c, 20) {
        Arrival::Dropped(d) => assert_eq!(d.why, why::NEWER_TRACKED),
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_frame_replaced_in_a_worker_is_dropped_and_frees_its_place() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Realtime, &c);
    arrive(&mut l, 0, &c, 0);
    routes(&mut l, &c, 0);
    l.on_masks(0, MaskSource::Segmenter, false);
    track(&mut l, 0, false, &c, 1);
    arrive(&mut l, 1, &c, 2);
    arrive(&mut l, 2, &c, 3);
    routes(&mut l, &c, 3);
    let d = l.on_masks_gone(1, MaskSource::Propagator, c.at(4)).unwrap();
    assert_eq!(d.why, why::REPLACED_IN_PROPAGATOR);
    // The segmenter telling "gone" for a propagated frame changes nothing.
    assert!(l.on_masks_gone(2, MaskSource::Segmenter, c.at(5)).is_none());
    arrive(&mut l, 3, &c, 6);
    assert_eq!(routes(&mut l, &c, 6), [(3, RouteKind::Propagate)]);
}

#[test]
fn a_background_segment_replaced_in_the_segmenter_frees_it_without_dropping_the_frame() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Realtime, &c);
    arrive(&mut l, 0, &c, 0);
    routes(&mut l, &c, 0);
    l.on_masks(0, MaskSource::Segmenter, false);
    track(&mut l, 0, true, &c, 1); // SLAM wants a keyframe
    arrive(&mut l, 1, &c, 2);
    assert_eq!(routes(&mut l, &c, 2), [(1, RouteKind::SegmentBehind)]);
    // The propagator still masks frame 1: not dropped; the segmenter is free.
    assert!(l.on_masks_gone(1, MaskSource::Segmenter, c.at(3)).is_none());
    track(&mut l, 1, true, &c, 4);
    arrive(&mut l, 2, &c, 5);
    assert_eq!(routes(&mut l, &c, 5), [(2, RouteKind::SegmentBehind)]);
}

#[test]
fn a_propagator_request_segments_the_next_frame_in_lockstep_and_says_why() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Lockstep, &c);
    arrive(&mut l, 0, &c, 0);
    routes(&mut l, &c, 0);
    track(&mut l, 0, false, &c, 1);
    arrive(&mut l, 1, &c, 2);
    routes(&mut l, &c, 2);
    l.on_masks(1, MaskSource::Propagator, true);
    track(&mut l, 1, false, &c, 3);
    arrive(&mut l, 2, &c, 4);
    assert_eq!(routes(&mut l, &c, 4), [(2, RouteKind::Segment)]);
    assert!(l.pending(2).unwrap().note.starts_with("segmented early"));
    assert_eq!(l.router().requests(), (1, 1));
}

#[test]
fn real_time_drops_what_is_left_only_after_the_end_of_stream_grace() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Realtime, &c);
    arrive(&mut l, 0, &c, 0);
    routes(&mut l, &c, 0);
    track(&mut l, 0, false, &c, 10);
    arrive(&mut l, 1, &c, 33);
    l.on_end_of_stream(3, c.at(66));
    assert!(l.on_tick(c.at(66 + 1000)).is_empty());
    let grace = END_OF_STREAM_GRACE.as_millis() as u64;
    let dropped = l.on_tick(c.at(66 + grace + 1));
    let seqs: Vec<u64> = dropped.iter().map(|d| d.seq).collect();
    assert_eq!(seqs, [1, 2], "frame 2 never reached the supervisor");
    assert!(dropped.iter().all(|d| d.why == why::END_OF_STREAM));
    assert!(dropped[1].frame.is_none());
    assert!(l.complete());
}

#[test]
fn a_resumed_run_goes_on_after_its_recorded_frames() {
    let c = Clock::new();
    let mut l: Ledger<()> = Ledger::new(
        ClockMode::Lockstep,
        RoutingConfig::default(),
        0..10,
        c.at(0),
    );
    l.resume(false, Some(8));
    assert_eq!(l.next_seq(), 10);
    assert!(matches!(arrive(&mut l, 9, &c, 1), Arrival::AlreadyRecorded));
    arrive(&mut l, 10, &c, 2);
    assert_eq!(routes(&mut l, &c, 2), [(10, RouteKind::Propagate)]);
}

// ---- the watchdog ----

#[test]
fn the_watchdog_names_the_stage_that_holds_the_oldest_frame() {
    let c = Clock::new();
    let t = Duration::from_secs(10);
    let mut l = ledger(ClockMode::Lockstep, &c);
    assert_eq!(
        l.stall(t, true, c.at(10_001)).map(|s| s.held_by),
        Some(Some(ServiceKind::CameraReader)),
        "no frame at all: the source"
    );
    arrive(&mut l, 0, &c, 0);
    assert_eq!(l.stall(t, true, c.at(9_999)), None, "not yet");
    assert_eq!(
        l.stall(t, false, c.at(10_001)),
        None,
        "a service is starting"
    );
    assert_eq!(l.stall(Duration::ZERO, true, c.at(99_999)), None, "off");
    let unrouted = l.stall(t, true, c.at(10_001)).unwrap();
    assert_eq!(unrouted.held_by, None, "lockstep: nobody explains it");
    routes(&mut l, &c, 0);
    let at_segmenter = l.stall(t, true, c.at(10_001)).unwrap();
    assert_eq!(
        at_segmenter,
        Stall {
            seq: Some(0),
            route: Some(RouteKind::Segment),
            held_by: Some(ServiceKind::Segmenter),
            stage: "waiting for its masks from the segmenter",
        }
    );
    l.on_masks(0, MaskSource::Segmenter, false);
    let at_slam = l.stall(t, true, c.at(10_001)).unwrap();
    assert_eq!(at_slam.held_by, Some(ServiceKind::Slam));
    l.note_progress(c.at(10_001));
    assert_eq!(l.stall(t, true, c.at(15_000)), None, "progress resets it");
}

#[test]
fn the_real_time_watchdog_blames_the_segmenter_for_an_unrouted_first_frame() {
    let c = Clock::new();
    let mut l = ledger(ClockMode::Realtime, &c);
    arrive(&mut l, 0, &c, 0);
    routes(&mut l, &c, 0);
    arrive(&mut l, 1, &c, 1);
    let s = l.stall(Duration::from_secs(1), true, c.at(2000)).unwrap();
    assert_eq!((s.seq, s.held_by), (Some(0), Some(ServiceKind::Segmenter)));
}

// ---- the camera-reader ----

#[test]
fn the_reader_leaves_nothing_out_until_slam_answers() {
    let mut b = Backlog::default();
    for seq in 0..10 {
        assert!(!b.full(seq * 1000));
        b.published(seq, seq * 1000);
    }
}

#[test]
fn the_reader_leaves_a_frame_out_with_three_decoded_frames_ahead_of_slam() {
    let mut b = Backlog::default();
    b.on_track(0);
    for seq in 1..=3 {
        assert!(!b.full(seq), "frame {seq}");
        b.published(seq, seq);
    }
    assert!(b.full(4), "frames 1-3 wait for SLAM");
    b.on_track(1);
    assert!(!b.full(5), "a Track makes room");
}

#[test]
fn a_decoded_frame_lost_on_the_way_stops_counting_after_a_second() {
    let mut b = Backlog::default();
    b.on_track(0);
    for seq in 1..=3 {
        b.published(seq, 0);
    }
    assert!(b.full(BACKLOG_TIMEOUT_NS - 1));
    assert!(!b.full(BACKLOG_TIMEOUT_NS));
}

#[test]
fn real_time_frames_are_due_at_their_recorded_instant_scaled_by_speed() {
    assert_eq!(due_ns(1_000, 10.0, 10.5, 1.0), 1_000 + 500_000_000);
    assert_eq!(due_ns(1_000, 10.0, 10.5, 2.0), 1_000 + 250_000_000);
    assert_eq!(due_ns(7, 3.0, 3.0, 1.0), 7);
}

#[test]
fn the_lockstep_reader_moves_on_only_when_its_frame_is_tracked() {
    let mut r = LockstepCursor::new(0, 3);
    assert_eq!(r.current(), 0);
    assert_eq!(r.on_tracks([]), None);
    assert_eq!(r.on_replay(0), Some(Publish::Replay(0)));
    assert_eq!(r.on_replay(5), None, "only the frame in flight is replayed");
    assert_eq!(r.on_tracks([0]), Some(Publish::Next(1)));
    assert_eq!(r.on_tracks([0]), None, "an old Track again");
    assert_eq!(r.on_tracks([1]), Some(Publish::Next(2)));
    assert_eq!(r.on_tracks([2]), Some(Publish::Next(3)), "3: the end");
    assert_eq!(r.on_tracks([3]), None);
    assert_eq!(
        LockstepCursor::new(9, 3).current(),
        3,
        "resumed past the end"
    );
}

// ---- the mask workers ----

#[test]
fn a_lockstep_worker_works_every_route_in_order() {
    let mut q = WorkQueue::new(ClockMode::Lockstep);
    q.on_route(1, "r1");
    q.on_route(2, "r2");
    assert!(q.keep_newest().is_empty());
    assert_eq!(q.next(|s| s <= 2, Some(1)), Next::Work("r1"));
    assert_eq!(q.next(|s| s <= 2, Some(1)), Next::Work("r2"));
    assert_eq!(q.next(|_| true, Some(1)), Next::Wait, "empty");
}

#[test]
fn a_real_time_worker_keeps_the_newest_route_and_tells_the_others_gone() {
    let mut q = WorkQueue::new(ClockMode::Realtime);
    for seq in 1..=3 {
        q.on_route(seq, seq);
    }
    assert_eq!(q.keep_newest(), [1, 2]);
    assert_eq!(q.len(), 1);
    assert_eq!(q.next(|s| s == 3, Some(3)), Next::Work(3));
}

#[test]
fn a_worker_passes_over_a_frame_it_no_longer_holds_and_waits_for_one_to_come() {
    let mut q = WorkQueue::new(ClockMode::Realtime);
    q.on_route(5, 5);
    // Frame 5 not held, only newer ones: replaced, told gone.
    assert_eq!(
        q.next(|s| s >= 7, Some(7)),
        Next::PassOver {
            route: 5,
            tell_gone: true
        }
    );
    q.on_route(9, 9);
    assert_eq!(q.next(|s| s == 7, Some(7)), Next::Wait, "not arrived yet");
    let mut lockstep = WorkQueue::new(ClockMode::Lockstep);
    lockstep.on_route(5, 5);
    assert_eq!(
        lockstep.next(|_| false, Some(7)),
        Next::PassOver {
            route: 5,
            tell_gone: false
        }
    );
}

#[test]
fn a_second_route_for_a_frame_replaces_the_first() {
    let mut q = WorkQueue::new(ClockMode::Lockstep);
    q.on_route(4, RouteKind::Segment);
    q.on_route(4, RouteKind::Skip);
    assert_eq!(q.len(), 1);
    assert_eq!(q.next(|_| true, Some(4)), Next::Work(RouteKind::Skip));
}

// ---- the SLAM ----

#[test]
fn slam_tracks_a_frame_once_routed_and_with_its_masks_unless_routed_without() {
    use RouteKind::*;
    let table = [
        (None, false, false),
        (None, true, false),
        (Some(Skip), false, true),
        (Some(Refuse), false, true),
        (Some(Segment), false, false),
        (Some(Segment), true, true),
        (Some(Propagate), false, false),
        (Some(SegmentBehind), true, true),
    ];
    for (route, masks, ready) in table {
        assert_eq!(frame_ready(route, masks), ready, "{route:?} masks {masks}");
    }
}

#[test]
fn slam_tracks_the_oldest_ready_frame_in_lockstep_and_the_newest_in_real_time() {
    let ready = [false, true, false, true, false];
    assert_eq!(next_frame(ClockMode::Lockstep, &ready), Some(1));
    assert_eq!(next_frame(ClockMode::Realtime, &ready), Some(3));
    assert_eq!(next_frame(ClockMode::Realtime, &[false, false]), None);
}

#[test]
fn a_real_time_pipeline_that_drops_frames_follows_by_flow_until_it_keeps_up_again() {
    use ClockMode::{Lockstep, Realtime};
    let mut pace = FlowPace::default();
    assert!(!pace.behind(Realtime), "nothing measured yet");
    pace.tracked(0);
    assert!(!pace.behind(Realtime), "one frame tells nothing");
    // 60 fps on a loaded machine: every other frame dropped.
    for seq in (2..20).step_by(2) {
        pace.tracked(seq);
        assert!(pace.behind(Realtime), "frame {seq}");
        assert!(!pace.behind(Lockstep), "lockstep never follows");
    }
    // Now every frame: behind for a few more frames, then keeping up.
    let mut frames_until_keeping_up = None;
    for seq in 19..60 {
        pace.tracked(seq);
        if !pace.behind(Realtime) {
            frames_until_keeping_up = Some(seq - 18);
            break;
        }
    }
    assert!(
        matches!(frames_until_keeping_up, Some(n) if (5..=30).contains(&n)),
        "{frames_until_keeping_up:?}"
    );
    // 30 fps with a frame dropped now and then (1 in 30, as with two busy
    // processes): keeping up, every frame extracted.
    let mut pace = FlowPace::default();
    let mut seq = 0;
    for k in 0..300 {
        seq += if k % 30 == 29 { 2 } else { 1 };
        pace.tracked(seq);
        assert!(!pace.behind(Realtime), "frame {seq}");
    }
    // A burst of drops (a busy second) is behind at once.
    for _ in 0..3 {
        seq += 3;
        pace.tracked(seq);
    }
    assert!(pace.behind(Realtime));
}

#[test]
fn a_keyframe_waits_for_its_segmenter_masks_at_most_the_patience() {
    assert!(completes_waiting_keyframe(10, 10));
    assert!(completes_waiting_keyframe(10, 12), "a newer frame's masks");
    assert!(!completes_waiting_keyframe(10, 9));
    assert!(!keyframe_waited_too_long(10, 10 + SEGMENTER_PATIENCE));
    assert!(keyframe_waited_too_long(10, 11 + SEGMENTER_PATIENCE));
    assert!(segmenter_alive(70, Some(10)));
    assert!(!segmenter_alive(71, Some(10)));
    assert!(!segmenter_alive(0, None), "no answer yet");
}

// ---- the per-mode defaults ----

#[test]
fn each_mode_has_its_defaults() {
    assert_eq!(segmenter_input_size(ClockMode::Lockstep), 480);
    assert_eq!(segmenter_input_size(ClockMode::Realtime), 320);
    assert_eq!(unseen_view_share(ClockMode::Lockstep, 0.2), 0.2);
    assert_eq!(unseen_view_share(ClockMode::Realtime, 0.2), 0.0);
}
