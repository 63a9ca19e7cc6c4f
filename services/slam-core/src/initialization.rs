//! Map initialisation. RGB-D needs one frame: its keypoints with depth
//! become the first keyframe's points, and its camera the world frame.
//! Monocular initialisation needs two views: [`two_view`] reconstructs
//! their motion and points.

pub mod two_view;

use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion};

use crate::camera::Camera;
use crate::frame::Frame;
use crate::map::{Map, MapPoint};
use crate::matcher::match_for_initialisation;
use crate::params::Sensor;
use crate::tracking::Tracking;
use two_view::{reconstruct, TwoView, TwoViewParams};

/// Keypoints with depth a frame needs to start a map.
const MIN_POINTS_WITH_DEPTH: usize = 100;

/// Starts `map` (empty) from `frame`; false when the frame has too few
/// keypoints with depth (the next frame tries again).
pub(crate) fn initialise_rgbd(tracking: &mut Tracking, map: &mut Map, frame: &Frame) -> bool {
    let Some(with_depth) = points_to_start(frame) else {
        return false;
    };
    start_rgbd_at(tracking, map, frame, with_depth, &Isometry3::identity());
    true
}

/// The keypoints of `frame` with depth, when there are enough to start a
/// map.
pub(crate) fn points_to_start(frame: &Frame) -> Option<usize> {
    let with_depth = frame.depth.iter().filter(|d| d.is_some()).count();
    (with_depth >= MIN_POINTS_WITH_DEPTH).then_some(with_depth)
}

/// Makes `frame` (`with_depth` from [`points_to_start`]) the map's first
/// keyframe with its camera at `pose_cw` (camera from world): its
/// keypoints with depth become the map's points.
pub(crate) fn start_rgbd_at(
    tracking: &mut Tracking,
    map: &mut Map,
    frame: &Frame,
    with_depth: usize,
    pose_cw: &Isometry3<f64>,
) {
    tracking.insert_keyframe(
        map,
        frame,
        pose_cw,
        &vec![None; frame.kps.len()],
        with_depth,
    );
}

/// Keypoints a frame needs to be a reference or a second view, and matches
/// the two need (ORB-SLAM2: 100 each).
const MIN_MONOCULAR_FEATURES: usize = 100;
const MIN_MONOCULAR_MATCHES: usize = 100;
/// Points the second keyframe must still see after the first bundle
/// adjustment (ORB-SLAM2: 100).
const MIN_MONOCULAR_POINTS: usize = 100;
/// How far (pixels) a keypoint is looked for in the second view.
const MONOCULAR_WINDOW_PX: f64 = 100.0;

/// A monocular map's start, tried frame by frame: a reference frame, and
/// each later frame matched to it until the two views reconstruct.
#[derive(Default)]
pub(crate) struct MonocularInitializer {
    reference: Option<(Frame, f64)>,
}

/// What a successful monocular start gives tracking: the second view's
/// pose and matches, and the reference frame's timestamp (the first
/// keyframe's).
pub(crate) struct MonocularStart {
    pub pose_cw: Isometry3<f64>,
    pub matched: Vec<Option<usize>>,
    pub inliers: usize,
    pub reference_timestamp: f64,
}

