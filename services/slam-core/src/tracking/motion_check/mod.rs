//! Motion consistency (RGB-D): features that move unlike the camera.
//!
//! A segmenter only masks the classes it knows; a pushed chair, a carried
//! box or a door moves all the same (DynaSLAM adds multi-view geometry for
//! this). After the pose of a frame is estimated, each keypoint with depth
//! is put into the world with that pose and looked for in a frame about
//! [`MotionCheckParams::gap_s`] older (its features and estimated pose are
//! kept here): near where the static hypothesis puts it, the keypoint of
//! the most similar descriptor (a distinct best: the nearest-neighbour
//! ratio, so repeated texture does not match its neighbour) is its earlier
//! view. A static point lands where it was seen, give or take depth noise
//! and pose error; a moving one lands elsewhere, in the image and in 3D.
//! One such keypoint proves nothing (a wrong match); a cluster of them,
//! close together in the image and displaced alike, that dominates the
//! keypoints checked in its region, is a moving thing: every keypoint in
//! the region is dropped from tracking and mapping like a masked one.
//!
//! A keypoint that has no earlier view (the mover came into sight, or its
//! texture changed) is still evidence when, put into the older frame, it
//! lies in front of everything that frame's depth saw around that spot:
//! it occupies what was free space (the depth-warp test). Its cluster is
//! grouped like the shifted ones.
//!
//! Why a gap and not the previous frame: at 30 fps a walking-speed object
//! moves 2-3 cm per frame, below what depth noise and pose error allow to
//! tell apart; over 0.2 s it moves 20 cm.

use std::collections::VecDeque;

use nalgebra::{Isometry3, Vector2};

use crate::camera::Camera;
use crate::features::grid::Grid;
use crate::features::orb::hamming;
use crate::frame::Frame;
use crate::matcher::ByCell;

mod depth;
use depth::{cell_centres, dense_regions, lookup_window, Around, CellCentres, NearestDepth};

/// What the check looks for (docs/models.md "Motion check" has the figures: the
/// static shared sequence keeps 99.66 % of its features and its ATE; a box
/// carried through it is found in 85.6 % of the frames, the bar
/// is 80 %).
#[derive(Debug, Clone, PartialEq)]
pub struct MotionCheckParams {
    /// The frame compared against is the newest at least this much older.
    pub gap_s: f64,
    /// The depth warp also against the newest frame at least this much
    /// older: a mover that turns back (carried to and fro, a door swung
    /// back) is about where it was `gap_s` before, not this long before.
    pub long_gap_s: f64,
    /// Search radius around the static prediction (pixels at level 0), at
    /// most...
    pub search_px: f64,
    /// ...and no farther than a point this fast (m/s, sideways) moves in
    /// the image over the frames' time apart at its depth, plus
    /// `search_margin_px` (pose error): at 2 m and 0.1 s apart, 62 px.
    pub max_speed_mps: f64,
    /// Pixels added around the predicted spot when looking for a keypoint again.
    pub search_margin_px: f64,
    /// A match needs at most this descriptor distance...
    pub max_hamming: u32,
    /// ...and at most this share of the second best's.
    pub ratio: f64,
    /// Moved at least this far in the image (pixels)...
    pub min_shift_px: f64,
    /// ...and in 3D at least `min_move_m + move_per_m2 * z^2` (Kinect depth
    /// noise grows with the square of the depth).
    pub min_move_m: f64,
    /// Added to `min_move_m` per square metre of depth.
    pub move_per_m2: f64,
    /// Moved keypoints within this image distance whose shifts differ by at
    /// most `shift_tolerance_px` are one cluster...
    pub cluster_px: f64,
    /// See `cluster_px`.
    pub shift_tolerance_px: f64,
    /// ...of at least this many keypoints...
    pub min_cluster: usize,
    /// ...that are at least this share of the matched keypoints in its box.
    pub min_share: f64,
    /// Margin added around a cluster's box (pixels).
    pub margin_px: f64,
    /// Dense depth warp: at least this many 4x4 cells, connected, in
    /// front of what the older frame saw...
    pub min_cells: usize,
    /// ...grown over neighbouring cells whose depth continues the surface
    /// (within `surface_m + surface_per_m * z`), to at most this many
    /// times its size.
    pub surface_m: f64,
    /// Added to `surface_m` per metre of depth.
    pub surface_per_m: f64,
    /// A region grows to at most this many times its seed's cells.
    pub max_growth: usize,
}

