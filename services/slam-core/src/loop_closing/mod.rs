//! Loop closing (ORB-SLAM2's LoopClosing), after local mapping of each
//! keyframe. The loop transform is a similarity: with depth its scale is
//! known and held at 1 (an SE(3)); a monocular map drifts in scale too, and
//! the loop's scale corrects that drift (Sim(3), as ORB-SLAM2 monocular):
//!
//! 1. **Detection** ([`LoopCloser::detect`]): keyframe-database candidates
//!    that look more alike than the keyframe's own covisible neighbours do
//!    and are not connected to it; a candidate counts only once three
//!    consecutive keyframes found consistent candidate groups (covisible
//!    groups that overlap), so that one look-alike never closes a loop.
//! 2. **Geometry** ([`LoopCloser::solve`]): exhaustive descriptor matches
//!    between the keyframe's points and the candidate's (matching by bag of
//!    words found too few with our small vocabulary), a rigid transform
//!    (with depth) or a similarity (monocular) by RANSAC on the matched
//!    points' world positions (the drifted one against the old one; a
//!    monocular inlier reprojects near its keypoint in both keyframes, as
//!    a distance in an unknown scale says nothing) whose inliers must
//!    spread across the image (a person seen at two
//!    places gives a consistent transform too), then verification by projection: the candidate's neighbourhood
//!    projected into the keyframe with the corrected pose must match enough
//!    of its keypoints.
//! 3. **Correction** ([`Map::correct_loop`]): the keyframe's neighbourhood
//!    moved by the correction with its points, duplicated points fused
//!    with the old ones, a loop edge, then the essential graph (spanning
//!    tree, strong covisibility, loop edges) optimised so that the rest of
//!    the map follows, and every point moved with the keyframe it belongs to.
//!
//! 4. **Global bundle adjustment** ([`Map::global_bundle_adjustment`])
//!    of the corrected map, when [`SlamParams::global_bundle_adjustment`]
//!    asks.
//!
//! Detection looks at the map; only a found loop copies it: the correction
//! and the adjustment run on that copy and come back as a
//! [`correction::LoopUpdate`] that [`Map::merge_loop`] applies. With a
//! mapping thread all of it runs on a thread of its own ([`thread`]) on a
//! snapshot of the map after each keyframe, so neither the frame path nor
//! local mapping waits for it; without one, inline after local mapping.
//!
//! [`SlamParams::global_bundle_adjustment`]: crate::params::SlamParams::global_bundle_adjustment

use std::collections::HashSet;

pub mod correction;
pub mod thread;

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::camera::Camera;
use crate::features::orb::{hamming, MATCH_MAX_DISTANCE};
use crate::geometry::alignment::Similarity;
use crate::geometry::ransac::{rigid_ransac, similarity_ransac};
use crate::map::{KeyFrame, KeyFrameObservation, Map};
use crate::matcher::match_exhaustive;
use crate::params::Sensor;
use correction::LoopUpdate;

/// Consecutive keyframes whose candidate groups must agree (ORB-SLAM2: 3).
const CONSISTENCY: u32 = 3;
/// No loop is looked for before the map has this many keyframes, nor within
/// this many keyframes of the last loop (ORB-SLAM2: 10), nor with a
/// candidate made within this many keyframes of the one looking.
const MIN_KEYFRAMES: usize = 10;
/// Point matches a candidate needs before RANSAC (ORB-SLAM2: 20).
const MIN_MATCHES: usize = 20;
/// RANSAC inliers of the loop transform (ORB-SLAM2: 20), and matches by
/// projection that must confirm it (ORB-SLAM2: 40).
const MIN_INLIERS: usize = 20;
const MIN_CONFIRMED: usize = 40;
/// RANSAC inlier distance of two matched points' positions (metres).
const INLIER_M: f64 = 0.05;
/// Monocular RANSAC inlier: reprojection error in both keyframes within
/// this chi-square bound (2 degrees of freedom, 99 %; ORB-SLAM2's 9.21).
const INLIER_CHI2: f64 = 9.21;
/// Search radius (pixels) when confirming by projection.
const CONFIRM_RADIUS_PX: f64 = 10.0;

