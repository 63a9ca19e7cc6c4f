//! The SLAM system's facade: one call per RGB-D frame. It owns the map and
//! wires the modules together, in ORB-SLAM2's order: features
//! ([`crate::frame`]), initialisation ([`crate::initialization`]) or
//! tracking ([`crate::tracking`]), the keyframe decision, and local mapping
//! ([`crate::local_mapping`]) on its own thread while the next frame's
//! features are extracted. Maps are saved and loaded with
//! [`crate::io::map_file`]; a loaded map is tracked in, in its own world
//! frame, after relocalisation. Loop closing ([`crate::loop_closing`])
//! runs on its own thread behind local mapping when it is on.

use std::sync::Arc;

use nalgebra::Isometry3;

use crate::camera::{Bounds, Camera};
use crate::features::mask::DynamicMask;
use crate::features::orb::OrbExtractor;
use crate::frame::{Detected, Frame, FrameContext, RgbdInput};
use crate::initialization::{
    initialise_rgbd, points_to_start, start_rgbd_at, MonocularInitializer,
};
use crate::io::map_file::{MapFile, MapFileError};
use crate::local_mapping::checkpoint::{CheckpointPolicy, Checkpointer};
use crate::local_mapping::snapshot::{MapSnapshot, SnapshotRequest, SnapshotSlot};
use crate::local_mapping::{map_keyframe, LocalMapper};
use crate::loop_closing::thread::LoopClosing;
use crate::loop_closing::LoopClosure;
use crate::map::{Map, MappingCounts, MappingReport};
use crate::params::SlamParams;
use crate::place_recognition::Vocabulary;
use crate::tracking::motion_check::{MotionCheck, MotionCheckParams, MovingRegion};
use crate::tracking::{Tracked, Tracking, TrackingState};

mod keyframes;
mod mapping;
mod per_frame;

/// Undistorted keypoint pixels and depths before the rolling-shutter
/// correction.
type RawKeypoints = (Vec<(f64, f64)>, Vec<Option<f64>>);

/// What a frame cost and produced.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FrameCounts {
    /// Keypoints extracted.
    pub features: u32,
    /// Corners dropped because they fell inside a dynamic mask.
    pub features_masked: u32,
    /// Features dropped after tracking because they move unlike the camera
    /// (RGB-D motion check, [`crate::tracking::motion_check`]).
    pub features_moving: u32,
    /// Keypoints matched to map points and kept by the pose optimisation.
    pub inliers: u32,
    /// Live map points and keyframes after this frame.
    pub map_points: u32,
    /// See `map_points`.
    pub keyframes: u32,
    /// Feature extraction, and local mapping of the keyframe whose mapping
    /// finished during this frame (microseconds).
    pub extract_us: u32,
    /// Local mapping (and loop closing) time of a keyframe finished during this frame (microseconds).
    pub mapping_us: u32,
    /// The frame was tracked by following the last frame's points with
    /// optical flow, not by ORB extraction (`SlamParams::flow_frames`).
    pub tracked_by_flow: bool,
}

/// Whether the SLAM keeps up with its frames, which decides if a frame may
/// be tracked by optical flow (`SlamParams::flow_frames`). Following points
/// saves about half a frame's time but tracks a little less accurately
/// under load, so it is for when the time is short.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Pace {
    /// Behind the camera (real time dropping frames), or a batch run that
    /// goes as fast as it can: frames may be followed by flow.
    #[default]
    Behind,
    /// Keeping up (lockstep, or real time losing few frames): every frame
    /// is extracted in full, and no flow pyramid is built.
    KeepingUp,
}

/// When a frame that the keyframe rule picks becomes a keyframe.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum KeyframeTiming {
    /// Now, with the masks it was tracked with (lockstep: a keyframe's
    /// masks are the segmenter's already).
    #[default]
    Now,
    /// When [`System::complete_keyframe`] brings its better masks (real
    /// time: the frame was tracked with propagated masks while the segmenter
    /// works on it); later frames are tracked meanwhile.
    AfterBetterMasks,
    /// Not this frame (no better masks will come for it): the keyframe
    /// waits for a frame that gets them, and the hint asks for one.
    NotThisFrame,
}