impl Default for MotionCheckParams {
    fn default() -> Self {
        Self {
            gap_s: 0.2,
            long_gap_s: 0.4,
            search_px: 120.0,
            max_speed_mps: 2.5,
            search_margin_px: 12.0,
            max_hamming: 40,
            ratio: 0.7,
            min_shift_px: 6.0,
            min_move_m: 0.04,
            move_per_m2: 0.015,
            cluster_px: 40.0,
            shift_tolerance_px: 20.0,
            min_cluster: 6,
            min_share: 0.5,
            margin_px: 8.0,
            min_cells: 40,
            surface_m: 0.02,
            surface_per_m: 0.01,
            max_growth: 3,
        }
    }
}

/// An image region (pixel box, undistorted) whose features move unlike
/// the camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MovingRegion {
    /// Smallest pixel (column, row).
    pub min: [f32; 2],
    /// Largest pixel (column, row).
    pub max: [f32; 2],
    /// Keypoints of the cluster that showed the motion.
    pub evidence: usize,
}

impl MovingRegion {
    /// Whether pixel (u, v) is inside.
    pub fn contains(&self, u: f64, v: f64) -> bool {
        (self.min[0] as f64..=self.max[0] as f64).contains(&u)
            && (self.min[1] as f64..=self.max[1] as f64).contains(&v)
    }
}

/// What later frames need of a frame: its keypoints' depths and, for the
/// search, its grid and its keypoints in the grid's cell order (positions,
/// levels, descriptors; not the whole frame: the rest is not used).
struct PastFrame {
    timestamp: f64,
    /// Depth per keypoint (the frame's `depth`).
    depth_at: Vec<Option<f64>>,
    grid: Grid,
    by_cell: ByCell,
    pose_cw: Isometry3<f64>,
    depth: NearestDepth,
    /// How fast the camera turned then (rad/s; 0 when not known).
    turn_rate: f64,
}

/// An image size and the ideal pixel and ray of each of its depth cells'
/// centres.
type CellPixels = ((usize, usize), CellCentres);

/// The check and the recent frames it compares with.
pub struct MotionCheck {
    params: MotionCheckParams,
    history: VecDeque<PastFrame>,
    /// Ideal (undistorted) pixel of each depth cell's centre, for the
    /// image size they were computed for.
    cell_pixels: Option<CellPixels>,
}

/// One keypoint's evidence: where it is, how far it moved in the image.
#[derive(Debug, Clone, Copy)]
struct Moved {
    at: Vector2<f64>,
    shift: Vector2<f64>,
}

impl MotionCheck {
    /// A check with `params`, no frame seen yet.
    pub fn new(params: MotionCheckParams) -> Self {
        Self {
            params,
            history: VecDeque::new(),
            cell_pixels: None,
        }
    }

    /// The regions of `frame` (tracked at `pose_cw`, with its raw depth)
    /// that move unlike the camera, then the frame kept for the frames
    /// after it. The depth is put into cells once, for both. `matched[k]`:
    /// the map point keypoint `k` is an inlier of the pose with, if any; such
    /// a keypoint lies where a static point does, so it is not looked for
    /// again in the older frames (it would be found unshifted: it counts as
    /// matched there).
    pub fn observe(
        &mut self,
        frame: &Frame,
        depth: &[u16],
        (pose_cw, matched): (&Isometry3<f64>, &[Option<usize>]),
        timestamp: f64,
        camera: &Camera,
    ) -> Vec<MovingRegion> {
        let on_map: Vec<bool> = matched.iter().map(Option::is_some).collect();
        let on_map = on_map.as_slice();
        let now = NearestDepth::new(depth, frame.width, frame.height, camera.depth_scale);
        let turn = self.turn_rate(pose_cw, timestamp);
        let regions = self.regions(frame, &now, (pose_cw, turn, on_map), timestamp, camera);
        self.remember(frame, now, (pose_cw, turn), timestamp);
        regions
    }

