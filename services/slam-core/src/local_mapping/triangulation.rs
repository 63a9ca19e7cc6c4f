//! New map points from keypoints that two keyframes saw without depth
//! (ORB-SLAM2's CreateNewMapPoints). Points from depth cover most of an
//! RGB-D map; triangulation adds what the depth camera misses: surfaces
//! beyond its range, black, shiny or glassy ones, object edges where the
//! depth image has holes.
//!
//! For keyframe `id` and each covisible neighbour far enough away, spare
//! keypoints (no point yet) are matched along the epipolar line by
//! descriptor, triangulated linearly, and kept when the rays have parallax,
//! the point lies in front of both cameras, reprojects within the chi-square
//! bound of each keypoint's level, and its distances agree with the two
//! pyramid levels. [`super::culling`] removes the ones no
//! third keyframe confirms.

use nalgebra::{Matrix3, Point3, RowVector4, Vector3};

use crate::camera::Camera;
use crate::map::{KeyFrame, Map, MapPoint, SpareKeypoint};
use crate::matcher::epipolar_matches;
use crate::matcher::ray;
use crate::optimizer::pose::chi2_threshold;
use crate::params::Sensor;

/// Rays closer than this (cosine of 1.15 degrees) fix depth too poorly.
const MAX_PARALLAX_COS: f64 = 0.9998;

impl Map {
    /// Triangulates new points between keyframe `id` and `neighbours`;
    /// `scale_factor` is the pyramid's step. Returns how many it made.
    pub(super) fn triangulate(
        &mut self,
        id: usize,
        neighbours: &[usize],
        camera: &Camera,
        scale_factor: f64,
        sensor: Sensor,
    ) -> usize {
        // Which of keyframe id's spare keypoints got a point.
        let mut taken: Vec<Option<usize>> = vec![None; self.keyframes[id].spare.len()];
        for &n in neighbours {
            let (kf1, kf2) = (&self.keyframes[id], &self.keyframes[n]);
            if kf2.culled || n == id {
                continue;
            }
            // RGB-D: below the depth camera's own (virtual) baseline, depth
            // already says more than the pair could (ORB-SLAM2's stereo
            // rule). Monocular: the baseline must be 1 % of the scene's
            // median depth from the neighbour (ORB-SLAM2's).
            let baseline = (kf1.centre() - kf2.centre()).norm();
            let too_short = match sensor {
                Sensor::Rgbd => baseline < camera.bf / camera.fx,
                Sensor::Monocular => self.median_depth(n).is_none_or(|d| baseline < 0.01 * d),
            };
            if too_short {
                continue;
            }
            let mut taken2: Vec<Option<usize>> = vec![None; kf2.spare.len()];
            let mut created = Vec::new();
            for (i, j) in epipolar_matches(camera, kf1, kf2, &taken) {
                let (s1, s2) = (&kf1.spare[i], &kf2.spare[j]);
                if taken2[j].is_some() {
                    continue;
                }
                let Some(x) = triangulate_pair(camera, kf1, s1, kf2, s2, scale_factor) else {
                    continue;
                };
                let p = self.points.len() + created.len();
                let mut point =
                    MapPoint::new(x, id, &s1.measurement, (x - kf1.centre()).norm(), s1.colour);
                point.observers.push(n);
                point.triangulated_in = Some(id);
                created.push(point);
                taken[i] = Some(p);
                taken2[j] = Some(p);
            }
            self.points.extend(created);
            self.keyframes[n].take_spare(&taken2);
        }
        let made = taken.iter().flatten().count();
        self.keyframes[id].take_spare(&taken);
        made
    }
}

impl Map {
    /// The median depth of keyframe `k`'s points in its camera (None
    /// without points).
    pub fn median_depth(&self, k: usize) -> Option<f64> {
        let kf = &self.keyframes[k];
        let mut z: Vec<f64> = kf
            .points
            .iter()
            .map(|&p| (kf.pose_cw * Point3::from(self.points[p].position)).z)
            .collect();
        if z.is_empty() {
            return None;
        }
        let mid = z.len() / 2;
        Some(*z.select_nth_unstable_by(mid, f64::total_cmp).1)
    }
}

impl KeyFrame {
    /// Spare keypoint `s` measures point `taken[s]` (where Some) from now
    /// on: it moves to the keyframe's measured points.
    pub(super) fn take_spare(&mut self, taken: &[Option<usize>]) {
        if taken.iter().all(Option::is_none) {
            return;
        }
        let spare = std::mem::take(&mut self.spare);
        for (s, point) in spare.into_iter().zip(taken) {
            match point {
                Some(p) => {
                    self.points.push(*p);
                    self.measurements.push(s.measurement);
                }
                None => self.spare.push(s),
            }
        }
    }
}

