//! Relocalisation of a lost frame against the map's keyframes.

use nalgebra::{Isometry3, Point3, Vector3};

use super::Tracking;
use crate::frame::Frame;
use crate::geometry::alignment::fit_rigid;
use crate::geometry::pnp::{pnp_ransac, PnpMatch};
use crate::geometry::ransac::Ransac;
use crate::map::Map;
use crate::matcher::match_to_keyframe;
use crate::optimizer::pose::is_finite_pose;

impl Tracking {
    /// A pose (camera from world) for a lost frame: descriptor matches to
    /// the points of each keyframe (newest first), then 3D-3D RANSAC on the
    /// depth of both sides, or, where too few matched keypoints have depth
    /// (a depth camera blinded by sunlight, glass, a too-near scene), PnP
    /// RANSAC on their pixels.
    pub(super) fn relocalise(&self, map: &Map, frame: &Frame) -> Option<Isometry3<f64>> {
        const MIN_MATCHES: usize = 20;
        let cam_points: Vec<Option<Vector3<f64>>> = (0..frame.kps.len())
            .map(|k| frame.depth[k].map(|d| self.camera.unproject(frame.un[k].0, frame.un[k].1, d)))
            .collect();
        for (_, kf) in map.live_keyframes().rev().take(40) {
            let mut pairs = Vec::new();
            let mut pixels = Vec::new();
            for (k, p) in match_to_keyframe(map, kf, &frame.descs) {
                let world = map.points[p].position;
                match cam_points[k] {
                    Some(c) => pairs.push((world, c)),
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
            if let Some(pose) = pose.filter(is_finite_pose) {
                return Some(pose);
            }
        }
        None
    }
}

/// Rigid transform mapping `world` to `camera` points (camera from world)
/// by RANSAC over 3-point fits, refitted on the inliers; None with fewer
/// than `min_inliers` inliers.
fn ransac_rigid(
    pairs: &[(Vector3<f64>, Vector3<f64>)],
    threshold: f64,
    iterations: usize,
    min_inliers: usize,
) -> Option<Isometry3<f64>> {
    let search = Ransac {
        sample: 3,
        iterations,
        seed: 0x5EED,
    };
    let (_, inliers) = search.run(
        pairs.len(),
        |s| fit_rigid(&s.iter().map(|&i| pairs[i]).collect::<Vec<_>>()),
        |t, i| ((t * Point3::from(pairs[i].0)).coords - pairs[i].1).norm() < threshold,
    )?;
    if inliers.len() < min_inliers {
        return None;
    }
    fit_rigid(&inliers.iter().map(|&i| pairs[i]).collect::<Vec<_>>())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

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
