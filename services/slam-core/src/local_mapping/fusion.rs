//! Fusion of duplicate map points (ORB-SLAM2's SearchInNeighbors).
//!
//! The same surface point enters the map more than once: a keypoint that
//! tracking did not match (outside the search window, an outlier that frame)
//! gets a new point from its depth at the next keyframe, and triangulation
//! may create what another keyframe already has. Duplicates split the
//! observations that should constrain one point, so a keyframe's points are
//! seen by fewer keyframes than they could be.
//!
//! After keyframe `id`, its points are projected into its covisible
//! keyframes (and their best neighbours), and theirs into it. A point seen
//! from a distance its descriptor can be recognised at, that lands on a
//! keypoint of the level its distance predicts (or one finer), within that
//! keypoint's chi-square bound (depth included: measured, or for a far
//! keypoint that of its point) and with a
//! close descriptor, either merges with the point that keypoint measures
//! (the one more keyframes measure stays) or, on a spare keypoint, gains
//! that keyframe as an observer.
//!
//! Off by default (`SlamParams::fuse_points`): on our sequences it leaves
//! ATE level without masks but costs a quarter of the inliers per frame,
//! and with the product's imperfect masks on the rendered room it triples
//! ATE (README, SLAM section, has the figures).

use std::collections::HashSet;

use nalgebra::{Point3, Vector3};

use crate::camera::Camera;
use crate::features::grid::Grid;
use crate::features::orb::{hamming, MATCH_MAX_DISTANCE};
use crate::map::{KeyFrameObservation, Map, MAPPING_NEIGHBOURS, SECOND_NEIGHBOURS};
use crate::optimizer::pose::{chi2_error, chi2_threshold};

/// Search window around a projection, in pixels at the predicted level
/// (ORB-SLAM2's 3); the chi-square test on each candidate decides.
const RADIUS: f64 = 3.0;

impl Map {
    /// Fuses keyframe `id`'s points with its neighbours'; the pyramid has
    /// `levels` levels `scale_factor` apart. Returns the points merged and
    /// the observations added to spare keypoints.
    pub(super) fn fuse(
        &mut self,
        id: usize,
        camera: &Camera,
        scale_factor: f64,
        levels: usize,
    ) -> (usize, usize) {
        let pyramid = (scale_factor, levels);
        let first = self.best_covisible(id, MAPPING_NEIGHBOURS);
        let mut targets = first.clone();
        for &k in &first {
            for &(n, _) in self.keyframes[k].covisible.iter().take(SECOND_NEIGHBOURS) {
                if n != id && !self.keyframes[n].culled && !targets.contains(&n) {
                    targets.push(n);
                }
            }
        }
        let (mut fused, mut added) = (0, 0);
        let own = self.keyframes[id].points.clone();
        for &k in &targets {
            let (f, a) = self.fuse_into(k, &own, camera, pyramid);
            fused += f;
            added += a;
        }
        let mut seen = HashSet::new();
        let theirs: Vec<usize> = targets
            .iter()
            .flat_map(|&k| self.keyframes[k].points.iter().copied())
            .filter(|&p| self.points[p].visible > 0 && seen.insert(p))
            .collect();
        let (f, a) = self.fuse_into(id, &theirs, camera, pyramid);
        (fused + f, added + a)
    }

