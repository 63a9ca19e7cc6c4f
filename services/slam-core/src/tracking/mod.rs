//! Tracking as ORB-SLAM2 does it for RGB-D: the constant-velocity motion
//! model predicts the pose, map points of the local map are matched by
//! projection and the pose optimised (motion only, robust); if that fails
//! the last pose is tried with a wider search. A lost frame triggers
//! relocalisation ([`relocalisation`]). Keyframes are decided as ORB-SLAM2
//! decides them (tracked points against the reference keyframe, frames
//! since the last keyframe) and create new map points from the depth of the
//! keypoints no map point explains. A rolling-shutter camera's keypoints
//! are moved to the middle row's instant ([`rolling_shutter`]).

mod flow;
mod local_map;
pub mod motion_check;
mod relocalisation;
pub(crate) mod rolling_shutter;
pub mod small_image;

use std::sync::Arc;

use nalgebra::{Isometry3, Point3};

use crate::camera::Camera;
use crate::frame::Frame;
use crate::map::{KeyFrame, Map, MapPoint, SpareKeypoint};
use crate::matcher::{match_by_projection, matched_pairs, ByCell, ProjectionSearch};
use crate::optimizer::pose::{is_finite_pose, optimize_pose, renormalized, Observation};
use crate::params::SlamParams;
use crate::place_recognition::Vocabulary;

/// Tracked frames the rolling-shutter correction estimates the motion over.
pub const MOTION_HISTORY: usize = 3;

/// Below this the images' turn and the motion model's agree, and tracking
/// starts from the motion model's prediction (which has the translation and
/// is smoother). The two differ by 0.46 degrees at the median on every frame
/// of fr1_rpy, 0.92 on every second (90th percentile 1.1 / 3.1); with every
/// difference taken (0 degrees, on every frame too) slam-bench on the
/// synthesised people sequences came out worse (docs/measurements.md, "Turn
/// from the images").
const TURN_DISAGREEMENT_DEG: f64 = 1.0;

/// Frames were left out since the last tracked one when the time since it
/// is more than this many of the shortest interval seen (fr1's intervals
/// jitter between 27 and 40 ms: every frame never reaches 1.5 of 27). On
/// every frame the turn is not used: a large unmasked mover pulls it.
const GAP: f64 = 1.5;

/// Whether a live keyframe of `map` older than the `recent` newest was
/// taken within `metres` and `degrees` of `pose_cw` (it sees what a new
/// keyframe there would: the camera came back). The recent ones do not
/// count: on the way out the periodic keyframes give the baselines that
/// triangulation and the local map need (with them counted, fr1_rpy kept
/// 19 keyframes and triangulated 8 points instead of 35 and 60-110); a
/// camera that stands still is kept bounded by keyframe culling.
fn has_old_keyframe_at(
    map: &Map,
    pose_cw: &Isometry3<f64>,
    recent: usize,
    metres: f64,
    degrees: f64,
) -> bool {
    let centre = pose_cw.inverse().translation.vector;
    let old = map.keyframes.len().saturating_sub(recent);
    map.keyframes[..old].iter().any(|k| {
        !k.culled
            && (k.centre() - centre).norm() < metres
            && k.pose_cw.rotation.angle_to(&pose_cw.rotation).to_degrees() < degrees
    })
}

/// How a frame was tracked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrackingState {
    /// No map yet (the first frame lacked depth).
    NotInitialised,
    /// Tracked from the motion model or the last pose.
    Ok,
    /// Found again after being lost (relocalisation), or for the first
    /// time in a loaded map.
    Relocalised,
    /// Not tracked: relocalisation is tried on the next frames.
    Lost,
    /// Not tracked: malformed input (buffers that do not match the size).
    Skipped,
    /// Monocular: the camera turned away from the map on the spot; the
    /// frame's turn since the last one comes from the images and its
    /// position is the last tracked one ([`MAX_TURNING_S`]).
    Turning,
}

impl TrackingState {
    /// The frame has a pose in the map.
    pub fn is_tracked(self) -> bool {
        matches!(self, Self::Ok | Self::Relocalised | Self::Turning)
    }

