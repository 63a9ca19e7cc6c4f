//! Motion-only pose optimisation (ORB-SLAM2's `PoseOptimization`):
//! Levenberg-Marquardt on SE(3) over the reprojection of matched map points,
//! with RGB-D measurements as (u, v, ur) triples, a Huber kernel, and four
//! rounds that reclassify outliers by their chi-square error.

use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6};

use crate::camera::Camera;
use crate::geometry::PoseMatrix;

/// One map point seen in the frame.
#[derive(Debug, Clone, Copy)]
pub struct Observation {
    /// The map point (world frame).
    pub world: Vector3<f64>,
    /// Its keypoint's undistorted pixel, column.
    pub u: f64,
    /// Its keypoint's undistorted pixel, row.
    pub v: f64,
    /// `u - bf / depth` when the keypoint has depth.
    pub ur: Option<f64>,
    /// 1 / sigma^2 of the keypoint's pyramid level.
    pub info: f64,
}

const CHI2_MONO: f64 = 5.991;
const CHI2_STEREO: f64 = 7.815;

/// Residual (measured - predicted) of a measurement (u, v, ur) of `world`
/// seen from `pose` (camera from world), and the point in the camera frame;
/// None behind the camera. Shared with bundle adjustment.
pub(crate) fn stereo_residual(
    cam: &Camera,
    pose: &Isometry3<f64>,
    world: &Vector3<f64>,
    measured: (f64, f64, Option<f64>),
) -> Option<(Vector3<f64>, Vector3<f64>)> {
    residual_in_camera(
        cam,
        (pose * nalgebra::Point3::from(*world)).coords,
        measured,
    )
}

/// [`stereo_residual`] of a point already in the camera frame.
fn residual_in_camera(
    cam: &Camera,
    pc: Vector3<f64>,
    (mu, mv, mur): (f64, f64, Option<f64>),
) -> Option<(Vector3<f64>, Vector3<f64>)> {
    if pc.z <= 1e-3 {
        return None;
    }
    let (u, v) = cam.project(&pc);
    let ur = u - cam.bf / pc.z;
    let r = Vector3::new(mu - u, mv - v, mur.map_or(0.0, |m| m - ur));
    Some((r, pc))
}

/// Information-weighted squared error; `ur` counts only when measured.
pub(crate) fn chi2_error(r: &Vector3<f64>, has_ur: bool, info: f64) -> f64 {
    (r.x * r.x + r.y * r.y + if has_ur { r.z * r.z } else { 0.0 }) * info
}

/// The chi-square outlier threshold at 95 % (2 or 3 degrees of freedom).
pub(crate) fn chi2_threshold(has_ur: bool) -> f64 {
    if has_ur {
        CHI2_STEREO
    } else {
        CHI2_MONO
    }
}

/// Rows of d(u, v, ur) / d(point in the camera frame) at `p`.
pub(crate) fn projection_rows(cam: &Camera, p: &Vector3<f64>) -> [Vector3<f64>; 3] {
    let (x, y, z) = (p.x, p.y, p.z);
    let iz = 1.0 / z;
    let iz2 = iz * iz;
    [
        Vector3::new(cam.fx * iz, 0.0, -cam.fx * x * iz2),
        Vector3::new(0.0, cam.fy * iz, -cam.fy * y * iz2),
        Vector3::new(cam.fx * iz, 0.0, (-cam.fx * x + cam.bf) * iz2),
    ]
}

/// One row of the Jacobian with respect to a left perturbation
/// [omega, upsilon] of camera-from-world: d(point)/d = [-[p]x, I].
pub(crate) fn pose_row(d: &Vector3<f64>, p: &Vector3<f64>) -> Vector6<f64> {
    Vector6::new(
        d[1] * -p.z + d[2] * p.y,
        d[0] * p.z + d[2] * -p.x,
        d[0] * -p.y + d[1] * p.x,
        d[0],
        d[1],
        d[2],
    )
}

