//! Local bundle adjustment (ORB-SLAM2's `LocalBundleAdjustment`): the poses
//! of the newest keyframes and the points they see, refined together
//! against every observation of those points, with keyframes outside the
//! window that also see them held fixed (they anchor the gauge).
//!
//! Levenberg-Marquardt on the RGB-D reprojection (u, v, ur) with a Huber
//! kernel; each step eliminates the points first (Schur complement: every
//! point's 3x3 block is inverted on its own), solves the small dense system
//! of the free poses, then back-substitutes the points. Two stages as in
//! ORB-SLAM2: robust iterations, then outliers (chi-square test) dropped
//! and a few more iterations without them.

use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Matrix3x6, Translation3, UnitQuaternion, Vector3, Vector6,
};

use std::ops::{AddAssign, SubAssign};

use super::pose::{
    chi2_error, chi2_threshold, huber_cost, pose_row, projection_rows, renormalized,
    stereo_residual,
};
use crate::camera::Camera;

/// One measurement of point `point` in keyframe `pose` (indices into the
/// problem's arrays).
#[derive(Debug, Clone, Copy)]
pub struct BaObservation {
    /// Index of the keyframe pose.
    pub pose: usize,
    /// Index of the point.
    pub point: usize,
    /// Undistorted pixel, column.
    pub u: f64,
    /// Undistorted pixel, row.
    pub v: f64,
    /// `u - bf / depth` when the keypoint had depth.
    pub ur: Option<f64>,
    /// 1 / sigma^2 of the keypoint's pyramid level.
    pub info: f64,
}

fn threshold(o: &BaObservation) -> f64 {
    chi2_threshold(o.ur.is_some())
}

fn residual(
    cam: &Camera,
    pose: &Isometry3<f64>,
    point: &Vector3<f64>,
    o: &BaObservation,
) -> Option<(Vector3<f64>, Vector3<f64>)> {
    stereo_residual(cam, pose, point, (o.u, o.v, o.ur))
}

fn chi2(r: &Vector3<f64>, o: &BaObservation) -> f64 {
    chi2_error(r, o.ur.is_some(), o.info)
}

/// Adjusts `poses` (camera from world; those with `fixed[i]` stay) and
/// `points` (world) to the observations. Returns the inlier flag of every
/// observation after the outlier stage.
pub fn bundle_adjust(
    cam: &Camera,
    poses: &mut [Isometry3<f64>],
    fixed: &[bool],
    points: &mut [Vector3<f64>],
    obs: &[BaObservation],
) -> Vec<bool> {
    let mut inlier = vec![true; obs.len()];
    optimise(cam, poses, fixed, points, obs, &inlier, 5, true);
    for (i, o) in obs.iter().enumerate() {
        inlier[i] = residual(cam, &poses[o.pose], &points[o.point], o)
            .is_some_and(|(r, _)| chi2(&r, o) <= threshold(o));
    }
    optimise(cam, poses, fixed, points, obs, &inlier, 10, false);
    for (i, o) in obs.iter().enumerate() {
        inlier[i] = inlier[i]
            && residual(cam, &poses[o.pose], &points[o.point], o)
                .is_some_and(|(r, _)| chi2(&r, o) <= threshold(o));
    }
    inlier
}

