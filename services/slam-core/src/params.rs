//! What the SLAM system is tuned with.

use crate::features::orb::OrbParams;

/// What the camera gives the SLAM.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Sensor {
    /// Colour and registered depth: the map is metric from the first frame.
    #[default]
    Rgbd,
    /// Colour only (depth ignored if given): the map starts from two views
    /// ([`crate::initialization::two_view`]) at an arbitrary scale (the
    /// first keyframe's median scene depth is 1).
    Monocular,
}

/// What the SLAM system is tuned with ([`SlamParams::default`] for RGB-D, [`SlamParams::monocular`]).
#[derive(Debug, Clone, Copy)]
pub struct SlamParams {
    /// What the camera gives.
    pub sensor: Sensor,
    /// ORB extraction's settings.
    pub orb: OrbParams,
    /// Keypoints with depth in this range (metres) get 3D measurements.
    pub min_depth_m: f64,
    /// See `min_depth_m`.
    pub max_depth_m: f64,
    /// Dynamic masks are grown by this many pixels before filtering.
    pub mask_dilation_px: usize,
    /// The newest keyframes, always part of the local map (with the older
    /// ones covisibility adds, see `local_points`).
    pub local_keyframes: usize,
    /// A keyframe at the latest after this many frames or this many
    /// seconds of the camera's time (timestamps), whichever comes first
    /// (ORB-SLAM2 counts frames at the camera's rate). At 30 fps the frame
    /// count comes first (0.32 s is 9.6 frame periods); the time counts
    /// where frames were dropped: in real time on a busy machine the SLAM
    /// tracks every second or third frame, and 10 tracked frames span
    /// 0.7-1 s of motion. Measured with `slam-bench` on the shared
    /// sequence thinned to every 2nd / 3rd frame: ATE 0.0182 / 0.0217 m
    /// counting frames alone, 0.0142 / 0.0203 m with the time too (every
    /// frame: 0.0119 m, 33 keyframes, either way)...
    pub max_frames_between_keyframes: u32,
    /// See `max_frames_between_keyframes`.
    pub max_seconds_between_keyframes: f64,
    /// ...unless a live keyframe older than the `local_keyframes` newest was
    /// taken within this distance (metres) and angle (degrees) of the
    /// frame: a camera that comes back over its path keeps a bounded map
    /// (0: off). Measured with `slam-bench --repeat 6` on the shared
    /// sequence: keyframes inserted per pass 35, 32, 32, ... (off) against
    /// 33, 13, 5, 2, 4, 3 (0.10 m, 10 deg), first-pass ATE 0.0119 m either
    /// way. A weakening view (ORB-SLAM2's tracked share and close points)
    /// gets its keyframe regardless.
    pub same_view_m: f64,
    /// See `same_view_m`.
    pub same_view_deg: f64,
    /// Fewer inliers than this: the frame is lost.
    pub min_inliers: usize,
    /// Tracking's match by projection keeps a keypoint for a map point only
    /// when its descriptor distance is at most this share of the second
    /// best's in the window (ORB-SLAM2's nearest-neighbour ratio); 1 (the
    /// default): the best wins. Measured with `slam-bench --match-ratio`,
    /// a trade, so not on by default: monocular on the rendered orbit
    /// (`dynslam render --path orbit`) 0.8 or 0.9 keep 444 of 450 frames
    /// tracked where 1 loses the map after 193 (a look-alike next to the
    /// predicted spot pulls the pose towards the prediction), but on the
    /// rendered room with people the masked monocular ATE goes 0.0093 ->
    /// 0.0176 m (0.9) and the static one 0.0072 -> 0.0110 m (0.8); with
    /// depth, the rendered circuit at 250 features goes 0.0130 -> 0.0256 m
    /// (0.8).
    pub match_ratio: f64,
    /// Keyframes whose poses local bundle adjustment refines (0 or 1: off,
    /// the default: measured with `slam-bench --local-ba 10` it makes ATE
    /// worse, 0.0337 -> 0.0350 m on fr1_rpy and 0.0028 -> 0.019 m on the
    /// rendered room: depth is weak in its residual and our points are seen
    /// by few keyframes, so keyframes slide with their points; README).
    pub local_ba_keyframes: usize,
    /// Keypoints nearer than this (metres) are measured with their depth as
    /// (u, v, ur); farther ones only by (u, v), since depth noise grows with
    /// the square of the distance (ORB-SLAM2's ThDepth: 40 baselines).
    pub close_depth_m: f64,
    /// Local mapping on its own thread (overlapping the next frame's
    /// feature extraction) rather than inline after each keyframe; the
    /// results are the same, only the time moves.
    pub mapping_thread: bool,
    /// Local mapping triangulates new points from keypoints without depth
    /// that two covisible keyframes see ([`crate::local_mapping::triangulation`]).
    pub triangulate: bool,
    /// Local mapping merges duplicate points with the neighbours' and adds
    /// observations to keypoints they land on ([`crate::local_mapping::fusion`]). Off by
    /// default: measured, it leaves ATE level on static scenes but cuts the
    /// inliers per frame by a quarter and, with the product's imperfect
    /// masks on the rendered room, triples ATE (0.0043 -> 0.0142 m; README).
    pub fuse_points: bool,
    /// After local mapping, look for loops and correct the map when one
    /// closes ([`crate::loop_closing`]). On by default, as in ORB-SLAM2: on
    /// every sequence measured the corrected trajectory is better (rendered
    /// circuit and orbit 0.31-0.69x) or no loop closes (the shared sequence
    /// forwards, and forwards then backwards; synthesised people), and the
    /// detection costs well under a millisecond a keyframe
    /// (docs/measurements.md, "Loop closing on every sequence we have").
    pub loop_closing: bool,
    /// After a loop correction, bundle-adjust the whole map (on the
    /// loop-closing thread, merged as ORB-SLAM2 does).
    pub global_bundle_adjustment: bool,
    /// RGB-D: drop features in regions that move unlike the camera
    /// ([`crate::tracking::motion_check`]), movers no mask names. On by
    /// default: the largest gain measured on real people walking (ATE
    /// 0.0188 -> 0.0151 m), about 1.7 ms a frame (docs/models.md "Motion check").
    pub motion_check: bool,
    /// After frames were left out (real time on a busy machine), tracking
    /// starts from the turn found by aligning the frame's small image with
    /// the last tracked one's ([`crate::tracking::small_image`]) where it
    /// differs from the motion model's by more than a degree (a hand-held
    /// camera reversing its turn).
    pub turn_from_images: bool,
    /// RGB-D: up to this many frames in a row between full extractions are
    /// tracked by following the last frame's inliers with pyramidal
    /// Lucas-Kanade and optimising the pose against their map points, with
    /// no ORB extraction and no search by projection
    /// ([`crate::tracking::flow`]; NGD-SLAM's hybrid tracking). A frame
    /// the keyframe rule may pick, one after a loss, one whose followed
    /// points fall short of the reference keyframe's, is extracted in full.
    /// 0 (the default): every frame is extracted.
    pub flow_frames: u32,
}