impl MonocularInitializer {
    /// Tries to start `map` (empty) from the reference frame and `frame`
    /// (taken at `timestamp`): on success the map holds two keyframes (the
    /// reference's camera is the world frame; the scale makes its median
    /// scene depth 1) and their points, bundle-adjusted. Otherwise `frame`
    /// may become the new reference (too few matches) and the next frame
    /// tries again.
    pub(crate) fn try_start(
        &mut self,
        tracking: &mut Tracking,
        map: &mut Map,
        frame: &Frame,
        timestamp: f64,
        camera: &Camera,
    ) -> Option<MonocularStart> {
        let Some((reference, reference_timestamp)) = &self.reference else {
            if frame.kps.len() > MIN_MONOCULAR_FEATURES {
                self.reference = Some((frame.clone(), timestamp));
            }
            return None;
        };
        if frame.kps.len() <= MIN_MONOCULAR_FEATURES {
            self.reference = None;
            return None;
        }
        let matches = match_for_initialisation(reference, frame, MONOCULAR_WINDOW_PX);
        if matches.len() < MIN_MONOCULAR_MATCHES {
            // The view changed too much: start again from this frame.
            tracing::debug!("monocular start: {} matches, new reference", matches.len());
            self.reference = Some((frame.clone(), timestamp));
            return None;
        }
        let k = Matrix3::new(
            camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0,
        );
        let two_view = match reconstruct(
            &k,
            &reference.un,
            &frame.un,
            &matches,
            &TwoViewParams::default(),
        ) {
            Ok(v) => v,
            Err(why) => {
                tracing::info!("monocular start refused with this frame: {why:?}");
                return None;
            }
        };
        let reference_timestamp = *reference_timestamp;
        let Some((pose_cw, matched, inliers)) =
            build_two_view_map(tracking, map, reference, frame, &matches, &two_view, camera)
        else {
            *map = Map::default();
            self.reference = None;
            return None;
        };
        tracing::info!(
            "monocular map started from two views ({:?}, parallax {:.1} deg): {inliers} points",
            two_view.model,
            two_view.parallax_deg
        );
        self.reference = None;
        Some(MonocularStart {
            pose_cw,
            matched,
            inliers,
            reference_timestamp,
        })
    }
}

/// The two keyframes and their points from a reconstruction, adjusted
/// together, scaled to a median depth of 1 in the first; None when too few
/// points survive the adjustment.
fn build_two_view_map(
    tracking: &mut Tracking,
    map: &mut Map,
    reference: &Frame,
    frame: &Frame,
    matches: &[(usize, usize)],
    two_view: &TwoView,
    camera: &Camera,
) -> Option<(Isometry3<f64>, Vec<Option<usize>>, usize)> {
    let close = f64::INFINITY; // no depth: every measurement is (u, v)
    let mut matched0 = vec![None; reference.kps.len()];
    let mut matched1 = vec![None; frame.kps.len()];
    for (&(i, j), x) in matches.iter().zip(&two_view.points) {
        let Some(x) = x else { continue };
        let m = reference.measure(i, camera, close);
        let point = MapPoint::new(*x, 0, &m, x.norm(), reference.colours[i]);
        let p = map.add_point(point);
        matched0[i] = Some(p);
        matched1[j] = Some(p);
    }
    let n = matched1.iter().flatten().count();
    let rotation = UnitQuaternion::from_matrix(&two_view.rotation);
    let pose1 = Isometry3::from_parts(Translation3::from(two_view.translation), rotation);
    tracking.insert_keyframe(map, reference, &Isometry3::identity(), &matched0, n);
    tracking.insert_keyframe(map, frame, &pose1, &matched1, n);
    map.global_bundle_adjustment(camera, Sensor::Monocular);
    let median = map.median_depth(0).filter(|d| *d > 0.0)?;
    let seen = map.keyframes[1].points.len();
    if seen < MIN_MONOCULAR_POINTS {
        tracing::debug!("monocular start refused: {seen} points after adjustment");
        return None;
    }
    let scale = 1.0 / median;
    for p in &mut map.points {
        p.position *= scale;
        p.level0_distance *= scale;
    }
    map.keyframes[1].pose_cw.translation.vector *= scale;
    // The second keyframe's points, as tracking goes on from it.
    let mut matched = vec![None; frame.kps.len()];
    for (j, m) in matched1.iter().enumerate() {
        matched[j] = m.filter(|p| map.keyframes[1].points.contains(p));
    }
    let inliers = matched.iter().flatten().count();
    Some((map.keyframes[1].pose_cw, matched, inliers))
}