#[allow(clippy::too_many_arguments)]
fn optimise(
    cam: &Camera,
    poses: &mut [Isometry3<f64>],
    fixed: &[bool],
    points: &mut [Vector3<f64>],
    obs: &[BaObservation],
    use_: &[bool],
    iterations: usize,
    robust: bool,
) {
    // Free poses get consecutive indices in the reduced system.
    let mut slot = vec![usize::MAX; poses.len()];
    let mut free = 0;
    for (i, f) in fixed.iter().enumerate() {
        if !f {
            slot[i] = free;
            free += 1;
        }
    }
    let problem = Problem {
        cam,
        obs,
        use_,
        robust,
        slot,
        free,
    };
    let mut current = problem.cost(poses, points);
    let mut lambda = 1e-4;
    for _ in 0..iterations {
        let normal = problem.normal_equations(poses, points);
        let mut improved = false;
        for _ in 0..5 {
            let Some((dp, inv_mm)) = problem.solve(&normal, lambda) else {
                lambda *= 10.0;
                continue;
            };
            let (cand_poses, cand_points) = problem.step(poses, points, &normal, &dp, &inv_mm);
            let c = problem.cost(&cand_poses, &cand_points);
            if c < current {
                let change = dp.norm();
                poses.copy_from_slice(&cand_poses);
                points.copy_from_slice(&cand_points);
                improved = (current - c) > 1e-9 * current.max(1.0) || change > 1e-9;
                current = c;
                lambda = (lambda * 0.3).max(1e-7);
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
}

/// The normal equations of one Levenberg-Marquardt iteration, in blocks.
struct Normal {
    /// Per free pose (by slot): its 6x6 block and gradient.
    h_pp: Vec<nalgebra::Matrix6<f64>>,
    g_p: Vec<Vector6<f64>>,
    /// Per point: its 3x3 block and gradient.
    h_mm: Vec<Matrix3<f64>>,
    g_m: Vec<Vector3<f64>>,
    /// (free pose slot, point, H_pm block) per observation, grouped by
    /// point for the Schur complement.
    h_pm: Vec<(usize, usize, Matrix3x6<f64>)>,
}

/// The free poses' step, and each point block's damped inverse (None:
/// singular, the point stays).
type Solution = (DVector<f64>, Vec<Option<Matrix3<f64>>>);

/// A bundle adjustment: the observations used, the kernel, and where each
/// free pose sits in the reduced system.
struct Problem<'a> {
    cam: &'a Camera,
    obs: &'a [BaObservation],
    use_: &'a [bool],
    robust: bool,
    /// Per pose: its slot among the free ones, `usize::MAX` when fixed.
    slot: Vec<usize>,
    free: usize,
}

impl Problem<'_> {
    /// The (robust) cost of the used observations.
    fn cost(&self, poses: &[Isometry3<f64>], points: &[Vector3<f64>]) -> f64 {
        let (cam, obs, use_, robust) = (self.cam, self.obs, self.use_, self.robust);
        obs.iter()
            .zip(use_)
            .filter(|(_, &u)| u)
            .map(
                |(o, _)| match residual(cam, &poses[o.pose], &points[o.point], o) {
                    Some((r, _)) => {
                        let e2 = chi2(&r, o);
                        if robust {
                            huber_cost(e2, threshold(o))
                        } else {
                            e2
                        }
                    }
                    // Behind the camera: a large, finite penalty.
                    None => 1e6,
                },
            )
            .sum()
    }

    /// The normal-equation blocks at `poses` and `points`.
    fn normal_equations(&self, poses: &[Isometry3<f64>], points: &[Vector3<f64>]) -> Normal {
        let (cam, obs, use_, robust, slot, free) = (
            self.cam,
            self.obs,
            self.use_,
            self.robust,
            &self.slot,
            self.free,
        );
        let mut h_pp = vec![nalgebra::Matrix6::<f64>::zeros(); free];
        let mut g_p = vec![Vector6::<f64>::zeros(); free];
        let mut h_mm = vec![Matrix3::<f64>::zeros(); points.len()];
        let mut g_m = vec![Vector3::<f64>::zeros(); points.len()];
        // (free pose slot, point, H_pm block) per observation.
        let mut h_pm: Vec<(usize, usize, Matrix3x6<f64>)> = Vec::new();
        for (o, _) in obs.iter().zip(use_).filter(|(_, &u)| u) {
            let pose = &poses[o.pose];
            let Some((r, p)) = residual(cam, pose, &points[o.point], o) else {
                continue;
            };
            let e2 = chi2(&r, o);
            let th = threshold(o);
            let w = if robust && e2 > th {
                (th / e2).sqrt()
            } else {
                1.0
            } * o.info;
            let rows = projection_rows(cam, &p);
            let residuals = [r.x, r.y, r.z];
            let n = if o.ur.is_some() { 3 } else { 2 };
            let rot = pose.rotation.to_rotation_matrix();
            let s = slot[o.pose];
            let mut pm = Matrix3x6::<f64>::zeros();
            for (dcam, e) in rows.iter().zip(&residuals).take(n) {
                // d(pred)/d(point in world) = d(pred)/d(camera point) * R.
                let jm = rot.matrix().transpose() * dcam;
                h_mm[o.point] += w * jm * jm.transpose();
                g_m[o.point] += w * jm * *e;
                if s != usize::MAX {
                    let jp = pose_row(dcam, &p);
                    h_pp[s] += w * jp * jp.transpose();
                    g_p[s] += w * jp * *e;
                    pm += w * jm * jp.transpose();
                }
            }
            if s != usize::MAX {
                h_pm.push((s, o.point, pm));
            }
        }
        // Group the pose-point couplings by point for the Schur complement.
        h_pm.sort_by_key(|&(_, m, _)| m);

        Normal {
            h_pp,
            g_p,
            h_mm,
            g_m,
            h_pm,
        }
    }

    /// The free poses' step with damping `lambda` (points eliminated by the
    /// Schur complement), and each point block's damped inverse; None when
    /// the reduced system cannot be solved.
    fn solve(&self, normal: &Normal, lambda: f64) -> Option<Solution> {
        let free = self.free;
        let Normal {
            h_pp,
            g_p,
            h_mm,
            g_m,
            h_pm,
        } = normal;
        let damp = |m: &Matrix3<f64>| {
            let mut d = *m;
            for i in 0..3 {
                d[(i, i)] += lambda * m[(i, i)].max(1e-9);
            }
            d
        };
        let inv_mm: Vec<Option<Matrix3<f64>>> =
            h_mm.iter().map(|m| damp(m).try_inverse()).collect();
        let mut s = DMatrix::<f64>::zeros(6 * free, 6 * free);
        let mut b = DVector::<f64>::zeros(6 * free);
        for (k, (h, g)) in h_pp.iter().zip(g_p).enumerate() {
            let mut hd = *h;
            for i in 0..6 {
                hd[(i, i)] += lambda * h[(i, i)].max(1e-9);
            }
            s.view_mut((6 * k, 6 * k), (6, 6)).add_assign(&hd);
            b.rows_mut(6 * k, 6).add_assign(g);
        }
        let mut start = 0;
        while start < h_pm.len() {
            let m = h_pm[start].1;
            let mut end = start;
            while end < h_pm.len() && h_pm[end].1 == m {
                end += 1;
            }
            if let Some(inv) = inv_mm[m] {
                let group = &h_pm[start..end];
                for &(a, _, pa) in group {
                    // pa: 3x6 (point rows, pose cols) = H_mp for pose a.
                    let left = pa.transpose() * inv; // 6x3
                    b.rows_mut(6 * a, 6).sub_assign(&(left * g_m[m]));
                    for &(c, _, pc) in group {
                        s.view_mut((6 * a, 6 * c), (6, 6)).sub_assign(&(left * pc));
                    }
                }
            }
            start = end;
        }
        let dp = if free > 0 {
            s.clone().cholesky()?.solve(&b)
        } else {
            DVector::zeros(0)
        };
        if !dp.iter().all(|v| v.is_finite()) {
            return None;
        }
        Some((dp, inv_mm))
    }

    /// The candidate poses and points after step `dp` (the points'
    /// back-substituted).
    fn step(
        &self,
        poses: &[Isometry3<f64>],
        points: &[Vector3<f64>],
        normal: &Normal,
        dp: &DVector<f64>,
        inv_mm: &[Option<Matrix3<f64>>],
    ) -> (Vec<Isometry3<f64>>, Vec<Vector3<f64>>) {
        let (slot, g_m, h_pm) = (&self.slot, &normal.g_m, &normal.h_pm);
        // Back-substitution for the points.
        let mut dm: Vec<Vector3<f64>> = g_m.clone();
        for &(a, m, pa) in h_pm {
            let d: Vector6<f64> = dp.fixed_rows::<6>(6 * a).into_owned();
            dm[m] -= pa * d;
        }
        let mut cand_poses = poses.to_vec();
        for (i, pose) in cand_poses.iter_mut().enumerate() {
            if slot[i] != usize::MAX {
                let d: Vector6<f64> = dp.fixed_rows::<6>(6 * slot[i]).into_owned();
                let step = Isometry3::from_parts(
                    Translation3::from(Vector3::new(d[3], d[4], d[5])),
                    UnitQuaternion::from_scaled_axis(Vector3::new(d[0], d[1], d[2])),
                );
                *pose = renormalized(&(step * *pose));
            }
        }
        let mut cand_points = points.to_vec();
        for (m, p) in cand_points.iter_mut().enumerate() {
            if let Some(inv) = inv_mm[m] {
                let d = inv * dm[m];
                if d.iter().all(|v| v.is_finite()) {
                    *p += d;
                }
            }
        }
        (cand_poses, cand_points)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use nalgebra::Point3;

    fn camera() -> Camera {
        Camera::tum_fr1()
    }

    /// Five keyframes looking at a cloud of points; every point measured
    /// exactly in every keyframe that sees it.
    fn scene() -> (Vec<Isometry3<f64>>, Vec<Vector3<f64>>, Vec<BaObservation>) {
        let cam = camera();
        let mut rng = SplitMix64::new(7);
        let points: Vec<Vector3<f64>> = (0..300)
            .map(|_| {
                Vector3::new(
                    rng.uniform(-1.0, 1.0),
                    rng.uniform(-0.8, 0.8),
                    rng.uniform(1.5, 3.5),
                )
            })
            .collect();
        let poses: Vec<Isometry3<f64>> = (0..5)
            .map(|k| {
                let t = k as f64;
                Isometry3::from_parts(
                    Translation3::new(-0.1 * t, 0.02 * t, 0.05 * t),
                    UnitQuaternion::from_euler_angles(0.01 * t, -0.03 * t, 0.005 * t),
                )
            })
            .collect();
        let mut obs = Vec::new();
        for (k, pose) in poses.iter().enumerate() {
            for (i, p) in points.iter().enumerate() {
                let pc = pose * Point3::from(*p);
                let (u, v) = cam.project(&pc.coords);
                if (0.0..640.0).contains(&u) && (0.0..480.0).contains(&v) {
                    obs.push(BaObservation {
                        pose: k,
                        point: i,
                        u,
                        v,
                        ur: Some(u - cam.bf / pc.z),
                        info: 1.0,
                    });
                }
            }
        }
        (poses, points, obs)
    }

    #[test]
    fn perturbed_poses_and_points_return_to_the_truth() {
        let cam = camera();
        let (truth_poses, truth_points, obs) = scene();
        let mut rng = SplitMix64::new(3);
        let mut poses = truth_poses.clone();
        for p in poses.iter_mut().skip(1) {
            let noise = Isometry3::from_parts(
                Translation3::new(
                    rng.uniform(-0.02, 0.02),
                    rng.uniform(-0.02, 0.02),
                    rng.uniform(-0.02, 0.02),
                ),
                UnitQuaternion::from_euler_angles(
                    rng.uniform(-0.01, 0.01),
                    rng.uniform(-0.01, 0.01),
                    rng.uniform(-0.01, 0.01),
                ),
            );
            *p = noise * *p;
        }
        let mut points: Vec<Vector3<f64>> = truth_points
            .iter()
            .map(|p| {
                p + Vector3::new(
                    rng.uniform(-0.03, 0.03),
                    rng.uniform(-0.03, 0.03),
                    rng.uniform(-0.03, 0.03),
                )
            })
            .collect();
        let fixed = [true, false, false, false, false];
        let inlier = bundle_adjust(&cam, &mut poses, &fixed, &mut points, &obs);
        assert!(inlier.iter().all(|&b| b));
        assert_eq!(poses[0], truth_poses[0], "the fixed pose does not move");
        for (p, t) in poses.iter().zip(&truth_poses) {
            let d = p.inverse() * t;
            assert!(d.translation.vector.norm() < 1e-5, "{d:?}");
            assert!(d.rotation.angle() < 1e-6);
        }
        // Points no keyframe sees keep their (perturbed) position.
        for (i, (p, t)) in points.iter().zip(&truth_points).enumerate() {
            if obs.iter().any(|o| o.point == i) {
                assert!((p - t).norm() < 1e-5, "{p} vs {t}");
            }
        }
    }

    #[test]
    fn a_gross_outlier_is_flagged_and_does_not_pull_the_solution() {
        let cam = camera();
        let (truth_poses, truth_points, mut obs) = scene();
        obs[10].u += 40.0;
        let (mut poses, mut points) = (truth_poses.clone(), truth_points.clone());
        let fixed = [true, false, false, false, false];
        let inlier = bundle_adjust(&cam, &mut poses, &fixed, &mut points, &obs);
        assert!(!inlier[10]);
        assert_eq!(inlier.iter().filter(|&&b| !b).count(), 1);
        for (p, t) in poses.iter().zip(&truth_poses) {
            assert!((p.inverse() * t).translation.vector.norm() < 1e-4);
        }
    }
}