impl SlamParams {
    /// The defaults for a monocular camera: local bundle adjustment on
    /// (without depth it is what fixes the triangulated points; ORB-SLAM2
    /// runs it in every mode).
    pub fn monocular() -> Self {
        Self {
            sensor: Sensor::Monocular,
            local_ba_keyframes: 10,
            ..Self::default()
        }
    }

    /// Colour only.
    pub fn is_monocular(&self) -> bool {
        self.sensor == Sensor::Monocular
    }

    /// Frames may be tracked by optical flow between extractions:
    /// `flow_frames` on, RGB-D (a followed point needs its depth's guess).
    pub fn flow_on(&self) -> bool {
        self.flow_frames > 0 && !self.is_monocular()
    }
}

impl Default for SlamParams {
    fn default() -> Self {
        Self {
            sensor: Sensor::Rgbd,
            orb: OrbParams::default(),
            min_depth_m: 0.1,
            max_depth_m: 6.0,
            mask_dilation_px: 5,
            local_keyframes: 20,
            max_frames_between_keyframes: 10,
            max_seconds_between_keyframes: 0.32,
            same_view_m: 0.10,
            same_view_deg: 10.0,
            min_inliers: 25,
            match_ratio: 1.0,
            local_ba_keyframes: 0,
            close_depth_m: 3.1,
            mapping_thread: true,
            triangulate: true,
            fuse_points: false,
            loop_closing: true,
            global_bundle_adjustment: true,
            motion_check: true,
            turn_from_images: true,
            flow_frames: 0,
        }
    }
}