    /// The regions of `frame` (tracked at `pose_cw` while the camera turned
    /// at `turn` rad/s) that move unlike the camera, against the newest
    /// kept frame at least `gap_s` older; none until there is one.
    fn regions(
        &mut self,
        frame: &Frame,
        now: &NearestDepth,
        (pose_cw, turn, on_map): (&Isometry3<f64>, f64, &[bool]),
        timestamp: f64,
        camera: &Camera,
    ) -> Vec<MovingRegion> {
        let (w, h) = (frame.width, frame.height);
        if self
            .cell_pixels
            .as_ref()
            .is_none_or(|(size, _)| *size != (w, h))
        {
            self.cell_pixels = Some(((w, h), cell_centres(camera, w, h)));
        }
        let p = &self.params;
        // The newest frame at least the gap older; in the first frames of a
        // run, before there is one, the oldest if it is half the gap older
        // (a mover in view from the start: at 1 m/s it moves 10 cm in 0.1 s).
        let Some(past) = self
            .history
            .iter()
            .rev()
            .find(|f| timestamp - f.timestamp >= p.gap_s)
            .or_else(|| {
                self.history
                    .front()
                    .filter(|f| timestamp - f.timestamp >= p.gap_s / 2.0)
            })
        else {
            return Vec::new();
        };
        let cells = &self.cell_pixels.as_ref().expect("computed above").1;
        // An older frame's nearest depth around each cell (the lookup window
        // grown by both frames' turns) and the depth warp against it.
        let warp = |older: &PastFrame| {
            let around = older
                .depth
                .around(lookup_window(camera, turn, older.turn_rate));
            let now_to_older = older.pose_cw * pose_cw.inverse();
            let dense = dense_regions(now, cells, &around, &now_to_older, camera, p);
            (around, dense)
        };
        let (around, dense) = warp(past);
        let evidence = keypoint_evidence(
            frame,
            (pose_cw, on_map, timestamp),
            past,
            Some(&around),
            camera,
            p,
        );
        // Two kinds of evidence, grouped apart: keypoints seen again
        // elsewhere (shifted), and keypoints now where the older frame saw
        // free space (no shift; an object that entered or moved onto it).
        let mut out = clusters(&evidence.moved, &evidence.matched_at, p);
        out.extend(clusters(&evidence.appeared, &evidence.seen_at, p));
        out.extend(dense);
        // The depth warp also against a frame half as old: it saw more of
        // what the camera sees now (a mover that came in with a turn or at
        // the border).
        if let Some(recent) = self
            .history
            .iter()
            .rev()
            .find(|f| timestamp - f.timestamp >= p.gap_s / 2.0 && f.timestamp > past.timestamp)
        {
            // Keypoints seen again elsewhere in it too: a mover that came
            // in at the border in the last 0.2 s is not in the older frame
            // (carried box: 94 -> 99 of 132 frames found; +1.4 ms a frame).
            let dense = warp(recent).1;
            // Only the keypoints the older frame did not show again: the
            // others' evidence is in already (half the search's time); the
            // free-space test is the depth warp's here.
            let known: Vec<bool> = (0..frame.kps.len())
                .map(|k| on_map.get(k).copied().unwrap_or(false) || evidence.found[k])
                .collect();
            let e = keypoint_evidence(frame, (pose_cw, &known, timestamp), recent, None, camera, p);
            out.extend(clusters(&e.moved, &e.matched_at, p));
            out.extend(dense);
        }
        // The depth warp against a frame twice as old, for a mover that
        // turned back within the gap (carried box, 6 synthesised walks:
        // found in 75.2 -> 79.6 % of its frames on average, the seed of
        // `just eval-motion` 76.5 -> 84.1 %; keypoint evidence at this gap
        // added nothing: matching across 0.4 s of a turn is poorer).
        if let Some(long_ago) = self
            .history
            .iter()
            .rev()
            .find(|f| timestamp - f.timestamp >= p.long_gap_s && f.timestamp < past.timestamp)
        {
            out.extend(warp(long_ago).1);
        }
        out
    }