    /// The frame was matched to the map's points (its pose is from them).
    pub fn is_in_map(self) -> bool {
        matches!(self, Self::Ok | Self::Relocalised)
    }
}

/// Monocular: frames are tracked by their turn alone
/// ([`TrackingState::Turning`]) for at most this much camera time after the
/// last frame in the map.
pub const MAX_TURNING_S: f64 = 1.0;
/// ... and while the position held is off by less than this angle of the
/// scene's depth at the speed the camera had.
pub const MAX_TURNING_PARALLAX_DEG: f64 = 4.0;

/// A frame's pose, its inliers and, per keypoint, the map point it was
/// matched to (inliers only).
pub(crate) struct Tracked {
    pub state: TrackingState,
    /// Camera from world.
    pub pose_cw: Isometry3<f64>,
    pub inliers: usize,
    pub matched: Vec<Option<usize>>,
}

/// Where the frames [`TrackingState::Turning`] turn from.
#[derive(Clone, Copy)]
struct Turn {
    /// Timestamp of the last frame in the map.
    since: f64,
    /// The speed the camera had over the scene's median depth (radians of
    /// parallax per second).
    parallax_rate: f64,
}

/// The tracking thread's state: the motion model, the reference keyframe's
/// strength and what the last frame matched.
pub struct Tracking {
    pub(crate) camera: Camera,
    pub(crate) params: SlamParams,
    /// Turns a lost frame into a bag of words for the keyframe database.
    pub(crate) vocabulary: Arc<Vocabulary>,
    /// Camera from world of the last tracked frame, and the motion since the one before.
    last_pose: Option<Isometry3<f64>>,
    /// The motion between the last two tracked frames, and the seconds
    /// between them.
    velocity: Option<(Isometry3<f64>, f64)>,
    /// Timestamp and pose (camera from world) of the last tracked frames,
    /// oldest first, at most `MOTION_HISTORY` (cleared when lost): the
    /// rolling-shutter correction's motion estimate.
    pub(crate) recent: Vec<(f64, Isometry3<f64>)>,
    /// Map points the last tracked frame matched (seeds the local map).
    last_matched: Vec<usize>,
    frames_since_keyframe: u32,
    /// Timestamp of the last keyframe's frame (None: not known, e.g. the
    /// map's first keyframe or a resumed map).
    keyframe_timestamp: Option<f64>,
    /// Inliers of the frame that made the last keyframe.
    reference_inliers: usize,
    pub(crate) lost: bool,
    /// Tracked frames since the last relocalisation (None: none since the
    /// start): keyframes wait until the motion model is back.
    since_relocalisation: Option<usize>,
    /// The motion model came from `resume_motion` and no frame has been
    /// tracked with it yet.
    resumed: bool,
    /// The keyframe the last relocalisation found the camera at.
    pub(crate) relocalised_at: Option<usize>,
    /// The last tracked frame's small image (the turn since it).
    last_image: Option<Arc<small_image::SmallImage>>,
    /// The shortest time between two tracked frames so far: the camera's
    /// frame period, where none was left out.
    shortest_interval: Option<f64>,
    /// The last tracked frame's inliers and pyramid, where frames between
    /// keyframes are tracked by optical flow ([`flow`]).
    flow: Option<flow::FlowSource>,
    /// Which way the rows are read out (kept through a reset: the camera's).
    readout: rolling_shutter::ReadoutDirection,
    /// While frames are [`TrackingState::Turning`]: where they turn from.
    turning_since: Option<Turn>,
}

impl Tracking {
    /// Tracking with `camera` and `params`; lost frames are looked up with `vocabulary`.
    pub fn new(camera: Camera, params: SlamParams, vocabulary: Arc<Vocabulary>) -> Self {
        Self {
            camera,
            params,
            vocabulary,
            last_pose: None,
            velocity: None,
            recent: Vec::new(),
            last_matched: Vec::new(),
            frames_since_keyframe: 0,
            keyframe_timestamp: None,
            reference_inliers: 0,
            lost: false,
            since_relocalisation: None,
            resumed: false,
            relocalised_at: None,
            last_image: None,
            shortest_interval: None,
            flow: None,
            readout: rolling_shutter::ReadoutDirection::default(),
            turning_since: None,
        }
    }

