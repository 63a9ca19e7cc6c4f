//! The routing rule (DESIGN section 3): which worker makes a frame's masks.
//!
//! A frame goes to the segmenter when SLAM asked for a keyframe with its
//! previous Track, when no segmenter masks exist yet, or when the newest
//! segmenter run is older than `max_segment_age` frames; otherwise to the
//! propagator. Workers that were given up on are routed around; with none
//! left the frame goes on unmasked (Skip).

use pipeline::config::RoutingConfig;
use shared_types::RouteKind;

#[derive(Debug, Clone)]
pub struct Router {
    policy: RoutingConfig,
    /// SLAM's keyframe flag from the latest Track.
    next_needs_keyframe: bool,
    /// Newest frame routed to the segmenter.
    last_segment: Option<u64>,
}

/// Which workers can still take frames (a worker that is restarting counts
/// as available: lockstep waits for it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Availability {
    pub segmenter: bool,
    pub propagator: bool,
}

impl Router {
    pub fn new(policy: RoutingConfig) -> Self {
        Self {
            policy,
            next_needs_keyframe: true,
            last_segment: None,
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

    /// Decides the route of frame `seq` and remembers it.
    pub fn route(&mut self, seq: u64, bad_input: bool, workers: Availability) -> RouteKind {
        if bad_input || self.policy.no_masks {
            return RouteKind::Skip;
        }
        let stale = self
            .last_segment
            .is_none_or(|last| seq.saturating_sub(last) > self.policy.max_segment_age);
        let want_segment = self.policy.segment_every_frame || self.next_needs_keyframe || stale;
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

    #[test]
    fn first_frame_is_segmented_then_flag_drives_routing() {
        let mut r = router();
        assert_eq!(r.route(0, false, BOTH), RouteKind::Segment);
        r.on_track(false);
        assert_eq!(r.route(1, false, BOTH), RouteKind::Propagate);
        r.on_track(true);
        assert_eq!(r.route(2, false, BOTH), RouteKind::Segment);
        r.on_track(false);
        assert_eq!(r.route(3, false, BOTH), RouteKind::Propagate);
    }

    #[test]
    fn stale_segmenter_masks_force_a_segment() {
        let mut r = Router::new(RoutingConfig {
            max_segment_age: 3,
            ..Default::default()
        });
        assert_eq!(r.route(0, false, BOTH), RouteKind::Segment);
        r.on_track(false);
        let kinds: Vec<_> = (1..=5).map(|s| r.route(s, false, BOTH)).collect();
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
    fn bad_frames_and_no_masks_skip() {
        let mut r = router();
        assert_eq!(r.route(0, true, BOTH), RouteKind::Skip);
        let mut r = Router::new(RoutingConfig {
            no_masks: true,
            ..Default::default()
        });
        assert_eq!(r.route(0, false, BOTH), RouteKind::Skip);
    }

    #[test]
    fn routes_around_failed_workers() {
        let mut r = router();
        let no_seg = Availability {
            segmenter: false,
            propagator: true,
        };
        // Nothing to propagate from yet: unmasked.
        assert_eq!(r.route(0, false, no_seg), RouteKind::Skip);
        assert_eq!(r.route(1, false, BOTH), RouteKind::Segment);
        r.on_track(true);
        assert_eq!(r.route(2, false, no_seg), RouteKind::Propagate);
        let no_prop = Availability {
            segmenter: true,
            propagator: false,
        };
        r.on_track(false);
        assert_eq!(r.route(3, false, no_prop), RouteKind::Segment);
        let none = Availability {
            segmenter: false,
            propagator: false,
        };
        assert_eq!(r.route(4, false, none), RouteKind::Skip);
    }

    #[test]
    fn segment_every_frame_ablation() {
        let mut r = Router::new(RoutingConfig {
            segment_every_frame: true,
            ..Default::default()
        });
        r.on_track(false);
        assert!((0..10).all(|s| r.route(s, false, BOTH) == RouteKind::Segment));
    }
}