    /// How fast the camera turns at a frame tracked at `pose_cw` (rad/s):
    /// against the newest kept frame when it is at most 0.1 s older, else
    /// not known (0).
    fn turn_rate(&self, pose_cw: &Isometry3<f64>, timestamp: f64) -> f64 {
        self.history
            .back()
            .map(|f| {
                (
                    f.pose_cw.rotation.angle_to(&pose_cw.rotation),
                    timestamp - f.timestamp,
                )
            })
            .filter(|&(_, dt)| dt > 1e-3 && dt <= 0.1)
            .map_or(0.0, |(angle, dt)| angle / dt)
    }

    /// Keeps `frame` (tracked at `pose_cw`, turning at `turn_rate`, with its
    /// raw depth image) for later frames to compare with; frames no longer
    /// needed are dropped (only the newest older than the long gap of the
    /// newest frame is ever used).
    fn remember(
        &mut self,
        frame: &Frame,
        depth: NearestDepth,
        (pose_cw, turn_rate): (&Isometry3<f64>, f64),
        timestamp: f64,
    ) {
        if self
            .history
            .back()
            .is_some_and(|f| timestamp <= f.timestamp)
        {
            // Time went back (a new pass of a sequence): start over.
            self.history.clear();
        }
        self.history.push_back(PastFrame {
            timestamp,
            by_cell: ByCell::new(frame),
            depth_at: frame.depth.clone(),
            grid: frame.grid.clone(),
            pose_cw: *pose_cw,
            depth,
            turn_rate,
        });
        let gap = self.params.gap_s.max(self.params.long_gap_s);
        while self.history.len() >= 2 && timestamp - self.history[1].timestamp >= gap {
            self.history.pop_front();
        }
    }
}

/// What the keypoints of `frame` (tracked at `pose_cw`) say against `past`:
/// the keypoints seen again elsewhere and all those matched there (for the
/// share test), and the keypoints now in what `past` saw as free space and
/// all those where it saw anything.
struct KeypointEvidence {
    moved: Vec<Moved>,
    matched_at: Vec<Vector2<f64>>,
    appeared: Vec<Moved>,
    seen_at: Vec<Vector2<f64>>,
    /// Per keypoint: seen again there (a distinct match with depth).
    found: Vec<bool>,
}

