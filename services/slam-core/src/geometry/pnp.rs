//! Camera pose from 2D-3D matches (Perspective-n-Point), for relocalising
//! a frame whose keypoints lack depth: RANSAC ([`super::ransac`]) over samples of six matches,
//! each solved by the normalised direct linear transform, scored by
//! reprojection error (chi-square at 95 %, per pyramid level as the pose
//! optimiser does), then the best hypothesis refined by the motion-only
//! optimiser on its inliers.
//!
//! kornia's PnP (kornia-pnp 0.1, EPnP) depends on nalgebra 0.32 and
//! kornia-3d 0.2 on faer and kiddo; the workspace keeps one nalgebra and a
//! small tree, so this is ours.

use nalgebra::{
    DMatrix, Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3,
};

use super::ransac::Ransac;
use crate::camera::Camera;
use crate::optimizer::pose::{chi2_threshold, is_finite_pose, optimize_pose, Observation};

/// A map point matched to an (undistorted) keypoint.
#[derive(Debug, Clone, Copy)]
pub struct PnpMatch {
    /// The map point (world frame).
    pub world: Vector3<f64>,
    /// Its keypoint's undistorted pixel, column.
    pub u: f64,
    /// Its keypoint's undistorted pixel, row.
    pub v: f64,
    /// 1 / sigma^2 of the keypoint's pyramid level.
    pub info: f64,
}

const SAMPLE: usize = 6;

/// Camera-from-world pose that best explains `matches` (RANSAC, then
/// refinement), with at least `min_inliers` inliers; None otherwise.
pub fn pnp_ransac(
    camera: &Camera,
    matches: &[PnpMatch],
    iterations: usize,
    min_inliers: usize,
) -> Option<(Isometry3<f64>, usize)> {
    if matches.len() < SAMPLE.max(min_inliers) {
        return None;
    }
    let search = Ransac {
        sample: SAMPLE,
        iterations,
        seed: 0x9E3779B9,
    };
    let (mut pose, inlying) = search.run(
        matches.len(),
        |sample| {
            dlt_pose(
                camera,
                &sample.iter().map(|&i| matches[i]).collect::<Vec<_>>(),
            )
        },
        |pose, i| inlier(camera, pose, &matches[i]),
    )?;
    if inlying.len() < min_inliers {
        return None;
    }
    // A hypothesis from six noisy matches is rough: refine on its inliers,
    // then once more on the inliers of the refined pose among all matches.
    let mut n = 0;
    for _ in 0..2 {
        let obs: Vec<Observation> = matches
            .iter()
            .zip(inliers(camera, &pose, matches))
            .filter(|(_, inlier)| *inlier)
            .map(|(m, _)| Observation {
                world: m.world,
                u: m.u,
                v: m.v,
                ur: None,
                info: m.info,
            })
            .collect();
        let (refined, inlier) = optimize_pose(camera, &pose, &obs);
        pose = refined;
        n = inlier.iter().filter(|&&b| b).count();
    }
    (is_finite_pose(&pose) && n >= min_inliers).then_some((pose, n))
}

fn inliers<'a>(
    camera: &'a Camera,
    pose: &'a Isometry3<f64>,
    matches: &'a [PnpMatch],
) -> impl Iterator<Item = bool> + 'a {
    matches.iter().map(move |m| inlier(camera, pose, m))
}

/// The match reprojects within the chi-square bound (2 degrees of freedom,
/// 95 %) of its level.
fn inlier(camera: &Camera, pose: &Isometry3<f64>, m: &PnpMatch) -> bool {
    let pc = pose * Point3::from(m.world);
    if pc.z <= 0.0 {
        return false;
    }
    let (u, v) = camera.project(&pc.coords);
    ((u - m.u).powi(2) + (v - m.v).powi(2)) * m.info < chi2_threshold(false)
}