    /// Nothing tracked yet: the next frame initialises (or, in a loaded
    /// map, relocalises).
    pub fn reset(&mut self) {
        let readout = self.readout;
        *self = Self::new(self.camera, self.params, self.vocabulary.clone());
        self.readout = readout;
    }

    /// Starts lost in an existing map: the next frames relocalise.
    pub fn start_lost(&mut self) {
        self.reset();
        self.lost = true;
    }

    /// Goes on from the last tracked frames of an earlier life of this
    /// system (a restarted process): `recent` are their (timestamp, camera
    /// from world), oldest first. The motion model and the rolling-shutter
    /// correction come back at once instead of after relocalisation.
    pub fn resume_motion(&mut self, recent: &[(f64, Isometry3<f64>)], map: &Map) {
        let recent = &recent[recent.len().saturating_sub(MOTION_HISTORY)..];
        let Some(&(_, last)) = recent.last() else {
            return;
        };
        self.reset();
        self.reference_inliers = reference_points(map);
        self.last_pose = Some(last);
        if let [.., (t0, before), (t1, _)] = recent {
            self.velocity = Some((renormalized(&(last * before.inverse())), t1 - t0));
        }
        self.recent = recent.to_vec();
        self.resumed = true;
    }

    /// The motion model was resumed and not yet used.
    pub fn is_resumed(&self) -> bool {
        self.resumed
    }

    /// The timestamp of the last tracked frame.
    pub fn last_timestamp(&self) -> Option<f64> {
        self.recent.last().map(|r| r.0)
    }

    /// Camera from world of the last tracked frame.
    pub fn last_pose(&self) -> Option<Isometry3<f64>> {
        self.last_pose
    }

    /// Local bundle adjustment or a loop correction moved the newest
    /// keyframe from `before` to `after` (camera from world): the recent
    /// frames, tracked relative to it, move with it (for the keyframe's own
    /// frame, the last one tracked, that is its adjusted pose).
    pub fn follow_keyframe(&mut self, before: &Isometry3<f64>, after: &Isometry3<f64>) {
        let world_change = before.inverse() * after;
        if let Some(last) = &mut self.last_pose {
            *last = renormalized(&(*last * world_change));
        }
        for (_, pose_cw) in &mut self.recent {
            *pose_cw = renormalized(&(*pose_cw * world_change));
        }
    }

    /// Where the constant-velocity model puts a frame taken at `timestamp`:
    /// the last motion, per second (frames skipped in real time, or gaps
    /// in the recording, mean more motion since the last tracked frame).
    fn predicted(&self, last: &Isometry3<f64>, timestamp: f64) -> Isometry3<f64> {
        let Some((v, dt)) = self.velocity else {
            return *last;
        };
        let since = self.last_timestamp().map_or(dt, |t| timestamp - t);
        let ratio = since / dt;
        let step = if ratio.is_finite() && ratio > 0.0 && ratio <= 4.0 {
            Isometry3::from_parts(
                nalgebra::Translation3::from(v.translation.vector * ratio),
                v.rotation.powf(ratio),
            )
        } else {
            v
        };
        renormalized(&(step * last))
    }

    /// After a gap ([`GAP`]), the motion model's prediction with the turn
    /// since the last tracked frame found from the images ([`small_image`])
    /// instead of its own, where the two differ by more than
    /// [`TURN_DISAGREEMENT_DEG`]; None otherwise, without a last image, or
    /// when the alignment fails.
    fn turned(
        &self,
        frame: &Frame,
        last: &Isometry3<f64>,
        predicted: &Isometry3<f64>,
        timestamp: f64,
    ) -> Option<Isometry3<f64>> {
        let since = self.last_timestamp().map(|t| timestamp - t)?;
        let gap = self
            .shortest_interval
            .is_some_and(|shortest| since > GAP * shortest);
        if !self.params.turn_from_images || !gap {
            return None;
        }
        let (older, newer) = (self.last_image.as_ref()?, frame.small.as_ref()?);
        let step = predicted * last.inverse();
        let turn = small_image::turn_between(older, newer, &step.rotation)?;
        ((turn.inverse() * step.rotation).angle() > TURN_DISAGREEMENT_DEG.to_radians())
            .then(|| renormalized(&(Isometry3::from_parts(step.translation, turn) * last)))
    }

