//! Local bundle adjustment as local mapping runs it: which keyframes and
//! points take part and what is held fixed; the solver is
//! [`crate::optimizer::local_ba`].

use std::collections::HashMap;

use nalgebra::{Isometry3, Point3, Vector3};

use crate::camera::Camera;
use crate::map::Map;
use crate::optimizer::local_ba::{bundle_adjust, BaObservation};

impl Map {
    /// Local bundle adjustment after a keyframe insertion: the newest
    /// `local_ba_keyframes` keyframes and every point they see, against all
    /// observations of those points; older keyframes seeing them are held
    /// fixed (and the first keyframe always is: it defines the world).
    /// Outlier observations are removed from their keyframe. False when
    /// there was nothing to adjust.
    pub(super) fn local_bundle_adjustment(&mut self, camera: &Camera, keyframes: usize) -> bool {
        let n = self.keyframes.len();
        let first_local = n.saturating_sub(keyframes);
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
        // A point seen once constrains no pose, and one never measured
        // with (close) depth has only parallax to fix its distance, which
        // between neighbouring keyframes is too little: leave both out.
        let adjusted: Vec<bool> = seen_by
            .iter()
            .zip(&with_depth)
            .map(|(&n, &d)| n >= 2 && d)
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
