//! Map initialisation. RGB-D needs one frame: its keypoints with depth
//! become the first keyframe's points, and its camera the world frame
//! (monocular initialisation, from two views, will live here too).

use nalgebra::Isometry3;

use crate::frame::Frame;
use crate::map::Map;
use crate::tracking::Tracking;

/// Keypoints with depth a frame needs to start a map.
const MIN_POINTS_WITH_DEPTH: usize = 100;

/// Starts `map` (empty) from `frame`; false when the frame has too few
/// keypoints with depth (the next frame tries again).
pub(crate) fn initialise_rgbd(tracking: &mut Tracking, map: &mut Map, frame: &Frame) -> bool {
    let with_depth = frame.depth.iter().filter(|d| d.is_some()).count();
    if with_depth < MIN_POINTS_WITH_DEPTH {
        return false;
    }
    let pose = Isometry3::identity();
    tracking.insert_keyframe(map, frame, &pose, &vec![None; frame.kps.len()], with_depth);
    true
}