    /// Remembers a tracked frame's small image for the next frame's turn,
    /// without the regions the motion check found moving in it.
    pub(crate) fn remember_image(&mut self, frame: &Frame, moving: &[motion_check::MovingRegion]) {
        self.last_image = frame.small.clone();
        // Copied only where the motion check found something.
        if let (Some(image), false) = (self.last_image.as_mut(), moving.is_empty()) {
            Arc::make_mut(image).without_boxes(moving.iter().map(|r| (r.min, r.max)));
        }
    }

    /// Tracks `frame`, taken at `timestamp`, against `map` (which has at
    /// least one keyframe).
    pub(crate) fn track(&mut self, map: &mut Map, frame: &Frame, timestamp: f64) -> Tracked {
        let local = self.local_points(map);
        if let Some(last) = self.last_pose.filter(|_| !self.lost) {
            let predicted = self.predicted(&last, timestamp);
            // After frames were left out, where the images say the camera
            // turned otherwise than the motion model does, their turn is
            // tried first.
            let turned = self.turned(frame, &last, &predicted, timestamp);
            let starts = turned
                .map(|t| (t, 15.0))
                .into_iter()
                .chain([(predicted, 15.0), (last, 30.0)]);
            // Monocular: the wide search first among the points the last
            // frame matched, as ORB-SLAM2's TrackWithMotionModel does, then
            // the local map from that pose; the local map at once where
            // that fails. Among the whole local map a look-alike near a
            // prediction that fell short wins, the pose follows it and the
            // map's scale shrinks frame by frame while the camera turns
            // (rendered orbit, 1000 features: 199/450 frames tracked, ATE
            // 0.37 m; 444/450, 0.0175 m this way). With depth every frame's
            // points are measured: no shrinking, and no change there.
            // Where the wide pass searches, in order of trial.
            let last_frame = self.params.is_monocular()
                && self.last_matched.len() >= 2 * self.params.min_inliers;
            let wide: &[&[usize]] = if last_frame {
                &[&self.last_matched, &local]
            } else {
                &[&local]
            };
            for (start, radius) in starts {
                for &first in wide {
                    if let Some(t) = self.track_from(map, frame, (first, &local), &start, radius) {
                        return Tracked {
                            state: TrackingState::Ok,
                            ..t
                        };
                    }
                }
            }
        }
        let lost = |pose_cw| Tracked {
            state: TrackingState::Lost,
            pose_cw,
            inliers: 0,
            matched: Vec::new(),
        };
        let (features, candidates) = self.relocalisation_candidates(map, frame);
        let mut everything = Vec::new();
        let mut tried = None;
        for id in candidates {
            let Some(start) = self.pose_at_keyframe(map, frame, &features, id) else {
                continue;
            };
            if everything.is_empty() {
                everything = map.live_points().map(|(p, _)| p).collect();
            }
            // The RANSAC pose must hold against the whole map.
            if let Some(t) = self.track_from(map, frame, (&everything, &everything), &start, 10.0) {
                self.relocalised_at = Some(id);
                return Tracked {
                    state: TrackingState::Relocalised,
                    ..t
                };
            }
            tried = Some(start);
        }
        if let Some(turned) = self.turned_on_the_spot(map, frame, timestamp) {
            return turned;
        }
        lost(tried.or(self.last_pose).unwrap_or_else(Isometry3::identity))
    }