/// Tracking has weakened when two tracked frames in a row have fewer than
/// this share of the inliers of the newest keyframe (or of the one waiting
/// for its segmenter masks): the map they track against is getting stale,
/// and a keyframe then does not wait for better masks (a waiting one goes
/// in with the masks it was tracked with; the frame's own goes in now). In
/// real time on a busy machine the niced segmenter may take a second to
/// answer: measured at 30 fps with two busy processes, a keyframe that
/// waited 25 frames saw the inliers fall 297 -> 45 and the camera was lost 3
/// frames after it went in. One weak frame alone is not enough: a sudden
/// fall is as often a wrong pose (at 60 fps under load a frame 0.1 s after
/// the last, 74 inliers after 598, 0.6 m off), which must not seed points.
const WEAKENED: f64 = 0.5;

/// A keyframe waiting for its better masks.
struct PendingKeyframe {
    frame: Frame,
    pose_cw: Isometry3<f64>,
    matched: Vec<Option<usize>>,
    inliers: usize,
    /// Its timestamp, and the keyframe rule's frame count when it was
    /// tracked.
    timestamp: f64,
    frames_counted: u32,
}

/// What one call of `track_rgbd` reports.
#[derive(Debug, Clone)]
pub struct FrameResult {
    /// World from camera.
    pub pose_wc: Isometry3<f64>,
    /// How the frame was tracked.
    pub state: TrackingState,
    /// The frame became a keyframe.
    pub keyframe_inserted: bool,
    /// The frame will become a keyframe when its better masks come
    /// ([`KeyframeTiming::AfterBetterMasks`]).
    pub keyframe_pending: bool,
    /// The keyframe that was pending went in with this frame's call (after
    /// this frame was tracked), with the masks it was tracked with:
    /// tracking weakened ([`WEAKENED`]) or was lost while it waited.
    pub waiting_keyframe_inserted: bool,
    /// The next frame should become a keyframe (a hint for whoever decides
    /// which frames get fresh masks).
    pub next_needs_keyframe: bool,
    /// What this frame counted.
    pub counts: FrameCounts,
    /// Feature extraction time (ms).
    pub extract_ms: f64,
    /// Tracking time (ms).
    pub track_ms: f64,
    /// The motion check's part of `track_ms` (0 when off).
    pub motion_ms: f64,
}

/// A map of at most this many keyframes is young: lost, it has too few
/// views to relocalise at, and a camera that keeps moving leaves them
/// behind for good. ORB-SLAM2 resets such a map (Tracking::Track: "Track
/// lost soon after initialisation, reseting...").
pub const YOUNG_MAP_KEYFRAMES: usize = 5;

/// RGB-D: a young map lost for this long (camera time) and at least
/// [`RESTART_AFTER_LOST_FRAMES`] frames (relocalisation had its chance: on
/// the shared sequence with frames left out, young maps that relocalise do
/// it within 0.3 s) is started again from the current frame, placed at the
/// last tracked pose, so that the world frame goes on as nearly as can be
/// told. Seen in real time at 60 fps with 2 busy processes (people, mixed
/// behaviours): a map of 2 keyframes lost in a fast turn 4 frames after its
/// start, then every one of 148 frames lost (13-25 bag-of-words matches at
/// its keyframe); `slam-bench --frames-of` on the same frames does the
/// same. With the restart those frames are tracked.
const RESTART_AFTER_LOST_S: f64 = 0.5;
const RESTART_AFTER_LOST_FRAMES: u32 = 3;

