//! The routing rule (DESIGN section 3): which worker makes a frame's masks.
//!
//! Lockstep: a frame goes to the segmenter when SLAM asked for a keyframe
//! with its previous Track, when the propagator asked for one (something
//! moves that it does not follow: `early_segment_requests`), when no
//! segmenter masks exist yet, or when the newest segmenter run is older than
//! `max_segment_age` frames; otherwise to the propagator. SLAM waits for a
//! segmented frame's masks.
//!
//! Real time: tracking never waits for the segmenter (the design of the
//! CPU-real-time dynamic SLAMs such as NGD-SLAM). Every frame is masked by
//! the propagator; when a segment is wanted (the same four reasons) and the
//! segmenter is idle, the frame is also segmented in the background
//! (`SegmentBehind`): at most one frame is at the segmenter at a time, and its
//! result re-prompts the propagator, which carries it forward to the frame of
//! the moment. Only the very first frames wait, for the first segmenter
//! result (there is nothing to propagate before it).
//!
//! Workers that were given up on are routed around; with none left the frame
//! goes on unmasked (Skip).

use serde::{Deserialize, Serialize};
use shared_types::RouteKind;

/// `[routing]` of the pipeline configuration.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RoutingConfig {
    /// Send a frame to the segmenter when the newest segmenter masks are more
    /// than this many frames old, whatever SLAM's keyframe flag says.
    pub max_segment_age: u64,
    /// Segment every frame (ablation: no propagation).
    pub segment_every_frame: bool,
    /// Run without any masks: every frame is routed Skip (ablation).
    pub no_masks: bool,
    /// The propagator asks for a segmenter run when something moves outside
    /// the objects it follows (a person walking in after the keyframe); the
    /// next frame is then routed to the segmenter (at most one request per
    /// 5 frames). Off: newcomers wait for `max_segment_age`.
    pub early_segment_requests: bool,
    /// With `early_segment_requests`: the propagator also asks once the
    /// camera has turned by this share of the image width (or height) since
    /// the segmenter last saw the view, for whoever the turn brought into
    /// view (they show no motion of their own to ask with). 0: never.
    pub unseen_view_share: f32,
}

impl Default for RoutingConfig {
    fn default() -> Self {
        Self {
            max_segment_age: 10,
            segment_every_frame: false,
            no_masks: false,
            early_segment_requests: true,
            unseen_view_share: 0.2,
        }
    }
}

/// The routing rule's state (see the module docs).
#[derive(Debug, Clone)]
pub struct Router {
    policy: RoutingConfig,
    /// Real time: segment in the background (see the module docs).
    background: bool,
    /// SLAM's keyframe flag from the latest Track.
    next_needs_keyframe: bool,
    /// The propagator asked for a segmenter run (until one is routed).
    segment_wanted: bool,
    /// Propagator requests taken, and those that made a frame's route.
    requests: u64,
    requests_routed: u64,
    /// The last route decided was a segment for a propagator request only.
    last_was_request: bool,
    /// Newest frame routed to the segmenter.
    last_segment: Option<u64>,
    /// Real time: the frame at the segmenter now, if any.
    segmenting: Option<u64>,
    /// Real time: a segmenter result has arrived (the propagator has a prompt).
    prompted: bool,
}

/// Which workers can still take frames (a worker that is restarting counts
/// as available: lockstep waits for it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Availability {
    /// The segmenter is not given up on.
    pub segmenter: bool,
    /// The propagator is not given up on.
    pub propagator: bool,
}

impl Router {
    /// The lockstep rule.
    pub fn new(policy: RoutingConfig) -> Self {
        Self {
            policy,
            background: false,
            next_needs_keyframe: true,
            segment_wanted: false,
            requests: 0,
            requests_routed: 0,
            last_was_request: false,
            last_segment: None,
            segmenting: None,
            prompted: false,
        }
    }

    /// The real-time rule: the segmenter runs behind the frame path.
    pub fn realtime(policy: RoutingConfig) -> Self {
        Self {
            background: true,
            ..Self::new(policy)
        }
    }

