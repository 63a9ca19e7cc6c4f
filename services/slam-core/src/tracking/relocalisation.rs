//! Relocalisation of a lost frame (ORB-SLAM2's Relocalization): candidate
//! keyframes from the keyframe database by bag of words, matches by bag of
//! words, then RANSAC on depth or pixels.

use nalgebra::{Isometry3, Vector3};

use super::Tracking;
use crate::frame::Frame;
use crate::geometry::pnp::{pnp_ransac, PnpMatch};
use crate::geometry::ransac::rigid_ransac;
use crate::map::Map;
use crate::matcher::match_by_bow;
use crate::optimizer::pose::is_finite_pose;
use crate::place_recognition::FeatureVector;

/// Candidate keyframes a lost frame is tried at, at most: each costs a
/// RANSAC and a search over the whole map.
const MAX_TRIES: usize = 8;

impl Tracking {
    /// The keyframes a lost frame may be at, best first: the keyframe
    /// database's candidates for the frame's bag of words (among all the
    /// keyframes of the map, not only recent ones), with the frame's
    /// feature vector for matching at them.
    pub(super) fn relocalisation_candidates(
        &self,
        map: &Map,
        frame: &Frame,
    ) -> (FeatureVector, Vec<usize>) {
        let (bow, features) = self.vocabulary.transform(&frame.descs);
        let mut candidates = map
            .database
            .relocalisation_candidates(&bow, |k| map.best_covisible(k, 10));
        candidates.truncate(MAX_TRIES);
        (features, candidates)
    }

    /// A pose (camera from world) for a lost frame at keyframe `id`:
    /// matches by bag of words to its points, then 3D-3D RANSAC on the
    /// depth of both sides, or, where too few matched keypoints have depth
    /// (a depth camera blinded by sunlight, glass, a too-near scene), PnP
    /// RANSAC on their pixels.
    pub(super) fn pose_at_keyframe(
        &self,
        map: &Map,
        frame: &Frame,
        features: &FeatureVector,
        id: usize,
    ) -> Option<Isometry3<f64>> {
        const MIN_MATCHES: usize = 20;
        let kf = &map.keyframes[id];
        let matches = match_by_bow(map, kf, &self.vocabulary, features, frame);
        if matches.len() < MIN_MATCHES {
            return None;
        }
        let mut pairs = Vec::new();
        let mut pixels = Vec::new();
        for (k, p) in matches {
            let world = map.points[p].position;
            match frame.depth[k] {
                Some(d) => {
                    let c = self.camera.unproject(frame.un[k].0, frame.un[k].1, d);
                    pairs.push((world, c));
                }
                None => {
                    let m = frame.measure(k, &self.camera, self.params.close_depth_m);
                    pixels.push(PnpMatch {
                        world,
                        u: m.u,
                        v: m.v,
                        info: m.info,
                    });
                }
            }
        }
        let pose = if pairs.len() >= MIN_MATCHES {
            ransac_rigid(&pairs, 0.05, 200, MIN_MATCHES)
        } else {
            // The keypoints with depth count as pixels too.
            pixels.extend(pairs.iter().map(|(world, c)| {
                let (u, v) = self.camera.project(c);
                PnpMatch {
                    world: *world,
                    u,
                    v,
                    info: 1.0,
                }
            }));
            pnp_ransac(&self.camera, &pixels, 300, MIN_MATCHES).map(|(pose, _)| pose)
        };
        pose.filter(is_finite_pose)
    }
}

/// Rigid transform mapping `world` to `camera` points (camera from world)
/// by [`rigid_ransac`]; None with fewer than `min_inliers` inliers.
fn ransac_rigid(
    pairs: &[(Vector3<f64>, Vector3<f64>)],
    threshold: f64,
    iterations: usize,
    min_inliers: usize,
) -> Option<Isometry3<f64>> {
    rigid_ransac(pairs, threshold, iterations, 0x5EED)
        .filter(|(_, inliers)| inliers.len() >= min_inliers)
        .map(|(t, _)| t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Translation3, UnitQuaternion};

    #[test]
    fn rigid_ransac_ignores_outliers() {
        let truth = Isometry3::from_parts(
            Translation3::new(0.3, -0.1, 0.2),
            UnitQuaternion::from_euler_angles(0.1, 0.2, -0.3),
        );
        let mut pairs: Vec<(Vector3<f64>, Vector3<f64>)> = (0..60)
            .map(|i| {
                let f = i as f64;
                let a = Vector3::new(f.sin(), (0.7 * f).cos(), 1.0 + 0.03 * f);
                (a, (truth * Point3::from(a)).coords)
            })
            .collect();
        for p in pairs.iter_mut().step_by(4) {
            p.1 += Vector3::new(0.5, 0.0, 0.0);
        }
        let t = ransac_rigid(&pairs, 0.01, 200, 20).unwrap();
        assert!((t.translation.vector - truth.translation.vector).norm() < 1e-9);
        assert!(ransac_rigid(&pairs, 0.01, 200, 50).is_none());
    }
}
