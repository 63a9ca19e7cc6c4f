//! The clock modes and what each one changes by default.

use serde::{Deserialize, Serialize};

/// How frames are clocked through the pipeline.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Hash, Default)]
#[serde(rename_all = "lowercase")]
pub enum ClockMode {
    /// Deterministic: the camera-reader waits for each frame's Track result.
    #[default]
    Lockstep,
    /// Camera rate: the newest frame wins, every dropped frame is counted.
    Realtime,
}

impl ClockMode {
    /// True in real time.
    pub fn is_realtime(self) -> bool {
        self == ClockMode::Realtime
    }
}

/// The segmenter's input size in lockstep when `input_size` is not set (as
/// in the shipped configuration): on synthesised people 480 has 60-75 % of
/// 640's IoU gain over 320 at 0.58x 640's time (docs/models.md "Segmenter
/// input size").
pub const LOCKSTEP_SEGMENTER_INPUT_SIZE: usize = 480;

/// The segmenter's input size in real time when `input_size` is not set.
/// There the segmenter's pace bounds the keyframes (a keyframe waits for
/// its own masks), and at 480 a loaded 2-core machine got too few of them:
/// static sequence, 60 fps with 2 busy processes, ATE 1.30x lockstep at 480
/// and 1.20x at 320 over 16 runs each (docs/measurements.md).
pub const REALTIME_SEGMENTER_INPUT_SIZE: usize = 320;

/// The segmenter input size an unset `input_size` (and no model naming an
/// export) means in a run of `mode`.
pub fn segmenter_input_size(mode: ClockMode) -> usize {
    match mode {
        ClockMode::Lockstep => LOCKSTEP_SEGMENTER_INPUT_SIZE,
        ClockMode::Realtime => REALTIME_SEGMENTER_INPUT_SIZE,
    }
}

/// The share of the view the camera must turn before the propagator asks
/// the segmenter to look at what the turn brought in (`configured`:
/// `routing.unseen_view_share`). In real time it asks nothing: there a
/// request keeps the segmenter busy on every frame it can take, and on the
/// 2-core machine it then takes the CPU the propagator and the SLAM need
/// (30 fps unloaded, static shared sequence: end-to-end p99 48-64 ms
/// without, 70-98 ms with 0.2).
pub fn unseen_view_share(mode: ClockMode, configured: f32) -> f32 {
    match mode {
        ClockMode::Lockstep => configured,
        ClockMode::Realtime => 0.0,
    }
}