/// `known[k]`: keypoint `k` is not looked for (an inlier of the pose, so
/// where a static point is; or seen again in a frame looked at before): it
/// counts as matched, unshifted. The free-space test runs only with the
/// older frame's surroundings (`around`; else `appeared` and `seen_at` stay
/// empty).
fn keypoint_evidence(
    frame: &Frame,
    (pose_cw, known, timestamp): (&Isometry3<f64>, &[bool], f64),
    past: &PastFrame,
    around: Option<&Around>,
    camera: &Camera,
    p: &MotionCheckParams,
) -> KeypointEvidence {
    let now_to_past = past.pose_cw * pose_cw.inverse();
    let past_wc = past.pose_cw.inverse();
    let now_wc = pose_cw.inverse();
    let mut moved = Vec::new();
    // Keypoints matched in the past frame, for the share test.
    let mut matched_at = Vec::new();
    // Keypoints where the past depth was seen, and those of them that
    // are now in what was free space then.
    let mut seen_at = Vec::new();
    let mut appeared = Vec::new();
    let mut found = vec![false; frame.kps.len()];
    #[allow(clippy::needless_range_loop)] // k indexes five arrays of the frame
    for k in 0..frame.kps.len() {
        let Some(z) = frame.depth[k] else { continue };
        let (u, v) = frame.un[k];
        let here = camera.unproject(u, v, z);
        let there = now_to_past * nalgebra::Point3::from(here);
        if there.z < 0.1 {
            continue;
        }
        let (pu, pv) = camera.project(&there.coords);
        let allowed = p.min_move_m + p.move_per_m2 * z * z;
        if let Some(seen) = around.and_then(|a| a.nearest_at(camera.distort(pu, pv))) {
            seen_at.push(Vector2::new(u, v));
            if seen - there.z > allowed {
                appeared.push(Moved {
                    at: Vector2::new(u, v),
                    shift: Vector2::zeros(),
                });
            }
        }
        if known.get(k).copied().unwrap_or(false) {
            // The search is most of this function's time.
            matched_at.push(Vector2::new(u, v));
            continue;
        }
        // A person walks 1-2 m/s: over 0.1-0.2 s, at a few metres, a few
        // dozen pixels; the full radius only near the camera. The square
        // searched shrinks with the square of this (the check's largest
        // cost after the depth warp).
        let reach = camera.fx * p.max_speed_mps * (timestamp - past.timestamp) / z;
        let radius = p.search_px.min(p.search_margin_px + reach);
        let level = frame.kps[k].level as i32;
        let desc = &frame.descs[k];
        let (mut best, mut second, mut best_i) = (u32::MAX, u32::MAX, None);
        let cells = &past.by_cell;
        for run in past.grid.rows_near(&cells.starts, pu, pv, radius) {
            let candidates = cells.levels[run.clone()]
                .iter()
                .zip(&cells.descs[run.clone()]);
            for (i, (&l, d)) in run.zip(candidates) {
                if (l as i32 - level).abs() > 1 {
                    continue;
                }
                let d = hamming(desc, d);
                if d < best {
                    (second, best, best_i) = (best, d, Some(i));
                } else if d < second {
                    second = d;
                }
            }
        }
        let Some(i) = best_i else {
            continue;
        };
        let j = cells.index[i];
        if best > p.max_hamming || (second != u32::MAX && best as f64 > p.ratio * second as f64) {
            continue;
        }
        let Some(zj) = past.depth_at[j] else {
            continue;
        };
        matched_at.push(Vector2::new(u, v));
        found[k] = true;
        let (ju, jv) = cells.un[i];
        let shift = Vector2::new(ju - pu, jv - pv);
        let world_now = now_wc * nalgebra::Point3::from(here);
        let world_then = past_wc * nalgebra::Point3::from(camera.unproject(ju, jv, zj));
        let moved_m = (world_now - world_then).norm();
        if shift.norm() >= p.min_shift_px && moved_m >= allowed {
            moved.push(Moved {
                at: Vector2::new(u, v),
                shift,
            });
        }
    }
    KeypointEvidence {
        moved,
        matched_at,
        appeared,
        seen_at,
        found,
    }
}