/// One loop closure, as `loops.csv` records it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LoopClosure {
    /// The new keyframe and the old one it closed the loop with.
    pub keyframe: usize,
    /// See `keyframe`.
    pub matched: usize,
    /// RANSAC inliers of the transform and matches confirming it.
    pub inliers: usize,
    /// See `inliers`.
    pub confirmed: usize,
    /// How far the new keyframe moved (metres, degrees).
    pub correction_m: f64,
    /// See `correction_m`.
    pub correction_deg: f64,
    /// Points fused with the old map, keyframes the essential graph moved.
    pub fused: usize,
    /// See `fused`.
    pub keyframes_moved: usize,
    /// The loop transform's scale: the drifted map's size against the old
    /// map's where the loop closed (1 with depth).
    pub scale: f64,
}

/// What the loop closer did after one keyframe.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LoopReport {
    /// The keyframe it looked from.
    pub keyframe: usize,
    /// Time (ms) spent looking for candidates (0 in a report of the
    /// loop-closing thread, which only verifies), verifying them,
    /// correcting and in global bundle adjustment.
    pub detect_ms: f64,
    /// See `detect_ms`.
    pub verify_ms: f64,
    /// See `detect_ms`.
    pub correct_ms: f64,
    /// See `detect_ms`.
    pub global_ba_ms: f64,
    /// The loop closed, if one did.
    pub closed: Option<LoopClosure>,
}

/// A loop closer's answer for one keyframe: its report and, when a loop
/// closed, the correction to merge into the map.
#[derive(Debug, Clone)]
pub struct LoopOutcome {
    /// What was looked for and found.
    pub report: LoopReport,
    /// The correction to merge, when a loop closed.
    pub update: Option<LoopUpdate>,
}

/// The loop closer's state between keyframes.
#[derive(Clone)]
pub struct LoopCloser {
    camera: Camera,
    sensor: Sensor,
    /// Adjust the whole map after a correction.
    global_ba: bool,
    /// Candidate groups of the last keyframe, each with its consistency
    /// count.
    groups: Vec<(HashSet<usize>, u32)>,
    /// The keyframe of the last loop closure.
    last_loop: Option<usize>,
}

/// A verified loop: the matched keyframe, the corrected pose of the new
/// keyframe and the point matches.
pub struct LoopGeometry {
    /// The old keyframe the loop closes with.
    pub matched: usize,
    /// Camera from world of the new keyframe, in the old map's frame (and,
    /// monocular, with the new keyframe's scale against the old map's).
    pub corrected_cw: Similarity,
    /// (new point, old point) pairs: the same place, measured twice.
    pub point_pairs: Vec<(usize, usize)>,
    /// RANSAC inliers of the transform.
    pub inliers: usize,
    /// Matches the transform confirmed by projection.
    pub confirmed: usize,
}

impl LoopCloser {
    /// A loop closer for `camera` and `sensor`; `global_ba`: adjust the
    /// whole map after each correction.
    pub fn new(camera: Camera, sensor: Sensor, global_ba: bool) -> Self {
        Self {
            camera,
            sensor,
            global_ba,
            groups: Vec::new(),
            last_loop: None,
        }
    }

    /// Looks for a loop closed by keyframe `id` (already in the keyframe
    /// database): candidates ([`LoopCloser::detect`]), then verification
    /// and correction ([`LoopCloser::close`]).
    pub fn process(&mut self, map: &Map, id: usize) -> LoopOutcome {
        let t = std::time::Instant::now();
        let candidates = self.detect(map, id);
        let detect_ms = t.elapsed().as_secs_f64() * 1e3;
        let mut outcome = self.close(map, id, &candidates);
        outcome.report.detect_ms = detect_ms;
        if outcome.update.is_some() {
            self.loop_closed(id);
        }
        outcome
    }

