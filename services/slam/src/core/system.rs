//! The RGB-D SLAM system: `System::track_rgbd` per frame.
//!
//! Tracking as ORB-SLAM2 does it for RGB-D: ORB features outside the
//! (dilated) dynamic mask, undistorted and, for a rolling-shutter camera,
//! moved to the middle row's instant; the constant-velocity motion model
//! predicts the pose, map points are matched by projection and the pose is
//! optimised (motion only, robust); if that fails the last pose is tried with
//! a wider search; then the local map (points of the recent keyframes) is
//! matched by projection and the pose optimised again. A lost frame triggers
//! relocalisation: descriptor matches against recent keyframes, 3D-3D RANSAC
//! on the depth of both sides (PnP RANSAC where the frame lacks depth),
//! then pose optimisation.
//!
//! Keyframes are decided as ORB-SLAM2 decides them (tracked points against
//! the reference keyframe, frames since the last keyframe) and create new
//! map points from the depth of the keypoints no map point explains; then
//! local mapping ([`super::map`]: covisibility, point culling, triangulation,
//! optional fusion of duplicates and local bundle adjustment, keyframe
//! culling, compaction) runs on its own thread
//! ([`super::local_mapping`]) while the next frame's features are
//! extracted. Not here yet (README): loop closing.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use pipeline::rng::SplitMix64;
use shared_types::{TrackCounts, TrackState};

use std::collections::HashMap;

use super::camera::{Bounds, Camera};
use super::grid::Grid;
use super::local_mapping::LocalMapper;
use super::map::{
    KeyFrame, KeyFrameObservation, Map, MapPoint, MappingCounts, MappingReport, SpareKeypoint,
};
use super::optimize::{is_finite_pose, optimize_pose, renormalized, Observation};
use super::orb::{
    hamming, Descriptor, GrayU8, KeyPoint, OrbExtractor, OrbParams, MATCH_MAX_DISTANCE,
};
use super::pnp::{pnp_ransac, PnpMatch};

/// Tracked frames the rolling-shutter correction estimates the motion over.
const MOTION_HISTORY: usize = 3;
/// Neighbours of each directly covisible keyframe added to the local map.
const LOCAL_NEIGHBOURS: usize = 10;
/// At most this many keyframes in the local map (ORB-SLAM2's 80).
const MAX_LOCAL_KEYFRAMES: usize = 80;

#[derive(Debug, Clone, Copy)]
pub struct SlamParams {
    pub orb: OrbParams,
    /// Keypoints with depth in this range (metres) get 3D measurements.
    pub min_depth_m: f64,
    pub max_depth_m: f64,
    /// Dynamic masks are grown by this many pixels before filtering.
    pub mask_dilation_px: usize,
    /// The newest keyframes, always part of the local map (with the older
    /// ones covisibility adds, see `local_points`).
    pub local_keyframes: usize,
    /// A keyframe at the latest after this many frames.
    pub max_frames_between_keyframes: u32,
    /// Fewer inliers than this: the frame is lost.
    pub min_inliers: usize,
    /// Keyframes whose poses local bundle adjustment refines (0 or 1: off,
    /// the default: measured with `slam-bench --local-ba 10` it makes ATE
    /// worse, 0.0337 -> 0.0350 m on fr1_rpy and 0.0028 -> 0.019 m on the
    /// rendered room: depth is weak in its residual and our points are seen
    /// by few keyframes, so keyframes slide with their points; README).
    pub local_ba_keyframes: usize,
    /// Keypoints nearer than this (metres) are measured with their depth as
    /// (u, v, ur); farther ones only by (u, v), since depth noise grows with
    /// the square of the distance (ORB-SLAM2's ThDepth: 40 baselines).
    pub close_depth_m: f64,
    /// Local mapping on its own thread (overlapping the next frame's
    /// feature extraction) rather than inline after each keyframe; the
    /// results are the same, only the time moves.
    pub mapping_thread: bool,
    /// Local mapping triangulates new points from keypoints without depth
    /// that two covisible keyframes see ([`super::triangulation`]).
    pub triangulate: bool,
    /// Local mapping merges duplicate points with the neighbours' and adds
    /// observations to keypoints they land on ([`super::fusion`]). Off by
    /// default: measured, it leaves ATE level on static scenes but cuts the
    /// inliers per frame by a quarter and, with the product's imperfect
    /// masks on the rendered room, triples ATE (0.0043 -> 0.0142 m; README).
    pub fuse_points: bool,
}

impl Default for SlamParams {
    fn default() -> Self {
        Self {
            orb: OrbParams::default(),
            min_depth_m: 0.1,
            max_depth_m: 6.0,
            mask_dilation_px: 5,
            local_keyframes: 20,
            max_frames_between_keyframes: 10,
            min_inliers: 25,
            local_ba_keyframes: 0,
            close_depth_m: 3.1,
            mapping_thread: true,
            triangulate: true,
            fuse_points: false,
        }
    }
}

/// One frame's features.
struct Frame {
    kps: Vec<KeyPoint>,
    /// Undistorted keypoint pixels.
    un: Vec<(f64, f64)>,
    descs: Vec<Descriptor>,
    depth: Vec<Option<f64>>,
    /// Colour under each keypoint.
    colours: Vec<[u8; 3]>,
    grid: Grid,
    /// Undistorted image extent (x0, x1, y0, y1).
    bounds: Bounds,
}