/// Groups moved keypoints (single linkage: near in the image, shifted
/// alike) and keeps the groups big enough that dominate their box.
fn clusters(
    moved: &[Moved],
    matched_at: &[Vector2<f64>],
    p: &MotionCheckParams,
) -> Vec<MovingRegion> {
    let n = moved.len();
    let mut parent: Vec<usize> = (0..n).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    for a in 0..n {
        for b in a + 1..n {
            if (moved[a].at - moved[b].at).norm() <= p.cluster_px
                && (moved[a].shift - moved[b].shift).norm() <= p.shift_tolerance_px
            {
                let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
                parent[ra] = rb;
            }
        }
    }
    let mut groups: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    for i in 0..n {
        groups.entry(root(&mut parent, i)).or_default().push(i);
    }
    groups
        .into_values()
        .filter(|g| g.len() >= p.min_cluster)
        .filter_map(|g| {
            let mut min = [f64::INFINITY; 2];
            let mut max = [f64::NEG_INFINITY; 2];
            for &i in &g {
                for d in 0..2 {
                    min[d] = min[d].min(moved[i].at[d]);
                    max[d] = max[d].max(moved[i].at[d]);
                }
            }
            let inside = matched_at
                .iter()
                .filter(|m| (min[0]..=max[0]).contains(&m.x) && (min[1]..=max[1]).contains(&m.y))
                .count();
            (g.len() as f64 >= p.min_share * inside as f64).then(|| MovingRegion {
                min: [(min[0] - p.margin_px) as f32, (min[1] - p.margin_px) as f32],
                max: [(max[0] + p.margin_px) as f32, (max[1] + p.margin_px) as f32],
                evidence: g.len(),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::depth::*;
    use super::*;

    fn moved(x: f64, y: f64, dx: f64) -> Moved {
        Moved {
            at: Vector2::new(x, y),
            shift: Vector2::new(dx, 0.0),
        }
    }

    #[test]
    fn a_dense_group_shifted_alike_is_a_region_and_stragglers_are_not() {
        let p = MotionCheckParams::default();
        // Eight keypoints on an object shifted 60 px, three scattered wrong
        // matches elsewhere.
        let mut m: Vec<Moved> = (0..8)
            .map(|i| moved(100.0 + 10.0 * i as f64, 200.0 + 5.0 * (i % 3) as f64, 60.0))
            .collect();
        m.extend([
            moved(400.0, 50.0, 30.0),
            moved(500.0, 400.0, -40.0),
            moved(20.0, 20.0, 12.0),
        ]);
        let matched: Vec<_> = m.iter().map(|x| x.at).collect();
        let r = clusters(&m, &matched, &p);
        assert_eq!(r.len(), 1, "{r:?}");
        assert_eq!(r[0].evidence, 8);
        assert!(r[0].contains(135.0, 205.0) && !r[0].contains(400.0, 50.0));
    }

    #[test]
    fn a_group_among_many_static_matches_is_not_a_region() {
        let p = MotionCheckParams::default();
        let m: Vec<Moved> = (0..6)
            .map(|i| moved(100.0 + 8.0 * i as f64, 100.0, 20.0))
            .collect();
        // 20 matched keypoints in the same box that did not move.
        let mut matched: Vec<_> = m.iter().map(|x| x.at).collect();
        matched.extend((0..20).map(|i| Vector2::new(100.0 + 2.0 * i as f64, 100.0)));
        assert!(clusters(&m, &matched, &p).is_empty());
    }

    #[test]
    fn cells_and_their_surroundings_follow_the_per_cell_definition() {
        // A depth image with holes, odd sizes (a partial last cell), and the
        // definitions written out plainly: the nearest nonzero depth of each
        // 4x4 block; per cell, the nearest over the window where two thirds
        // of its cells saw something.
        let (width, height) = (37, 23);
        let mut seed = 7u32;
        let depth: Vec<u16> = (0..width * height)
            .map(|_| {
                seed = seed.wrapping_mul(1_103_515_245).wrapping_add(12_345);
                let d = (seed >> 16) as u16;
                if d.is_multiple_of(5) {
                    0
                } else {
                    3000 + d % 20_000
                }
            })
            .collect();
        let cells = NearestDepth::new(&depth, width, height, 5000.0);
        let (w, h) = (width.div_ceil(CELL), height.div_ceil(CELL));
        for cy in 0..h {
            for cx in 0..w {
                let nearest = (cy * CELL..((cy + 1) * CELL).min(height))
                    .flat_map(|y| (cx * CELL..((cx + 1) * CELL).min(width)).map(move |x| (x, y)))
                    .map(|(x, y)| depth[y * width + x])
                    .filter(|&d| d != 0)
                    .min()
                    .map_or(0.0, |d| (d as f64 / 5000.0) as f32);
                assert_eq!(cells.metres[cy * w + cx], nearest, "cell {cx},{cy}");
            }
        }
        let mut holes = cells.metres.clone();
        for (i, m) in holes.iter_mut().enumerate() {
            if i.is_multiple_of(3) || i.is_multiple_of(7) {
                *m = 0.0; // more empty cells, so the two-thirds rule bites
            }
        }
        let cells = NearestDepth {
            metres: holes,
            ..cells
        };
        for window in [0, 1, 2, 4, 9] {
            let around = cells.around(window);
            let all = ((2 * window + 1) * (2 * window + 1)) as u32;
            for y in 0..h {
                for x in 0..w {
                    let (mut nearest, mut seen) = (f32::INFINITY, 0u32);
                    for yy in y.saturating_sub(window)..(y + window + 1).min(h) {
                        for xx in x.saturating_sub(window)..(x + window + 1).min(w) {
                            let m = cells.metres[yy * w + xx];
                            if m > 0.0 {
                                seen += 1;
                                nearest = nearest.min(m);
                            }
                        }
                    }
                    let want = if seen * 3 >= all * 2 { nearest } else { 0.0 };
                    assert_eq!(
                        around.metres[y * w + x],
                        want,
                        "window {window}, cell {x},{y}"
                    );
                }
            }
        }
    }

    /// Depth of a 640x480 view of a wall at 2 m, with a square at 1 m
    /// over columns `x0..x0 + 120`, rows 180..300 (when `x0` is given).
    fn wall_with_square(x0: Option<usize>) -> NearestDepth {
        let (w, h) = (640, 480);
        let mut depth = vec![10_000u16; w * h]; // 2 m at 5000 units per metre
        if let Some(x0) = x0 {
            for y in 180..300 {
                depth[y * w + x0..y * w + x0 + 120].fill(5000);
            }
        }
        NearestDepth::new(&depth, w, h, 5000.0)
    }

    #[test]
    fn the_depth_warp_finds_what_moved_into_free_space_and_nothing_in_a_still_scene() {
        let camera = Camera::new([500.0, 500.0, 320.0, 240.0], [0.0; 5], 5000.0, 0.0);
        let cells = cell_centres(&camera, 640, 480);
        let p = MotionCheckParams::default();
        // The camera does not move between the two views.
        let warp = |now: Option<usize>, past: Option<usize>| {
            dense_regions(
                &wall_with_square(now),
                &cells,
                &wall_with_square(past).around(WINDOW),
                &Isometry3::identity(),
                &camera,
                &p,
            )
        };
        // The square moved 80 px to the right.
        let regions = warp(Some(300), Some(220));
        assert_eq!(regions.len(), 1, "{regions:?}");
        let r = regions[0];
        // It covers the square now (grown over its surface, the part that
        // overlaps where it was included), not the wall beside it.
        assert!(
            r.contains(310.0, 190.0) && r.contains(410.0, 290.0),
            "{r:?}"
        );
        assert!(
            !r.contains(200.0, 240.0) && !r.contains(460.0, 240.0),
            "{r:?}"
        );
        // Nothing moved: nothing found.
        let same = warp(Some(300), Some(300));
        assert!(same.is_empty(), "{same:?}");
        // The square left: the wall behind it is not in front of anything.
        let left = warp(None, Some(300));
        assert!(left.is_empty(), "{left:?}");
    }

    #[test]
    fn shifted_unalike_keypoints_do_not_group() {
        let p = MotionCheckParams::default();
        let m: Vec<Moved> = (0..8)
            .map(|i| {
                moved(
                    100.0 + 5.0 * i as f64,
                    100.0,
                    if i % 2 == 0 { 60.0 } else { -60.0 },
                )
            })
            .collect();
        let matched: Vec<_> = m.iter().map(|x| x.at).collect();
        assert!(clusters(&m, &matched, &p).is_empty());
    }
}