fn residual(
    cam: &Camera,
    pose: &PoseMatrix,
    o: &Observation,
) -> Option<(Vector3<f64>, Vector3<f64>)> {
    residual_in_camera(cam, pose.apply(&o.world), (o.u, o.v, o.ur))
}

fn chi2(r: &Vector3<f64>, o: &Observation) -> f64 {
    chi2_error(r, o.ur.is_some(), o.info)
}

/// No NaN or infinity in the pose (what a degenerate solve leaves).
pub(crate) fn is_finite_pose(pose: &Isometry3<f64>) -> bool {
    pose.translation
        .vector
        .iter()
        .chain(pose.rotation.coords.iter())
        .all(|x| x.is_finite())
}

/// Optimises `pose` (camera from world); returns the pose and the inlier
/// flag of every observation. Fewer than 3 inliers leave the pose unchanged.
pub fn optimize_pose(
    cam: &Camera,
    pose: &Isometry3<f64>,
    obs: &[Observation],
) -> (Isometry3<f64>, Vec<bool>) {
    let mut inlier = vec![true; obs.len()];
    let mut pose = *pose;
    for round in 0..4 {
        pose = refine(
            cam,
            &pose,
            obs,
            &inlier,
            if round < 3 { 10 } else { 5 },
            round < 2,
        );
        let matrix = PoseMatrix::of(&pose);
        for (i, o) in obs.iter().enumerate() {
            let th = chi2_threshold(o.ur.is_some());
            inlier[i] = residual(cam, &matrix, o).is_some_and(|(r, _)| chi2(&r, o) <= th);
        }
        if inlier.iter().filter(|&&b| b).count() < 3 {
            break;
        }
    }
    (pose, inlier)
}

fn refine(
    cam: &Camera,
    start: &Isometry3<f64>,
    obs: &[Observation],
    use_: &[bool],
    iterations: usize,
    robust: bool,
) -> Isometry3<f64> {
    let cost = |pose: &Isometry3<f64>| -> f64 {
        let matrix = PoseMatrix::of(pose);
        obs.iter()
            .zip(use_)
            .filter(|(_, &u)| u)
            .filter_map(|(o, _)| {
                residual(cam, &matrix, o).map(|(r, _)| huber(chi2(&r, o), o, robust))
            })
            .sum()
    };
    let mut pose = *start;
    let mut current = cost(&pose);
    let mut lambda = 1e-3;
    for _ in 0..iterations {
        let mut h = Matrix6::<f64>::zeros();
        let mut g = Vector6::<f64>::zeros();
        let matrix = PoseMatrix::of(&pose);
        for (o, _) in obs.iter().zip(use_).filter(|(_, &u)| u) {
            let Some((r, p)) = residual(cam, &matrix, o) else {
                continue;
            };
            let w = weight(&r, o, robust);
            let [du, dv, dur] = projection_rows(cam, &p);
            let rows = [(pose_row(&du, &p), r.x), (pose_row(&dv, &p), r.y)];
            for (j, e) in rows
                .iter()
                .chain(o.ur.map(|_| (pose_row(&dur, &p), r.z)).iter())
            {
                // Residual is measured - predicted: the Jacobian of the residual is -j.
                // Lower triangle only (the upper is filled once below).
                h.syger(w, j, j, 1.0);
                g.axpy(w * e, j, 1.0);
            }
        }
        h.fill_upper_triangle_with_lower_triangle();
        let step = damped_step(&h, &g, &mut lambda, &mut current, |delta| {
            let candidate = renormalized(&(perturbation(delta.as_slice()) * pose));
            (cost(&candidate), candidate)
        });
        let Some((candidate, moved)) = step else {
            break;
        };
        pose = candidate;
        if !moved {
            break;
        }
    }
    pose
}

/// The left perturbation of a pose whose first six values `delta` are
/// [omega, upsilon].
fn perturbation(delta: &[f64]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(Vector3::new(delta[3], delta[4], delta[5])),
        UnitQuaternion::from_scaled_axis(Vector3::new(delta[0], delta[1], delta[2])),
    )
}