/// What one call of `track_rgbd` reports.
#[derive(Debug, Clone)]
pub struct FrameResult {
    /// World from camera.
    pub pose_wc: Isometry3<f64>,
    pub state: TrackState,
    pub keyframe_inserted: bool,
    pub next_needs_keyframe: bool,
    pub counts: TrackCounts,
    pub extract_ms: f64,
    pub track_ms: f64,
}

pub struct System {
    pub params: SlamParams,
    camera: Camera,
    extractor: OrbExtractor,
    /// Owned here while tracking; lent to `mapper` after a keyframe until
    /// the next frame is tracked (see `mapping`).
    map: Map,
    mapper: Option<LocalMapper>,
    mapping: Mapping,
    /// Camera from world of the last tracked frame, and the motion since the one before.
    last_pose: Option<Isometry3<f64>>,
    velocity: Option<Isometry3<f64>>,
    /// Timestamp and pose (camera from world) of the last tracked frames,
    /// oldest first, at most `MOTION_HISTORY` (cleared when lost): the
    /// rolling-shutter correction's motion estimate.
    recent: Vec<(f64, Isometry3<f64>)>,
    /// Map points the last tracked frame matched (seeds the local map).
    last_matched: Vec<usize>,
    frames_since_keyframe: u32,
    /// Inliers of the frame that made the last keyframe.
    reference_inliers: usize,
    lost: bool,
    /// Undistorted image extent, computed once per frame size.
    bounds: Option<((usize, usize), Bounds)>,
    /// Local mapping time of the keyframe whose mapping finished while this
    /// frame was processed (0 if none).
    mapping_ms: f64,
    /// What local mapping did over the run so far.
    mapped: MappingCounts,
}

/// Where the last keyframe's local mapping stands.
enum Mapping {
    /// Nothing to take back.
    Idle,
    /// The map is on the mapping thread.
    OnThread,
    /// Done inline (no mapping thread); its report still to be applied.
    Inline(MappingReport),
}

