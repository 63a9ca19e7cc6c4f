//! Local bundle adjustment as local mapping runs it: which keyframes and
//! points take part and what is held fixed; the solver is
//! [`crate::optimizer::local_ba`].

use std::collections::HashMap;

use nalgebra::{Isometry3, Point3, Vector3};

use crate::camera::Camera;
use crate::map::Map;
use crate::optimizer::local_ba::{bundle_adjust, BaObservation};
use crate::params::Sensor;

/// Which adjustment: a local one over the newest keyframes (which may be
/// every keyframe of a young map) or the global one after a loop or a
/// monocular start. They take different points: in a local adjustment
/// (RGB-D) a point never measured with (close) depth has only parallax to
/// fix its distance, which between neighbouring keyframes is too little
/// next to the depth-measured ones: left out. The global one takes it (as
/// ORB-SLAM2 does), its keyframes far apart: a keyframe looking across a
/// room has few close points, and without the far ones its turn is barely
/// held (the rendered orbit, 250 features: keyframes moved 4-42 cm, ATE
/// after a loop 0.0211 -> 0.0817 m; with them 0.0146 m). Monocular points
/// all have only parallax, in both.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scope {
    Local,
    Global,
}

impl Map {
    /// Local bundle adjustment after a keyframe insertion: the newest
    /// `local_ba_keyframes` keyframes and every point they see, against all
    /// observations of those points; older keyframes seeing them are held
    /// fixed (and the first keyframe always is: it defines the world).
    /// Outlier observations are removed from their keyframe. False when
    /// there was nothing to adjust.
    pub(super) fn local_bundle_adjustment(
        &mut self,
        camera: &Camera,
        keyframes: usize,
        sensor: Sensor,
    ) -> bool {
        let first_local = self.keyframes.len().saturating_sub(keyframes);
        self.bundle_adjustment_from(camera, first_local, sensor, Scope::Local)
    }

    /// Global bundle adjustment (ORB-SLAM2's after a loop correction and
    /// after monocular initialisation): every keyframe and point, the first
    /// keyframe held fixed (it defines the world). False when there was
    /// nothing to adjust.
    pub fn global_bundle_adjustment(&mut self, camera: &Camera, sensor: Sensor) -> bool {
        self.bundle_adjustment_from(camera, 0, sensor, Scope::Global)
    }