/// The pose from at least six matches by the direct linear transform on
/// normalised coordinates (world points centred and scaled), its 3x3 part
/// projected onto a rotation. None for a degenerate set (e.g. coplanar or
/// collinear points, where the DLT has no unique solution).
pub fn dlt_pose(camera: &Camera, matches: &[PnpMatch]) -> Option<Isometry3<f64>> {
    let n = matches.len();
    if n < SAMPLE {
        return None;
    }
    let centre = matches.iter().map(|m| m.world).sum::<Vector3<f64>>() / n as f64;
    let spread = matches
        .iter()
        .map(|m| (m.world - centre).norm())
        .sum::<f64>()
        / n as f64;
    if spread < 1e-9 {
        return None;
    }
    let scale = 3f64.sqrt() / spread;
    // Rows of A p = 0 for P (3x4, row-major in p) mapping normalised world
    // points to normalised image coordinates.
    let mut a = DMatrix::<f64>::zeros(2 * n, 12);
    for (i, m) in matches.iter().enumerate() {
        let w = (m.world - centre) * scale;
        let ray = camera.unproject(m.u, m.v, 1.0);
        let (x, y) = (ray.x, ray.y);
        let h = [w.x, w.y, w.z, 1.0];
        for j in 0..4 {
            a[(2 * i, j)] = h[j];
            a[(2 * i, 8 + j)] = -x * h[j];
            a[(2 * i + 1, 4 + j)] = h[j];
            a[(2 * i + 1, 8 + j)] = -y * h[j];
        }
    }
    // The null vector: the eigenvector of A^T A with the smallest eigenvalue.
    let ata = a.transpose() * &a;
    let eig = ata.symmetric_eigen();
    let (k, smallest) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|x, y| x.1.total_cmp(y.1))?;
    let largest = eig.eigenvalues.iter().fold(0.0f64, |m, &v| m.max(v.abs()));
    let second = eig
        .eigenvalues
        .iter()
        .enumerate()
        .filter(|&(i, _)| i != k)
        .map(|(_, &v)| v)
        .fold(f64::INFINITY, f64::min);
    // A second (near) null vector: no unique solution.
    if second <= 1e-10 * largest || !smallest.is_finite() {
        return None;
    }
    let p = eig.eigenvectors.column(k);
    let m = Matrix3::new(p[0], p[1], p[2], p[4], p[5], p[6], p[8], p[9], p[10]);
    let t = Vector3::new(p[3], p[7], p[11]);
    // P ~ s [R | t']: sign so that det(R) = +1, scale from the singular values.
    let sign = m.determinant().signum();
    if sign == 0.0 {
        return None;
    }
    let (m, t) = (m * sign, t * sign);
    let svd = m.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let s = svd.singular_values.mean();
    let mut r = u * vt;
    if r.determinant() < 0.0 {
        return None;
    }
    r = Rotation3::from_matrix_unchecked(r).into_inner();
    // Undo the normalisation: x ~ R (scale (X - c)) + t / s
    //                         = (scale R) X + (t / s - scale R c), up to scale.
    let translation = (t / s - scale * r * centre) / scale;
    let pose = Isometry3::from_parts(
        Translation3::from(translation),
        UnitQuaternion::from_matrix(&r),
    );
    // Points must lie in front of the camera.
    let in_front = matches
        .iter()
        .filter(|m| (pose * Point3::from(m.world)).z > 0.0)
        .count();
    (in_front * 2 > n).then_some(pose)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    fn camera() -> Camera {
        Camera::tum_fr1()
    }

    /// Points spread over a room 1-4 m in front of the true camera, seen at
    /// `truth`, with `outliers` of them moved to random pixels.
    fn scene(truth: &Isometry3<f64>, n: usize, outliers: usize, noise_px: f64) -> Vec<PnpMatch> {
        let cam = camera();
        let mut rng = SplitMix64::new(7);
        (0..n)
            .map(|i| {
                let pc = Vector3::new(
                    rng.uniform(-1.5, 1.5),
                    rng.uniform(-1.0, 1.0),
                    rng.uniform(1.0, 4.0),
                );
                let world = (truth.inverse() * Point3::from(pc)).coords;
                let (mut u, mut v) = cam.project(&pc);
                u += rng.uniform(-noise_px, noise_px);
                v += rng.uniform(-noise_px, noise_px);
                if i < outliers {
                    (u, v) = (rng.uniform(0.0, 640.0), rng.uniform(0.0, 480.0));
                }
                PnpMatch {
                    world,
                    u,
                    v,
                    info: 1.0,
                }
            })
            .collect()
    }

    fn truth() -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(0.3, -0.2, 0.5),
            UnitQuaternion::from_euler_angles(0.2, -0.4, 0.1),
        )
    }

    fn error(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
        let d = a.inverse() * b;
        (d.translation.vector.norm(), d.rotation.angle())
    }

    #[test]
    fn dlt_recovers_an_exact_pose_from_six_points() {
        let truth = truth();
        let pose = dlt_pose(&camera(), &scene(&truth, 6, 0, 0.0)).unwrap();
        let (t, r) = error(&truth, &pose);
        assert!(t < 1e-6 && r < 1e-6, "{t} m {r} rad");
    }

    #[test]
    fn ransac_finds_the_pose_through_noise_and_40_percent_outliers() {
        let truth = truth();
        let matches = scene(&truth, 100, 40, 1.0);
        let (pose, n) = pnp_ransac(&camera(), &matches, 300, 30).unwrap();
        let (t, r) = error(&truth, &pose);
        assert!(t < 0.01 && r < 0.005, "{t} m {r} rad");
        assert!((55..=60).contains(&n), "{n} inliers");
    }

    #[test]
    fn too_few_or_degenerate_matches_give_no_pose() {
        let cam = camera();
        let truth = truth();
        assert!(pnp_ransac(&cam, &scene(&truth, 20, 0, 0.0), 50, 25).is_none());
        // All six points on one line.
        let line: Vec<PnpMatch> = (0..6)
            .map(|i| {
                let pc = Vector3::new(0.1 * i as f64, 0.0, 2.0);
                let (u, v) = cam.project(&pc);
                PnpMatch {
                    world: pc,
                    u,
                    v,
                    info: 1.0,
                }
            })
            .collect();
        assert!(dlt_pose(&cam, &line).is_none());
    }
}