    /// Projects `points` into keyframe `k` and fuses each with the keypoint
    /// it lands on (see the module). Returns (merged, observations added).
    fn fuse_into(
        &mut self,
        k: usize,
        points: &[usize],
        camera: &Camera,
        (scale_factor, levels): (f64, usize),
    ) -> (usize, usize) {
        let kf = &self.keyframes[k];
        let pose = kf.pose_cw;
        let centre = kf.centre();
        let (x0, x1, y0, y1) = kf.bounds;
        // Candidates: measured keypoints first (index j), then spare ones
        // (index measured + s). Replacing points below never reorders this
        // keyframe's measurements: it only ever observes the point kept.
        let measured = kf.measurements.len();
        let candidates: Vec<KeyFrameObservation> = kf
            .measurements
            .iter()
            .copied()
            .chain(kf.spare.iter().map(|s| s.measurement))
            .collect();
        let pixels: Vec<(f64, f64)> = candidates.iter().map(|m| (m.u, m.v)).collect();
        let grid = Grid::new(
            &pixels,
            x1.max(0.0).ceil() as usize,
            y1.max(0.0).ceil() as usize,
        );
        let mut observes: HashSet<usize> = kf.points.iter().copied().collect();
        let mut spare_taken: Vec<Option<usize>> = vec![None; kf.spare.len()];
        let (mut fused, mut added) = (0, 0);
        let mut near = Vec::new();
        for &p in points {
            if self.points[p].visible == 0 || observes.contains(&p) {
                continue;
            }
            let point = &self.points[p];
            let pc = pose * Point3::from(point.position);
            if pc.z <= 1e-3 {
                continue;
            }
            let (u, v) = camera.project(&pc.coords);
            if !(x0..x1).contains(&u) || !(y0..y1).contains(&v) {
                continue;
            }
            let distance = (point.position - centre).norm();
            let Some(level) = point.predicted_level(distance, scale_factor, levels) else {
                continue;
            };
            let ur = u - camera.bf / pc.z;
            let descriptor = point.descriptor;
            grid.near(u, v, RADIUS * scale_factor.powi(level), &mut near);
            let mut best: Option<(usize, u32)> = None;
            for &c in &near {
                let m = &candidates[c];
                // A measured keypoint's depth: measured if close, else that
                // of its point (far depth is not measured but still tells
                // a person 2 m away from the wall behind them).
                let (free, depth_ur) = match c.checked_sub(measured) {
                    Some(s) => (spare_taken[s].is_none(), m.ur),
                    None => {
                        let q = &self.points[self.keyframes[k].points[c]];
                        let zq = (pose * Point3::from(q.position)).z;
                        let ur_q = (zq > 1e-3).then(|| m.u - camera.bf / zq);
                        (q.visible > 0, m.ur.or(ur_q))
                    }
                };
                let r = Vector3::new(m.u - u, m.v - v, depth_ur.map_or(0.0, |mr| mr - ur));
                let has_ur = depth_ur.is_some();
                if !free
                    || !(level - 1..=level).contains(&m.level(scale_factor))
                    || chi2_error(&r, has_ur, m.info) > chi2_threshold(has_ur)
                {
                    continue;
                }
                let d = hamming(&descriptor, &m.descriptor);
                if d <= MATCH_MAX_DISTANCE && best.is_none_or(|b| d < b.1) {
                    best = Some((c, d));
                }
            }
            let Some((c, _)) = best else {
                continue;
            };
            match c.checked_sub(measured) {
                Some(s) => {
                    spare_taken[s] = Some(p);
                    observes.insert(p);
                    self.points[p].observers.push(k);
                    added += 1;
                }
                None => {
                    let q = self.keyframes[k].points[c];
                    let (keep, gone) =
                        if self.points[q].observers.len() >= self.points[p].observers.len() {
                            (q, p)
                        } else {
                            (p, q)
                        };
                    self.replace_point(gone, keep);
                    observes.remove(&gone);
                    observes.insert(keep);
                    fused += 1;
                }
            }
        }
        self.keyframes[k].take_spare(&spare_taken);
        (fused, added)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::orb::Descriptor;
    use crate::map::{KeyFrame, MapPoint, SpareKeypoint};
    use nalgebra::Isometry3;

    fn descriptor(i: usize) -> Descriptor {
        let mut rng = crate::rng::SplitMix64::new(i as u64 + 7);
        [0; 4].map(|_: u64| rng.next_u64())
    }

    /// Keyframe `pose` measuring `world` as keypoint `i` (level 0, with
    /// depth when `depth`).
    fn measure(
        camera: &Camera,
        pose: &Isometry3<f64>,
        world: &Vector3<f64>,
        i: usize,
        depth: bool,
    ) -> KeyFrameObservation {
        let pc = pose * Point3::from(*world);
        let (u, v) = camera.project(&pc.coords);
        KeyFrameObservation {
            u,
            v,
            ur: depth.then(|| u - camera.bf / pc.z),
            info: 1.0,
            descriptor: descriptor(i),
            angle: 0.0,
        }
    }

    fn point(world: Vector3<f64>, i: usize, observer: usize, distance: f64) -> MapPoint {
        MapPoint {
            position: world,
            descriptor: descriptor(i),
            observers: vec![observer],
            visible: 1,
            found: 1,
            colour: [0; 3],
            triangulated_in: None,
            level0_distance: distance,
        }
    }

    fn keyframe(pose_cw: Isometry3<f64>) -> KeyFrame {
        KeyFrame {
            pose_cw,
            points: Vec::new(),
            measurements: Vec::new(),
            spare: Vec::new(),
            bounds: (0.0, 640.0, 0.0, 480.0),
            covisible: Vec::new(),
            parent: None,
            loops: Vec::new(),
            culled: false,
        }
    }

    /// Keyframe 1 shares ten points with keyframe 0, made duplicates of ten
    /// more from its depth (3 mm off), has five spare keypoints on points of
    /// keyframe 0, and five points 80 cm behind points of keyframe 0 on the
    /// same pixels. Fusion merges the ten duplicates, gives the five spare
    /// keypoints their points, leaves the five deeper points alone (depth
    /// disagrees), and compaction then drops the merged ones.
    #[test]
    fn duplicates_merge_spare_keypoints_gain_points_and_other_depths_stay() {
        let mut camera = Camera::tum_fr1();
        camera.dist = [0.0; 5];
        let world: Vec<Vector3<f64>> = (0..30)
            .map(|i| {
                let f = i as f64;
                Vector3::new(
                    0.7 * (1.7 * f).sin(),
                    0.5 * (0.9 * f).cos(),
                    1.6 + (f % 5.0) / 5.0,
                )
            })
            .collect();
        let poses = [
            Isometry3::identity(),
            Isometry3::translation(-0.1, 0.0, 0.0),
        ];
        let mut map = Map {
            keyframes: vec![keyframe(poses[0]), keyframe(poses[1])],
            ..Map::default()
        };
        for (i, w) in world.iter().enumerate() {
            map.points.push(point(*w, i, 0, w.norm()));
            map.keyframes[0].points.push(i);
            let m = measure(&camera, &poses[0], w, i, true);
            map.keyframes[0].measurements.push(m);
        }
        let centre1 = Vector3::new(0.1, 0.0, 0.0);
        for (i, w) in world.iter().enumerate() {
            let m = measure(&camera, &poses[1], w, i, true);
            let kf1 = 1;
            match i {
                0..10 => {
                    map.points[i].observers.push(kf1);
                    map.keyframes[kf1].points.push(i);
                }
                10..20 => {
                    let dup = w + Vector3::new(0.003, -0.002, 0.003);
                    map.points.push(point(dup, i, kf1, (dup - centre1).norm()));
                    map.keyframes[kf1].points.push(map.points.len() - 1);
                }
                20..25 => {
                    let measurement = measure(&camera, &poses[1], w, i, false);
                    map.keyframes[kf1].spare.push(SpareKeypoint {
                        measurement,
                        colour: [0; 3],
                    });
                    continue;
                }
                _ => {
                    let deeper = centre1 + (w - centre1) * (1.0 + 0.8 / (w - centre1).norm());
                    let m = measure(&camera, &poses[1], &deeper, i, true);
                    map.points
                        .push(point(deeper, i, kf1, (deeper - centre1).norm()));
                    map.keyframes[kf1].points.push(map.points.len() - 1);
                    map.keyframes[kf1].measurements.push(m);
                    continue;
                }
            }
            map.keyframes[kf1].measurements.push(m);
        }
        let (fused, added) = map.fuse(1, &camera, 1.2, 8);
        assert_eq!((fused, added), (10, 5));
        let kf1 = &map.keyframes[1];
        assert!(kf1.spare.is_empty());
        // Keyframe 1 now measures the original points 0..25 and its 5 deeper ones.
        let mut measured: Vec<usize> = kf1.points.clone();
        measured.sort_unstable();
        let expected: Vec<usize> = (0..25).chain(40..45).collect();
        assert_eq!(measured, expected);
        for p in 0..25 {
            assert_eq!(map.points[p].observers.len(), 2, "point {p}");
        }
        assert!(map.points[30..40]
            .iter()
            .all(|p| p.visible == 0 && p.observers.is_empty()));
        // Ids are stable: the merged-away points keep their (empty) slots,
        // the deeper ones are still 40..45, and the map is consistent.
        assert_eq!((map.points.len(), map.live_point_count()), (45, 35));
        assert!(map.points[40..45].iter().all(|p| p.is_live()));
        map.check_invariants().unwrap();
    }
}