fn to_ms(t: std::time::Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

impl System {
    pub fn new(params: SlamParams, camera: Camera) -> Self {
        let mapper = params
            .mapping_thread
            .then(|| LocalMapper::spawn(camera, params))
            .and_then(|spawned| {
                spawned
                    .map_err(|e| {
                        tracing::warn!("local mapping thread not started ({e}): mapping inline")
                    })
                    .ok()
            });
        Self {
            extractor: OrbExtractor::new(params.orb),
            params,
            camera,
            map: Map::default(),
            mapper,
            mapping: Mapping::Idle,
            last_pose: None,
            velocity: None,
            recent: Vec::new(),
            last_matched: Vec::new(),
            frames_since_keyframe: 0,
            reference_inliers: 0,
            lost: false,
            bounds: None,
            mapping_ms: 0.0,
            mapped: MappingCounts::default(),
        }
    }

    /// Tracks one RGB-D frame taken at `timestamp` (seconds). `rgb` is
    /// RGB8, `depth` u16 in `camera.depth_scale` units per metre (0: no
    /// depth), `mask` an optional label image (non-zero: dynamic object).
    /// The pose returned is the camera's at the middle image row's
    /// exposure (with a rolling shutter, `camera.readout_s > 0`, the other
    /// rows' keypoints are moved to that instant). Never panics on odd input:
    /// blank, depthless or fully masked frames come back LOST (or
    /// NOT_INITIALISED before the map exists).
    pub fn track_rgbd(
        &mut self,
        rgb: &[u8],
        depth: &[u16],
        mask: Option<&[u8]>,
        width: usize,
        height: usize,
        timestamp: f64,
    ) -> FrameResult {
        let t0 = std::time::Instant::now();
        self.mapping_ms = 0.0;
        let pixels = width * height;
        if width < 64
            || height < 64
            || rgb.len() != 3 * pixels
            || depth.len() != pixels
            || mask.is_some_and(|m| m.len() != pixels)
        {
            return FrameResult {
                pose_wc: self.last_pose.unwrap_or_else(Isometry3::identity).inverse(),
                state: TrackState::Skipped,
                keyframe_inserted: false,
                next_needs_keyframe: false,
                counts: TrackCounts::default(),
                extract_ms: 0.0,
                track_ms: 0.0,
            };
        }
        let gray = GrayU8::from_rgb(rgb, width, height);
        let dilated = mask.map(|m| dilate(m, width, height, self.params.mask_dilation_px));
        let keep = |x: f32, y: f32| match &dilated {
            Some(m) => {
                let (xi, yi) = ((x as usize).min(width - 1), (y as usize).min(height - 1));
                !m[yi * width + xi]
            }
            None => true,
        };
        let (kps, descs, masked) = self.extractor.extract(&gray, &keep);
        let mut un: Vec<(f64, f64)> = kps
            .iter()
            .map(|k| self.camera.undistort(k.x as f64, k.y as f64))
            .collect();
        let depth_of = |k: &KeyPoint| {
            let (x, y) = (
                (k.x.round() as usize).min(width - 1),
                (k.y.round() as usize).min(height - 1),
            );
            let d = depth.get(y * width + x).copied().unwrap_or(0) as f64 / self.camera.depth_scale;
            (d >= self.params.min_depth_m && d <= self.params.max_depth_m).then_some(d)
        };
        let mut depths: Vec<Option<f64>> = kps.iter().map(depth_of).collect();
        let motion = self.shutter_motion(None);
        // Raw positions for the second pass (see `refine_for_shutter`).
        let raw = motion.map(|m| {
            let raw = (un.clone(), depths.clone());
            self.undo_rolling_shutter(&kps, &mut un, &mut depths, height, m);
            raw
        });
        let colours: Vec<[u8; 3]> = kps
            .iter()
            .map(|k| {
                let i =
                    3 * ((k.y as usize).min(height - 1) * width + (k.x as usize).min(width - 1));
                [rgb[i], rgb[i + 1], rgb[i + 2]]
            })
            .collect();
        let grid = Grid::new(&un, width, height);
        let mut frame = Frame {
            kps,
            un,
            descs,
            depth: depths,
            colours,
            grid,
            bounds: self.bounds(width, height),
        };
        let extract_ms = to_ms(t0);
        let t1 = std::time::Instant::now();
        // The map comes back from local mapping (a wait, if it is not done,
        // counts as tracking time).
        self.settle();

        let mut counts = TrackCounts {
            features: frame.kps.len() as u32,
            features_masked: masked as u32,
            extract_us: (extract_ms * 1e3) as u32,
            ..Default::default()
        };
        let initialising = self.map.keyframes.is_empty();
        let (state, mut pose_cw, inliers, matched) = if initialising {
            match self.initialise(&frame) {
                true => (
                    TrackState::Ok,
                    Isometry3::identity(),
                    frame.kps.len(),
                    Vec::new(),
                ),
                false => (
                    TrackState::NotInitialised,
                    Isometry3::identity(),
                    0,
                    Vec::new(),
                ),
            }
        } else {
            self.track(&frame)
        };
        if let (TrackState::Ok, Some(raw)) = (state, &raw) {
            if let Some(refined) =
                self.refine_for_shutter(&mut frame, raw, &pose_cw, &matched, timestamp, height)
            {
                pose_cw = refined;
            }
        }
        // A successful initialisation made the first keyframe.
        let mut keyframe_inserted = initialising && state == TrackState::Ok;
        if matches!(state, TrackState::Ok | TrackState::Relocalised) {
            if let Some(last) = self.last_pose {
                self.velocity = Some(renormalized(&(pose_cw * last.inverse())));
            }
            self.last_pose = Some(pose_cw);
            self.last_matched = matched.iter().flatten().copied().collect();
            if self.recent.len() == MOTION_HISTORY {
                self.recent.remove(0);
            }
            self.recent.push((timestamp, pose_cw));
            self.lost = false;
            if !keyframe_inserted {
                if self.need_keyframe(inliers, &frame, &matched) {
                    self.insert_keyframe(&frame, &pose_cw, &matched, inliers);
                    keyframe_inserted = true;
                } else {
                    self.frames_since_keyframe += 1;
                }
            }
        } else if !self.map.keyframes.is_empty() {
            self.lost = true;
            self.velocity = None;
            self.recent.clear();
        }
        counts.inliers = inliers as u32;
        counts.map_points = self.map.points.len() as u32;
        counts.keyframes = self.map.live_keyframes().count() as u32;
        if keyframe_inserted {
            self.start_mapping(self.map.keyframes.len() - 1);
        }
        counts.mapping_us = (self.mapping_ms * 1e3) as u32;
        let next_needs_keyframe = !keyframe_inserted
            && (self.lost
                || self.keyframe_due()
                || (inliers as f64) < 0.85 * self.reference_inliers as f64);
        let pose_for_output = self.last_pose.unwrap_or(pose_cw);
        FrameResult {
            pose_wc: pose_for_output.inverse(),
            state,
            keyframe_inserted,
            next_needs_keyframe,
            counts,
            extract_ms,
            track_ms: to_ms(t1),
        }
    }

    /// The map, once local mapping has given it back.
    pub fn map(&mut self) -> &Map {
        self.settle();
        &self.map
    }

    /// Points local mapping triangulated and fused so far (once it has
    /// given the map back).
    pub fn mapping_counts(&mut self) -> MappingCounts {
        self.settle();
        self.mapped
    }

    /// Local mapping for keyframe `id`: on the mapping thread (the map goes
    /// with it until `settle`) or, without one, here and now.
    fn start_mapping(&mut self, id: usize) {
        if let Some(mapper) = &self.mapper {
            match mapper.submit(std::mem::take(&mut self.map), id) {
                Ok(()) => {
                    self.mapping = Mapping::OnThread;
                    return;
                }
                Err(map) => {
                    tracing::error!("local mapping thread gone: mapping inline from now on");
                    self.map = map;
                    self.mapper = None;
                }
            }
        }
        let report = self.map.process_keyframe(id, &self.camera, &self.params);
        self.mapping_ms = report.ms;
        self.mapping = Mapping::Inline(report);
    }

    /// Takes the map back from local mapping (waiting for it) and applies
    /// what it did: after local bundle adjustment tracking goes on from the
    /// newest keyframe's adjusted pose (that keyframe is the last tracked
    /// frame). If the mapping thread died the map is lost: tracking starts
    /// a new one with the next frame.
    fn settle(&mut self) {
        let report = match std::mem::replace(&mut self.mapping, Mapping::Idle) {
            Mapping::Idle => return,
            Mapping::Inline(report) => report,
            Mapping::OnThread => match self.mapper.as_ref().and_then(|m| m.collect()) {
                Some((map, report)) => {
                    self.map = map;
                    self.mapping_ms = report.ms;
                    report
                }
                None => {
                    tracing::error!(
                        "local mapping thread died: map lost, starting a new one (mapping inline)"
                    );
                    self.mapper = None;
                    self.start_over();
                    return;
                }
            },
        };
        self.mapped += report.counts;
        if let Some(renumbered) = &report.renumbered {
            self.last_matched = self
                .last_matched
                .iter()
                .filter_map(|&p| renumbered[p])
                .collect();
        }
        if report.adjusted {
            if let Some(kf) = self.map.keyframes.last() {
                self.last_pose = Some(kf.pose_cw);
            }
        }
    }

    /// An empty map, nothing tracked: the next frame initialises.
    fn start_over(&mut self) {
        self.map = Map::default();
        self.last_pose = None;
        self.velocity = None;
        self.recent.clear();
        self.last_matched.clear();
        self.frames_since_keyframe = 0;
        self.reference_inliers = 0;
        self.lost = false;
    }

    /// Rolling shutter: row y is exposed `readout_s * (y - h/2) / h` seconds
    /// after the middle row. The constant-velocity model says how the camera
    /// moved in that time; each keypoint is moved back to where the middle
    /// row's camera saw it: with its depth as a 3D point (rotation and
    /// translation, its depth updated too), without depth as a bearing
    /// (rotation only). Turning alone is not enough: a camera that slides
    /// while turning towards what it looks at has image motions that cancel.
    /// On fr1_rpy, which turns at up to 2 rad/s, this takes ATE from 0.034
    /// to 0.012 m (README, SLAM section).
    fn undo_rolling_shutter(
        &self,
        kps: &[KeyPoint],
        un: &mut [(f64, f64)],
        depths: &mut [Option<f64>],
        height: usize,
        (velocity, span): (Isometry3<f64>, f64),
    ) {
        let readout = self.camera.readout_s;
        let h = height as f64;
        for ((k, p), d) in kps.iter().zip(un.iter_mut()).zip(depths.iter_mut()) {
            // Fraction of the inter-frame motion from the middle row to this one:
            // points in camera coordinates move as x(row) = R^f x(mid) + f t.
            let f = readout * (k.y as f64 - h / 2.0) / h / span;
            let back = velocity.rotation.powf(-f);
            let seen = match d {
                Some(z) => {
                    back * (self.camera.unproject(p.0, p.1, *z) - f * velocity.translation.vector)
                }
                None => back * self.camera.unproject(p.0, p.1, 1.0),
            };
            if seen.z > 1e-6 {
                *p = self.camera.project(&seen);
                if let Some(z) = d {
                    *z = seen.z;
                }
            }
        }
    }

    /// The camera motion (camera from camera) the rolling-shutter
    /// correction uses, and the seconds it spans: from the oldest remembered
    /// tracked frame to `until` (timestamp, pose) or else to the last one.
    /// Spanning two intervals: one interval's estimate feeds back (a pose
    /// error this frame is a velocity error with the opposite sign next
    /// frame) and can oscillate. None without a rolling shutter, when lost,
    /// or across a gap (dropped frames, a restart: the motion is stale).
    fn shutter_motion(
        &self,
        until: Option<(f64, Isometry3<f64>)>,
    ) -> Option<(Isometry3<f64>, f64)> {
        if self.camera.readout_s <= 0.0 || self.lost {
            return None;
        }
        let (t0, first) = match until {
            // Two intervals back from the current frame.
            Some(_) => *self.recent.get(self.recent.len().checked_sub(2)?)?,
            None => *self.recent.first()?,
        };
        let (t1, last) = until.or_else(|| self.recent.last().copied())?;
        let span = t1 - t0;
        (1e-3..0.5)
            .contains(&span)
            .then(|| (renormalized(&(last * first.inverse())), span))
    }

    /// Second pass of the rolling-shutter correction once the frame's pose
    /// is known: the motion from two frames back to this one is a frame
    /// more recent than what the first pass had. Keypoints are corrected
    /// again from their raw positions and the pose re-optimised on the same
    /// matches. None when it does not apply or the optimisation fails.
    fn refine_for_shutter(
        &self,
        frame: &mut Frame,
        raw: &(Vec<(f64, f64)>, Vec<Option<f64>>),
        pose_cw: &Isometry3<f64>,
        matched: &[Option<usize>],
        timestamp: f64,
        height: usize,
    ) -> Option<Isometry3<f64>> {
        let motion = self.shutter_motion(Some((timestamp, *pose_cw)))?;
        frame.un.clone_from(&raw.0);
        frame.depth.clone_from(&raw.1);
        self.undo_rolling_shutter(&frame.kps, &mut frame.un, &mut frame.depth, height, motion);
        let ids = matched_pairs(matched);
        let (pose, inlier) = optimize_pose(&self.camera, pose_cw, &self.observations(frame, &ids));
        let n = inlier.iter().filter(|&&b| b).count();
        let finite = is_finite_pose(&pose);
        (n >= self.params.min_inliers && finite).then_some(pose)
    }

    /// How keypoint `k` measures a point: its pixel, the virtual right
    /// pixel when its depth is close enough to trust, and the information
    /// (1 / sigma^2) of its pyramid level.
    fn measure(&self, frame: &Frame, k: usize) -> KeyFrameObservation {
        let (u, v) = frame.un[k];
        let sigma = self.extractor.scale(frame.kps[k].level) as f64;
        KeyFrameObservation {
            u,
            v,
            ur: frame.depth[k]
                .filter(|&d| d < self.params.close_depth_m)
                .map(|d| u - self.camera.bf / d),
            info: 1.0 / (sigma * sigma),
            descriptor: frame.descs[k],
        }
    }

    /// Pose-optimisation measurements of keypoint k matched to map point p.
    fn observations(&self, frame: &Frame, ids: &[(usize, usize)]) -> Vec<Observation> {
        ids.iter()
            .map(|&(k, p)| {
                let m = self.measure(frame, k);
                Observation {
                    world: self.map.points[p].position,
                    u: m.u,
                    v: m.v,
                    ur: m.ur,
                    info: m.info,
                }
            })
            .collect()
    }

    fn bounds(&mut self, width: usize, height: usize) -> Bounds {
        match self.bounds {
            Some((size, b)) if size == (width, height) => b,
            _ => {
                let b = self.camera.undistorted_bounds(width, height);
                self.bounds = Some(((width, height), b));
                b
            }
        }
    }

    fn initialise(&mut self, frame: &Frame) -> bool {
        let with_depth = frame.depth.iter().filter(|d| d.is_some()).count();
        if with_depth < 100 {
            return false;
        }
        let pose = Isometry3::identity();
        self.insert_keyframe(frame, &pose, &vec![None; frame.kps.len()], with_depth);
        true
    }

    /// Returns state, pose (camera from world), inliers and, per keypoint,
    /// the map point it was matched to (inliers only).
    fn track(&mut self, frame: &Frame) -> (TrackState, Isometry3<f64>, usize, Vec<Option<usize>>) {
        let local = self.local_points();
        if let Some(last) = self.last_pose.filter(|_| !self.lost) {
            let predicted = self.velocity.map_or(last, |v| renormalized(&(v * last)));
            for (start, radius) in [(predicted, 15.0), (last, 30.0)] {
                if let Some((pose, matched, n)) = self.track_from(frame, &local, &start, radius) {
                    return (TrackState::Ok, pose, n, matched);
                }
            }
        }
        match self.relocalise(frame) {
            Some(start) => match self.track_from(
                frame,
                &(0..self.map.points.len()).collect::<Vec<_>>(),
                &start,
                10.0,
            ) {
                Some((pose, matched, n)) => (TrackState::Relocalised, pose, n, matched),
                None => (TrackState::Lost, start, 0, Vec::new()),
            },
            None => (
                TrackState::Lost,
                self.last_pose.unwrap_or_else(Isometry3::identity),
                0,
                Vec::new(),
            ),
        }
    }

    /// Two passes of match-by-projection and pose optimisation: wide from
    /// `start`, then narrow from the first estimate.
    fn track_from(
        &mut self,
        frame: &Frame,
        local: &[usize],
        start: &Isometry3<f64>,
        radius: f64,
    ) -> Option<(Isometry3<f64>, Vec<Option<usize>>, usize)> {
        let mut pose = *start;
        let mut matched = Vec::new();
        let mut n = 0;
        for (pass, r) in [radius, 6.0].into_iter().enumerate() {
            matched = self.match_by_projection(frame, local, &pose, r, pass == 1);
            let ids = matched_pairs(&matched);
            if ids.len() < self.params.min_inliers {
                return None;
            }
            let obs = self.observations(frame, &ids);
            let (optimised, inlier) = optimize_pose(&self.camera, &pose, &obs);
            n = inlier.iter().filter(|&&b| b).count();
            let finite = is_finite_pose(&optimised);
            if n < self.params.min_inliers || !finite {
                return None;
            }
            pose = optimised;
            for (j, &(k, p)) in ids.iter().enumerate() {
                if !inlier[j] {
                    matched[k] = None;
                } else if pass == 1 {
                    self.map.points[p].found += 1;
                }
            }
        }
        Some((pose, matched, n))
    }

    /// The local map: the newest `local_keyframes` keyframes, older ones
    /// that observe points the last frame tracked (ORB-SLAM2's K1, most
    /// shared first), and the strongest covisible neighbours and
    /// spanning-tree parents of all of them; the points they observe
    /// (culled ones left out). Measured on fr1_rpy and the room, adding K1
    /// and the neighbours to the newest keyframes changed no figure (the
    /// camera rarely comes back to points older than 20 keyframes there); it
    /// is what a camera returning to a place after a long way needs.
    fn local_points(&self) -> Vec<usize> {
        let mut votes: HashMap<usize, u32> = HashMap::new();
        for &p in &self.last_matched {
            for &k in &self.map.points[p].observers {
                *votes.entry(k).or_default() += 1;
            }
        }
        let mut direct: Vec<(usize, u32)> = votes.into_iter().collect();
        direct.sort_unstable_by(|a, b| b.1.cmp(&a.1).then(b.0.cmp(&a.0)));
        // The newest keyframes that were not culled.
        let mut local: Vec<usize> = self
            .map
            .live_keyframes()
            .rev()
            .take(self.params.local_keyframes)
            .map(|(k, _)| k)
            .collect();
        let first = local.last().copied().unwrap_or(0);
        local.extend(
            direct
                .iter()
                .map(|&(k, _)| k)
                .filter(|&k| k < first)
                .take(LOCAL_NEIGHBOURS),
        );
        let mut in_local = vec![false; self.map.keyframes.len()];
        for &k in &local {
            in_local[k] = true;
        }
        let mut add = |k: usize, local: &mut Vec<usize>| {
            if local.len() < MAX_LOCAL_KEYFRAMES && !in_local[k] {
                in_local[k] = true;
                local.push(k);
            }
        };
        for i in 0..local.len() {
            let kf = &self.map.keyframes[local[i]];
            for &(n, _) in kf.covisible.iter().take(LOCAL_NEIGHBOURS) {
                add(n, &mut local);
            }
            if let Some(parent) = kf.parent {
                add(parent, &mut local);
            }
        }
        let mut taken = vec![false; self.map.points.len()];
        let mut points = Vec::new();
        for &k in &local {
            for &p in &self.map.keyframes[k].points {
                if !taken[p] && self.map.points[p].visible > 0 {
                    taken[p] = true;
                    points.push(p);
                }
            }
        }
        // Id order: which of two equally good map points wins a keypoint
        // must not depend on how the local map was gathered.
        points.sort_unstable();
        points
    }

    /// For each keypoint, the best map point projecting within `radius`
    /// with a descriptor distance below the threshold (each map point used
    /// once, the closer descriptor wins).
    fn match_by_projection(
        &mut self,
        frame: &Frame,
        local: &[usize],
        pose: &Isometry3<f64>,
        radius: f64,
        count_visible: bool,
    ) -> Vec<Option<usize>> {
        let mut best: Vec<Option<(usize, u32)>> = vec![None; frame.kps.len()];
        let mut near = Vec::new();
        for &p in local {
            let pc = pose * Point3::from(self.map.points[p].position);
            if pc.z < self.params.min_depth_m {
                continue;
            }
            let (u, v) = self.camera.project(&pc.coords);
            let (x0, x1, y0, y1) = frame.bounds;
            if !(x0..x1).contains(&u) || !(y0..y1).contains(&v) {
                continue;
            }
            // Coarse-level keypoints are located less precisely: the window
            // grows with their scale (up to 2x here).
            frame.grid.near(u, v, 2.0 * radius, &mut near);
            if near.is_empty() {
                continue;
            }
            if count_visible {
                self.map.points[p].visible += 1;
            }
            let mut cand: Option<(usize, u32)> = None;
            for &k in &near {
                let (ku, kv) = frame.un[k];
                let r = radius * (self.extractor.scale(frame.kps[k].level) as f64).min(2.0);
                if (ku - u).powi(2) + (kv - v).powi(2) > r * r {
                    continue;
                }
                let d = hamming(&self.map.points[p].descriptor, &frame.descs[k]);
                if d <= MATCH_MAX_DISTANCE && cand.is_none_or(|c| d < c.1) {
                    cand = Some((k, d));
                }
            }
            if let Some((k, d)) = cand {
                if best[k].is_none_or(|b| d < b.1) {
                    best[k] = Some((p, d));
                }
            }
        }
        best.into_iter().map(|b| b.map(|(p, _)| p)).collect()
    }

    fn need_keyframe(&self, inliers: usize, frame: &Frame, matched: &[Option<usize>]) -> bool {
        // ORB-SLAM2 (RGB-D): many close points not yet in the map, or too few
        // tracked against the reference keyframe, or too long since the last.
        let (mut close_tracked, mut close_untracked) = (0, 0);
        for (m, d) in matched.iter().zip(&frame.depth) {
            if d.is_some_and(|d| d < self.params.close_depth_m) {
                match m {
                    Some(_) => close_tracked += 1,
                    None => close_untracked += 1,
                }
            }
        }
        let long = self.keyframe_due();
        let weak = (inliers as f64) < 0.75 * self.reference_inliers as f64
            || (close_tracked < 100 && close_untracked > 70);
        (long || weak) && inliers > 15
    }

    /// The next frame reaches the longest allowed gap between keyframes.
    fn keyframe_due(&self) -> bool {
        self.frames_since_keyframe + 1 >= self.params.max_frames_between_keyframes
    }

    fn insert_keyframe(
        &mut self,
        frame: &Frame,
        pose_cw: &Isometry3<f64>,
        matched: &[Option<usize>],
        inliers: usize,
    ) {
        let id = self.map.keyframes.len();
        let pose_wc = pose_cw.inverse();
        let mut observed = Vec::new();
        let mut measurements = Vec::new();
        let mut spare = Vec::new();
        for (k, m) in matched.iter().enumerate() {
            if let Some(p) = m {
                self.map.points[*p].observers.push(id);
                observed.push(*p);
                measurements.push(self.measure(frame, k));
            } else if let Some(d) = frame.depth[k] {
                let (u, v) = frame.un[k];
                let seen = self.camera.unproject(u, v, d);
                let world = pose_wc * Point3::from(seen);
                let m = self.measure(frame, k);
                self.map.points.push(MapPoint::new(
                    world.coords,
                    id,
                    &m,
                    seen.norm(),
                    frame.colours[k],
                ));
                observed.push(self.map.points.len() - 1);
                measurements.push(m);
            } else {
                spare.push(SpareKeypoint {
                    measurement: self.measure(frame, k),
                    colour: frame.colours[k],
                });
            }
        }
        self.map.keyframes.push(KeyFrame {
            pose_cw: *pose_cw,
            points: observed,
            measurements,
            spare,
            bounds: frame.bounds,
            // Local mapping connects it.
            covisible: Vec::new(),
            parent: None,
            culled: false,
        });
        self.frames_since_keyframe = 0;
        self.reference_inliers = inliers.max(1);
    }

    /// A pose (camera from world) for a lost frame: descriptor matches to
    /// the points of each keyframe (newest first), then 3D-3D RANSAC on the
    /// depth of both sides, or, where too few matched keypoints have depth
    /// (a depth camera blinded by sunlight, glass, a too-near scene), PnP
    /// RANSAC on their pixels.
    fn relocalise(&self, frame: &Frame) -> Option<Isometry3<f64>> {
        const MIN_MATCHES: usize = 20;
        let cam_points: Vec<Option<Vector3<f64>>> = (0..frame.kps.len())
            .map(|k| frame.depth[k].map(|d| self.camera.unproject(frame.un[k].0, frame.un[k].1, d)))
            .collect();
        for (_, kf) in self.map.live_keyframes().rev().take(40) {
            let mut pairs = Vec::new();
            let mut pixels = Vec::new();
            for (k, d) in frame.descs.iter().enumerate() {
                let (mut b1, mut b2, mut bp) = (u32::MAX, u32::MAX, 0);
                for &p in &kf.points {
                    let h = hamming(d, &self.map.points[p].descriptor);
                    if h < b1 {
                        b2 = b1;
                        b1 = h;
                        bp = p;
                    } else if h < b2 {
                        b2 = h;
                    }
                }
                if b1 <= MATCH_MAX_DISTANCE && (b1 as f64) < 0.8 * b2 as f64 {
                    let world = self.map.points[bp].position;
                    match cam_points[k] {
                        Some(c) => pairs.push((world, c)),
                        None => {
                            let m = self.measure(frame, k);
                            pixels.push(PnpMatch {
                                world,
                                u: m.u,
                                v: m.v,
                                info: m.info,
                            });
                        }
                    }
                }
            }
            let pose = if pairs.len() >= MIN_MATCHES {
                ransac_rigid(&pairs, 0.05, 200)
            } else {
                // The keypoints with depth count as pixels too.
                pixels.extend(pairs.iter().map(|(world, c)| {
                    let (u, v) = self.camera.project(c);
                    PnpMatch {
                        world: *world,
                        u,
                        v,
                        info: 1.0,
                    }
                }));
                pnp_ransac(&self.camera, &pixels, 300, MIN_MATCHES).map(|(pose, _)| pose)
            };
            if let Some(pose) = pose.filter(is_finite_pose) {
                return Some(pose);
            }
        }
        None
    }

    /// World-from-camera poses of the keyframes in the map (culled ones
    /// left out).
    pub fn keyframe_poses(&mut self) -> Vec<Isometry3<f64>> {
        self.map()
            .live_keyframes()
            .map(|(_, k)| k.pose_cw.inverse())
            .collect()
    }
}

/// (keypoint, map point) of every matched keypoint.
fn matched_pairs(matched: &[Option<usize>]) -> Vec<(usize, usize)> {
    matched
        .iter()
        .enumerate()
        .filter_map(|(k, m)| m.map(|p| (k, p)))
        .collect()
}

/// Binary mask of non-zero labels grown by `r` pixels (square).
fn dilate(labels: &[u8], width: usize, height: usize, r: usize) -> Vec<bool> {
    let mut rows = vec![false; width * height];
    for y in 0..height {
        let mut last: Option<usize> = None;
        for x in 0..width {
            if labels[y * width + x] != 0 {
                last = Some(x);
            }
            rows[y * width + x] = last.is_some_and(|l| x - l <= r);
        }
        let mut next: Option<usize> = None;
        for x in (0..width).rev() {
            if labels[y * width + x] != 0 {
                next = Some(x);
            }
            rows[y * width + x] |= next.is_some_and(|n| n - x <= r);
        }
    }
    let mut out = vec![false; width * height];
    for x in 0..width {
        let mut last: Option<usize> = None;
        for y in 0..height {
            if rows[y * width + x] {
                last = Some(y);
            }
            out[y * width + x] = last.is_some_and(|l| y - l <= r);
        }
        let mut next: Option<usize> = None;
        for y in (0..height).rev() {
            if rows[y * width + x] {
                next = Some(y);
            }
            out[y * width + x] |= next.is_some_and(|n| n - y <= r);
        }
    }
    out
}

/// Rigid transform mapping `world` to `camera` points (camera from world)
/// by RANSAC over 3-point Kabsch fits; `None` with under 20 inliers.
fn ransac_rigid(
    pairs: &[(Vector3<f64>, Vector3<f64>)],
    threshold: f64,
    iterations: usize,
) -> Option<Isometry3<f64>> {
    let mut rng = SplitMix64::new(0x5EED);
    let mut pick = |n: usize| rng.below(n);
    let mut best: Option<(usize, Vec<usize>)> = None;
    for _ in 0..iterations {
        let s = [pick(pairs.len()), pick(pairs.len()), pick(pairs.len())];
        if s[0] == s[1] || s[1] == s[2] || s[0] == s[2] {
            continue;
        }
        let Some(t) = kabsch(&s.iter().map(|&i| pairs[i]).collect::<Vec<_>>()) else {
            continue;
        };
        let inl: Vec<usize> = (0..pairs.len())
            .filter(|&i| ((t * Point3::from(pairs[i].0)).coords - pairs[i].1).norm() < threshold)
            .collect();
        if best.as_ref().is_none_or(|b| inl.len() > b.0) {
            best = Some((inl.len(), inl));
        }
    }
    let (n, inl) = best?;
    if n < 20 {
        return None;
    }
    kabsch(&inl.iter().map(|&i| pairs[i]).collect::<Vec<_>>())
}

fn kabsch(pairs: &[(Vector3<f64>, Vector3<f64>)]) -> Option<Isometry3<f64>> {
    let n = pairs.len() as f64;
    let ca = pairs.iter().map(|p| p.0).sum::<Vector3<f64>>() / n;
    let cb = pairs.iter().map(|p| p.1).sum::<Vector3<f64>>() / n;
    let mut h = Matrix3::zeros();
    for (a, b) in pairs {
        h += (b - cb) * (a - ca).transpose();
    }
    let svd = h.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    if (u * vt).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = u * d * vt;
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let t = cb - rot * ca;
    Some(Isometry3::from_parts(Translation3::from(t), rot))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kabsch_recovers_a_rigid_motion_and_ransac_ignores_outliers() {
        let truth = Isometry3::from_parts(
            Translation3::new(0.3, -0.1, 0.2),
            UnitQuaternion::from_euler_angles(0.1, 0.2, -0.3),
        );
        let mut pairs: Vec<(Vector3<f64>, Vector3<f64>)> = (0..60)
            .map(|i| {
                let f = i as f64;
                let a = Vector3::new(f.sin(), (0.7 * f).cos(), 1.0 + 0.03 * f);
                (a, (truth * Point3::from(a)).coords)
            })
            .collect();
        for p in pairs.iter_mut().step_by(4) {
            p.1 += Vector3::new(0.5, 0.0, 0.0);
        }
        let t = ransac_rigid(&pairs, 0.01, 200).unwrap();
        assert!((t.translation.vector - truth.translation.vector).norm() < 1e-9);
    }

    /// A camera turning and sliding at a constant rate, rows exposed over
    /// 20 ms: a point seen on the top row is moved to the pixel (and depth)
    /// where the middle row's camera sees it.
    #[test]
    fn rolling_shutter_keypoints_move_to_the_middle_rows_instant() {
        let mut camera = Camera::from_config(&pipeline::config::CameraConfig::default(), 5000.0);
        camera.dist = [0.0; 5];
        camera.readout_s = 0.02;
        let mut sys = System::new(SlamParams::default(), camera);
        // Camera from world at time t: turning 1.5 rad/s about y, sliding 0.3 m/s in x.
        let pose_at = |t: f64| {
            Isometry3::from_parts(
                Translation3::new(0.3 * t, 0.0, 0.0),
                UnitQuaternion::from_euler_angles(0.0, 1.5 * t, 0.0),
            )
        };
        let (dt, t_now) = (1.0 / 30.0, 3.0 / 30.0);
        sys.recent = (0..3)
            .map(|k| (k as f64 * dt, pose_at(k as f64 * dt)))
            .collect();
        let h = 480;
        let world = Vector3::new(0.2, -0.9, 2.0);
        // The top row (y = 0) is exposed readout/2 before the middle row.
        let mid = pose_at(t_now);
        let early = pose_at(t_now - camera.readout_s / 2.0);
        let seen_top = early * Point3::from(world);
        let (u, v) = camera.project(&seen_top.coords);
        assert!(
            v.abs() < 40.0,
            "the test point should sit near the top row: v = {v}"
        );
        let kp = KeyPoint {
            x: u as f32,
            y: 0.0,
            level: 0,
            angle: 0.0,
            score: 0.0,
        };
        let mut un = vec![(u, v)];
        let mut depth = vec![Some(seen_top.z)];
        let motion = sys.shutter_motion(None).expect("a moving camera");
        sys.undo_rolling_shutter(&[kp], &mut un, &mut depth, h, motion);
        let seen_mid = mid * Point3::from(world);
        let (um, vm) = camera.project(&seen_mid.coords);
        let before = ((u - um).powi(2) + (v - vm).powi(2)).sqrt();
        let after = ((un[0].0 - um).powi(2) + (un[0].1 - vm).powi(2)).sqrt();
        assert!(before > 5.0, "the shutter should matter here: {before} px");
        // First order in the motion: what is left is the turn of the slide
        // over the interval (about 0.1 px here).
        assert!(
            after < 0.25,
            "{after} px off after the correction ({before} before)"
        );
        assert!((depth[0].unwrap() - seen_mid.z).abs() < 1e-3);
        // A global shutter needs no motion, a stale one is not used.
        sys.camera.readout_s = 0.0;
        assert!(sys.shutter_motion(None).is_none());
        sys.camera.readout_s = 0.02;
        assert!(sys.shutter_motion(Some((t_now + 1.0, mid))).is_none());
    }

    #[test]
    fn dilation_grows_by_the_radius() {
        let (w, h) = (9, 7);
        let mut l = vec![0u8; w * h];
        l[3 * w + 4] = 1;
        let d = dilate(&l, w, h, 2);
        assert_eq!(d.iter().filter(|&&b| b).count(), 25);
        assert!(d[w + 2] && !d[w + 1]);
    }
}