/// The SLAM system: tracking on the caller's thread, local mapping and loop closing on their own; frames in, poses and a map out.
pub struct System {
    /// The settings it runs with.
    pub params: SlamParams,
    camera: Camera,
    extractor: OrbExtractor,
    /// Owned here while tracking; lent to `mapper` after a keyframe until
    /// the next frame is tracked (see `mapping`).
    map: Map,
    mapper: Option<LocalMapper>,
    mapping: Mapping,
    tracking: Tracking,
    /// ORB-SLAM2's localization mode: track against the map, add nothing.
    localize_only: bool,
    /// Writes the map every N keyframes off the frame path (None: never).
    checkpointer: Option<Checkpointer>,
    /// Map snapshots for the outside: where they are left, at most one per
    /// period, and when the last was asked for (None: none asked).
    snapshots: Option<(
        SnapshotSlot,
        std::time::Duration,
        Option<std::time::Instant>,
    )>,
    /// Keyframes inserted since the map was made or loaded.
    keyframes_inserted: usize,
    /// The map was started by this system (not loaded: a loaded map is
    /// never restarted).
    map_started_here: bool,
    /// Frames lost in a row, and the timestamp of the first of them.
    lost_in_a_row: (u32, f64),
    /// Times a young map was given up and started again (see
    /// [`YOUNG_MAP_KEYFRAMES`]).
    map_restarts: usize,
    /// Undistorted image extent, computed once per frame size.
    bounds: Option<((usize, usize), Bounds)>,
    /// Local mapping time of the keyframe whose mapping finished while this
    /// frame was processed (0 if none).
    mapping_ms: f64,
    /// What local mapping did over the run so far.
    mapped: MappingCounts,
    /// A keyframe waiting for its better masks.
    pending_keyframe: Option<PendingKeyframe>,
    /// The last frame was weak ([`WEAKENED`]).
    weak_before: bool,
    /// Bag-of-words vocabulary of the keyframe database (relocalisation).
    vocabulary: Arc<Vocabulary>,
    /// Loop closing when mapping is inline (the mapping thread has its own).
    inline_loops: LoopClosing,
    /// A monocular map's start: the reference view and its attempts.
    monocular_start: MonocularInitializer,
    /// The newest keyframe and its pose when its local mapping started
    /// (tracking follows the keyframe if mapping moves it).
    mapped_keyframe: Option<(usize, Isometry3<f64>)>,
    /// Every tracked frame: timestamp, reference keyframe, camera from
    /// reference keyframe (see [`System::trajectory`]).
    tracked_frames: Vec<(f64, usize, Isometry3<f64>)>,
    /// The loops closed so far, and the time loop detection took.
    loops: Vec<LoopClosure>,
    /// Every report of the loop closer.
    loop_reports: Vec<crate::loop_closing::LoopReport>,
    /// Features that move unlike the camera (RGB-D, `params.motion_check`).
    motion: MotionCheck,
    /// The last frame's moving regions (undistorted pixel boxes).
    moving_regions: Vec<MovingRegion>,
    /// The last frame's result asked for a keyframe next
    /// (`next_needs_keyframe`): the next frame is extracted in full.
    keyframe_hinted: bool,
    /// The pace of the frame being tracked.
    pace: Pace,
}

