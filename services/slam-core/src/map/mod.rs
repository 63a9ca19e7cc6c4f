//! The map: keyframes and map points in arenas with stable ids, the
//! covisibility graph and the spanning tree (room for loop edges: the next
//! issue's loop closer adds them here), and the small mutation API that
//! keeps them consistent. What local mapping does to the map after each
//! keyframe is [`crate::local_mapping`]'s.

use std::collections::HashMap;

use nalgebra::{Isometry3, Vector3};

use serde::{Deserialize, Serialize};

use crate::camera::Bounds;
use crate::features::orb::Descriptor;
use crate::place_recognition::{KeyframeDatabase, Vocabulary};

/// Shared points that make two keyframes neighbours (ORB-SLAM2's 15).
pub const COVISIBILITY_MIN: u32 = 15;
/// Covisible keyframes triangulation and fusion work with (ORB-SLAM2's 20
/// for RGB-D), and the neighbours of each that fusion adds.
pub(crate) const MAPPING_NEIGHBOURS: usize = 20;
pub(crate) const SECOND_NEIGHBOURS: usize = 5;

/// Keyframes and map points in two arenas, indexed by id. Ids are stable:
/// culled keyframes and points are flagged and emptied, never removed or
/// renumbered, so an id held anywhere (a tracker's matches, a map file, a
/// loop closer's snapshot) names the same thing for the map's life.
/// Structural changes go through the mutation API (`add_point`,
/// `add_keyframe`, `cull_point`, `cull_keyframe`, `replace_point`), which
/// keeps the invariants [`Map::check_invariants`] checks.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Map {
    /// The map points, by id (culled ones stay until compaction).
    pub points: Vec<MapPoint>,
    /// The keyframes, by id (culled ones stay until compaction).
    pub keyframes: Vec<KeyFrame>,
    /// Points culled so far (their slots stay).
    pub(crate) culled_points: usize,
    /// The mapped keyframes' bag-of-words vectors and their inverted index.
    pub database: KeyframeDatabase,
}

/// What local mapping did for one keyframe.
#[derive(Debug, Clone, Default)]
pub struct MappingReport {
    /// Wall time of the whole job (ms).
    pub ms: f64,
    /// Local bundle adjustment or a loop correction moved keyframe poses.
    pub adjusted: bool,
    /// What local mapping added and merged.
    pub counts: MappingCounts,
    /// What the loop closer reported meanwhile (when loop closing is on):
    /// inline, about this keyframe; on its thread, about earlier ones.
    pub loops: Vec<crate::loop_closing::LoopReport>,
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

/// A 3D point of the map.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MapPoint {
    /// Position (world frame).
    pub position: Vector3<f64>,
    /// The descriptor it is matched by.
    pub descriptor: Descriptor,
    /// Keyframes that measured it (ids, in insertion order).
    pub observers: Vec<usize>,
    /// Frames in which it was predicted visible / actually matched; 0
    /// visible: culled (never matched again, dropped at the next compaction).
    pub visible: u32,
    /// See `visible`.
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
    /// Not culled: matched, observed, part of the map.
    pub fn is_live(&self) -> bool {
        self.visible > 0
    }

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
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct KeyFrameObservation {
    /// Undistorted pixel, column.
    pub u: f64,
    /// Undistorted pixel, row.
    pub v: f64,
    /// `u - bf / depth` when the keypoint had depth.
    pub ur: Option<f64>,
    /// 1 / sigma^2 of the keypoint's pyramid level.
    pub info: f64,
    /// The keypoint's own descriptor (fusion compares map points with it).
    pub descriptor: Descriptor,
    /// The keypoint's orientation (radians): matching by bag of words
    /// keeps the matches whose rotation agrees with most others.
    pub angle: f32,
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
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct SpareKeypoint {
    /// The keypoint as a measurement.
    pub measurement: KeyFrameObservation,
    /// RGB colour under it.
    pub colour: [u8; 3],
}

/// A keyframe: its pose, the points it measured and the keypoints that are no point yet.
#[derive(Debug, Clone, Serialize, Deserialize)]
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
    /// Loop edges: keyframes a loop closure joined this one to (the
    /// essential graph keeps them for every later correction).
    pub loops: Vec<usize>,
    /// Removed by keyframe culling: its points and edges are gone, the id
    /// stays so that other ids stay valid.
    pub culled: bool,
}

impl KeyFrame {
    /// Drops its measurement of point `p` (if it has one).
    fn forget(&mut self, p: usize) {
        if let Some(j) = self.points.iter().position(|&q| q == p) {
            self.points.swap_remove(j);
            self.measurements.swap_remove(j);
        }
    }