    /// Verifies the loop candidates of keyframe `id` in turn; at the first
    /// that holds, corrects a copy of `map` (and adjusts it) and returns
    /// that correction as an update to merge.
    pub fn close(&self, map: &Map, id: usize, candidates: &[usize]) -> LoopOutcome {
        let t = std::time::Instant::now();
        let geometry = candidates.iter().find_map(|&c| self.solve(map, id, c));
        let mut report = LoopReport {
            keyframe: id,
            verify_ms: t.elapsed().as_secs_f64() * 1e3,
            ..Default::default()
        };
        let Some(g) = geometry else {
            return LoopOutcome {
                report,
                update: None,
            };
        };
        let t = std::time::Instant::now();
        let mut corrected = map.clone();
        let correction = corrected.correct_loop(id, &g, self.sensor);
        report.correct_ms = t.elapsed().as_secs_f64() * 1e3;
        if self.global_ba {
            let t = std::time::Instant::now();
            corrected.global_bundle_adjustment(&self.camera, self.sensor);
            report.global_ba_ms = t.elapsed().as_secs_f64() * 1e3;
        }
        report.closed = Some(correction.closure);
        LoopOutcome {
            report,
            update: Some(LoopUpdate::from_corrected(&corrected, correction)),
        }
    }

    /// Keyframe `id` closed a loop: no other is looked for within
    /// `MIN_KEYFRAMES` of it, and the consistency count starts again.
    pub fn loop_closed(&mut self, id: usize) {
        self.last_loop = Some(id);
        self.groups.clear();
    }

    /// The candidates keyframe `id` closes a loop with, consistent over
    /// the last keyframes (ORB-SLAM2's DetectLoop).
    pub fn detect(&mut self, map: &Map, id: usize) -> Vec<usize> {
        let too_soon = map.live_keyframes().count() < MIN_KEYFRAMES
            || self.last_loop.is_some_and(|l| id < l + MIN_KEYFRAMES);
        let Some(query) = map.database.vector(id).filter(|_| !too_soon) else {
            self.groups.clear();
            return Vec::new();
        };
        let connected: HashSet<usize> = map.keyframes[id]
            .covisible
            .iter()
            .map(|e| e.0)
            .chain([id])
            .collect();
        // The loop candidate must look more alike than the least alike of
        // the keyframe's covisible neighbours.
        let min_score = map.keyframes[id]
            .covisible
            .iter()
            .filter_map(|e| map.database.vector(e.0))
            .map(|v| query.score(v))
            .fold(f32::INFINITY, f32::min);
        if !min_score.is_finite() {
            self.groups.clear();
            return Vec::new();
        }
        // A loop comes back after a path: a keyframe made within the last
        // MIN_KEYFRAMES is never a candidate, connected or not. With 40 % of
        // the shared sequence's frames dropped, keyframe 17 closed a "loop"
        // with keyframe 15 (0.8 s earlier, not covisible after a fast turn)
        // and moved 9 cm / 5.8 deg: ATE 0.0163 -> 0.0252 m.
        let candidates = map.database.candidates(
            query,
            min_score,
            |k| connected.contains(&k) || k + MIN_KEYFRAMES > id,
            |k| map.best_covisible(k, 10),
        );
        // Consistency: a candidate's group (it and its covisible keyframes)
        // must overlap a group of the previous keyframe's candidates.
        let mut groups = Vec::new();
        let mut consistent = Vec::new();
        for c in candidates {
            let group: HashSet<usize> = map.keyframes[c]
                .covisible
                .iter()
                .map(|e| e.0)
                .chain([c])
                .collect();
            let count = self
                .groups
                .iter()
                .filter(|(previous, _)| !previous.is_disjoint(&group))
                .map(|(_, n)| n + 1)
                .max()
                .unwrap_or(0);
            if count >= CONSISTENCY && !consistent.contains(&c) {
                consistent.push(c);
            }
            groups.push((group, count));
        }
        self.groups = groups;
        consistent
    }