/// What the keyframe rule made of a tracked frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Decision {
    None,
    Inserted,
    Pending,
    Wanted,
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
    /// A system with an empty map: the first frame with depth starts it
    /// and defines the world frame.
    pub fn new(params: SlamParams, camera: Camera) -> Self {
        let vocabulary = Vocabulary::embedded();
        let mapper = params
            .mapping_thread
            .then(|| LocalMapper::spawn(camera, params, vocabulary.clone()))
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
            tracking: Tracking::new(camera, params, vocabulary.clone()),
            inline_loops: LoopClosing::new(&params, camera, false),
            monocular_start: MonocularInitializer::default(),
            mapped_keyframe: None,
            vocabulary,
            tracked_frames: Vec::new(),
            loops: Vec::new(),
            loop_reports: Vec::new(),
            localize_only: false,
            checkpointer: None,
            snapshots: None,
            keyframes_inserted: 0,
            map_started_here: true,
            lost_in_a_row: (0, 0.0),
            map_restarts: 0,
            bounds: None,
            mapping_ms: 0.0,
            mapped: MappingCounts::default(),
            pending_keyframe: None,
            weak_before: false,
            motion: MotionCheck::new(MotionCheckParams::default()),
            moving_regions: Vec::new(),
            keyframe_hinted: false,
            pace: Pace::default(),
        }
    }

    /// A system that goes on in a saved map, in its world frame: the first
    /// frames relocalise against its keyframes. The file's camera and
    /// pyramid must be this system's (see [`MapFile::check_compatible`]).
    pub fn with_map(params: SlamParams, camera: Camera, file: MapFile) -> Self {
        let mut system = Self::new(params, camera);
        system.map = file.map;
        system.map_started_here = false;
        let indexed = system.map.reindex(&system.vocabulary);
        if indexed > 0 {
            tracing::info!("{indexed} keyframes of the loaded map put in the keyframe database");
        }
        system.tracking.start_lost();
        system
    }

    /// Goes on from the last frames an earlier life of this system tracked
    /// in this map (a restarted process): `poses_wc` are their timestamps
    /// and world-from-camera poses, oldest first. The next frame is tracked
    /// from the motion model (relocalisation only if that fails), unless it
    /// comes more than half a second after them.
    pub fn resume_motion(&mut self, poses_wc: &[(f64, Isometry3<f64>)]) {
        let recent: Vec<(f64, Isometry3<f64>)> =
            poses_wc.iter().map(|&(t, p)| (t, p.inverse())).collect();
        self.tracking.resume_motion(&recent, &self.map);
    }

    /// ORB-SLAM2's localization mode: frames are tracked (and relocalised)
    /// against the map, and no keyframe or point is added.
    pub fn set_localize_only(&mut self, on: bool) {
        self.localize_only = on;
    }

    /// Writes the map atomically to `policy.path` every
    /// `policy.every_keyframes` inserted keyframes, on a writer thread from
    /// a copy taken by local mapping (off the frame path).
    pub fn set_checkpoint(&mut self, policy: Option<CheckpointPolicy>) {
        self.checkpointer = policy.and_then(|p| {
            Checkpointer::spawn(p, self.camera, self.params)
                .map_err(|e| tracing::warn!("checkpoint writer not started: {e}"))
                .ok()
        });
    }

    /// Map snapshots ([`MapSnapshot`]) after keyframes, at most one per
    /// `period` and after every closed loop, taken off the frame path;
    /// [`System::take_map_snapshot`] hands out the newest.
    pub fn enable_map_snapshots(&mut self, period: std::time::Duration) {
        self.snapshots = Some((SnapshotSlot::default(), period, None));
    }

    /// The newest map snapshot not handed out yet.
    pub fn take_map_snapshot(&mut self) -> Option<MapSnapshot> {
        self.snapshots.as_ref()?.0.take()
    }

    /// The map as a file's contents (once local mapping has given it back
    /// and loop closing has finished).
    pub fn map_file(&mut self) -> MapFile {
        self.finish_loops();
        MapFile::new(self.camera, &self.params, self.map.clone())
    }

    /// Writes the map to `path` now (atomically: a temporary file, synced,
    /// renamed), waiting for local mapping and the checkpoint writer first
    /// (which stops: this is the end of the run's map).
    pub fn save_map(&mut self, path: &std::path::Path) -> Result<(), MapFileError> {
        self.checkpointer = None;
        self.map_file().write(path)
    }

    /// Tracks one colour frame of a monocular system (see
    /// [`System::track_rgbd`]; there is no depth): the map starts once two
    /// views reconstruct, frames before that come back NOT_INITIALISED.
    pub fn track_monocular(
        &mut self,
        rgb: &[u8],
        mask: Option<&[u8]>,
        width: usize,
        height: usize,
        timestamp: f64,
    ) -> FrameResult {
        self.track_rgbd(rgb, &[], mask, width, height, timestamp)
    }

    /// Tracks one RGB-D frame taken at `timestamp` (seconds). `rgb` is
    /// RGB8, `depth` u16 in `camera.depth_scale` units per metre (0: no
    /// depth; empty, or ignored, for a monocular system:
    /// `SlamParams::sensor`), `mask` an optional label image (non-zero:
    /// dynamic object).
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
        self.track(&RgbdInput {
            rgb,
            depth,
            mask,
            width,
            height,
            timestamp,
        })
    }

    /// [`System::track_rgbd`] on a bundled input: features, then the map
    /// back from local mapping, then initialisation or tracking, the
    /// keyframe decision, and local mapping of a new keyframe.
    pub fn track(&mut self, input: &RgbdInput) -> FrameResult {
        self.track_with(input, KeyframeTiming::Now)
    }

    /// [`System::track`], with the keyframe of this frame (if the rule
    /// picks it) inserted as `timing` says. While a keyframe is pending no
    /// other frame becomes one.
    pub fn track_with(&mut self, input: &RgbdInput, timing: KeyframeTiming) -> FrameResult {
        self.track_paced(input, timing, Pace::Behind)
    }

    /// [`System::track_with`] at a `pace`: only a frame [`Pace::Behind`]
    /// may be tracked by optical flow.
    pub fn track_paced(
        &mut self,
        input: &RgbdInput,
        timing: KeyframeTiming,
        pace: Pace,
    ) -> FrameResult {
        self.pace = pace;
        let t0 = std::time::Instant::now();
        self.mapping_ms = 0.0;
        if !input.is_well_formed() {
            return self.skipped();
        }
        if self
            .tracking
            .last_timestamp()
            .is_some_and(|t| !(0.0..=0.5).contains(&(input.timestamp - t)))
            && self.tracking.is_resumed()
        {
            // The resumed motion is stale: find the frame in the map instead.
            self.tracking.start_lost();
        }
        let follow = self.may_follow(input.timestamp);
        let (mut frame, mut raw, mut followed) = self.features(input, follow);
        let mut extract_ms = to_ms(t0);
        let t1 = std::time::Instant::now();
        // The map comes back from local mapping (a wait, if it is not done,
        // counts as tracking time).
        self.settle();
        let initialising = self.map.keyframes.is_empty();
        let mut tracked = if initialising {
            self.initialise(&frame, input.timestamp)
        } else {
            self.track_in_map(
                input,
                (&mut frame, &mut raw),
                &mut followed,
                &mut extract_ms,
            )
        };
        let by_flow = followed.is_some();
        let restarted =
            !initialising && self.restart_young_map(&frame, &mut tracked, input.timestamp);
        self.refine_for_shutter(&mut frame, raw.as_ref(), &mut tracked, input.timestamp);
        // A frame tracked by flow has only the points of the last frame,
        // which was checked.
        let checked = tracked.state.is_in_map() && !initialising && !restarted && !by_flow;
        let (moving, motion_ms) = self.drop_moving(&mut frame, &mut tracked, (input, checked));
        let weakened = self.weakened(&tracked);
        let timing = match (by_flow, weakened) {
            // Its keypoints are the last frame's: should the rule pick it,
            // the next frame (extracted in full) becomes the keyframe.
            (true, _) => KeyframeTiming::NotThisFrame,
            (false, true) => KeyframeTiming::Now,
            (false, false) => timing,
        };
        // A successful initialisation (or restart) made the first keyframe.
        let started = (initialising || restarted) && tracked.state == TrackingState::Ok;
        let decision = self.decide_keyframe(&tracked, &frame, input.timestamp, started, timing);
        let keyframe_inserted = decision == Decision::Inserted;
        if tracked.state.is_in_map() {
            self.tracking
                .remember_flow(&frame, &tracked.matched, by_flow);
        }
        if matches!(decision, Decision::Inserted | Decision::Pending) {
            // A new reference: weak frames count against it afresh.
            self.weak_before = false;
        }
        self.record_pose(&tracked, input.timestamp);
        let mut counts = FrameCounts {
            features: frame.kps.len() as u32,
            features_masked: (frame.masked - moving) as u32,
            features_moving: moving as u32,
            tracked_by_flow: by_flow,
            extract_us: (extract_ms * 1e3) as u32,
            inliers: tracked.inliers as u32,
            map_points: self.map.live_point_count() as u32,
            keyframes: self.map.live_keyframes().count() as u32,
            ..Default::default()
        };
        if keyframe_inserted {
            self.keyframe_inserted(started);
        }
        counts.mapping_us = (self.mapping_ms * 1e3) as u32;
        // The keyframe waiting for its masks goes in without them once
        // tracking weakened or was lost (after this frame's own work with
        // the map: inserting hands the map to local mapping).
        let waiting_keyframe_inserted = self.pending_keyframe.is_some()
            && (weakened || !tracked.state.is_in_map())
            && self.complete_keyframe(None);
        let keyframe_pending = decision == Decision::Pending;
        let (state, pose_cw, inliers) = (tracked.state, tracked.pose_cw, tracked.inliers);
        if keyframe_pending {
            self.pending_keyframe = Some(PendingKeyframe {
                frame,
                pose_cw,
                matched: tracked.matched,
                inliers,
                timestamp: input.timestamp,
                frames_counted: self.tracking.frames_since_keyframe(),
            });
        }
        let next_needs_keyframe = !keyframe_inserted
            && self.pending_keyframe.is_none()
            && self.hint_keyframe(decision, inliers);
        self.keyframe_hinted = next_needs_keyframe;
        let pose_for_output = self.tracking.last_pose().unwrap_or(pose_cw);
        FrameResult {
            pose_wc: pose_for_output.inverse(),
            state,
            keyframe_inserted,
            keyframe_pending,
            waiting_keyframe_inserted,
            next_needs_keyframe,
            counts,
            extract_ms,
            track_ms: to_ms(t1),
            motion_ms,
        }
    }

    /// The map's start (not in localization mode: it adds nothing, so an
    /// empty map stays empty). RGB-D: the first keyframe from `frame`.
    /// Monocular: two keyframes, once `frame` and an earlier reference
    /// view reconstruct; the reference's frame joins the trajectory at the
    /// world's origin.
    fn initialise(&mut self, frame: &Frame, timestamp: f64) -> Tracked {
        let not_yet = Tracked {
            state: TrackingState::NotInitialised,
            pose_cw: Isometry3::identity(),
            inliers: 0,
            matched: Vec::new(),
        };
        if self.localize_only {
            return not_yet;
        }
        if self.params.is_monocular() {
            let Some(start) = self.monocular_start.try_start(
                &mut self.tracking,
                &mut self.map,
                frame,
                timestamp,
                &self.camera,
            ) else {
                return not_yet;
            };
            self.tracked_frames
                .push((start.reference_timestamp, 0, Isometry3::identity()));
            // The reference keyframe (the second is counted as any).
            self.keyframes_inserted += 1;
            return Tracked {
                state: TrackingState::Ok,
                pose_cw: start.pose_cw,
                inliers: start.inliers,
                matched: start.matched,
            };
        }
        if !initialise_rgbd(&mut self.tracking, &mut self.map, frame) {
            return not_yet;
        }
        Tracked {
            state: TrackingState::Ok,
            pose_cw: Isometry3::identity(),
            inliers: frame.kps.len(),
            matched: Vec::new(),
        }
    }

    fn skipped(&self) -> FrameResult {
        FrameResult {
            pose_wc: self
                .tracking
                .last_pose()
                .unwrap_or_else(Isometry3::identity)
                .inverse(),
            state: TrackingState::Skipped,
            keyframe_inserted: false,
            keyframe_pending: false,
            waiting_keyframe_inserted: false,
            next_needs_keyframe: false,
            counts: FrameCounts::default(),
            extract_ms: 0.0,
            track_ms: 0.0,
            motion_ms: 0.0,
        }
    }

    /// The trajectory of the tracked frames as the map stands now
    /// (ORB-SLAM2's SaveTrajectoryTUM): each frame's pose relative to its
    /// reference keyframe, composed with that keyframe's current pose, so
    /// that a loop correction moves the frames before it too. Without a
    /// correction (and with local BA off) it is the poses tracking gave.
    pub fn trajectory(&mut self) -> crate::io::trajectory::Trajectory {
        self.finish_loops();
        let mut out = crate::io::trajectory::Trajectory {
            stamps: Vec::with_capacity(self.tracked_frames.len()),
            poses: Vec::with_capacity(self.tracked_frames.len()),
        };
        for &(t, reference, relative) in &self.tracked_frames {
            let Some(kf) = self.map.keyframes.get(reference) else {
                continue;
            };
            out.stamps.push(t);
            out.poses.push((relative * kf.pose_cw).inverse());
        }
        out
    }

    /// The timestamp of the frame that became keyframe `id` (None for a
    /// keyframe of a loaded map).
    pub fn keyframe_timestamp(&self, id: usize) -> Option<f64> {
        let i = self.tracked_frames.partition_point(|f| f.1 < id);
        self.tracked_frames
            .get(i)
            .filter(|f| f.1 == id)
            .map(|f| f.0)
    }

    /// The loops closed so far.
    pub fn loops(&self) -> &[LoopClosure] {
        &self.loops
    }

    /// Per loop closed: the time (ms) its correction and the global bundle
    /// adjustment after it took (on the loop-closing thread when mapping
    /// has a thread).
    pub fn loop_correction_ms(&self) -> Vec<(f64, f64)> {
        self.loop_reports
            .iter()
            .filter(|r| r.closed.is_some())
            .map(|r| (r.correct_ms, r.global_ba_ms))
            .collect()
    }

    /// Per mapped keyframe: the time (ms) spent deciding whether it closes
    /// a loop (candidates, and their verification wherever it ran).
    pub fn loop_detection_ms(&self) -> Vec<f64> {
        let mut per_keyframe: std::collections::BTreeMap<usize, f64> = Default::default();
        for r in &self.loop_reports {
            *per_keyframe.entry(r.keyframe).or_default() += r.detect_ms + r.verify_ms;
        }
        per_keyframe.into_values().collect()
    }

    /// The keyframe the last relocalisation found the camera at (by bag
    /// of words, among all keyframes of the map).
    pub fn last_relocalisation_keyframe(&self) -> Option<usize> {
        self.tracking.relocalised_at
    }

    /// Keyframes this system inserted (a loaded map's own not counted).
    pub fn keyframes_inserted(&self) -> usize {
        self.keyframes_inserted
    }

    /// Times a young map was lost and started again
    /// ([`YOUNG_MAP_KEYFRAMES`]).
    pub fn map_restarts(&self) -> usize {
        self.map_restarts
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

    /// World-from-camera poses of the keyframes in the map (culled ones
    /// left out).
    pub fn keyframe_poses(&mut self) -> Vec<Isometry3<f64>> {
        self.map()
            .live_keyframes()
            .map(|(_, k)| k.pose_cw.inverse())
            .collect()
    }
}