    /// Its camera centre in the world.
    pub fn centre(&self) -> Vector3<f64> {
        self.pose_cw.inverse().translation.vector
    }

    /// The descriptors of all its keypoints, with a point or spare: what
    /// its bag-of-words vector is made of (masked features never got here).
    pub fn descriptors(&self) -> Vec<Descriptor> {
        self.measurements
            .iter()
            .map(|m| m.descriptor)
            .chain(self.spare.iter().map(|s| s.measurement.descriptor))
            .collect()
    }
}

impl Map {
    /// The keyframes keyframe culling left in the map, with their ids,
    /// oldest first.
    pub fn live_keyframes(&self) -> impl DoubleEndedIterator<Item = (usize, &KeyFrame)> {
        self.keyframes.iter().enumerate().filter(|(_, k)| !k.culled)
    }

    /// The points culling left in the map, with their ids.
    pub fn live_points(&self) -> impl Iterator<Item = (usize, &MapPoint)> {
        self.points.iter().enumerate().filter(|(_, p)| p.is_live())
    }

    /// How many points are live (kept up to date by the mutation API).
    pub fn live_point_count(&self) -> usize {
        self.points.len() - self.culled_points
    }

    /// Adds a point nobody observes yet; its id is the next free one and is
    /// never reused.
    pub fn add_point(&mut self, mut point: MapPoint) -> usize {
        point.observers.clear();
        self.points.push(point);
        self.points.len() - 1
    }

    /// Adds keyframe `kf` (its `points` and `measurements` filled, its graph
    /// edges empty: local mapping connects it) and registers it as an
    /// observer of each of its points. Returns its id.
    pub fn add_keyframe(&mut self, kf: KeyFrame) -> usize {
        let id = self.keyframes.len();
        for &p in &kf.points {
            self.points[p].observers.push(id);
        }
        self.keyframes.push(kf);
        id
    }

    /// Culls point `p`: every keyframe's measurement of it goes, it is
    /// never matched again, and its slot stays (ids are stable: nothing is
    /// renumbered). A slot costs its fixed size only; the observer list is
    /// freed.
    pub fn cull_point(&mut self, p: usize) {
        if !self.points[p].is_live() {
            return;
        }
        for o in std::mem::take(&mut self.points[p].observers) {
            self.keyframes[o].forget(p);
        }
        let point = &mut self.points[p];
        point.observers = Vec::new();
        point.visible = 0;
        point.found = 0;
        self.culled_points += 1;
    }

    /// Point `gone` is point `keep`: its observers measure `keep` instead
    /// (or drop the measurement where they already measure `keep`), its
    /// tracking counts add to `keep`'s, and it is culled.
    pub fn replace_point(&mut self, gone: usize, keep: usize) {
        for o in std::mem::take(&mut self.points[gone].observers) {
            let kf = &mut self.keyframes[o];
            let Some(j) = kf.points.iter().position(|&q| q == gone) else {
                continue;
            };
            if kf.points.contains(&keep) {
                kf.points.swap_remove(j);
                kf.measurements.swap_remove(j);
            } else {
                kf.points[j] = keep;
                self.points[keep].observers.push(o);
            }
        }
        let (visible, found) = (self.points[gone].visible, self.points[gone].found);
        let kept = &mut self.points[keep];
        kept.visible += visible;
        kept.found += found;
        self.cull_point(gone);
    }

