//! Motion-only pose optimisation (ORB-SLAM2's `PoseOptimization`):
//! Levenberg-Marquardt on SE(3) over the reprojection of matched map points,
//! with RGB-D measurements as (u, v, ur) triples, a Huber kernel, and four
//! rounds that reclassify outliers by their chi-square error.

use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6};

use crate::camera::Camera;

/// One map point seen in the frame.
#[derive(Debug, Clone, Copy)]
pub struct Observation {
    pub world: Vector3<f64>,
    pub u: f64,
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
    (mu, mv, mur): (f64, f64, Option<f64>),
) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let pc = pose * nalgebra::Point3::from(*world);
    if pc.z <= 1e-3 {
        return None;
    }
    let (u, v) = cam.project(&pc.coords);
    let ur = u - cam.bf / pc.z;
    let r = Vector3::new(mu - u, mv - v, mur.map_or(0.0, |m| m - ur));
    Some((r, pc.coords))
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
    pose: &Isometry3<f64>,
    o: &Observation,
) -> Option<(Vector3<f64>, Vector3<f64>)> {
    stereo_residual(cam, pose, &o.world, (o.u, o.v, o.ur))
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
        for (i, o) in obs.iter().enumerate() {
            let th = chi2_threshold(o.ur.is_some());
            inlier[i] = residual(cam, &pose, o).is_some_and(|(r, _)| chi2(&r, o) <= th);
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
        obs.iter()
            .zip(use_)
            .filter(|(_, &u)| u)
            .filter_map(|(o, _)| residual(cam, pose, o).map(|(r, _)| huber(chi2(&r, o), o, robust)))
            .sum()
    };
    let mut pose = *start;
    let mut current = cost(&pose);
    let mut lambda = 1e-3;
    for _ in 0..iterations {
        let mut h = Matrix6::<f64>::zeros();
        let mut g = Vector6::<f64>::zeros();
        for (o, _) in obs.iter().zip(use_).filter(|(_, &u)| u) {
            let Some((r, p)) = residual(cam, &pose, o) else {
                continue;
            };
            let e2 = chi2(&r, o);
            let th = chi2_threshold(o.ur.is_some());
            // Huber weight on the squared error.
            let w = if robust && e2 > th {
                (th / e2).sqrt()
            } else {
                1.0
            } * o.info;
            let [du, dv, dur] = projection_rows(cam, &p);
            let rows = [(pose_row(&du, &p), r.x), (pose_row(&dv, &p), r.y)];
            for (j, e) in rows
                .iter()
                .chain(o.ur.map(|_| (pose_row(&dur, &p), r.z)).iter())
            {
                // Residual is measured - predicted: the Jacobian of the residual is -j.
                h += w * j * j.transpose();
                g += w * j * *e;
            }
        }
        let mut improved = false;
        for _ in 0..6 {
            let mut hl = h;
            for i in 0..6 {
                hl[(i, i)] *= 1.0 + lambda;
            }
            let Some(delta) = hl
                .cholesky()
                .map(|c| c.solve(&g))
                .filter(|d| d.iter().all(|x| x.is_finite()))
            else {
                lambda *= 10.0;
                continue;
            };
            let step = Isometry3::from_parts(
                Translation3::from(Vector3::new(delta[3], delta[4], delta[5])),
                UnitQuaternion::from_scaled_axis(Vector3::new(delta[0], delta[1], delta[2])),
            );
            let candidate = renormalized(&(step * pose));
            let c = cost(&candidate);
            if c < current {
                pose = candidate;
                current = c;
                lambda = (lambda * 0.3).max(1e-7);
                improved = delta.norm() > 1e-9;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    pose
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