    /// Restores the state of a resumed run.
    pub fn resume(&mut self, next_needs_keyframe: bool, last_segment: Option<u64>) {
        self.next_needs_keyframe = next_needs_keyframe;
        self.last_segment = last_segment;
    }

    /// Takes SLAM's flag from a Track.
    pub fn on_track(&mut self, next_needs_keyframe: bool) {
        self.next_needs_keyframe = next_needs_keyframe;
    }

    /// The propagator asked for a segmenter run (its masks carried
    /// `SEGMENT_WANTED`): the next frame that can be is segmented.
    pub fn on_segment_wanted(&mut self) {
        if self.policy.early_segment_requests {
            self.requests += 1;
            self.segment_wanted = true;
        }
    }

    /// Propagator requests taken, and how many of them had a frame
    /// segmented for them (others were met by a segment wanted anyway).
    pub fn requests(&self) -> (u64, u64) {
        (self.requests, self.requests_routed)
    }

    /// Whether the route just decided segments a frame only because the
    /// propagator asked (for the frame's note).
    pub fn last_was_request(&self) -> bool {
        self.last_was_request
    }

    /// A segmenter result for frame `seq` was published: the segmenter is
    /// free again and the propagator has a prompt.
    pub fn on_segmenter_result(&mut self, seq: u64) {
        if self.segmenting.is_some_and(|s| s <= seq) {
            self.segmenting = None;
        }
        self.prompted = true;
    }

    /// The segmenter will not answer for `seq` (its frame was replaced
    /// before its turn): it is free again, with no new prompt.
    pub fn on_segment_gone(&mut self, seq: u64) {
        if self.segmenting.is_some_and(|s| s <= seq) {
            self.segmenting = None;
        }
    }

    /// A worker died: the frame it was segmenting will not come back.
    pub fn on_worker_lost(&mut self) {
        self.segmenting = None;
    }

    /// Frames after which a background segment that never answered (its
    /// frame was replaced before the segmenter's turn) is given up.
    fn segment_timeout(&self) -> u64 {
        (4 * self.policy.max_segment_age).max(60)
    }

    /// Decides the route of frame `seq` and remembers it; `None` (real time
    /// only): not yet, the first segmenter result is still on its way.
    pub fn route(&mut self, seq: u64, bad_input: bool, workers: Availability) -> Option<RouteKind> {
        self.last_was_request = false;
        if bad_input || self.policy.no_masks {
            return Some(RouteKind::Skip);
        }
        let stale = self
            .last_segment
            .is_none_or(|last| seq.saturating_sub(last) > self.policy.max_segment_age);
        let wanted_anyway = self.policy.segment_every_frame || self.next_needs_keyframe || stale;
        let want_segment = wanted_anyway || self.segment_wanted;
        let route = if self.background {
            self.route_behind(seq, want_segment, workers)
        } else {
            Some(self.route_lockstep(seq, want_segment, workers))
        };
        if route.is_some_and(|r| r.segments()) && self.segment_wanted {
            self.segment_wanted = false;
            if !wanted_anyway {
                self.requests_routed += 1;
                self.last_was_request = true;
            }
        }
        route
    }

    fn route_lockstep(&mut self, seq: u64, want_segment: bool, workers: Availability) -> RouteKind {
        let kind = if want_segment && workers.segmenter {
            RouteKind::Segment
        } else if workers.propagator && self.last_segment.is_some() {
            RouteKind::Propagate
        } else if workers.segmenter {
            RouteKind::Segment
        } else {
            RouteKind::Skip
        };
        if kind == RouteKind::Segment {
            self.last_segment = Some(seq);
        }
        kind
    }

