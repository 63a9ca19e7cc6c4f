//! Descriptor matching, in one place: a frame against map points by
//! projection (tracking), a frame against a keyframe's points by bag of
//! words (relocalisation), two frames' keypoints near the same pixel
//! (monocular initialisation), and two keyframes' spare keypoints
//! along the epipolar line (triangulation). Fusion's search, which merges
//! as it goes, is in [`crate::local_mapping::fusion`].

use nalgebra::{Isometry3, Vector3};

use crate::camera::Camera;
use crate::features::orb::{hamming, Descriptor, MATCH_MAX_DISTANCE};
use crate::frame::Frame;
use crate::geometry::PoseMatrix;
use crate::map::{KeyFrame, Map, SpareKeypoint};
use crate::place_recognition::{FeatureVector, Vocabulary};

/// The best match must beat the second best along the line by this ratio:
/// a repeated texture gives many candidates on one epipolar line.
const EPIPOLAR_RATIO: f64 = 0.9;
/// Chi-square (1 degree of freedom, 95 %) of a keypoint's distance to the
/// epipolar line, in units of its level's sigma.
const EPIPOLAR_CHI2: f64 = 3.84;
/// Matching by bag of words: the best keypoint must beat the second best
/// by this ratio (ORB-SLAM2's relocalisation matcher: 0.75).
const BOW_RATIO: f64 = 0.75;
/// Exhaustive matching's ratio test between the best and second-best point.
const EXHAUSTIVE_RATIO: f64 = 0.8;
/// Matching for initialisation: the ratio (ORB-SLAM2's SearchForInitialization: 0.9).
const INITIALISATION_RATIO: f64 = 0.9;

/// For each keypoint of `reference`, the keypoint of `current` on the same
/// pyramid level within `window` pixels with the closest descriptor (below
/// the threshold, clearly better than the second best, each keypoint of
/// `current` used once: the closer wins), kept when its change of
/// orientation agrees with most others (ORB-SLAM2's
/// SearchForInitialization). Returns (reference keypoint, current keypoint).
pub fn match_for_initialisation(
    reference: &Frame,
    current: &Frame,
    window: f64,
) -> Vec<(usize, usize)> {
    // Per current keypoint: (distance, reference keypoint).
    let mut taken: Vec<Option<(u32, usize)>> = vec![None; current.kps.len()];
    let mut near = Vec::new();
    for (i, kp) in reference.kps.iter().enumerate() {
        let (u, v) = reference.un[i];
        current.grid.near(u, v, window, &mut near);
        let (mut best, mut second, mut best_j) = (u32::MAX, u32::MAX, None);
        for &j in &near {
            let (cu, cv) = current.un[j];
            if current.kps[j].level != kp.level
                || (cu - u).powi(2) + (cv - v).powi(2) > window * window
            {
                continue;
            }
            let d = hamming(&reference.descs[i], &current.descs[j]);
            if d < best {
                (second, best, best_j) = (best, d, Some(j));
            } else if d < second {
                second = d;
            }
        }
        let Some(j) = best_j else { continue };
        if best > MATCH_MAX_DISTANCE || best as f64 >= INITIALISATION_RATIO * second as f64 {
            continue;
        }
        if taken[j].is_none_or(|(d, _)| best < d) {
            taken[j] = Some((best, i));
        }
    }
    let pairs: Vec<(usize, usize)> = taken
        .iter()
        .enumerate()
        .filter_map(|(j, t)| t.map(|(_, i)| (i, j)))
        .collect();
    let rotations: Vec<f32> = pairs
        .iter()
        .map(|&(i, j)| current.kps[j].angle - reference.kps[i].angle)
        .collect();
    pairs
        .into_iter()
        .zip(consistent_rotations(&rotations))
        .filter(|(_, ok)| *ok)
        .map(|(p, _)| p)
        .collect()
}