    /// The loop transform between keyframe `id` and candidate `matched`,
    /// verified (ORB-SLAM2's ComputeSim3; with depth the scale is 1).
    pub fn solve(&self, map: &Map, id: usize, matched: usize) -> Option<LoopGeometry> {
        let kf = &map.keyframes[id];
        let old = &map.keyframes[matched];
        let descs: Vec<_> = kf.measurements.iter().map(|m| m.descriptor).collect();
        // (keyframe measurement, its point, the candidate's point); the
        // points they already share say nothing about a loop.
        let matches: Vec<(usize, usize, usize)> = match_exhaustive(map, old, &descs)
            .into_iter()
            .map(|(i, p_old)| (i, kf.points[i], p_old))
            .filter(|&(_, p_new, p_old)| p_new != p_old)
            .collect();
        if matches.len() < MIN_MATCHES {
            return None;
        }
        // World-from-world: old positions from the drifted ones.
        let positions: Vec<(Vector3<f64>, Vector3<f64>)> = matches
            .iter()
            .map(|&(_, n, o)| (map.points[n].position, map.points[o].position))
            .collect();
        let (correction, inliers) = match self.sensor {
            Sensor::Rgbd => rigid_ransac(&positions, INLIER_M, 300, 0x100B)
                .map(|(t, inliers)| (Similarity::from_isometry(&t), inliers))?,
            Sensor::Monocular => {
                // The old keyframe's measurement of each of its points.
                let measured_old: std::collections::HashMap<usize, _> =
                    old.points.iter().copied().zip(&old.measurements).collect();
                similarity_ransac(&positions, 300, 0x100B, |s, j| {
                    let (i, _, p_old) = matches[j];
                    let (new_x, old_x) = &positions[j];
                    let Some(m_old) = measured_old.get(&p_old) else {
                        return false;
                    };
                    self.reprojects(kf, &kf.measurements[i], &s.inverse().apply_point(old_x))
                        && self.reprojects(old, m_old, &s.apply_point(new_x))
                })?
            }
        };
        if inliers.len() < MIN_INLIERS {
            return None;
        }
        // A place is seen across the image; a consistent set of matches in
        // one region is an object that moved (a person seen twice) or one
        // look-alike surface.
        let pixels: Vec<(f64, f64)> = inliers
            .iter()
            .map(|&j| {
                let m = &kf.measurements[matches[j].0];
                (m.u, m.v)
            })
            .collect();
        let across = match self.sensor {
            Sensor::Rgbd => MIN_SPREAD,
            Sensor::Monocular => MIN_SPREAD_ACROSS_MONOCULAR,
        };
        if !spread_across(&pixels, kf.bounds, across) {
            return None;
        }
        // The camera sees the old world through the correction.
        let corrected_cw = Similarity::from_isometry(&kf.pose_cw) * correction.inverse();
        let confirmed = self.confirm(map, id, matched, &corrected_cw);
        if confirmed < MIN_CONFIRMED {
            return None;
        }
        Some(LoopGeometry {
            matched,
            corrected_cw,
            point_pairs: inliers
                .iter()
                .map(|&i| (matches[i].1, matches[i].2))
                .collect(),
            inliers: inliers.len(),
            confirmed,
        })
    }

    /// World point `x` projects within the chi-square bound of keyframe
    /// `kf`'s measurement `m`.
    fn reprojects(&self, kf: &KeyFrame, m: &KeyFrameObservation, x: &Vector3<f64>) -> bool {
        let pc = kf.pose_cw * Point3::from(*x);
        if pc.z <= 0.0 {
            return false;
        }
        let (u, v) = self.camera.project(&pc.coords);
        ((u - m.u).powi(2) + (v - m.v).powi(2)) * m.info <= INLIER_CHI2
    }

