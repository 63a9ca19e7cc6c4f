//! The SLAM service's frame rule: which held frame it tracks next, and how
//! long a keyframe waits for its segmenter masks. (When a frame the
//! keyframe rule picks becomes a keyframe is [`crate::keyframe_timing`].)

use shared_types::RouteKind;

use crate::mode::ClockMode;

/// Real time: frames after which a keyframe stops waiting for its segmenter
/// masks (the segmenter died or its frame was replaced) and goes in with the
/// propagated ones; also how long without any segmenter result before
/// keyframes are made from propagated masks again.
pub const SEGMENTER_PATIENCE: u64 = 60;

/// A held frame can be tracked: routed, and with its masks unless routed
/// to go without them.
pub fn frame_ready(route: Option<RouteKind>, has_masks: bool) -> bool {
    match route {
        Some(RouteKind::Skip | RouteKind::Refuse) => true,
        Some(_) => has_masks,
        None => false,
    }
}

/// Which of the held frames (in the order they arrived; `ready` says which
/// can be tracked) is tracked next: lockstep the oldest ready, real time
/// the newest (the older ones are left: the supervisor drops them).
pub fn next_frame(mode: ClockMode, ready: &[bool]) -> Option<usize> {
    match mode {
        ClockMode::Lockstep => ready.iter().position(|&r| r),
        ClockMode::Realtime => ready.iter().rposition(|&r| r),
    }
}

/// Frame `seq` counts the segmenter as alive: its newest answer is at most
/// [`SEGMENTER_PATIENCE`] frames older.
pub fn segmenter_alive(seq: u64, last_segmented: Option<u64>) -> bool {
    last_segmented.is_some_and(|s| seq <= s + SEGMENTER_PATIENCE)
}

/// Segmenter masks for `segmented` complete the keyframe `waiting` for its
/// own: its own, or a newer frame's (its own will not come then).
pub fn completes_waiting_keyframe(waiting: u64, segmented: u64) -> bool {
    waiting <= segmented
}

/// The keyframe `waiting` for its segmenter masks stops waiting and goes in
/// with its propagated masks: the SLAM has tracked frame `last_tracked`,
/// more than [`SEGMENTER_PATIENCE`] frames later.
pub fn keyframe_waited_too_long(waiting: u64, last_tracked: u64) -> bool {
    last_tracked > waiting + SEGMENTER_PATIENCE
}