/// One Levenberg-Marquardt step on the normal equations `h delta = g`:
/// the damping `lambda` is raised until `apply(delta)` gives a lower cost
/// than `current` (at most six tries), then lowered. Returns the improved
/// state and whether it moved measurably (a step over 1e-6: a micro-radian
/// or a micrometre; smaller steps change no pixel, and stopping at them
/// saves a quarter of the iterations), None when no try improved.
fn damped_step<const N: usize, T>(
    h: &nalgebra::SMatrix<f64, N, N>,
    g: &nalgebra::SVector<f64, N>,
    lambda: &mut f64,
    current: &mut f64,
    apply: impl Fn(&nalgebra::SVector<f64, N>) -> (f64, T),
) -> Option<(T, bool)> {
    for _ in 0..6 {
        let mut hl = *h;
        for i in 0..N {
            hl[(i, i)] *= 1.0 + *lambda;
        }
        let Some(delta) = hl
            .cholesky()
            .map(|c| c.solve(g))
            .filter(|d| d.iter().all(|x| x.is_finite()))
        else {
            *lambda *= 10.0;
            continue;
        };
        let (c, candidate) = apply(&delta);
        if c < *current {
            *current = c;
            *lambda = (*lambda * 0.3).max(1e-7);
            return Some((candidate, delta.norm() > 1e-6));
        }
        *lambda *= 10.0;
    }
    None
}

/// The camera's motion during one frame's readout, per second: the rate of
/// its rotation vector (omega) and its velocity (v), in the middle row's
/// camera frame. A row exposed `dt` seconds after the middle row sees a
/// point at `R(dt omega) x_mid + dt v` (first order in the motion, as the
/// rolling-shutter correction models it).
pub type Twist = Vector6<f64>;

/// What the twist is expected to be (the motion model's) and how sure that
/// is (standard deviations: rad/s for the rotation, m/s for the velocity).
#[derive(Debug, Clone, Copy)]
pub struct TwistPrior {
    /// The expected twist.
    pub twist: Twist,
    /// Standard deviation of the rotation rate (rad/s).
    pub sigma_rotation: f64,
    /// Standard deviation of the velocity (m/s).
    pub sigma_velocity: f64,
}

impl TwistPrior {
    fn information(&self) -> Vector6<f64> {
        let (r, v) = (
            1.0 / (self.sigma_rotation * self.sigma_rotation),
            1.0 / (self.sigma_velocity * self.sigma_velocity),
        );
        Vector6::new(r, r, r, v, v, v)
    }

    fn cost(&self, twist: &Twist) -> f64 {
        (twist - self.twist)
            .component_mul(&(twist - self.twist))
            .dot(&self.information())
    }
}

/// Camera from world of the row exposed `dt` after the middle row, given
/// the middle row's `pose` and the readout `twist`.
pub fn pose_at_row(pose: &Isometry3<f64>, twist: &Twist, dt: f64) -> Isometry3<f64> {
    let during = Isometry3::from_parts(
        Translation3::from(dt * twist.fixed_rows::<3>(3).into_owned()),
        UnitQuaternion::from_scaled_axis(dt * twist.fixed_rows::<3>(0).into_owned()),
    );
    during * pose
}

/// `p` (a point in the middle row's camera) as the row exposed `dt` later
/// sees it: turned by `dt omega` (to second order: a readout turns the
/// camera by hundredths of a radian, where the third-order term is below a
/// thousandth of a pixel) and moved by `dt v`. Returns the point and its
/// turned part (before the move).
fn seen_from_row(p: &Vector3<f64>, twist: &Twist, dt: f64) -> (Vector3<f64>, Vector3<f64>) {
    let a = dt * Vector3::new(twist[0], twist[1], twist[2]);
    let ap = a.cross(p);
    let turned = p + ap + 0.5 * a.cross(&ap);
    (
        turned + dt * Vector3::new(twist[3], twist[4], twist[5]),
        turned,
    )
}

