//! The seam between the SLAM service and a SLAM implementation.

use pipeline::views::{FrameView, MasksView};
use shared_types::{MaskSource, TrackCounts, TrackState};
use slam_core::local_mapping::snapshot::MapSnapshot;
use slam_core::{KeyframeTiming, Pace};

/// Everything a tracker gets for one frame.
pub struct TrackInput<'a> {
    /// The frame's sequence number.
    pub seq: u64,
    /// Its pixels (colour and depth) in shared memory.
    pub frame: &'a FrameView<'a>,
    /// Dynamic-object masks, when the frame was routed to a mask worker and
    /// the worker succeeded.
    pub masks: Option<&'a MasksView<'a>>,
    /// When the frame becomes a keyframe if the tracker's rule picks it.
    pub keyframe: KeyframeTiming,
    /// Whether the pipeline is behind the camera
    /// ([`scheduling::tracking::FlowPace`]): only then may the frame be
    /// tracked by optical flow.
    pub pace: Pace,
}

impl TrackInput<'_> {
    /// Who made the frame's masks (none without masks).
    pub fn mask_source(&self) -> MaskSource {
        self.masks.map(|m| m.source()).unwrap_or(MaskSource::None)
    }
}

/// A tracker's answer for one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackOutcome {
    /// World-from-camera pose: tx ty tz qx qy qz qw.
    pub pose: [f64; 7],
    /// Tracked, relocalised, lost, ...
    pub state: TrackState,
    /// The frame is a keyframe now, or becomes one when its segmenter masks
    /// come (`keyframe_pending`).
    pub keyframe_inserted: bool,
    /// The frame's keyframe waits for its segmenter masks.
    pub keyframe_pending: bool,
    /// The keyframe that waited for its segmenter masks went in with this
    /// frame, without them (tracking weakened or was lost while it waited).
    pub waiting_keyframe_inserted: bool,
    /// The next frame should be a keyframe (drives the supervisor's routing).
    pub next_needs_keyframe: bool,
    /// Features, inliers, map size and step times (frames.csv).
    pub counts: TrackCounts,
}

/// A SLAM implementation as the service sees it.
pub trait Tracker {
    /// The backend's name (logged at start).
    fn name(&self) -> &str;
    /// Tracks one frame.
    fn track(&mut self, input: &TrackInput) -> TrackOutcome;
    /// At stop: writes what the tracker keeps (map files); the error names
    /// the file.
    fn finish(&mut self) -> Result<(), String> {
        Ok(())
    }
    /// Inserts the keyframe a [`KeyframeTiming::AfterBetterMasks`] frame
    /// left pending, without its features inside `masks` (`None`: they did
    /// not come). True when one was inserted.
    fn complete_keyframe(&mut self, _masks: Option<&MasksView>) -> bool {
        false
    }
    /// Loops closed since the last call: (timestamp of the keyframe's
    /// frame, the closure).
    fn take_loops(&mut self) -> Vec<(f64, slam_core::loop_closing::LoopClosure)> {
        Vec::new()
    }
    /// After a loop closed: the trajectory as the map stands now (frames
    /// moved with their keyframes by the corrections). None otherwise.
    fn corrected_trajectory(&mut self) -> Option<slam_core::io::trajectory::Trajectory> {
        None
    }
    /// The map's points (empty for trackers without a map).
    fn map_points(&mut self) -> Vec<slam_core::io::ply::ColouredPoint> {
        Vec::new()
    }
    /// The newest map snapshot taken since the last call (the bridge's map
    /// topics), with the capture time of its newest keyframe's frame.
    fn take_map_snapshot(&mut self) -> Option<(f64, MapSnapshot)> {
        None
    }
    /// Loops closed by this process so far.
    fn loops_closed(&self) -> usize {
        0
    }

    // Commands from outside (the bridge's ROS 2 services). The error says
    // why not, for the caller.

    /// The map as a file's contents, to be written elsewhere.
    fn map_file(&mut self) -> Result<slam_core::MapFile, String> {
        Err(format!("the {} backend keeps no map", self.name()))
    }
    /// Drops the map: the next frame starts a new one (mapping mode).
    fn reset(&mut self) -> Result<(), String> {
        Err(format!("the {} backend keeps no map", self.name()))
    }
    /// ORB-SLAM2's localization mode on or off.
    fn set_localize_only(&mut self, _on: bool) -> Result<(), String> {
        Err(format!("the {} backend keeps no map", self.name()))
    }
}
