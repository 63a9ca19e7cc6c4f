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

/// Weight of the newest tracked frame in [`FlowPace`]'s moving average
/// (about the last ten count).
const PACE_WEIGHT: f64 = 0.1;

/// [`FlowPace`]: the share of the camera's frames left untracked above
/// which the SLAM counts as behind. Real time on 2 cores drops 0-5 % at
/// 30 fps with two busy processes and 40 % at 60 fps
/// (docs/measurements.md "Frames tracked by flow, when behind").
pub const BEHIND_DROP_SHARE: f64 = 0.1;

/// Real time: whether the pipeline is behind the camera, so that frames
/// may be tracked by optical flow (`services.slam.flow_frames`): more than
/// [`BEHIND_DROP_SHARE`] of the recent frames went untracked (dropped by
/// the SLAM or before it). Following points halves the SLAM's time per
/// frame, and the CPU it frees lets the other stages keep up too, but under
/// load it tracks a little less accurately; so a pipeline that keeps up
/// extracts every frame. A moving average, so that the flow frames' own
/// speed does not switch it back and forth frame by frame. Lockstep is
/// never behind: the camera waits for each frame.
#[derive(Debug, Clone, Default)]
pub struct FlowPace {
    /// Moving average of the camera's frames per tracked frame (1: none
    /// dropped).
    frames_per_track: Option<f64>,
    /// The last tracked frame's sequence number.
    last: Option<u64>,
}

impl FlowPace {
    /// Notes that frame `seq` was tracked (whatever the outcome).
    pub fn tracked(&mut self, seq: u64) {
        if let Some(last) = self.last.filter(|&last| seq > last) {
            let passed = (seq - last) as f64;
            self.frames_per_track = Some(
                self.frames_per_track
                    .map_or(passed, |old| old + PACE_WEIGHT * (passed - old)),
            );
        }
        self.last = Some(seq);
    }

    /// The next frame may be tracked by flow: real time, and more than
    /// [`BEHIND_DROP_SHARE`] of the recent frames were not tracked.
    pub fn behind(&self, mode: ClockMode) -> bool {
        matches!(mode, ClockMode::Realtime)
            && self
                .frames_per_track
                .is_some_and(|f| 1.0 - 1.0 / f > BEHIND_DROP_SHARE)
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