/// A search by projection.
#[derive(Debug, Clone, Copy)]
pub struct ProjectionSearch {
    /// Camera from world the points are projected with.
    pub pose: Isometry3<f64>,
    /// Pixels (grown with the keypoint's scale, up to 2x).
    pub radius: f64,
    /// Points nearer than this (metres) are not searched.
    pub min_depth_m: f64,
    /// A keypoint's descriptor distance must be at most this share of the
    /// second-best keypoint's in the window (1: the best wins).
    pub ratio: f64,
    /// Count each point that lands in the image as seen (`visible`), for
    /// recent-point culling: done on the final pass only.
    pub count_visible: bool,
}

/// A frame's keypoints copied in its grid's cell order (position, level,
/// descriptor): the candidates of a search are then one contiguous run per
/// row of cells rather than an index per candidate into the frame's arrays
/// (fewer cache misses over a few thousand points). Tracking's search by
/// projection and the motion check's search in older frames read it.
pub(crate) struct ByCell {
    /// Keypoint index in the frame.
    pub index: Vec<usize>,
    pub un: Vec<(f64, f64)>,
    pub levels: Vec<u8>,
    pub descs: Vec<Descriptor>,
    /// Where each grid cell starts in the order (`Grid::cell_order`).
    pub starts: Vec<usize>,
}

impl ByCell {
    pub(crate) fn new(frame: &Frame) -> Self {
        let (index, starts) = frame.grid.cell_order();
        Self {
            un: index.iter().map(|&k| frame.un[k]).collect(),
            levels: index.iter().map(|&k| frame.kps[k].level).collect(),
            descs: index.iter().map(|&k| frame.descs[k]).collect(),
            index,
            starts,
        }
    }
}

/// For each keypoint of `frame`, the best of the map points `candidates`
/// projecting within the search radius with a descriptor distance below
/// the threshold and clearly below the second-best keypoint's
/// (`search.ratio`) (each map point used once, the closer descriptor wins).
/// `ordered` is `frame`'s keypoints in cell order, built once for the
/// frame's passes.
pub(crate) fn match_by_projection(
    map: &mut Map,
    (frame, ordered): (&Frame, &ByCell),
    camera: &Camera,
    candidates: &[usize],
    search: &ProjectionSearch,
) -> Vec<Option<usize>> {
    let mut best: Vec<Option<(usize, u32)>> = vec![None; frame.kps.len()];
    let pose = PoseMatrix::of(&search.pose);
    for &p in candidates {
        let pc = pose.apply(&map.points[p].position);
        if pc.z < search.min_depth_m {
            continue;
        }
        let (u, v) = camera.project(&pc);
        let (x0, x1, y0, y1) = frame.bounds;
        if !(x0..x1).contains(&u) || !(y0..y1).contains(&v) {
            continue;
        }
        // The window of the farthest reach (2x the radius).
        let mut runs = frame
            .grid
            .rows_near(&ordered.starts, u, v, 2.0 * search.radius)
            .filter(|run| !run.is_empty())
            .peekable();
        if runs.peek().is_none() {
            continue;
        }
        if search.count_visible {
            map.points[p].visible += 1;
        }
        let descriptor = &map.points[p].descriptor;
        let mut cand: Option<(usize, u32)> = None;
        let mut second = u32::MAX;
        for i in runs.flatten() {
            let (ku, kv) = ordered.un[i];
            // Coarse-level keypoints are located less precisely: the radius
            // grows with their scale (up to 2x).
            let r = search.radius * frame.level_scale(ordered.levels[i]).min(2.0);
            if (ku - u).powi(2) + (kv - v).powi(2) > r * r {
                continue;
            }
            let d = hamming(descriptor, &ordered.descs[i]);
            if cand.is_none_or(|c| d < c.1) {
                if let Some(c) = cand {
                    second = second.min(c.1);
                }
                cand = Some((ordered.index[i], d));
            } else {
                second = second.min(d);
            }
        }
        let cand = cand
            .filter(|c| c.1 <= MATCH_MAX_DISTANCE && (c.1 as f64) <= search.ratio * second as f64);
        if let Some((k, d)) = cand {
            if best[k].is_none_or(|b| d < b.1) {
                best[k] = Some((p, d));
            }
        }
    }
    best.into_iter().map(|b| b.map(|(p, _)| p)).collect()
}

