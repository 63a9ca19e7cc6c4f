//! The map (keyframes, map points, covisibility graph, spanning tree) and
//! what local mapping does to it after each keyframe (ORB-SLAM2's
//! LocalMapping): cull points that are rarely found, triangulate new points
//! with covisible keyframes ([`super::triangulation`]), optionally fuse
//! duplicate points ([`super::fusion`]), connect the keyframe in the
//! covisibility graph, optionally bundle-adjust the newest keyframes, cull
//! keyframes whose points others see well enough, and drop culled points
//! once they pile up. [`super::local_mapping`] runs this on its own thread.

use std::collections::HashMap;

use nalgebra::{Isometry3, Point3, Vector3};

use super::camera::{Bounds, Camera};
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
/// Covisible keyframes triangulation and fusion work with (ORB-SLAM2's 20
/// for RGB-D), and the neighbours of each that fusion adds.
pub(super) const MAPPING_NEIGHBOURS: usize = 20;
pub(super) const SECOND_NEIGHBOURS: usize = 5;
/// A triangulated point must be measured by this many keyframes two
/// keyframes after its creation, or it goes (ORB-SLAM2's recent-point rule:
/// a point only its two creators agree on is likely a wrong match).
const TRIANGULATED_MIN_OBSERVERS: usize = 3;

/// Keyframes and map points, both by index. Culled keyframes are flagged,
/// never removed, so keyframe ids stay valid; culled points are flagged
/// and dropped later by [`Map::compact`], which renumbers the rest.
#[derive(Debug, Clone, Default)]
pub struct Map {
    pub points: Vec<MapPoint>,
    pub keyframes: Vec<KeyFrame>,
}

/// Culled points are dropped from the map once there are more of them than
/// live ones, and at least this many (so that compaction, which renumbers
/// the points, stays rare).
const COMPACT_MIN_CULLED: usize = 2000;

/// What local mapping did for one keyframe.
#[derive(Debug, Clone, Default)]
pub struct MappingReport {
    /// Wall time of the whole job (ms).
    pub ms: f64,
    /// Local bundle adjustment moved keyframe poses.
    pub adjusted: bool,
    pub counts: MappingCounts,
    /// The points were compacted: the new id of each old one (None:
    /// dropped). Whoever holds point ids renumbers them with it.
    pub renumbered: Option<Vec<Option<usize>>>,
}

/// What local mapping added to and merged in the map.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MappingCounts {
    /// Points triangulated with covisible keyframes.
    pub triangulated: usize,
    /// Duplicate points merged.
    pub fused: usize,
    /// Keyframe keypoints that gained a point they had not been matched to.
    pub observations_added: usize,
}

impl std::ops::AddAssign for MappingCounts {
    fn add_assign(&mut self, o: Self) {
        self.triangulated += o.triangulated;
        self.fused += o.fused;
        self.observations_added += o.observations_added;
    }
}

#[derive(Debug, Clone)]
pub struct MapPoint {
    pub position: Vector3<f64>,
    pub descriptor: Descriptor,
    /// Keyframes that measured it (ids, in insertion order).
    pub observers: Vec<usize>,
    /// Frames in which it was predicted visible / actually matched; 0
    /// visible: culled (never matched again, dropped at the next compaction).
    pub visible: u32,
    pub found: u32,
    /// Colour of the pixel it was created from (for the PLY map).
    pub colour: [u8; 3],
    /// The keyframe that triangulated it, until it has proved itself (see
    /// `TRIANGULATED_MIN_OBSERVERS`); None for points from depth.
    pub triangulated_in: Option<usize>,
    /// Its distance from the camera that created it times the scale of the
    /// keypoint's pyramid level: the distance at which it would appear at
    /// level 0, which gives the distances a camera can recognise it from
    /// and the level it appears at (ORB-SLAM2's scale-invariance region).
    pub level0_distance: f64,
}

impl MapPoint {
    /// A new point at `position`, first measured by keyframe `by` as `m`
    /// from `distance` metres (its descriptor and scale are `m`'s).
    pub fn new(
        position: Vector3<f64>,
        by: usize,
        m: &KeyFrameObservation,
        distance: f64,
        colour: [u8; 3],
    ) -> Self {
        Self {
            position,
            descriptor: m.descriptor,
            observers: vec![by],
            visible: 1,
            found: 1,
            colour,
            triangulated_in: None,
            level0_distance: distance * m.sigma(),
        }
    }

    /// The pyramid level (of `levels`, `scale_factor` apart) the point
    /// should appear at from `distance` metres; None outside the distances
    /// its descriptor can be recognised from (with ORB-SLAM2's 20 % slack).
    pub fn predicted_level(&self, distance: f64, scale_factor: f64, levels: usize) -> Option<i32> {
        let finest = self.level0_distance / scale_factor.powi(levels as i32 - 1);
        if !(0.8 * finest..=1.2 * self.level0_distance).contains(&distance) {
            return None;
        }
        let level = (self.level0_distance / distance).ln() / scale_factor.ln();
        Some((level.ceil() as i32).clamp(0, levels as i32 - 1))
    }
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
    /// The keypoint's own descriptor (fusion compares map points with it).
    pub descriptor: Descriptor,
}

impl KeyFrameObservation {
    /// The keypoint's scale (1.2^level for the default pyramid).
    pub fn sigma(&self) -> f64 {
        1.0 / self.info.sqrt()
    }

    /// The keypoint's pyramid level, for a pyramid `scale_factor` apart.
    pub fn level(&self, scale_factor: f64) -> i32 {
        (self.sigma().ln() / scale_factor.ln()).round() as i32
    }
}