    /// Points of the candidate's neighbourhood that project, with the
    /// corrected pose, near a keypoint of keyframe `id` with a close
    /// descriptor.
    fn confirm(&self, map: &Map, id: usize, matched: usize, pose_cw: &Similarity) -> usize {
        let kf = &map.keyframes[id];
        let keypoints: Vec<(f64, f64, &crate::features::orb::Descriptor)> = kf
            .measurements
            .iter()
            .chain(kf.spare.iter().map(|s| &s.measurement))
            .map(|m| (m.u, m.v, &m.descriptor))
            .collect();
        let (x0, x1, y0, y1) = kf.bounds;
        let mut points: HashSet<usize> = HashSet::new();
        for k in std::iter::once(matched).chain(map.best_covisible(matched, 10)) {
            points.extend(map.keyframes[k].points.iter().copied());
        }
        let mut used = vec![false; keypoints.len()];
        let mut confirmed = 0;
        for p in points {
            let point = &map.points[p];
            let pc = pose_cw.apply_point(&point.position);
            if pc.z <= 0.0 {
                continue;
            }
            let (u, v) = self.camera.project(&pc);
            if !(x0..x1).contains(&u) || !(y0..y1).contains(&v) {
                continue;
            }
            let best = keypoints
                .iter()
                .enumerate()
                .filter(|(j, (ku, kv, _))| {
                    !used[*j] && (ku - u).powi(2) + (kv - v).powi(2) < CONFIRM_RADIUS_PX.powi(2)
                })
                .map(|(j, (_, _, d))| (hamming(d, &point.descriptor), j))
                .min();
            if let Some((_, j)) = best.filter(|b| b.0 <= MATCH_MAX_DISTANCE) {
                used[j] = true;
                confirmed += 1;
            }
        }
        confirmed
    }
}

/// Inlier pixels span at least this share of the image's width and of its
/// height (between their 10th and 90th percentiles): a person is tall and
/// narrow. With depth that is what refuses a person seen at two places,
/// whose points fit one rigid transform (on the shared sequence with
/// people and no masks such a loop spans 27 % of the width, 58 % of the
/// height: refused).
const MIN_SPREAD: f64 = 0.35;
/// Monocular, the other direction needs only this share: a place seen
/// again is matched where its structure is, which can be the middle of the
/// view (the rendered orbit's loop: 35 % of the width, 58 % of the height;
/// other keyframes of it 21-35 % wide), and a person's points rarely fit a
/// similarity whose inliers reproject in both keyframes (on the people
/// sequences, monocular, with and without masks, none gets this far:
/// `tests/no_false_loops.rs`).
const MIN_SPREAD_ACROSS_MONOCULAR: f64 = 0.2;

/// The pixels cover the image (`bounds`) widely enough: `MIN_SPREAD` in one
/// direction, `across` in the other.
fn spread_across(pixels: &[(f64, f64)], bounds: crate::camera::Bounds, across: f64) -> bool {
    let (x0, x1, y0, y1) = bounds;
    let extent = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
        at(0.9) - at(0.1)
    };
    if pixels.is_empty() {
        return false;
    }
    let wide = extent(pixels.iter().map(|p| p.0).collect()) / (x1 - x0);
    let high = extent(pixels.iter().map(|p| p.1).collect()) / (y1 - y0);
    wide.max(high) >= MIN_SPREAD && wide.min(high) >= across
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inliers_in_one_region_are_not_a_place() {
        let bounds = (0.0, 640.0, 0.0, 480.0);
        let grid: Vec<(f64, f64)> = (0..100)
            .map(|i| (32.0 + 64.0 * (i % 10) as f64, 24.0 + 48.0 * (i / 10) as f64))
            .collect();
        let person: Vec<(f64, f64)> = grid.iter().map(|&(u, v)| (300.0 + u / 8.0, v)).collect();
        // The middle third of the view, most of its height.
        let middle: Vec<(f64, f64)> = grid.iter().map(|&(u, v)| (213.0 + u / 3.0, v)).collect();
        for across in [MIN_SPREAD, MIN_SPREAD_ACROSS_MONOCULAR] {
            assert!(spread_across(&grid, bounds, across));
            // A person: a tall, narrow region.
            assert!(!spread_across(&person, bounds, across));
            assert!(!spread_across(&[], bounds, across));
        }
        // A place with depth must fill the view more than monocular.
        assert!(!spread_across(&middle, bounds, MIN_SPREAD));
        assert!(spread_across(&middle, bounds, MIN_SPREAD_ACROSS_MONOCULAR));
    }
}