/// Residual of `o` seen from the row `dt` after the middle row, the point
/// in the middle row's camera, the point in the row's camera and its
/// turned part; None behind the camera.
fn row_residual(
    cam: &Camera,
    pose: &PoseMatrix,
    twist: &Twist,
    dt: f64,
    o: &Observation,
) -> Option<(Vector3<f64>, [Vector3<f64>; 3])> {
    let mid = pose.apply(&o.world);
    let (q, turned) = seen_from_row(&mid, twist, dt);
    if q.z <= 1e-3 {
        return None;
    }
    let (u, v) = cam.project(&q);
    let ur = u - cam.bf / q.z;
    let r = Vector3::new(o.u - u, o.v - v, o.ur.map_or(0.0, |m| m - ur));
    Some((r, [mid, q, turned]))
}

/// [`optimize_pose`] for a rolling-shutter camera: the middle row's pose and
/// the camera's motion during the readout are estimated together, each
/// observation seen from its own row's pose (`dts[i]` seconds after the
/// middle row). The motion comes from the frame's own measurements (the
/// rows disagree when the camera moves) with the motion model as a prior,
/// so that a pose error of the frames before does not become this frame's
/// correction error (see `tracking::rolling_shutter`).
pub fn optimize_pose_and_twist(
    cam: &Camera,
    pose: &Isometry3<f64>,
    prior: &TwistPrior,
    obs: &[Observation],
    dts: &[f64],
) -> (Isometry3<f64>, Twist, Vec<bool>) {
    let mut inlier = vec![true; obs.len()];
    let (mut pose, mut twist) = (*pose, prior.twist);
    for round in 0..4 {
        (pose, twist) = refine_with_twist(
            cam,
            (&pose, &twist),
            prior,
            (obs, dts),
            &inlier,
            if round < 3 { 10 } else { 5 },
            round < 2,
        );
        let matrix = PoseMatrix::of(&pose);
        for (i, (o, &dt)) in obs.iter().zip(dts).enumerate() {
            let th = chi2_threshold(o.ur.is_some());
            inlier[i] =
                row_residual(cam, &matrix, &twist, dt, o).is_some_and(|(r, _)| chi2(&r, o) <= th);
        }
        if inlier.iter().filter(|&&b| b).count() < 3 {
            break;
        }
    }
    (pose, twist, inlier)
}

/// The robust (Huber) cost of a joint estimate over every observation,
/// each seen from its own row's pose, plus the twist's prior: what
/// [`optimize_pose_and_twist`] lowers, comparable between two readout
/// hypotheses of the same observations.
pub fn pose_and_twist_cost(
    cam: &Camera,
    (pose, twist): (&Isometry3<f64>, &Twist),
    prior: &TwistPrior,
    (obs, dts): (&[Observation], &[f64]),
) -> f64 {
    joint_cost(cam, (pose, twist), prior, (obs, dts), None, true)
}

/// The joint estimate's cost over the observations `use_` keeps (all
/// where None).
fn joint_cost(
    cam: &Camera,
    (pose, twist): (&Isometry3<f64>, &Twist),
    prior: &TwistPrior,
    (obs, dts): (&[Observation], &[f64]),
    use_: Option<&[bool]>,
    robust: bool,
) -> f64 {
    let pose = PoseMatrix::of(pose);
    obs.iter()
        .zip(dts)
        .enumerate()
        .filter(|(i, _)| use_.is_none_or(|u| u[*i]))
        .filter_map(|(_, (o, &dt))| {
            row_residual(cam, &pose, twist, dt, o).map(|(r, _)| huber(chi2(&r, o), o, robust))
        })
        .sum::<f64>()
        + prior.cost(twist)
}

type Matrix12 = nalgebra::SMatrix<f64, 12, 12>;
type Vector12 = nalgebra::SVector<f64, 12>;

