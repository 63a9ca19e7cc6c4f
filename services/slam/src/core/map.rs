//! The map (keyframes, map points, covisibility graph, spanning tree) and
//! what local mapping does to it after each keyframe (ORB-SLAM2's
//! LocalMapping): connect the keyframe in the covisibility graph, cull
//! points that are rarely found, optionally bundle-adjust the newest
//! keyframes, and cull keyframes whose points others see well enough.
//! [`super::local_mapping`] runs this on its own thread.

use std::collections::HashMap;

use nalgebra::{Isometry3, Point3, Vector3};

use super::camera::Camera;
use super::local_ba::{bundle_adjust, BaObservation};
use super::orb::Descriptor;
use super::system::SlamParams;

/// Shared points that make two keyframes neighbours (ORB-SLAM2's 15).
pub const COVISIBILITY_MIN: u32 = 15;
/// A keyframe goes when this share of its close points is seen by at least
/// `REDUNDANT_OBSERVERS` other keyframes at the same or a finer scale
/// (ORB-SLAM2's 90 % and 3).
const REDUNDANT_SHARE: f64 = 0.9;
const REDUNDANT_OBSERVERS: usize = 3;

/// Keyframes and map points. Ids are indices and stay valid: culled
/// keyframes and points are flagged, not removed.
#[derive(Debug, Clone, Default)]
pub struct Map {
    pub points: Vec<MapPoint>,
    pub keyframes: Vec<KeyFrame>,
}

/// What local mapping did for one keyframe.
#[derive(Debug, Clone, Copy, Default)]
pub struct MappingReport {
    /// Wall time of the whole job (ms).
    pub ms: f64,
    /// Local bundle adjustment moved keyframe poses.
    pub adjusted: bool,
}

#[derive(Debug, Clone)]
pub struct MapPoint {
    pub position: Vector3<f64>,
    pub descriptor: Descriptor,
    /// Keyframes that measured it (ids, in insertion order).
    pub observers: Vec<usize>,
    /// Frames in which it was predicted visible / actually matched; 0
    /// visible: culled (kept so ids stay valid, never matched again).
    pub visible: u32,
    pub found: u32,
    /// Colour of the pixel it was created from (for the PLY map).
    pub colour: [u8; 3],
}

/// A map point as one keyframe measured it (for bundle adjustment).
#[derive(Debug, Clone, Copy)]
pub struct KeyFrameObservation {
    pub u: f64,
    pub v: f64,
    /// `u - bf / depth` when the keypoint had depth.
    pub ur: Option<f64>,
    /// 1 / sigma^2 of the keypoint's pyramid level.
    pub info: f64,
}

#[derive(Debug, Clone)]
pub struct KeyFrame {
    /// Camera from world.
    pub pose_cw: Isometry3<f64>,
    /// Points this keyframe observes (ids into the map).
    pub points: Vec<usize>,
    /// How it measured each of them (same order as `points`).
    pub measurements: Vec<KeyFrameObservation>,
    /// Covisibility graph: keyframes sharing at least `COVISIBILITY_MIN`
    /// points with this one (or the one sharing most), with the count,
    /// most shared first.
    pub covisible: Vec<(usize, u32)>,
    /// Spanning tree: the keyframe it shared most points with when it was
    /// inserted (None for the first). With the covisibility graph this is
    /// what a loop closer corrects along (ORB-SLAM2's essential graph).
    pub parent: Option<usize>,
    /// Removed by keyframe culling: its points and edges are gone, the id
    /// stays so that other ids stay valid.
    pub culled: bool,
}

impl Map {
    /// The keyframes keyframe culling left in the map, with their ids,
    /// oldest first.
    pub fn live_keyframes(&self) -> impl DoubleEndedIterator<Item = (usize, &KeyFrame)> {
        self.keyframes.iter().enumerate().filter(|(_, k)| !k.culled)
    }

    /// Local mapping after keyframe `id` was inserted (its points and
    /// observations in place): covisibility edges and spanning-tree parent,
    /// recent-point culling, local bundle adjustment over the newest
    /// `params.local_ba_keyframes` keyframes (below 2: off), keyframe culling
    /// among its neighbours.
    pub fn process_keyframe(
        &mut self,
        id: usize,
        camera: &Camera,
        params: &SlamParams,
    ) -> MappingReport {
        let t = std::time::Instant::now();
        self.connect(id);
        self.cull_points();
        let ba = params.local_ba_keyframes;
        let adjusted = ba > 1 && self.local_bundle_adjustment(camera, ba);
        self.cull_keyframes(id, params.orb.scale_factor as f64);
        MappingReport {
            ms: t.elapsed().as_secs_f64() * 1e3,
            adjusted,
        }
    }

    /// Puts keyframe `id` into the covisibility graph and the spanning tree.
    fn connect(&mut self, id: usize) {
        let (covisible, parent) = self.covisibility_of(id);
        for &(other, n) in &covisible {
            let list = &mut self.keyframes[other].covisible;
            list.push((id, n));
            list.sort_unstable_by_key(|e| std::cmp::Reverse(e.1));
        }
        let kf = &mut self.keyframes[id];
        kf.covisible = covisible;
        kf.parent = parent;
    }