    /// Monocular, when the map is out of sight: the camera's turn since
    /// the last tracked frame from the images ([`small_image`]), its
    /// position held. A camera that turns on the spot gives no parallax to
    /// triangulate the new view with, and comes back to the mapped one; one
    /// that also moves is lost once the position held is off by more than
    /// [`MAX_TURNING_PARALLAX_DEG`] of the scene's depth at the speed it
    /// had, or after [`MAX_TURNING_S`].
    fn turned_on_the_spot(&mut self, map: &Map, frame: &Frame, timestamp: f64) -> Option<Tracked> {
        if !self.params.is_monocular() || self.lost {
            return None;
        }
        let last = self.last_pose?;
        let held = match self.turning_since {
            Some(held) => held,
            None => {
                // Over the recent frames, not the last interval alone: a
                // monocular frame's translation jumps (fr1_rpy: 0.71 rad/s
                // of parallax from one interval where the three frames say
                // 0.04).
                let (&(t0, first), &(t1, last_in_map)) =
                    (self.recent.first()?, self.recent.last()?);
                let moved = (first.inverse().translation.vector
                    - last_in_map.inverse().translation.vector)
                    .norm();
                let depth = map
                    .live_keyframes()
                    .next_back()
                    .and_then(|(k, _)| map.median_depth(k))?;
                Turn {
                    since: t1,
                    parallax_rate: if t1 > t0 {
                        moved / (t1 - t0) / depth
                    } else {
                        0.0
                    },
                }
            }
        };
        let elapsed = timestamp - held.since;
        if elapsed > MAX_TURNING_S
            || elapsed * held.parallax_rate > MAX_TURNING_PARALLAX_DEG.to_radians()
        {
            return None;
        }
        // Frame to frame: aligned with the last frame in the map instead,
        // fr1_rpy kept 261 frames instead of 279, ATE 0.0357 m against
        // 0.0280 (errors of 2-3 deg either way: the translation the small
        // images take for a turn).
        let (older, newer) = (self.last_image.as_ref()?, frame.small.as_ref()?);
        let step = self.predicted(&last, timestamp) * last.inverse();
        // From the motion model's turn, else from none: an alignment that
        // starts where it ends (the turn went on as before) is refused.
        let turn = small_image::turn_between(older, newer, &step.rotation)
            .or_else(|| small_image::turn_between(older, newer, &Default::default()))?;
        self.turning_since = Some(held);
        Some(Tracked {
            state: TrackingState::Turning,
            pose_cw: renormalized(&(Isometry3::from_parts(Default::default(), turn) * last)),
            inliers: 0,
            matched: vec![None; frame.kps.len()],
        })
    }