/// Levenberg-Marquardt over the pose (a left perturbation, as in `refine`)
/// and the twist (additive), with the twist's prior.
fn refine_with_twist(
    cam: &Camera,
    (start, start_twist): (&Isometry3<f64>, &Twist),
    prior: &TwistPrior,
    (obs, dts): (&[Observation], &[f64]),
    use_: &[bool],
    iterations: usize,
    robust: bool,
) -> (Isometry3<f64>, Twist) {
    let cost = |pose: &Isometry3<f64>, twist: &Twist| -> f64 {
        joint_cost(cam, (pose, twist), prior, (obs, dts), Some(use_), robust)
    };
    let information = prior.information();
    let (mut pose, mut twist) = (*start, *start_twist);
    let mut current = cost(&pose, &twist);
    let mut lambda = 1e-3;
    for _ in 0..iterations {
        let mut h = Matrix12::zeros();
        let mut g = Vector12::zeros();
        let matrix = PoseMatrix::of(&pose);
        for ((o, &dt), _) in obs.iter().zip(dts).zip(use_).filter(|(_, &u)| u) {
            let Some((r, [mid, q, turned])) = row_residual(cam, &matrix, &twist, dt, o) else {
                continue;
            };
            let w = weight(&r, o, robust);
            let [du, dv, dur] = projection_rows(cam, &q);
            let row_of = |d: &Vector3<f64>| -> Vector12 {
                let mut j = Vector12::zeros();
                // d(row point)/d(pose perturbation) = R_readout [-[p]x, I],
                // with R_readout ~ I to first order in the Jacobian (the
                // residual itself keeps the turn).
                j.fixed_rows_mut::<6>(0).copy_from(&pose_row(d, &mid));
                // d(row point)/d(omega) = -dt [turned]x, d/d(v) = dt I.
                let spin = turned.cross(d);
                j.fixed_rows_mut::<3>(6).copy_from(&(dt * spin));
                j.fixed_rows_mut::<3>(9).copy_from(&(dt * d));
                j
            };
            for (d, e) in [(du, r.x), (dv, r.y)]
                .into_iter()
                .chain(o.ur.map(|_| (dur, r.z)))
            {
                let j = row_of(&d);
                // Residual is measured - predicted: the Jacobian of the residual is -j.
                // Lower triangle only (the upper is filled once below).
                h.syger(w, &j, &j, 1.0);
                g.axpy(w * e, &j, 1.0);
            }
        }
        h.fill_upper_triangle_with_lower_triangle();
        for i in 0..6 {
            h[(6 + i, 6 + i)] += information[i];
            g[6 + i] += information[i] * (prior.twist[i] - twist[i]);
        }
        let step = damped_step(&h, &g, &mut lambda, &mut current, |delta| {
            let candidate = renormalized(&(perturbation(delta.as_slice()) * pose));
            let candidate_twist = twist + delta.fixed_rows::<6>(6);
            (
                cost(&candidate, &candidate_twist),
                (candidate, candidate_twist),
            )
        });
        let Some(((candidate, candidate_twist), moved)) = step else {
            break;
        };
        (pose, twist) = (candidate, candidate_twist);
        if !moved {
            break;
        }
    }
    (pose, twist)
}

/// The pose with its quaternion scaled back to unit length. nalgebra's
/// products of unit quaternions do not renormalise; composed every frame
/// (velocity times last pose), the rounding error grows geometrically.
pub fn renormalized(pose: &Isometry3<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(
        pose.translation,
        UnitQuaternion::new_normalize(pose.rotation.into_inner()),
    )
}

/// The Huber cost of a squared error `e2` (the kernel's threshold `th`).
pub(crate) fn huber_cost(e2: f64, th: f64) -> f64 {
    if e2 > th {
        2.0 * (th * e2).sqrt() - th
    } else {
        e2
    }
}

/// An observation's weight in the normal equations: its information,
/// times the Huber kernel's weight on its squared error when `robust`.
fn weight(r: &Vector3<f64>, o: &Observation, robust: bool) -> f64 {
    let e2 = chi2(r, o);
    let th = chi2_threshold(o.ur.is_some());
    let huber = if robust && e2 > th {
        (th / e2).sqrt()
    } else {
        1.0
    };
    huber * o.info
}