    /// Recent-point culling: points seen in under a quarter of the frames
    /// that should have seen them stop being matched.
    fn cull_points(&mut self) {
        for p in &mut self.points {
            if p.visible >= 20 && (p.found as f64) < 0.25 * p.visible as f64 {
                p.visible = 0;
            }
        }
    }

    /// Keyframe culling (ORB-SLAM2's rule) among the neighbours of `id`:
    /// a keyframe most of whose close points (those with depth) are
    /// measured by at least three other keyframes at the same or a finer
    /// pyramid level (`scale_factor`: the pyramid's step) adds nothing to
    /// the map and goes. The first keyframe (it defines the world) and `id`
    /// itself stay.
    fn cull_keyframes(&mut self, id: usize, scale_factor: f64) {
        let candidates: Vec<usize> = self.keyframes[id]
            .covisible
            .iter()
            .map(|&(k, _)| k)
            .filter(|&k| k != 0 && k != id)
            .collect();
        // How each keyframe measured each point (info = 1 / sigma^2 of its
        // level), built for the keyframes consulted.
        let mut measured: HashMap<usize, HashMap<usize, f64>> = HashMap::new();
        for k in candidates {
            if self.keyframes[k].culled {
                continue;
            }
            let (mut close, mut redundant) = (0usize, 0usize);
            let kf = &self.keyframes[k];
            for (&p, m) in kf.points.iter().zip(&kf.measurements) {
                if m.ur.is_none() || self.points[p].visible == 0 {
                    continue;
                }
                close += 1;
                let observers = &self.points[p].observers;
                if observers.len() <= REDUNDANT_OBSERVERS {
                    continue;
                }
                let mut others = 0;
                for &o in observers.iter().filter(|&&o| o != k) {
                    let info = measured
                        .entry(o)
                        .or_insert_with(|| {
                            let other = &self.keyframes[o];
                            other
                                .points
                                .iter()
                                .zip(&other.measurements)
                                .map(|(&q, m)| (q, m.info))
                                .collect()
                        })
                        .get(&p)
                        .copied()
                        .unwrap_or(0.0);
                    // Same or finer level: sigma at most one level larger.
                    if info * scale_factor * scale_factor >= m.info * (1.0 - 1e-9) {
                        others += 1;
                        if others >= REDUNDANT_OBSERVERS {
                            break;
                        }
                    }
                }
                if others >= REDUNDANT_OBSERVERS {
                    redundant += 1;
                }
            }
            if close > 0 && redundant as f64 > REDUNDANT_SHARE * close as f64 {
                self.cull_keyframe(k);
                measured.remove(&k);
            }
        }
    }

    /// Removes keyframe `k` from the map: its observations leave its points
    /// (a point nobody observes any more is culled), its edges leave the
    /// covisibility graph, and its children in the spanning tree take its
    /// parent as theirs.
    fn cull_keyframe(&mut self, k: usize) {
        let kf = &mut self.keyframes[k];
        kf.culled = true;
        let points = std::mem::take(&mut kf.points);
        kf.measurements.clear();
        let edges = std::mem::take(&mut kf.covisible);
        let parent = kf.parent;
        for p in points {
            let point = &mut self.points[p];
            point.observers.retain(|&o| o != k);
            if point.observers.is_empty() {
                point.visible = 0;
            }
        }
        for (other, _) in edges {
            self.keyframes[other].covisible.retain(|&(o, _)| o != k);
        }
        for other in &mut self.keyframes {
            if other.parent == Some(k) {
                other.parent = parent;
            }
        }
    }

    /// Edges of keyframe `id` in the covisibility graph (from the
    /// observers of its points), most shared first, and its spanning-tree
    /// parent.
    fn covisibility_of(&self, id: usize) -> (Vec<(usize, u32)>, Option<usize>) {
        let mut shared: HashMap<usize, u32> = HashMap::new();
        for &p in &self.keyframes[id].points {
            for &k in &self.points[p].observers {
                if k != id {
                    *shared.entry(k).or_default() += 1;
                }
            }
        }
        let mut all: Vec<(usize, u32)> = shared.into_iter().collect();
        all.sort_unstable_by(|a, b| b.1.cmp(&a.1).then(b.0.cmp(&a.0)));
        let parent = all.first().map(|&(k, _)| k);
        let strong = all.iter().take_while(|e| e.1 >= COVISIBILITY_MIN).count();
        // A keyframe with no strong neighbour keeps its best one.
        all.truncate(strong.max(1));
        (all, parent)
    }

    /// Local bundle adjustment after a keyframe insertion: the newest
    /// `local_ba_keyframes` keyframes and every point they see, against all
    /// observations of those points; older keyframes seeing them are held
    /// fixed (and the first keyframe always is: it defines the world).
    /// Outlier observations are removed from their keyframe. False when
    /// there was nothing to adjust.
    fn local_bundle_adjustment(&mut self, camera: &Camera, keyframes: usize) -> bool {
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