    fn route_behind(
        &mut self,
        seq: u64,
        want_segment: bool,
        workers: Availability,
    ) -> Option<RouteKind> {
        if self
            .segmenting
            .is_some_and(|s| seq.saturating_sub(s) > self.segment_timeout())
        {
            tracing::warn!(
                seq = self.segmenting,
                "no segmenter result for this frame; segmenting another"
            );
            self.segmenting = None;
        }
        // Without a propagator there is nothing to mask the frames between.
        let can_propagate = workers.propagator && (self.prompted || !workers.segmenter);
        // Without a propagator every frame's masks are the segmenter's.
        let want_segment = want_segment || !can_propagate;
        if want_segment && workers.segmenter && self.segmenting.is_none() {
            self.segmenting = Some(seq);
            self.last_segment = Some(seq);
            return Some(if can_propagate {
                RouteKind::SegmentBehind
            } else {
                RouteKind::Segment
            });
        }
        if can_propagate && self.last_segment.is_some() {
            Some(RouteKind::Propagate)
        } else if workers.segmenter {
            None // the segmenter is busy; this frame waits (or is dropped for a newer one)
        } else {
            Some(RouteKind::Skip)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const BOTH: Availability = Availability {
        segmenter: true,
        propagator: true,
    };

    fn router() -> Router {
        Router::new(RoutingConfig::default())
    }

    impl Router {
        /// A decided route (lockstep always decides).
        fn route_now(&mut self, seq: u64, bad: bool, workers: Availability) -> RouteKind {
            self.route(seq, bad, workers).expect("decided")
        }
    }

    #[test]
    fn first_frame_is_segmented_then_flag_drives_routing() {
        let mut r = router();
        assert_eq!(r.route_now(0, false, BOTH), RouteKind::Segment);
        r.on_track(false);
        assert_eq!(r.route_now(1, false, BOTH), RouteKind::Propagate);
        r.on_track(true);
        assert_eq!(r.route_now(2, false, BOTH), RouteKind::Segment);
        r.on_track(false);
        assert_eq!(r.route_now(3, false, BOTH), RouteKind::Propagate);
    }

    #[test]
    fn stale_segmenter_masks_force_a_segment() {
        let mut r = Router::new(RoutingConfig {
            max_segment_age: 3,
            ..Default::default()
        });
        assert_eq!(r.route_now(0, false, BOTH), RouteKind::Segment);
        r.on_track(false);
        let kinds: Vec<_> = (1..=5).map(|s| r.route_now(s, false, BOTH)).collect();
        assert_eq!(
            kinds,
            vec![
                RouteKind::Propagate,
                RouteKind::Propagate,
                RouteKind::Propagate,
                RouteKind::Segment,
                RouteKind::Propagate
            ]
        );
    }

    #[test]
    fn a_propagator_request_segments_the_next_frame_once() {
        let mut r = router();
        assert_eq!(r.route_now(0, false, BOTH), RouteKind::Segment);
        r.on_track(false);
        assert_eq!(r.route_now(1, false, BOTH), RouteKind::Propagate);
        r.on_segment_wanted();
        assert_eq!(r.route_now(2, false, BOTH), RouteKind::Segment);
        assert!(r.last_was_request());
        assert_eq!(r.route_now(3, false, BOTH), RouteKind::Propagate);
        assert!(!r.last_was_request());
        // A request met by a keyframe anyway does not count as routed.
        r.on_segment_wanted();
        r.on_track(true);
        assert_eq!(r.route_now(4, false, BOTH), RouteKind::Segment);
        assert_eq!(r.requests(), (2, 1));
        // Real time: honoured when the segmenter is free, behind the
        // propagator's masks.
        let mut r = Router::realtime(RoutingConfig::default());
        assert_eq!(r.route(0, false, BOTH), Some(RouteKind::Segment));
        r.on_segmenter_result(0);
        r.on_track(false);
        assert_eq!(r.route(1, false, BOTH), Some(RouteKind::Propagate));
        r.on_segment_wanted();
        assert_eq!(r.route(2, false, BOTH), Some(RouteKind::SegmentBehind));
        // Switched off: requests are ignored.
        let mut r = Router::new(RoutingConfig {
            early_segment_requests: false,
            ..Default::default()
        });
        assert_eq!(r.route_now(0, false, BOTH), RouteKind::Segment);
        r.on_track(false);
        r.on_segment_wanted();
        assert_eq!(r.route_now(1, false, BOTH), RouteKind::Propagate);
        assert_eq!(r.requests(), (0, 0));
    }

    #[test]
    fn bad_frames_and_no_masks_skip() {
        let mut r = router();
        assert_eq!(r.route_now(0, true, BOTH), RouteKind::Skip);
        let mut r = Router::new(RoutingConfig {
            no_masks: true,
            ..Default::default()
        });
        assert_eq!(r.route_now(0, false, BOTH), RouteKind::Skip);
    }

    #[test]
    fn routes_around_failed_workers() {
        let mut r = router();
        let no_seg = Availability {
            segmenter: false,
            propagator: true,
        };
        // Nothing to propagate from yet: unmasked.
        assert_eq!(r.route_now(0, false, no_seg), RouteKind::Skip);
        assert_eq!(r.route_now(1, false, BOTH), RouteKind::Segment);
        r.on_track(true);
        assert_eq!(r.route_now(2, false, no_seg), RouteKind::Propagate);
        let no_prop = Availability {
            segmenter: true,
            propagator: false,
        };
        r.on_track(false);
        assert_eq!(r.route_now(3, false, no_prop), RouteKind::Segment);
        let none = Availability {
            segmenter: false,
            propagator: false,
        };
        assert_eq!(r.route_now(4, false, none), RouteKind::Skip);
    }

    #[test]
    fn segment_every_frame_ablation() {
        let mut r = Router::new(RoutingConfig {
            segment_every_frame: true,
            ..Default::default()
        });
        r.on_track(false);
        assert!((0..10).all(|s| r.route_now(s, false, BOTH) == RouteKind::Segment));
    }

    #[test]
    fn real_time_never_waits_for_the_segmenter_after_its_first_result() {
        let mut r = Router::realtime(RoutingConfig::default());
        // The very first frame is segmented; the frames after it wait for
        // that first result (nothing to propagate yet).
        assert_eq!(r.route(0, false, BOTH), Some(RouteKind::Segment));
        assert_eq!(r.route(1, false, BOTH), None);
        r.on_segmenter_result(0);
        r.on_track(true);
        // SLAM wants a keyframe: the segmenter is idle, so the frame is
        // segmented behind the propagator's masks.
        assert_eq!(r.route(2, false, BOTH), Some(RouteKind::SegmentBehind));
        // While it runs, frames go to the propagator only, however much a
        // keyframe is wanted: one frame at a time at the segmenter.
        for seq in 3..8 {
            assert_eq!(r.route(seq, false, BOTH), Some(RouteKind::Propagate));
        }
        r.on_segmenter_result(2);
        assert_eq!(r.route(8, false, BOTH), Some(RouteKind::SegmentBehind));
        // A segmenter that never answers is given up after a while.
        r.on_track(false);
        let timeout = r.segment_timeout();
        assert_eq!(
            r.route(8 + timeout, false, BOTH),
            Some(RouteKind::Propagate)
        );
        assert_eq!(
            r.route(9 + timeout, false, BOTH),
            Some(RouteKind::SegmentBehind)
        );
        // A dead worker frees the segmenter too.
        r.on_track(true);
        assert_eq!(
            r.route(10 + timeout, false, BOTH),
            Some(RouteKind::Propagate)
        );
        r.on_worker_lost();
        assert_eq!(
            r.route(11 + timeout, false, BOTH),
            Some(RouteKind::SegmentBehind)
        );
    }

    #[test]
    fn real_time_without_a_propagator_segments_whenever_the_segmenter_is_idle() {
        let mut r = Router::realtime(RoutingConfig::default());
        let no_prop = Availability {
            segmenter: true,
            propagator: false,
        };
        assert_eq!(r.route(0, false, no_prop), Some(RouteKind::Segment));
        assert_eq!(r.route(1, false, no_prop), None);
        r.on_segmenter_result(0);
        r.on_track(false);
        assert_eq!(r.route(2, false, no_prop), Some(RouteKind::Segment));
        let none = Availability {
            segmenter: false,
            propagator: false,
        };
        assert_eq!(r.route(3, false, none), Some(RouteKind::Skip));
    }
}