fn huber(e2: f64, o: &Observation, robust: bool) -> f64 {
    if robust {
        huber_cost(e2, chi2_threshold(o.ur.is_some()))
    } else {
        e2
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera turning at 2 rad/s while sliding, rows exposed over 18 ms:
    /// the middle row's pose and the motion come back from the rows alone
    /// (the prior is no motion, loosely held), where a rigid pose is off.
    #[test]
    fn recovers_the_pose_and_the_readout_motion_of_a_rolling_shutter() {
        let cam = Camera::tum_fr1();
        let truth = Isometry3::from_parts(
            Translation3::new(0.05, -0.02, 0.1),
            UnitQuaternion::from_euler_angles(0.03, -0.05, 0.02),
        );
        let twist = Twist::new(0.4, -2.0, 0.3, 0.3, 0.1, -0.2);
        let (readout, h) = (0.018, 480.0);
        let (mut obs, mut dts) = (Vec::new(), Vec::new());
        for i in 0..300 {
            let f = i as f64;
            let world = Vector3::new(
                (f * 0.37).sin() * 1.2,
                (f * 0.23).cos() * 0.9,
                1.5 + (f * 0.11).sin(),
            );
            // The row a point lands on depends on the row's pose: two
            // fixed-point steps find it.
            let mut dt = 0.0;
            for _ in 0..3 {
                let pc = pose_at_row(&truth, &twist, dt) * nalgebra::Point3::from(world);
                dt = readout * (cam.project(&pc.coords).1 - h / 2.0) / h;
            }
            let pc = pose_at_row(&truth, &twist, dt) * nalgebra::Point3::from(world);
            let (u, v) = cam.project(&pc.coords);
            obs.push(Observation {
                world,
                u,
                v,
                ur: Some(u - cam.bf / pc.z),
                info: 1.0,
            });
            dts.push(dt);
        }
        let prior = TwistPrior {
            twist: Twist::zeros(),
            sigma_rotation: 3.0,
            sigma_velocity: 1.0,
        };
        let (pose, found, inliers) =
            optimize_pose_and_twist(&cam, &Isometry3::identity(), &prior, &obs, &dts);
        let err = (pose.inverse() * truth).translation.vector.norm();
        assert!(err < 1e-3, "pose {err} m off");
        assert!(
            (found - twist).fixed_rows::<3>(0).norm() < 0.05,
            "rotation rate {found:?}"
        );
        assert!(inliers.iter().all(|&b| b));
        let (rigid, _) = optimize_pose(&cam, &Isometry3::identity(), &obs);
        let rigid_err = (rigid.inverse() * truth).translation.vector.norm();
        assert!(
            rigid_err > 5.0 * err.max(1e-4),
            "rigid {rigid_err} vs {err}"
        );
    }

    #[test]
    fn recovers_a_pose_despite_outliers() {
        let cam = Camera::tum_fr1();
        let truth = Isometry3::from_parts(
            Translation3::new(0.05, -0.02, 0.1),
            UnitQuaternion::from_euler_angles(0.03, -0.05, 0.02),
        );
        let mut obs = Vec::new();
        for i in 0..200 {
            let f = i as f64;
            let world = Vector3::new(
                (f * 0.37).sin() * 1.5,
                (f * 0.23).cos(),
                1.5 + (f * 0.11).sin(),
            );
            let pc = truth * nalgebra::Point3::from(world);
            let (mut u, v) = cam.project(&pc.coords);
            if i % 10 == 0 {
                u += 40.0; // gross outlier
            }
            obs.push(Observation {
                world,
                u,
                v,
                ur: Some(u - cam.bf / pc.z),
                info: 1.0,
            });
        }
        let (pose, inliers) = optimize_pose(&cam, &Isometry3::identity(), &obs);
        let err = (pose.inverse() * truth).translation.vector.norm();
        assert!(err < 1e-4, "{err}");
        assert_eq!(inliers.iter().filter(|&&b| !b).count(), 20);
    }
}