/// A keyframe keypoint no map point explains (it had no depth and matched
/// nothing when the keyframe was made): triangulation and fusion may still
/// give it one.
#[derive(Debug, Clone, Copy)]
pub struct SpareKeypoint {
    pub measurement: KeyFrameObservation,
    pub colour: [u8; 3],
}

#[derive(Debug, Clone)]
pub struct KeyFrame {
    /// Camera from world.
    pub pose_cw: Isometry3<f64>,
    /// Points this keyframe observes (ids into the map).
    pub points: Vec<usize>,
    /// How it measured each of them (same order as `points`).
    pub measurements: Vec<KeyFrameObservation>,
    /// Its keypoints without a point.
    pub spare: Vec<SpareKeypoint>,
    /// Undistorted image extent.
    pub bounds: Bounds,
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

impl KeyFrame {
    /// Its camera centre in the world.
    pub fn centre(&self) -> Vector3<f64> {
        self.pose_cw.inverse().translation.vector
    }
}

impl Map {
    /// The keyframes keyframe culling left in the map, with their ids,
    /// oldest first.
    pub fn live_keyframes(&self) -> impl DoubleEndedIterator<Item = (usize, &KeyFrame)> {
        self.keyframes.iter().enumerate().filter(|(_, k)| !k.culled)
    }

    /// Local mapping after keyframe `id` was inserted (its points and
    /// observations in place), in ORB-SLAM2's order: recent-point culling,
    /// new points triangulated with its covisible keyframes, duplicate
    /// points fused with theirs (each step as `params` enables it),
    /// covisibility edges and spanning-tree parent, local bundle adjustment
    /// over the newest `params.local_ba_keyframes` keyframes (below 2: off),
    /// keyframe culling among its neighbours, and compaction of the points
    /// when culled ones outnumber the live ones.
    pub fn process_keyframe(
        &mut self,
        id: usize,
        camera: &Camera,
        params: &SlamParams,
    ) -> MappingReport {
        let t = std::time::Instant::now();
        let mut report = MappingReport::default();
        self.cull_points(id);
        let scale_factor = params.orb.scale_factor as f64;
        if params.triangulate {
            let neighbours = self.best_covisible(id, MAPPING_NEIGHBOURS);
            report.counts.triangulated = self.triangulate(id, &neighbours, camera, scale_factor);
        }
        if params.fuse_points {
            (report.counts.fused, report.counts.observations_added) =
                self.fuse(id, camera, scale_factor, params.orb.levels);
        }
        self.connect(id);
        let ba = params.local_ba_keyframes;
        report.adjusted = ba > 1 && self.local_bundle_adjustment(camera, ba);
        self.cull_keyframes(id, scale_factor);
        let culled = self.points.iter().filter(|p| p.visible == 0).count();
        if culled >= COMPACT_MIN_CULLED && culled > self.points.len() - culled {
            report.renumbered = Some(self.compact());
        }
        report.ms = t.elapsed().as_secs_f64() * 1e3;
        report
    }

    /// Drops the culled points, and the keyframes' measurements of them;
    /// the others are renumbered in order. Returns the new id of each old
    /// one. Without it a map grows by every point ever made (about 70 per
    /// frame on fr1_rpy) however few stay in use.
    pub fn compact(&mut self) -> Vec<Option<usize>> {
        let mut next = 0;
        let renumbered: Vec<Option<usize>> = self
            .points
            .iter()
            .map(|p| {
                (p.visible > 0).then(|| {
                    next += 1;
                    next - 1
                })
            })
            .collect();
        self.points.retain(|p| p.visible > 0);
        for kf in &mut self.keyframes {
            let points = std::mem::take(&mut kf.points);
            let measurements = std::mem::take(&mut kf.measurements);
            for (p, m) in points.into_iter().zip(measurements) {
                if let Some(new) = renumbered[p] {
                    kf.points.push(new);
                    kf.measurements.push(m);
                }
            }
        }
        renumbered
    }

    /// The `n` live keyframes sharing most points with keyframe `id`
    /// (among those sharing at least `COVISIBILITY_MIN`, or the best one).
    pub(super) fn best_covisible(&self, id: usize, n: usize) -> Vec<usize> {
        let (mut neighbours, _) = self.covisibility_of(id);
        neighbours.truncate(n);
        neighbours.into_iter().map(|(k, _)| k).collect()
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

    /// Recent-point culling when keyframe `id` arrives: points seen in
    /// under a quarter of the frames that should have seen them stop being
    /// matched, and so do triangulated points that two keyframes later fewer
    /// than `TRIANGULATED_MIN_OBSERVERS` keyframes measure.
    fn cull_points(&mut self, id: usize) {
        for p in &mut self.points {
            if p.visible == 0 {
                continue;
            }
            let rarely_found = p.visible >= 20 && (p.found as f64) < 0.25 * p.visible as f64;
            let unconfirmed = match p.triangulated_in {
                Some(k) if id >= k + 2 => {
                    p.triangulated_in = None;
                    p.observers.len() < TRIANGULATED_MIN_OBSERVERS
                }
                _ => false,
            };
            if rarely_found || unconfirmed {
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
        kf.spare = Vec::new();
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
    /// observers of its live points), most shared first, and its
    /// spanning-tree parent.
    fn covisibility_of(&self, id: usize) -> (Vec<(usize, u32)>, Option<usize>) {
        let mut shared: HashMap<usize, u32> = HashMap::new();
        for &p in &self.keyframes[id].points {
            if self.points[p].visible == 0 {
                continue;
            }
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
