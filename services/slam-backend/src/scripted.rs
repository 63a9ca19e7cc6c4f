//! A scripted tracker: its keyframe flags follow a fixed pattern, so the
//! pipeline's routing and delivery can be tested exactly (every
//! `keyframe_every`-th frame is requested as a keyframe). It reports a
//! pose that advances along x, inserts a keyframe whenever a frame comes with
//! segmenter masks, and can log every seq it sees. It does not estimate
//! motion: it is the pipeline's test double for SLAM, named as such.

use std::fs::OpenOptions;
use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;

use shared_types::{MaskSource, TrackCounts, TrackState};

use crate::tracker::{TrackInput, TrackOutcome, Tracker};

/// A test double: a made-up trajectory, a keyframe every N frames, a fixed
/// work time per frame.
pub struct ScriptedTracker {
    keyframe_every: u64,
    work: Duration,
    seen_log: Option<PathBuf>,
    keyframes: u32,
}

impl ScriptedTracker {
    /// A keyframe every `keyframe_every` frames, `work` per frame, every
    /// tracked frame number appended to `seen_log` (delivery tests).
    pub fn new(keyframe_every: u64, work: Duration, seen_log: Option<PathBuf>) -> Self {
        Self {
            keyframe_every: keyframe_every.max(1),
            work,
            seen_log,
            keyframes: 0,
        }
    }

    /// The scripted keyframe flag published with frame `seq`.
    pub fn wants_keyframe_after(&self, seq: u64) -> bool {
        (seq + 1).is_multiple_of(self.keyframe_every)
    }
}

impl Tracker for ScriptedTracker {
    fn name(&self) -> &str {
        "scripted"
    }

    fn track(&mut self, input: &TrackInput) -> TrackOutcome {
        if !self.work.is_zero() {
            std::thread::sleep(self.work);
        }
        if let Some(path) = &self.seen_log {
            // One line per delivered frame; append + flush so a kill loses nothing.
            if let Ok(mut f) = OpenOptions::new().create(true).append(true).open(path) {
                let _ = writeln!(f, "{} {}", input.seq, input.mask_source().as_str());
            }
        }
        let keyframe = input.mask_source() == MaskSource::Segmenter;
        if keyframe {
            self.keyframes += 1;
        }
        TrackOutcome {
            pose: [input.seq as f64 * 0.01, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            state: TrackState::Ok,
            keyframe_inserted: keyframe,
            keyframe_pending: false,
            waiting_keyframe_inserted: false,
            next_needs_keyframe: self.wants_keyframe_after(input.seq),
            counts: TrackCounts {
                keyframes: self.keyframes,
                ..Default::default()
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pattern_requests_every_nth_frame() {
        let t = ScriptedTracker::new(5, Duration::ZERO, None);
        let flagged: Vec<u64> = (0..12).filter(|&s| t.wants_keyframe_after(s)).collect();
        assert_eq!(flagged, vec![4, 9]);
    }
}