    /// Bundle adjustment of keyframes `first_local..` and their points
    /// (see [`Map::local_bundle_adjustment`]).
    fn bundle_adjustment_from(
        &mut self,
        camera: &Camera,
        first_local: usize,
        sensor: Sensor,
        scope: Scope,
    ) -> bool {
        let mut point_slot: HashMap<usize, usize> = HashMap::new();
        let mut point_ids: Vec<usize> = Vec::new();
        for kf in &self.keyframes[first_local..] {
            for &p in &kf.points {
                if self.points[p].visible > 0 && !point_slot.contains_key(&p) {
                    point_slot.insert(p, point_ids.len());
                    point_ids.push(p);
                }
            }
        }
        // Every keyframe observing a local point takes part.
        let mut kf_slot: HashMap<usize, usize> = HashMap::new();
        let mut kf_ids: Vec<usize> = Vec::new();
        let mut obs: Vec<BaObservation> = Vec::new();
        let mut obs_at: Vec<(usize, usize)> = Vec::new();
        let mut seen_by = vec![0u32; point_ids.len()];
        let mut with_depth = vec![false; point_ids.len()];
        for (kid, kf) in self.keyframes.iter().enumerate() {
            for (j, (&p, m)) in kf.points.iter().zip(&kf.measurements).enumerate() {
                let Some(&slot) = point_slot.get(&p) else {
                    continue;
                };
                let pose = *kf_slot.entry(kid).or_insert_with(|| {
                    kf_ids.push(kid);
                    kf_ids.len() - 1
                });
                seen_by[slot] += 1;
                with_depth[slot] |= m.ur.is_some();
                obs.push(BaObservation {
                    pose,
                    point: slot,
                    u: m.u,
                    v: m.v,
                    ur: m.ur,
                    info: m.info,
                });
                obs_at.push((kid, j));
            }
        }
        // A point seen once constrains no pose; one with only parallax
        // (never measured with close depth) takes part as [`Scope`] says.
        let parallax_only = scope == Scope::Global || sensor == Sensor::Monocular;
        let adjusted: Vec<bool> = seen_by
            .iter()
            .zip(&with_depth)
            .map(|(&n, &d)| n >= 2 && (d || parallax_only))
            .collect();
        let keep: Vec<bool> = obs.iter().map(|o| adjusted[o.point]).collect();
        let (obs, obs_at): (Vec<_>, Vec<_>) = obs
            .into_iter()
            .zip(obs_at)
            .zip(&keep)
            .filter(|(_, &k)| k)
            .map(|(pair, _)| pair)
            .unzip();
        if obs.is_empty() {
            return false;
        }
        let fixed: Vec<bool> = kf_ids.iter().map(|&k| k < first_local || k == 0).collect();
        if fixed.iter().all(|&f| !f) || fixed.iter().all(|&f| f) {
            return false;
        }
        let mut poses: Vec<Isometry3<f64>> =
            kf_ids.iter().map(|&k| self.keyframes[k].pose_cw).collect();
        let mut positions: Vec<Vector3<f64>> =
            point_ids.iter().map(|&p| self.points[p].position).collect();
        let inlier = bundle_adjust(camera, &mut poses, &fixed, &mut positions, &obs);
        for (slot, &p) in point_ids.iter().enumerate() {
            if adjusted[slot] {
                self.points[p].position = positions[slot];
            }
        }
        // Points left out of the adjustment move rigidly with the newest
        // keyframe that measured them, so they stay where that keyframe saw
        // them (else the adjusted pose and its own points would disagree).
        let mut moved = adjusted.clone();
        for (i, &k) in kf_ids.iter().enumerate().rev() {
            if fixed[i] {
                continue;
            }
            let correction = poses[i].inverse() * self.keyframes[k].pose_cw;
            for &p in &self.keyframes[k].points {
                if let Some(&slot) = point_slot.get(&p) {
                    if !moved[slot] {
                        moved[slot] = true;
                        self.points[p].position =
                            (correction * Point3::from(self.points[p].position)).coords;
                    }
                }
            }
            self.keyframes[k].pose_cw = poses[i];
        }
        // Drop outlier observations (highest index first per keyframe).
        let mut outliers: Vec<(usize, usize)> = obs_at
            .iter()
            .zip(&inlier)
            .filter(|(_, &ok)| !ok)
            .map(|(&at, _)| at)
            .collect();
        outliers.sort_unstable_by(|a, b| b.cmp(a));
        for (kid, j) in outliers {
            let p = self.keyframes[kid].points.swap_remove(j);
            self.keyframes[kid].measurements.swap_remove(j);
            self.points[p].observers.retain(|&k| k != kid);
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::{KeyFrame, KeyFrameObservation, MapPoint};
    use nalgebra::{Translation3, UnitQuaternion};

    /// A camera gliding sideways along a textured wall 3 m away: 10
    /// keyframes 0.2 m apart, 200 wall points, each keyframe measuring
    /// (u, v, ur) exactly from its true pose. The map drifted: keyframe k
    /// is 1.5 cm * k off sideways and 0.25 deg * k off in heading, its new
    /// points where its drifted pose put them. Global BA, the first
    /// keyframe fixed, brings every keyframe back within 5 mm and 0.05 deg
    /// and every point within 1 cm (from up to 13.5 cm and 2.25 deg).
    #[test]
    fn global_bundle_adjustment_removes_a_known_drift() {
        let camera = Camera::tum_fr1();
        let n = 10;
        let truth_wc: Vec<Isometry3<f64>> = (0..n)
            .map(|k| Isometry3::translation(0.2 * k as f64, 0.0, 0.0))
            .collect();
        let drift = |k: usize| {
            Isometry3::from_parts(
                Translation3::new(0.015 * k as f64, 0.0, 0.0),
                UnitQuaternion::from_euler_angles(0.0, (0.25 * k as f64).to_radians(), 0.0),
            )
        };
        let drifted_wc: Vec<Isometry3<f64>> = (0..n).map(|k| truth_wc[k] * drift(k)).collect();
        let wall: Vec<Vector3<f64>> = (0..200)
            .map(|i| {
                let (col, row) = ((i % 20) as f64, (i / 20) as f64);
                Vector3::new(
                    -1.2 + 0.2 * col + 0.03 * row,
                    -0.9 + 0.2 * row,
                    3.0 + 0.1 * ((i * 7) % 5) as f64,
                )
            })
            .collect();
        let bounds = (0.0, 640.0, 0.0, 480.0);
        let mut map = Map::default();
        let mut point_of: Vec<Option<usize>> = vec![None; wall.len()];
        for k in 0..n {
            let cw = truth_wc[k].inverse();
            let mut points = Vec::new();
            let mut measurements = Vec::new();
            for (i, x) in wall.iter().enumerate() {
                let pc = cw * Point3::from(*x);
                let (u, v) = camera.project(&pc.coords);
                if !(20.0..620.0).contains(&u) || !(20.0..460.0).contains(&v) {
                    continue;
                }
                let m = KeyFrameObservation {
                    u,
                    v,
                    ur: Some(u - camera.bf / pc.z),
                    info: 1.0,
                    descriptor: [i as u64; 4],
                    angle: 0.0,
                };
                let p = *point_of[i].get_or_insert_with(|| {
                    // Where this keyframe's drifted pose puts it.
                    let seen = drifted_wc[k] * pc;
                    map.add_point(MapPoint::new(seen.coords, k, &m, pc.z, [0; 3]))
                });
                points.push(p);
                measurements.push(m);
            }
            map.add_keyframe(KeyFrame {
                pose_cw: drifted_wc[k].inverse(),
                points,
                measurements,
                spare: Vec::new(),
                bounds,
                covisible: Vec::new(),
                parent: k.checked_sub(1),
                loops: Vec::new(),
                culled: false,
            });
        }
        let errors = |map: &Map| {
            let mut kf = (0.0f64, 0.0f64);
            for (kf_now, truth) in map.keyframes.iter().zip(&truth_wc) {
                let d = kf_now.pose_cw * truth;
                kf.0 = kf.0.max(d.translation.vector.norm());
                kf.1 = kf.1.max(d.rotation.angle().to_degrees());
            }
            let point = (0..wall.len())
                .filter_map(|i| point_of[i].map(|p| (map.points[p].position - wall[i]).norm()))
                .fold(0.0, f64::max);
            (kf, point)
        };
        let (kf_before, point_before) = errors(&map);
        assert!(map.global_bundle_adjustment(&camera, Sensor::Rgbd));
        let (kf_after, point_after) = errors(&map);
        eprintln!(
            "keyframes {:.4} m / {:.3} deg -> {:.5} m / {:.4} deg, points {point_before:.3} -> {point_after:.5} m",
            kf_before.0, kf_before.1, kf_after.0, kf_after.1
        );
        assert!(kf_before.0 > 0.1 && kf_before.1 > 2.0);
        assert!(kf_after.0 < 0.005 && kf_after.1 < 0.05, "{kf_after:?}");
        assert!(point_after < 0.01, "{point_after}");
        // The first keyframe is the fixed gauge.
        assert_eq!(map.keyframes[0].pose_cw, truth_wc[0].inverse());
        map.check_invariants().unwrap();
    }
}