/// (keypoint, map point) of every matched keypoint.
pub fn matched_pairs(matched: &[Option<usize>]) -> Vec<(usize, usize)> {
    matched
        .iter()
        .enumerate()
        .filter_map(|(k, m)| m.map(|p| (k, p)))
        .collect()
}

/// Matches of a frame's keypoints to the points of keyframe `kf` by bag of
/// words (ORB-SLAM2's SearchByBoW): only descriptors under the same
/// vocabulary node at the feature level are compared (`features` is the
/// frame's feature vector over its descriptors); a keyframe measurement's best
/// keypoint must be below the threshold and clearly better than the second
/// best; a keypoint keeps its closest point; then only matches whose
/// change of keypoint orientation agrees with the most common changes stay
/// (a camera turns the whole image at once). (keypoint index, point id).
pub fn match_by_bow(
    map: &Map,
    kf: &KeyFrame,
    vocabulary: &Vocabulary,
    features: &FeatureVector,
    frame: &Frame,
) -> Vec<(usize, usize)> {
    let descs = &frame.descs;
    let kf_descs: Vec<Descriptor> = kf.measurements.iter().map(|m| m.descriptor).collect();
    let kf_features = vocabulary.features(&kf_descs);
    // (point, distance, measurement index) per keypoint.
    let mut best: Vec<Option<(usize, u32, usize)>> = vec![None; descs.len()];
    let (a, b) = (&kf_features.0, &features.0);
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        match a[i].0.cmp(&b[j].0) {
            std::cmp::Ordering::Less => i += 1,
            std::cmp::Ordering::Greater => j += 1,
            std::cmp::Ordering::Equal => {
                for &m in &a[i].1 {
                    let p = kf.points[m as usize];
                    if !map.points[p].is_live() {
                        continue;
                    }
                    let d = &kf_descs[m as usize];
                    let (mut b1, mut b2, mut bk) = (u32::MAX, u32::MAX, 0);
                    for &k in &b[j].1 {
                        let h = hamming(d, &descs[k as usize]);
                        if h < b1 {
                            b2 = b1;
                            b1 = h;
                            bk = k as usize;
                        } else if h < b2 {
                            b2 = h;
                        }
                    }
                    if b1 <= MATCH_MAX_DISTANCE
                        && (b1 as f64) < BOW_RATIO * b2 as f64
                        && best[bk].is_none_or(|(_, d, _)| b1 < d)
                    {
                        best[bk] = Some((p, b1, m as usize));
                    }
                }
                i += 1;
                j += 1;
            }
        }
    }
    let matches: Vec<(usize, usize, usize)> = best
        .iter()
        .enumerate()
        .filter_map(|(k, m)| m.map(|(p, _, i)| (k, p, i)))
        .collect();
    let rotations: Vec<f32> = matches
        .iter()
        .map(|&(k, _, i)| frame.kps[k].angle - kf.measurements[i].angle)
        .collect();
    let keep = consistent_rotations(&rotations);
    matches
        .iter()
        .zip(keep)
        .filter_map(|(&(k, p, _), keep)| keep.then_some((k, p)))
        .collect()
}

/// Bins of the histogram of orientation changes (ORB-SLAM2's 30).
const ROTATION_BINS: usize = 30;

/// Which of the orientation changes (radians) fall in the three most
/// populated bins of their histogram (the second and third only when they
/// hold at least a tenth of the first: ORB-SLAM2's ComputeThreeMaxima).
pub(crate) fn consistent_rotations(rotations: &[f32]) -> Vec<bool> {
    let bin = |r: f32| {
        let turns = (r / std::f32::consts::TAU).rem_euclid(1.0);
        ((turns * ROTATION_BINS as f32) as usize).min(ROTATION_BINS - 1)
    };
    let mut counts = [0usize; ROTATION_BINS];
    for &r in rotations {
        counts[bin(r)] += 1;
    }
    let mut order: Vec<usize> = (0..ROTATION_BINS).collect();
    order.sort_by(|&a, &b| counts[b].cmp(&counts[a]).then(a.cmp(&b)));
    let top = counts[order[0]];
    let kept: Vec<usize> = order
        .into_iter()
        .take(3)
        .enumerate()
        .filter(|&(rank, b)| rank == 0 || counts[b] * 10 >= top)
        .map(|(_, b)| b)
        .collect();
    rotations.iter().map(|&r| kept.contains(&bin(r))).collect()
}

