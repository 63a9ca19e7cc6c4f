//! Rolling-shutter correction: keypoints moved to the middle row's instant
//! with the motion model's estimate (for matching), then (RGB-D) the pose
//! and the camera's motion during the readout optimised together once the
//! matches are known, and the keypoints moved again with that motion.

use nalgebra::Isometry3;

use super::Tracking;
use crate::features::orb::KeyPoint;
use crate::frame::Frame;
use crate::map::Map;
use crate::matcher::matched_pairs;
use crate::optimizer::pose::{
    is_finite_pose, optimize_pose, optimize_pose_and_twist, pose_and_twist_cost, pose_at_row,
    renormalized, Observation, Twist, TwistPrior,
};

impl Tracking {
    /// Rolling shutter: row y is exposed `readout_s * (y - h/2) / h` seconds
    /// after the middle row. The constant-velocity model says how the camera
    /// moved in that time; each keypoint is moved back to where the middle
    /// row's camera saw it: with its depth as a 3D point (rotation and
    /// translation, its depth updated too), without depth as a bearing
    /// (rotation only). Turning alone is not enough: a camera that slides
    /// while turning towards what it looks at has image motions that cancel.
    /// On fr1_rpy, which turns at up to 2 rad/s, this takes ATE from 0.034
    /// to 0.012 m (README, SLAM section).
    pub(crate) fn undo_rolling_shutter(
        &self,
        kps: &[KeyPoint],
        un: &mut [(f64, f64)],
        depths: &mut [Option<f64>],
        height: usize,
        (velocity, span): (Isometry3<f64>, f64),
    ) {
        for ((k, p), d) in kps.iter().zip(un.iter_mut()).zip(depths.iter_mut()) {
            // Fraction of the inter-frame motion from the middle row to this one:
            // points in camera coordinates move as x(row) = R^f x(mid) + f t.
            let f = self.row_delay(k.y, height) / span;
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
    /// correction uses, and the seconds it spans. Before the frame is
    /// tracked (`until` None): from the oldest remembered tracked frame to
    /// the last one (two intervals: the first pass only has to bring the
    /// keypoints within the matching radius). Once it is tracked (`until`:
    /// its timestamp and pose), the prior of the joint estimate: from the
    /// last tracked frame to it. The interval that ends at the frame is the
    /// motion nearest its readout; two intervals back it was centred one
    /// interval earlier, and where frames were left out (real time on a busy
    /// machine) that is 67-100 ms behind a turn that reverses within a few
    /// hundred. Measured (docs/measurements.md, "Rolling-shutter prior over
    /// the last interval"): `just bench-dropped` median 0.0144 -> 0.0128 m,
    /// every frame 0.0103 -> 0.0107 m; real time at 60 fps with two busy
    /// processes 1.38x -> 1.24x lockstep. A monocular frame keeps two
    /// intervals: it has no joint estimate, the motion itself is its
    /// correction, and with one interval the rendered orbit closed no loop
    /// (`tests/loop_circuit.rs`). None without a rolling shutter, when
    /// lost, or across a gap (a restart: the motion is stale).
    pub(crate) fn shutter_motion(
        &self,
        until: Option<(f64, Isometry3<f64>)>,
    ) -> Option<(Isometry3<f64>, f64)> {
        if self.camera.readout_s <= 0.0 || self.lost {
            return None;
        }
        let (t0, first) = match until {
            Some(_) if !self.params.is_monocular() => *self.recent.last()?,
            Some(_) => *self.recent.get(self.recent.len().checked_sub(2)?)?,
            None => *self.recent.first()?,
        };
        let (t1, last) = until.or_else(|| self.recent.last().copied())?;
        let span = t1 - t0;
        (1e-3..0.5)
            .contains(&span)
            .then(|| (renormalized(&(last * first.inverse())), span))
    }

    /// Second pass of the rolling-shutter correction once the frame's
    /// matches are known. With depth, the pose and the camera's motion
    /// during the readout are optimised together on the raw (uncorrected)
    /// keypoints, each seen from its own row's pose, with the motion from the
    /// last tracked frame to this one as the prior, and the keypoints are
    /// corrected again with the motion found. A monocular frame keeps the
    /// motion from two frames back to this one: corrected with it, the pose
    /// is optimised rigidly (without depth one frame hardly says how the
    /// camera moved along its axis; the joint estimate took the rendered
    /// room's monocular ATE from 0.0072 to 0.0097 m). None when it does not
    /// apply (no motion model: the frame before was lost) or the
    /// optimisation fails.
    pub(crate) fn refine_for_shutter(
        &mut self,
        map: &Map,
        frame: &mut Frame,
        raw: &(Vec<(f64, f64)>, Vec<Option<f64>>),
        pose_cw: &Isometry3<f64>,
        matched: &[Option<usize>],
        timestamp: f64,
    ) -> Option<Isometry3<f64>> {
        let (motion, span) = self.shutter_motion(Some((timestamp, *pose_cw)))?;
        frame.un.clone_from(&raw.0);
        frame.depth.clone_from(&raw.1);
        let height = frame.height;
        let ids = matched_pairs(matched);
        let (pose, inlier) = if self.params.is_monocular() {
            self.undo_rolling_shutter(
                &frame.kps,
                &mut frame.un,
                &mut frame.depth,
                height,
                (motion, span),
            );
            optimize_pose(&self.camera, pose_cw, &self.observations(map, frame, &ids))
        } else {
            let prior = TwistPrior {
                twist: twist_of(&motion, span),
                sigma_rotation: SIGMA_ROTATION,
                sigma_velocity: SIGMA_VELOCITY,
            };
            let dts: Vec<f64> = ids
                .iter()
                .map(|&(k, _)| self.row_delay(frame.kps[k].y, height))
                .collect();
            let observations = self.observations(map, frame, &ids);
            let (pose, twist, inlier) = self.estimate_readout(pose_cw, &prior, &observations, &dts);
            let twist = if twist.iter().all(|x| x.is_finite()) {
                twist
            } else {
                prior.twist
            };
            self.undo_rolling_shutter(
                &frame.kps,
                &mut frame.un,
                &mut frame.depth,
                height,
                (motion_of(&twist), 1.0),
            );
            (pose, inlier)
        };
        let n = inlier.iter().filter(|&&b| b).count();
        (n >= self.params.min_inliers && is_finite_pose(&pose)).then_some(pose)
    }

    /// The pose and the readout's motion together (with depth), the rows
    /// read out the way the frames have shown so far. In a fast turn the
    /// estimate's pull away from the motion model's turn is evidence of the
    /// way ([`ReadoutDirection`]); where it points the other way, that way
    /// is estimated too, and the lower cost decides. Where the way turns,
    /// this frame takes the other way's estimate.
    fn estimate_readout(
        &mut self,
        pose_cw: &Isometry3<f64>,
        prior: &TwistPrior,
        observations: &[Observation],
        dts: &[f64],
    ) -> (Isometry3<f64>, Twist, Vec<bool>) {
        let camera = &self.camera;
        let estimate = optimize_pose_and_twist(camera, pose_cw, prior, observations, dts);
        let turn = prior.twist.fixed_rows::<3>(0).into_owned();
        if turn.norm() < READOUT_EVIDENCE_TURN {
            return estimate;
        }
        let pull = (estimate.1.fixed_rows::<3>(0) - turn).dot(&turn) / turn.norm_squared();
        if !self.readout.suspects(pull) {
            return estimate;
        }
        let flipped: Vec<f64> = dts.iter().map(|dt| -dt).collect();
        let other = optimize_pose_and_twist(camera, pose_cw, prior, observations, &flipped);
        let cost = |(pose, twist, _): &(Isometry3<f64>, Twist, Vec<bool>), dts: &[f64]| {
            pose_and_twist_cost(camera, (pose, twist), prior, (observations, dts))
        };
        if self
            .readout
            .settle(cost(&other, &flipped) < cost(&estimate, dts))
        {
            other
        } else {
            estimate
        }
    }

    /// Seconds from the middle row's exposure to row `y`'s.
    fn row_delay(&self, y: f32, height: usize) -> f64 {
        let h = height as f64;
        self.readout.sign * self.camera.readout_s * (y as f64 - h / 2.0) / h
    }
}

/// How sure the motion model is of the camera's motion during a readout
/// (rad/s, m/s): it is the motion between frames, and a hand-held camera
/// changes its turn rate within one. Looser priors let the rows' own
/// evidence lead, but on fr1_rpy (every frame, and every 2nd and 3rd) 0.5-3
/// rad/s came out worse than 0.1 (docs/design.md, "Rolling shutter").
const SIGMA_ROTATION: f64 = 0.1;
const SIGMA_VELOCITY: f64 = 0.05;

/// The twist per second of `motion` (camera from camera) over `span` seconds.
fn twist_of(motion: &Isometry3<f64>, span: f64) -> Twist {
    let w = motion.rotation.scaled_axis() / span;
    let v = motion.translation.vector / span;
    Twist::new(w.x, w.y, w.z, v.x, v.y, v.z)
}

/// The motion of one second at `twist`, for [`Tracking::undo_rolling_shutter`]
/// with a span of one second.
fn motion_of(twist: &Twist) -> Isometry3<f64> {
    pose_at_row(&Isometry3::identity(), twist, 1.0)
}

/// Turn rate (rad/s) of the motion model above which a frame is evidence
/// of the readout's direction: slower, the two ways hardly differ.
const READOUT_EVIDENCE_TURN: f64 = 0.5;
/// Weight of the evidence before each new frame's.
const READOUT_EVIDENCE_DECAY: f64 = 0.8;
/// Evidence (decayed sum of pulls) below which the other way is estimated
/// too. On the shared sequence played forwards the sum's lowest is -0.6;
/// played backwards the first fast frame's pull alone is -2.1, and the
/// pulls stay at -0.2 to -2 (docs/measurements.md, "Rows read out the
/// other way").
const READOUT_SUSPECT: f64 = -1.5;

/// Which way the rows are read out, as the frames show it. The camera's
/// `readout_s` says top row first; a sensor set to flip its image reads
/// the image's bottom row first, and so does a recording played backwards
/// (the motion between frames is reversed, the rows' order is not): there a
/// correction along the motion model doubles the shutter's error instead of
/// removing it. The evidence: the joint estimate's turn during the readout,
/// held near the motion model's by its prior, is pulled towards what the
/// rows show; read out the other way, the rows show the opposite turn and
/// the pull is backwards (a negative fraction of the model's turn).
#[derive(Debug, Clone, Copy)]
pub(crate) struct ReadoutDirection {
    /// +1: top row first, as configured; -1: bottom row first.
    sign: f64,
    /// Decayed sum of the fast frames' pulls.
    evidence: f64,
}

impl Default for ReadoutDirection {
    fn default() -> Self {
        Self {
            sign: 1.0,
            evidence: 0.0,
        }
    }
}

impl ReadoutDirection {
    /// Adds one fast frame's pull (the estimated turn minus the model's,
    /// along the model's, as a fraction of it); true when the evidence
    /// says to try the other way.
    fn suspects(&mut self, pull: f64) -> bool {
        self.evidence = READOUT_EVIDENCE_DECAY * self.evidence + pull;
        self.evidence < READOUT_SUSPECT
    }

    /// After the other way was tried: turns the direction when it fitted
    /// better (true), and starts the evidence again either way.
    fn settle(&mut self, other_fits_better: bool) -> bool {
        self.evidence = 0.0;
        if other_fits_better {
            self.sign = -self.sign;
            tracing::info!(
                "rolling shutter: the rows read out {} row first, as the frames show",
                if self.sign > 0.0 { "top" } else { "bottom" }
            );
        }
        other_fits_better
    }
}
#[cfg(test)]
mod tests {
    use nalgebra::{Point3, Translation3, UnitQuaternion, Vector3};

    use super::*;
    use crate::camera::Camera;
    use crate::params::SlamParams;

    /// A camera turning and sliding at a constant rate, rows exposed over
    /// 20 ms: a point seen on the top row is moved to the pixel (and depth)
    /// where the middle row's camera sees it.
    #[test]
    fn rolling_shutter_keypoints_move_to_the_middle_rows_instant() {
        let mut camera = Camera::tum_fr1();
        camera.dist = [0.0; 5];
        camera.readout_s = 0.02;
        let mut t = Tracking::new(
            camera,
            SlamParams::default(),
            crate::place_recognition::Vocabulary::embedded(),
        );
        // Camera from world at time t: turning 1.5 rad/s about y, sliding 0.3 m/s in x.
        let pose_at = |t: f64| {
            Isometry3::from_parts(
                Translation3::new(0.3 * t, 0.0, 0.0),
                UnitQuaternion::from_euler_angles(0.0, 1.5 * t, 0.0),
            )
        };
        let (dt, t_now) = (1.0 / 30.0, 3.0 / 30.0);
        t.recent = (0..3)
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
        let motion = t.shutter_motion(None).expect("a moving camera");
        t.undo_rolling_shutter(&[kp], &mut un, &mut depth, h, motion);
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
        t.camera.readout_s = 0.0;
        assert!(t.shutter_motion(None).is_none());
        t.camera.readout_s = 0.02;
        assert!(t.shutter_motion(Some((t_now + 1.0, mid))).is_none());
    }

    /// The readout's direction turns only on evidence: pulls like the
    /// shared sequence's played forwards never make it suspect; played
    /// backwards the first fast frame does, and it turns only where the
    /// other way fitted better.
    #[test]
    fn the_readout_direction_turns_on_evidence_only() {
        let mut way = ReadoutDirection::default();
        for pull in [-0.56, -0.55, -0.13, -0.10, 0.04, -0.10, -0.09, 0.3, -0.3] {
            assert!(!way.suspects(pull), "{way:?}");
        }
        assert!(way.suspects(-2.06));
        assert!(!way.settle(false), "the other way did not fit better");
        assert_eq!(way.sign, 1.0);
        assert!(way.suspects(-1.6));
        assert!(way.settle(true));
        assert_eq!(way.sign, -1.0);
        assert!(!way.suspects(-0.5), "the evidence starts again");
    }
}
