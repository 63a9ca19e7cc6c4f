//! When a frame the keyframe rule picks may become a keyframe, from what
//! the SLAM service knows about its masks (DESIGN section 3: keyframes are
//! made from segmenter masks).
//!
//! Lockstep: now (a frame is routed to the segmenter when a keyframe was
//! asked for, and SLAM waits for its masks). Real time the segmenter
//! answers frames late and one at a time, so a keyframe either waits for
//! its frame's segmenter masks or is left to the next segmented frame,
//! except where waiting buys nothing or cannot be afforded ([`keyframe_timing`]:
//! an empty scene, a young map, a segmenter that stopped answering).

use shared_types::RouteKind;

/// When a frame that the keyframe rule picks becomes a keyframe (the SLAM
/// core's `KeyframeTiming`, which the SLAM service converts it to).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum KeyframeWhen {
    /// Now, with the masks it was tracked with.
    #[default]
    Now,
    /// When its better (segmenter) masks come; later frames are tracked
    /// meanwhile.
    AfterBetterMasks,
    /// Not this frame: the keyframe waits for a frame that gets segmenter
    /// masks.
    NotThisFrame,
}

/// What the service knows about a frame when it tracks it.
#[derive(Debug, Clone, Copy, Default)]
pub struct KeyframeFacts {
    /// Real time (else lockstep).
    pub realtime: bool,
    /// The frame's route.
    pub route: Option<RouteKind>,
    /// Its masks are the segmenter's (they beat the propagated ones).
    pub segmented: bool,
    /// The map has at most `YOUNG_MAP_KEYFRAMES` keyframes (it cannot
    /// relocalise yet; a keyframe must not wait).
    pub young_map: bool,
    /// The segmenter answered recently enough to wait for it.
    pub segmenter_alive: bool,
    /// Nothing dynamic in view: the segmenter's newest answer found no
    /// object, the propagator has seen nothing move since (no early
    /// segmenter request), and this frame's masks have no object either.
    pub scene_empty: bool,
    /// The frame tracked before asked for a keyframe (its Track's
    /// `next_needs_keyframe`).
    pub asked_before: bool,
}

/// When the frame may become a keyframe. Real time, in an empty scene a
/// keyframe does not wait for segmenter masks: this frame's would almost
/// surely be empty too, and under load waiting for them halves the
/// keyframes (the shared static sequence at 60 fps with two busy processes:
/// 12-16 keyframes against lockstep's 33, ATE 1.43x lockstep's over 19
/// runs). It keeps lockstep's cadence, though: the keyframe is the frame
/// after the one that asked for it (as in lockstep, where the asking
/// Track routes the next frame to the segmenter); taking the asking frame
/// itself made 30 fps unloaded 0.0101 -> 0.0125 m, every run. Anything in
/// view, or anything the propagator saw move since, keeps the wait: a
/// keyframe from propagated masks puts the people they missed into the
/// map (docs/measurements.md "Real-time masks on people").
pub fn keyframe_timing(f: KeyframeFacts) -> KeyframeWhen {
    if !f.realtime || f.segmented || f.young_map {
        return KeyframeWhen::Now;
    }
    match f.route {
        Some(RouteKind::SegmentBehind) if f.scene_empty => KeyframeWhen::Now,
        Some(RouteKind::SegmentBehind) => KeyframeWhen::AfterBetterMasks,
        Some(RouteKind::Propagate) if f.scene_empty && f.asked_before => KeyframeWhen::Now,
        Some(RouteKind::Propagate) if f.segmenter_alive => KeyframeWhen::NotThisFrame,
        _ => KeyframeWhen::Now,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn realtime(route: RouteKind) -> KeyframeFacts {
        KeyframeFacts {
            realtime: true,
            route: Some(route),
            segmenter_alive: true,
            ..Default::default()
        }
    }

    #[test]
    fn lockstep_and_segmented_frames_become_keyframes_now() {
        let lockstep = KeyframeFacts {
            route: Some(RouteKind::Propagate),
            segmenter_alive: true,
            ..Default::default()
        };
        assert_eq!(keyframe_timing(lockstep), KeyframeWhen::Now);
        let segmented = KeyframeFacts {
            segmented: true,
            ..realtime(RouteKind::SegmentBehind)
        };
        assert_eq!(keyframe_timing(segmented), KeyframeWhen::Now);
    }

    #[test]
    fn with_something_in_view_a_keyframe_waits_for_segmenter_masks() {
        assert_eq!(
            keyframe_timing(realtime(RouteKind::SegmentBehind)),
            KeyframeWhen::AfterBetterMasks
        );
        assert_eq!(
            keyframe_timing(realtime(RouteKind::Propagate)),
            KeyframeWhen::NotThisFrame
        );
    }

    #[test]
    fn in_an_empty_scene_the_frame_after_the_asking_one_does_not_wait() {
        let empty = |route| KeyframeFacts {
            scene_empty: true,
            ..realtime(route)
        };
        assert_eq!(
            keyframe_timing(empty(RouteKind::SegmentBehind)),
            KeyframeWhen::Now
        );
        // The asking frame itself leaves it to the next, as in lockstep.
        assert_eq!(
            keyframe_timing(empty(RouteKind::Propagate)),
            KeyframeWhen::NotThisFrame
        );
        let after_asking = KeyframeFacts {
            asked_before: true,
            ..empty(RouteKind::Propagate)
        };
        assert_eq!(keyframe_timing(after_asking), KeyframeWhen::Now);
        // Not empty: the wait stays, asked or not.
        let in_view = KeyframeFacts {
            asked_before: true,
            ..realtime(RouteKind::Propagate)
        };
        assert_eq!(keyframe_timing(in_view), KeyframeWhen::NotThisFrame);
    }

    #[test]
    fn a_young_map_or_silent_segmenter_does_not_wait() {
        for route in [RouteKind::SegmentBehind, RouteKind::Propagate] {
            let young = KeyframeFacts {
                young_map: true,
                ..realtime(route)
            };
            assert_eq!(keyframe_timing(young), KeyframeWhen::Now, "{route:?}");
        }
        let silent = KeyframeFacts {
            segmenter_alive: false,
            ..realtime(RouteKind::Propagate)
        };
        assert_eq!(keyframe_timing(silent), KeyframeWhen::Now);
    }
}