    /// Two passes of match-by-projection and pose optimisation: wide from
    /// `start` among the `first` points, then narrow among the `local` ones
    /// from the first estimate.
    fn track_from(
        &self,
        map: &mut Map,
        frame: &Frame,
        (first, local): (&[usize], &[usize]),
        start: &Isometry3<f64>,
        radius: f64,
    ) -> Option<Tracked> {
        let mut pose = *start;
        let mut matched = Vec::new();
        let mut n = 0;
        let ordered = ByCell::new(frame);
        for (pass, r) in [radius, 6.0].into_iter().enumerate() {
            let search = ProjectionSearch {
                pose,
                radius: r,
                min_depth_m: self.params.min_depth_m,
                ratio: self.params.match_ratio,
                count_visible: pass == 1,
            };
            let candidates = if pass == 0 { first } else { local };
            matched =
                match_by_projection(map, (frame, &ordered), &self.camera, candidates, &search);
            let ids = matched_pairs(&matched);
            if ids.len() < self.params.min_inliers {
                return None;
            }
            let obs = self.observations(map, frame, &ids);
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
                    map.points[p].found += 1;
                }
            }
        }
        Some(Tracked {
            state: TrackingState::Ok,
            pose_cw: pose,
            inliers: n,
            matched,
        })
    }

    /// Pose-optimisation measurements of keypoint k matched to map point p.
    pub(crate) fn observations(
        &self,
        map: &Map,
        frame: &Frame,
        ids: &[(usize, usize)],
    ) -> Vec<Observation> {
        ids.iter()
            .map(|&(k, p)| {
                let m = frame.measure(k, &self.camera, self.params.close_depth_m);
                Observation {
                    world: map.points[p].position,
                    u: m.u,
                    v: m.v,
                    ur: m.ur,
                    info: m.info,
                }
            })
            .collect()
    }

    /// A tracked frame moves the motion model on.
    pub(crate) fn accept(&mut self, tracked: &Tracked, timestamp: f64) {
        let pose_cw = tracked.pose_cw;
        if let Some(last) = self.last_pose {
            let dt = self.last_timestamp().map_or(0.0, |t| timestamp - t);
            if dt > 1e-3 {
                self.shortest_interval = Some(self.shortest_interval.map_or(dt, |s| s.min(dt)));
            }
            self.velocity = Some((renormalized(&(pose_cw * last.inverse())), dt));
        }
        self.last_pose = Some(pose_cw);
        // The map points of the last frame in the map stay the local map's
        // seed for when a turning camera turns back.
        if tracked.state != TrackingState::Turning {
            self.turning_since = None;
            self.last_matched = tracked.matched.iter().flatten().copied().collect();
        }
        if self.recent.len() == MOTION_HISTORY {
            self.recent.remove(0);
        }
        self.recent.push((timestamp, pose_cw));
        self.lost = false;
        self.resumed = false;
        self.since_relocalisation = match tracked.state {
            TrackingState::Relocalised => Some(0),
            _ => self.since_relocalisation.map(|n| n + 1),
        };
    }

    /// A frame that could not be tracked: the motion model is stale.
    pub(crate) fn mark_lost(&mut self) {
        self.lost = true;
        self.last_image = None;
        self.flow = None;
        self.resumed = false;
        self.velocity = None;
        self.recent.clear();
        self.turning_since = None;
    }

    /// The frame (tracked, not made a keyframe) counts towards the next
    /// keyframe.
    pub(crate) fn count_frame(&mut self) {
        self.frames_since_keyframe += 1;
    }

    /// Inliers of the frame that made the last keyframe.
    pub(crate) fn reference_inliers(&self) -> usize {
        self.reference_inliers
    }

    /// Frames tracked since the last keyframe.
    pub(crate) fn frames_since_keyframe(&self) -> u32 {
        self.frames_since_keyframe
    }

    /// The keyframe just inserted was taken from a frame `frames` tracked
    /// frames ago, at `timestamp` (it waited for its masks): the next
    /// keyframe is due counting from that frame.
    pub(crate) fn backdate_keyframe(&mut self, frames: u32, timestamp: f64) {
        self.frames_since_keyframe = frames;
        self.keyframe_timestamp = Some(timestamp);
    }

    /// ORB-SLAM2 (RGB-D): many close points not yet in the map, or too few
    /// tracked against the reference keyframe, or too long since the last
    /// unless an older keyframe of `map` already sees from where the camera
    /// is (a camera that comes back keeps a bounded map; a weakening view
    /// still gets its keyframe).
    pub(crate) fn need_keyframe(&self, tracked: &Tracked, frame: &Frame, map: &Map) -> bool {
        // Just relocalised: after a loss or a restart there is no velocity
        // and no rolling-shutter correction yet (it needs MOTION_HISTORY
        // tracked frames), and a relocalised pose is rougher than a tracked
        // one; a keyframe now would seed points from it. Measured on
        // fr1_rpy with the map reloaded at frame 11 (a SLAM restart while
        // the camera turns fast): ATE 0.0309 m with an immediate keyframe,
        // see docs/design.md for the figure with this wait.
        if self
            .since_relocalisation
            .is_some_and(|n| n < MOTION_HISTORY)
        {
            return false;
        }
        let (mut close_tracked, mut close_untracked) = (0, 0);
        for (m, d) in tracked.matched.iter().zip(&frame.depth) {
            if d.is_some_and(|d| d < self.params.close_depth_m) {
                match m {
                    Some(_) => close_tracked += 1,
                    None => close_untracked += 1,
                }
            }
        }
        let inliers = tracked.inliers;
        let long = self.keyframe_due();
        // ORB-SLAM2's thRefRatio: 0.75 with depth, 0.9 monocular (no close
        // points to count: only the tracked share says the view changed).
        let ratio = if self.params.is_monocular() {
            0.9
        } else {
            0.75
        };
        let weak = (inliers as f64) < ratio * self.reference_inliers as f64
            || (close_tracked < 100 && close_untracked > 70);
        let p = &self.params;
        let long = long
            && !(p.same_view_m > 0.0
                && has_old_keyframe_at(
                    map,
                    &tracked.pose_cw,
                    p.local_keyframes,
                    p.same_view_m,
                    p.same_view_deg,
                ));
        (long || weak) && inliers > 15
    }

    /// The routing hint: the next frame should become a keyframe (lost,
    /// due, or weakening against the reference keyframe).
    pub(crate) fn next_needs_keyframe(&self, inliers: usize) -> bool {
        self.lost || self.keyframe_due() || (inliers as f64) < 0.85 * self.reference_inliers as f64
    }

    /// Localization mode's routing hint (no keyframes come): fresh masks
    /// when lost and at the keyframe cadence.
    pub(crate) fn refresh_due(&mut self) -> bool {
        if self.lost {
            return true;
        }
        let due = self.keyframe_due();
        if due {
            self.frames_since_keyframe = 0;
        }
        due
    }

    /// The next frame reaches the longest allowed gap between keyframes,
    /// in frames or, where frames were dropped (real time on a busy
    /// machine), in the camera's time since the last keyframe's frame.
    fn keyframe_due(&self) -> bool {
        let long_ago = self
            .keyframe_timestamp
            .zip(self.last_timestamp())
            .is_some_and(|(then, now)| now - then >= self.params.max_seconds_between_keyframes);
        self.frames_since_keyframe + 1 >= self.params.max_frames_between_keyframes || long_ago
    }

    /// Makes `frame` (tracked at `pose_cw`) a keyframe of `map`: matched
    /// keypoints observe their points, unmatched ones with depth make new
    /// points, the rest stay spare for triangulation. Returns its id.
    pub(crate) fn insert_keyframe(
        &mut self,
        map: &mut Map,
        frame: &Frame,
        pose_cw: &Isometry3<f64>,
        matched: &[Option<usize>],
        inliers: usize,
    ) -> usize {
        let pose_wc = pose_cw.inverse();
        let mut observed = Vec::new();
        let mut measurements = Vec::new();
        let mut spare = Vec::new();
        for k in 0..frame.kps.len() {
            let m = frame.measure(k, &self.camera, self.params.close_depth_m);
            if let Some(p) = matched.get(k).copied().flatten() {
                observed.push(p);
                measurements.push(m);
            } else if let Some(d) = frame.depth[k] {
                let (u, v) = frame.un[k];
                let seen = self.camera.unproject(u, v, d);
                let world = pose_wc * Point3::from(seen);
                let id = map.keyframes.len();
                let point = MapPoint::new(world.coords, id, &m, seen.norm(), frame.colours[k]);
                observed.push(map.add_point(point));
                measurements.push(m);
            } else {
                spare.push(SpareKeypoint {
                    measurement: m,
                    colour: frame.colours[k],
                });
            }
        }
        self.frames_since_keyframe = 0;
        self.keyframe_timestamp = self.last_timestamp();
        self.reference_inliers = inliers.max(1);
        map.add_keyframe(KeyFrame {
            pose_cw: *pose_cw,
            points: observed,
            measurements,
            spare,
            bounds: frame.bounds,
            // Local mapping connects it.
            covisible: Vec::new(),
            parent: None,
            loops: Vec::new(),
            culled: false,
        })
    }
}

/// What the newest keyframe of `map` tracks, for a resumed system's
/// keyframe rule (the inliers of the frame that made it died with the old
/// process): its live points that another keyframe observes too (ORB-SLAM2's
/// `TrackedMapPoints`), all of its live points when it is the only keyframe.
fn reference_points(map: &Map) -> usize {
    let Some((newest, keyframe)) = map.live_keyframes().next_back() else {
        return 0;
    };
    let min_observers = if map.live_keyframes().nth(1).is_some() {
        2
    } else {
        1
    };
    keyframe
        .points
        .iter()
        .map(|&p| &map.points[p])
        .filter(|p| {
            p.is_live() && p.observers.iter().filter(|&&k| k != newest).count() + 1 >= min_observers
        })
        .count()
        .max(1)
}