    /// Checks the map's invariants: every keyframe measures each of its
    /// points once, and they are live and list it as an observer (and the
    /// other way round); culled keyframes hold nothing; covisibility edges
    /// are symmetric and join live keyframes; spanning-tree parents are
    /// live and older; the keyframe database holds live keyframes only and
    /// its index matches its vectors. The first broken one is described.
    pub fn check_invariants(&self) -> Result<(), String> {
        let kfs = self.keyframes.len();
        for (k, kf) in self.keyframes.iter().enumerate() {
            if kf.points.len() != kf.measurements.len() {
                return Err(format!(
                    "keyframe {k}: {} points but {} measurements",
                    kf.points.len(),
                    kf.measurements.len()
                ));
            }
            if kf.culled && (!kf.points.is_empty() || !kf.covisible.is_empty()) {
                return Err(format!("culled keyframe {k} still holds points or edges"));
            }
            let mut seen = std::collections::HashSet::new();
            for &p in &kf.points {
                let Some(point) = self.points.get(p) else {
                    return Err(format!(
                        "keyframe {k} measures point {p}, which does not exist"
                    ));
                };
                if !seen.insert(p) {
                    return Err(format!("keyframe {k} measures point {p} twice"));
                }
                if !point.is_live() {
                    return Err(format!("keyframe {k} measures culled point {p}"));
                }
                if !point.observers.contains(&k) {
                    return Err(format!("point {p} does not list its observer keyframe {k}"));
                }
            }
            for &(o, n) in &kf.covisible {
                if o >= kfs || self.keyframes[o].culled {
                    return Err(format!(
                        "keyframe {k} has an edge to missing or culled keyframe {o}"
                    ));
                }
                if !self.keyframes[o]
                    .covisible
                    .iter()
                    .any(|&(b, m)| b == k && m == n)
                {
                    return Err(format!("edge {k}-{o} ({n} points) is not symmetric"));
                }
            }
            for &o in &kf.loops {
                if o >= kfs || self.keyframes[o].culled || !self.keyframes[o].loops.contains(&k) {
                    return Err(format!(
                        "loop edge {k}-{o} is not symmetric or joins a culled keyframe"
                    ));
                }
            }
            if let Some(parent) = kf.parent {
                if parent >= k || self.keyframes[parent].culled && !kf.culled {
                    return Err(format!(
                        "keyframe {k} has parent {parent}, culled or not older"
                    ));
                }
            }
        }
        let mut culled = 0;
        for (p, point) in self.points.iter().enumerate() {
            if !point.is_live() {
                culled += 1;
                if !point.observers.is_empty() {
                    return Err(format!("culled point {p} still has observers"));
                }
                continue;
            }
            for &o in &point.observers {
                if o >= kfs || !self.keyframes[o].points.contains(&p) {
                    return Err(format!(
                        "point {p} lists keyframe {o}, which does not measure it"
                    ));
                }
            }
        }
        if culled != self.culled_points {
            return Err(format!(
                "{culled} culled points, but the count says {}",
                self.culled_points
            ));
        }
        self.database
            .check(|k| self.keyframes.get(k).is_some_and(|kf| !kf.culled))
    }

    /// The `n` live keyframes sharing most points with keyframe `id`
    /// (among those sharing at least `COVISIBILITY_MIN`, or the best one).
    pub(crate) fn best_covisible(&self, id: usize, n: usize) -> Vec<usize> {
        let (mut neighbours, _) = self.covisibility_of(id);
        neighbours.truncate(n);
        neighbours.into_iter().map(|(k, _)| k).collect()
    }

    /// Recomputes keyframe `id`'s covisibility edges from its points (after
    /// a loop fusion changed them); its spanning-tree parent stays.
    pub(crate) fn reconnect(&mut self, id: usize) {
        for (other, _) in std::mem::take(&mut self.keyframes[id].covisible) {
            self.keyframes[other].covisible.retain(|e| e.0 != id);
        }
        let parent = self.keyframes[id].parent;
        self.connect(id);
        self.keyframes[id].parent = parent;
    }

    /// Joins keyframes `a` and `b` by a loop edge (both ways, once).
    pub fn add_loop_edge(&mut self, a: usize, b: usize) {
        if !self.keyframes[a].loops.contains(&b) {
            self.keyframes[a].loops.push(b);
            self.keyframes[b].loops.push(a);
        }
    }