/// For each descriptor, the point of keyframe `kf` closest in descriptor
/// space when it is below the threshold and clearly better than the
/// second best (ratio test): (descriptor index, point id). Exhaustive: for
/// the rare searches that must not miss (a loop candidate's geometry),
/// where matching by bag of words finds too few.
pub fn match_exhaustive(map: &Map, kf: &KeyFrame, descs: &[Descriptor]) -> Vec<(usize, usize)> {
    let mut pairs = Vec::new();
    for (k, d) in descs.iter().enumerate() {
        let (mut b1, mut b2, mut bp) = (u32::MAX, u32::MAX, 0);
        for &p in &kf.points {
            if !map.points[p].is_live() {
                continue;
            }
            let h = hamming(d, &map.points[p].descriptor);
            if h < b1 {
                b2 = b1;
                b1 = h;
                bp = p;
            } else if h < b2 {
                b2 = h;
            }
        }
        if b1 <= MATCH_MAX_DISTANCE && (b1 as f64) < EXHAUSTIVE_RATIO * b2 as f64 {
            pairs.push((k, bp));
        }
    }
    pairs
}

/// Normalised image coordinates (z = 1) of a keypoint.
pub(crate) fn ray(camera: &Camera, s: &SpareKeypoint) -> Vector3<f64> {
    camera.unproject(s.measurement.u, s.measurement.v, 1.0)
}

/// Pairs (spare index in kf1, spare index in kf2) of keypoints with close
/// descriptors whose kf2 keypoint lies on the epipolar line of the kf1 one
/// (within its level's chi-square bound) and away from the epipole, kf1's
/// keypoints already `taken` left out.
pub fn epipolar_matches(
    camera: &Camera,
    kf1: &KeyFrame,
    kf2: &KeyFrame,
    taken: &[Option<usize>],
) -> Vec<(usize, usize)> {
    // Camera 2 from camera 1, and the essential matrix [t]x R.
    let t21 = kf2.pose_cw * kf1.pose_cw.inverse();
    let essential =
        t21.translation.vector.cross_matrix() * t21.rotation.to_rotation_matrix().matrix();
    let epipole = {
        let c1 = t21.translation.vector;
        (c1.z > 1e-6).then(|| camera.project(&c1))
    };
    let rays2: Vec<Vector3<f64>> = kf2.spare.iter().map(|s| ray(camera, s)).collect();
    let mut pairs = Vec::new();
    for (i, s1) in kf1.spare.iter().enumerate() {
        if taken[i].is_some() {
            continue;
        }
        let m1 = &s1.measurement;
        let line = essential * ray(camera, s1);
        let norm = line.x.hypot(line.y);
        if norm < 1e-12 {
            continue;
        }
        let (mut best, mut second) = ((u32::MAX, 0), u32::MAX);
        for (j, s2) in kf2.spare.iter().enumerate() {
            let m2 = &s2.measurement;
            let d = hamming(&m1.descriptor, &m2.descriptor);
            if d > MATCH_MAX_DISTANCE || d >= second {
                continue;
            }
            let sigma2 = m2.sigma() * m2.sigma();
            if let Some((eu, ev)) = epipole {
                if (m2.u - eu).powi(2) + (m2.v - ev).powi(2) < 100.0 * m2.sigma() {
                    continue;
                }
            }
            let off = line.dot(&rays2[j]).abs() / norm * camera.fx;
            if off * off > EPIPOLAR_CHI2 * sigma2 {
                continue;
            }
            if d < best.0 {
                second = best.0;
                best = (d, j);
            } else {
                second = d;
            }
        }
        if best.0 <= MATCH_MAX_DISTANCE && (best.0 as f64) < EPIPOLAR_RATIO * second as f64 {
            pairs.push((i, best.1));
        }
    }
    pairs
}