/// The world point two keypoints see (linear triangulation, least squares
/// on the four DLT rows), if it passes the parallax, cheirality,
/// reprojection and scale checks.
fn triangulate_pair(
    camera: &Camera,
    kf1: &KeyFrame,
    s1: &SpareKeypoint,
    kf2: &KeyFrame,
    s2: &SpareKeypoint,
    scale_factor: f64,
) -> Option<Vector3<f64>> {
    let (m1, m2) = (&s1.measurement, &s2.measurement);
    let (r1, r2) = (ray(camera, s1), ray(camera, s2));
    let (w1, w2) = (
        kf1.pose_cw.rotation.inverse() * r1,
        kf2.pose_cw.rotation.inverse() * r2,
    );
    let cos = w1.dot(&w2) / (w1.norm() * w2.norm());
    if !(0.0..MAX_PARALLAX_COS).contains(&cos) {
        return None;
    }
    // Rows x P3 - P1 and y P3 - P2 of each camera's 3x4 projection.
    let mut rows = Vec::with_capacity(4);
    for (pose, r) in [(&kf1.pose_cw, r1), (&kf2.pose_cw, r2)] {
        let p = pose.to_homogeneous();
        rows.push(r.x * p.row(2) - p.row(0));
        rows.push(r.y * p.row(2) - p.row(1));
    }
    let (mut ata, mut atb) = (Matrix3::zeros(), Vector3::zeros());
    for row in &rows {
        let a: RowVector4<f64> = *row;
        let a3 = Vector3::new(a[0], a[1], a[2]);
        ata += a3 * a3.transpose();
        atb -= a3 * a[3];
    }
    let x = ata.try_inverse()? * atb;
    if !x.iter().all(|c| c.is_finite()) {
        return None;
    }
    for (kf, m) in [(kf1, m1), (kf2, m2)] {
        let pc = kf.pose_cw * Point3::from(x);
        if pc.z <= 0.0 {
            return None;
        }
        let (u, v) = camera.project(&pc.coords);
        let err = ((u - m.u).powi(2) + (v - m.v).powi(2)) * m.info;
        if err > chi2_threshold(false) {
            return None;
        }
    }
    // Distances from the two cameras in the ratio of the two levels'
    // scales (within 1.5 pyramid steps either way).
    let ratio_distance = (x - kf2.centre()).norm() / (x - kf1.centre()).norm();
    let ratio_octave = m1.sigma() / m2.sigma();
    let slack = 1.5 * scale_factor;
    if ratio_distance * slack < ratio_octave || ratio_distance > ratio_octave * slack {
        return None;
    }
    Some(x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::KeyFrameObservation;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    fn camera() -> Camera {
        let mut c = Camera::tum_fr1();
        c.dist = [0.0; 5];
        c
    }

    fn keyframe(pose_cw: Isometry3<f64>, camera: &Camera, world: &[Vector3<f64>]) -> KeyFrame {
        let spare = world
            .iter()
            .enumerate()
            .map(|(i, x)| {
                let (u, v) = camera.project(&(pose_cw * Point3::from(*x)).coords);
                // Distinct descriptors (far apart), the same in both keyframes.
                let mut rng = crate::rng::SplitMix64::new(i as u64 + 1);
                let descriptor = [0; 4].map(|_: u64| rng.next_u64());
                SpareKeypoint {
                    measurement: KeyFrameObservation {
                        u,
                        v,
                        ur: None,
                        info: 1.0,
                        descriptor,
                        angle: 0.0,
                    },
                    colour: [1, 2, 3],
                }
            })
            .collect();
        KeyFrame {
            pose_cw,
            points: Vec::new(),
            measurements: Vec::new(),
            spare,
            bounds: (0.0, 640.0, 0.0, 480.0),
            covisible: Vec::new(),
            parent: None,
            loops: Vec::new(),
            culled: false,
        }
    }

    /// Two keyframes 30 cm apart seeing points 2-4 m away without depth:
    /// every point comes back where it is, observed by both.
    #[test]
    fn points_seen_from_two_keyframes_are_triangulated_where_they_are() {
        let camera = camera();
        let world: Vec<Vector3<f64>> = (0..40)
            .map(|i| {
                let f = i as f64;
                Vector3::new(
                    0.8 * (0.9 * f).sin(),
                    0.6 * (1.3 * f).cos(),
                    2.0 + (f % 7.0) / 3.5,
                )
            })
            .collect();
        let second = Isometry3::from_parts(
            Translation3::new(-0.3, 0.02, 0.0),
            UnitQuaternion::from_euler_angles(0.01, 0.05, 0.0),
        );
        let mut map = Map {
            keyframes: vec![
                keyframe(Isometry3::identity(), &camera, &world),
                keyframe(second, &camera, &world),
            ],
            ..Map::default()
        };
        let made = map.triangulate(1, &[0], &camera, 1.2, Sensor::Rgbd);
        assert_eq!(made, world.len());
        for (p, kf) in map.points.iter().zip(&map.keyframes[1].points) {
            assert_eq!(p.observers, vec![1, 0]);
            let truth = world
                .iter()
                .min_by(|a, b| {
                    (*a - p.position)
                        .norm()
                        .total_cmp(&(*b - p.position).norm())
                })
                .unwrap();
            assert!((truth - p.position).norm() < 1e-6, "{kf}: {}", p.position);
        }
        assert!(map.keyframes.iter().all(|k| k.spare.is_empty()));
        assert!(map.keyframes.iter().all(|k| k.points.len() == world.len()));
        // Nothing is left to triangulate a second time.
        assert_eq!(map.triangulate(1, &[0], &camera, 1.2, Sensor::Rgbd), 0);
    }

    /// Too little baseline, or a keypoint off its epipolar line: no point.
    #[test]
    fn no_points_without_baseline_or_off_the_epipolar_line() {
        let camera = camera();
        let world = vec![Vector3::new(0.1, 0.2, 3.0), Vector3::new(-0.4, 0.1, 2.5)];
        let near = Isometry3::translation(-0.03, 0.0, 0.0);
        let mut map = Map {
            keyframes: vec![
                keyframe(Isometry3::identity(), &camera, &world),
                keyframe(near, &camera, &world),
            ],
            ..Map::default()
        };
        assert_eq!(map.triangulate(1, &[0], &camera, 1.2, Sensor::Rgbd), 0);
        map.keyframes[1] = keyframe(Isometry3::translation(-0.3, 0.0, 0.0), &camera, &world);
        // Moved 20 px across the epipolar line (horizontal here).
        map.keyframes[1].spare[0].measurement.v += 20.0;
        assert_eq!(map.triangulate(1, &[0], &camera, 1.2, Sensor::Rgbd), 1);
        assert_eq!(map.keyframes[1].spare.len(), 1);
    }
}