    /// Puts keyframe `id` into the covisibility graph and the spanning tree.
    pub(crate) fn connect(&mut self, id: usize) {
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

    /// Makes sure every live keyframe is in a database made with
    /// `vocabulary`: the keyframe local mapping is working on, and all of a
    /// map from a file written with another vocabulary (or with keyframes
    /// not yet mapped when it was saved). Returns how many keyframes were
    /// (re)indexed.
    pub fn reindex(&mut self, vocabulary: &Vocabulary) -> usize {
        if !self.database.is_made_with(vocabulary) {
            self.database = KeyframeDatabase::new(vocabulary);
        }
        let missing: Vec<usize> = self
            .live_keyframes()
            .filter(|(k, _)| self.database.vector(*k).is_none())
            .map(|(k, _)| k)
            .collect();
        for &k in &missing {
            let vector = vocabulary.bow(&self.keyframes[k].descriptors());
            self.database.add(k, vector);
        }
        missing.len()
    }

    /// Removes keyframe `k` from the map: its observations leave its points
    /// (a point nobody observes any more is culled), its edges leave the
    /// covisibility graph, and its children in the spanning tree take its
    /// parent as theirs.
    pub fn cull_keyframe(&mut self, k: usize) {
        self.database.remove(k);
        let kf = &mut self.keyframes[k];
        kf.culled = true;
        // Taken, not cleared: a culled keyframe keeps only its pose and
        // graph place (stable ids), not the capacity of its measurements.
        let points = std::mem::take(&mut kf.points);
        kf.measurements = Vec::new();
        kf.spare = Vec::new();
        let edges = std::mem::take(&mut kf.covisible);
        let parent = kf.parent;
        for p in points {
            let point = &mut self.points[p];
            point.observers.retain(|&o| o != k);
            if point.observers.is_empty() {
                self.cull_point(p);
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
}

#[cfg(test)]
mod tests {
    use super::*;

    fn measurement(i: usize) -> KeyFrameObservation {
        KeyFrameObservation {
            u: i as f64,
            v: 10.0,
            ur: None,
            info: 1.0,
            descriptor: [i as u64; 4],
            angle: 0.0,
        }
    }

    /// Keyframe seeing `points` (ids), not yet connected.
    fn keyframe(points: &[usize]) -> KeyFrame {
        KeyFrame {
            pose_cw: Isometry3::identity(),
            points: points.to_vec(),
            measurements: points.iter().map(|&p| measurement(p)).collect(),
            spare: Vec::new(),
            bounds: (0.0, 640.0, 0.0, 480.0),
            covisible: Vec::new(),
            parent: None,
            loops: Vec::new(),
            culled: false,
        }
    }

    /// Three keyframes: 0 sees points 0..20, 1 sees 0..20 and 20..40, 2
    /// sees 20..40.
    fn three_keyframes() -> Map {
        let mut map = Map::default();
        for i in 0..40 {
            let p = MapPoint::new(
                Vector3::new(i as f64, 0.0, 3.0),
                0,
                &measurement(i),
                3.0,
                [0; 3],
            );
            assert_eq!(map.add_point(p), i, "ids are handed out in order");
        }
        let a: Vec<usize> = (0..20).collect();
        let b: Vec<usize> = (20..40).collect();
        // As tracking and local mapping do it: insert, then connect.
        for (k, points) in [a.clone(), [a.clone(), b.clone()].concat(), b]
            .iter()
            .enumerate()
        {
            assert_eq!(map.add_keyframe(keyframe(points)), k);
            map.connect(k);
        }
        map
    }

    #[test]
    fn the_mutation_api_keeps_the_invariants_and_the_ids() {
        let mut map = three_keyframes();
        map.check_invariants().unwrap();
        assert_eq!(map.keyframes[1].covisible, vec![(0, 20), (2, 20)]);
        assert_eq!(map.keyframes[2].covisible, vec![(1, 20)]);
        assert_eq!(map.keyframes[2].parent, Some(1));
        // Culling a point: every keyframe forgets it, the others keep their ids.
        let position_of_7 = map.points[7].position;
        map.cull_point(3);
        map.check_invariants().unwrap();
        assert!(!map.points[3].is_live() && map.points[3].observers.is_empty());
        assert!(!map.keyframes[0].points.contains(&3) && !map.keyframes[1].points.contains(&3));
        assert_eq!(map.points[7].position, position_of_7);
        assert_eq!(map.live_point_count(), 39);
        map.cull_point(3); // twice is once
        assert_eq!(map.live_point_count(), 39);
        // Merging point 25 into 5: keyframe 1 measured both and keeps one.
        map.replace_point(25, 5);
        map.check_invariants().unwrap();
        assert_eq!(map.points[5].observers, vec![0, 1, 2]);
        assert_eq!(
            map.keyframes[1].points.iter().filter(|&&p| p == 5).count(),
            1
        );
        // Culling keyframe 1: its edges go, keyframe 2 hangs from 0 now, and
        // points only it saw would go (none here).
        map.cull_keyframe(1);
        map.check_invariants().unwrap();
        assert!(map.keyframes[0].covisible.is_empty());
        assert_eq!(map.keyframes[2].parent, Some(0));
        assert_eq!(
            map.live_keyframes().map(|(k, _)| k).collect::<Vec<_>>(),
            [0, 2]
        );
        // A point whose last observer goes is culled with it.
        map.cull_keyframe(2);
        map.check_invariants().unwrap();
        assert!(!map.points[30].is_live());
        assert!(map.points[5].is_live(), "keyframe 0 still sees point 5");
    }

    #[test]
    fn broken_maps_are_described() {
        let broken = |f: fn(&mut Map)| {
            let mut map = three_keyframes();
            f(&mut map);
            map.check_invariants().unwrap_err()
        };
        assert!(broken(|m| m.keyframes[0].points.push(1)).contains("points but"));
        assert!(broken(|m| m.points[2].observers.clear()).contains("does not list"));
        assert!(broken(|m| m.points[2].visible = 0).contains("culled point 2"));
        assert!(broken(|m| m.keyframes[2].covisible[0].1 = 3).contains("not symmetric"));
        assert!(broken(|m| m.keyframes[1].parent = Some(2)).contains("not older"));
        assert!(broken(|m| m.points[2].observers.push(2)).contains("does not measure it"));
        assert!(broken(|m| m.culled_points = 4).contains("the count says"));
    }
}
