//! Two-view reconstruction for monocular initialisation (ORB-SLAM2's
//! Initializer): from pixel matches between a reference view and a current
//! one, a homography (planar or low-parallax scenes) and a fundamental
//! matrix (general scenes) are estimated by RANSAC on the same minimal
//! sets, each scored by its symmetric transfer error with chi-square
//! gates; the score ratio picks the model, whose motion hypotheses (8 from
//! the homography's decomposition, 4 from the essential matrix) are tested
//! by triangulating the inliers: the one with most points in front of both
//! cameras, with small reprojection error, wins if it is clearly better
//! than the others and the views have enough parallax.
//!
//! Pixels are undistorted; the motion is camera 2 from camera 1
//! (`x2 = R x1 + t`, `|t| = 1`), the points in camera 1's frame.

use nalgebra::{DMatrix, DVector, Matrix3, Matrix3x4, Vector3, Vector4};

use crate::rng::SplitMix64;

/// What a reconstruction needs; ORB-SLAM2's values by default.
#[derive(Debug, Clone, Copy)]
pub struct TwoViewParams {
    /// RANSAC iterations (each scores both models).
    pub iterations: usize,
    /// Keypoint position noise (pixels, level 0).
    pub sigma: f64,
    /// The 50th smallest parallax among the triangulated points (degrees).
    pub min_parallax_deg: f64,
    /// Fewest points triangulated well for a map to start.
    pub min_triangulated: usize,
    /// Seed of the RANSAC samples.
    pub seed: u64,
}

impl Default for TwoViewParams {
    fn default() -> Self {
        Self {
            iterations: 200,
            sigma: 1.0,
            min_parallax_deg: 1.0,
            min_triangulated: 50,
            seed: 0x1417,
        }
    }
}

/// Which model the motion came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TwoViewModel {
    /// A plane or a pure rotation (few parallax): homography.
    Homography,
    /// A general scene: fundamental matrix.
    Fundamental,
}

/// A reconstruction: camera 2 from camera 1 and the points.
#[derive(Debug, Clone)]
pub struct TwoView {
    /// Rotation of camera 2 from camera 1.
    pub rotation: Matrix3<f64>,
    /// Unit length (the scale is the map's to choose).
    pub translation: Vector3<f64>,
    /// Per match: its point in camera 1's frame where it triangulated well.
    pub points: Vec<Option<Vector3<f64>>>,
    /// The model the motion was recovered from.
    pub model: TwoViewModel,
    /// Homography score / (homography + fundamental score).
    pub score_ratio: f64,
    /// Median parallax of the triangulated points (degrees).
    pub parallax_deg: f64,
}

/// Why two views did not initialise (the caller tries a later frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TwoViewRefusal {
    /// Fewer matches than the models need.
    TooFewMatches(usize),
    /// No motion hypothesis triangulated enough points (the best count).
    TooFewPoints(usize),
    /// Enough points, too little parallax (degrees).
    TooLittleParallax(f64),
    /// Two hypotheses explain the matches about equally well.
    Ambiguous,
}

/// Matches a RANSAC sample holds (the eight-point algorithm's eight).
const SAMPLE: usize = 8;
/// Chi-square at 95 %: one degree of freedom (distance to a line), two
/// (distance to a point).
const CHI2_1DOF: f64 = 3.841;
const CHI2_2DOF: f64 = 5.991;
/// The homography is chosen above this score ratio (ORB-SLAM2: 0.40).
const HOMOGRAPHY_RATIO: f64 = 0.40;

/// Reconstructs the motion and points from `matches` ((index in `p1`,
/// index in `p2`)) between undistorted pixels `p1` and `p2` of a camera
/// with intrinsics `k`.
pub fn reconstruct(
    k: &Matrix3<f64>,
    p1: &[(f64, f64)],
    p2: &[(f64, f64)],
    matches: &[(usize, usize)],
    params: &TwoViewParams,
) -> Result<TwoView, TwoViewRefusal> {
    let n = matches.len();
    if n < SAMPLE.max(params.min_triangulated) {
        return Err(TwoViewRefusal::TooFewMatches(n));
    }
    let x1: Vec<(f64, f64)> = matches.iter().map(|&(a, _)| p1[a]).collect();
    let x2: Vec<(f64, f64)> = matches.iter().map(|&(_, b)| p2[b]).collect();
    let (n1, t1) = normalise(&x1);
    let (n2, t2) = normalise(&x2);
    let inv_sigma2 = 1.0 / (params.sigma * params.sigma);
    let mut rng = SplitMix64::new(params.seed);
    let (mut best_h, mut best_f) = (None::<Scored>, None::<Scored>);
    for _ in 0..params.iterations {
        let sample = sample_indices(&mut rng, n);
        let s1: Vec<(f64, f64)> = sample.iter().map(|&i| n1[i]).collect();
        let s2: Vec<(f64, f64)> = sample.iter().map(|&i| n2[i]).collect();
        if let Some(hn) = homography_dlt(&s1, &s2) {
            let h21 = t2.try_inverse().unwrap_or_else(Matrix3::identity) * hn * t1;
            if let Some(h12) = h21.try_inverse() {
                let scored = score_homography(&h21, &h12, &x1, &x2, inv_sigma2);
                if best_h.as_ref().is_none_or(|b| scored.score > b.score) {
                    best_h = Some(scored);
                }
            }
        }
        if let Some(f_n) = fundamental_8point(&s1, &s2) {
            let f21 = t2.transpose() * f_n * t1;
            let scored = score_fundamental(&f21, &x1, &x2, inv_sigma2);
            if best_f.as_ref().is_none_or(|b| scored.score > b.score) {
                best_f = Some(scored);
            }
        }
    }
    let (sh, sf) = (
        best_h.as_ref().map_or(0.0, |s| s.score),
        best_f.as_ref().map_or(0.0, |s| s.score),
    );
    if sh + sf <= 0.0 {
        return Err(TwoViewRefusal::TooFewPoints(0));
    }
    let ratio = sh / (sh + sf);
    let (model, scored) = if ratio > HOMOGRAPHY_RATIO {
        (TwoViewModel::Homography, best_h)
    } else {
        (TwoViewModel::Fundamental, best_f)
    };
    let scored = scored.ok_or(TwoViewRefusal::TooFewPoints(0))?;
    let inliers = scored.inliers.iter().filter(|&&b| b).count();
    let hypotheses = match model {
        TwoViewModel::Homography => decompose_homography(k, &scored.matrix),
        TwoViewModel::Fundamental => decompose_essential(&(k.transpose() * scored.matrix * k)),
    };
    let tested: Vec<Checked> = hypotheses
        .iter()
        .map(|(r, t)| {
            check_motion(
                r,
                t,
                &x1,
                &x2,
                &scored.inliers,
                k,
                4.0 * params.sigma.powi(2),
            )
        })
        .collect();
    // Hypotheses are compared by their points with parallax: a wrong
    // decomposition of a plane's homography can put most points barely in
    // front of both cameras at nearly parallel rays (measured: 237 such
    // against the true motion's 300, which ORB-SLAM2's count of all points
    // in front calls ambiguous).
    let mut order: Vec<usize> = (0..tested.len()).collect();
    order.sort_by_key(|&i| std::cmp::Reverse(tested[i].good));
    let best = &tested[order[0]];
    let min_in_front = params.min_triangulated.max((0.9 * inliers as f64) as usize);
    if best.in_front < min_in_front || best.good < params.min_triangulated {
        return Err(TwoViewRefusal::TooFewPoints(best.good));
    }
    // ORB-SLAM2: the homography's second best must be well below (0.75x);
    // of the essential matrix's four, only one may come near (0.7x).
    let similar = match model {
        TwoViewModel::Homography => {
            usize::from(tested[order[1]].good as f64 >= 0.75 * best.good as f64)
        }
        TwoViewModel::Fundamental => tested
            .iter()
            .filter(|c| c.good as f64 > 0.7 * best.good as f64)
            .count()
            .saturating_sub(1),
    };
    if similar > 0 {
        return Err(TwoViewRefusal::Ambiguous);
    }
    if best.parallax_deg < params.min_parallax_deg {
        return Err(TwoViewRefusal::TooLittleParallax(best.parallax_deg));
    }
    let (rotation, translation) = hypotheses[order[0]];
    Ok(TwoView {
        rotation,
        translation,
        points: best.points.clone(),
        model,
        score_ratio: ratio,
        parallax_deg: best.parallax_deg,
    })
}

/// Eight distinct indices below `n`.
fn sample_indices(rng: &mut SplitMix64, n: usize) -> [usize; SAMPLE] {
    let mut out = [0; SAMPLE];
    let mut taken = 0;
    while taken < SAMPLE {
        let i = rng.below(n);
        if !out[..taken].contains(&i) {
            out[taken] = i;
            taken += 1;
        }
    }
    out
}

/// Points moved to zero mean and unit mean absolute deviation per axis
/// (Hartley's normalisation, as ORB-SLAM2 does it), and the transform.
fn normalise(points: &[(f64, f64)]) -> (Vec<(f64, f64)>, Matrix3<f64>) {
    let n = points.len() as f64;
    let (mx, my) = points
        .iter()
        .fold((0.0, 0.0), |(a, b), p| (a + p.0 / n, b + p.1 / n));
    let (dx, dy) = points.iter().fold((0.0, 0.0), |(a, b), p| {
        (a + (p.0 - mx).abs() / n, b + (p.1 - my).abs() / n)
    });
    let (sx, sy) = (1.0 / dx.max(1e-12), 1.0 / dy.max(1e-12));
    let out = points
        .iter()
        .map(|p| ((p.0 - mx) * sx, (p.1 - my) * sy))
        .collect();
    let t = Matrix3::new(sx, 0.0, -mx * sx, 0.0, sy, -my * sy, 0.0, 0.0, 1.0);
    (out, t)
}

/// The unit-norm null vector of `a` (its right singular vector of the
/// smallest singular value), as a 3x3 matrix row by row.
fn null_space_3x3(a: DMatrix<f64>) -> Option<Matrix3<f64>> {
    let v = null_vector(a)?;
    let m = Matrix3::from_row_slice(v.as_slice());
    m.iter().all(|x| x.is_finite()).then_some(m)
}

/// The unit null vector of `a` (least squares): the eigenvector of the
/// symmetric AᵀA with the smallest eigenvalue (works with fewer rows than
/// columns too).
fn null_vector(a: DMatrix<f64>) -> Option<DVector<f64>> {
    let ata = a.transpose() * &a;
    let eig = nalgebra::SymmetricEigen::new(ata);
    let (i, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    Some(eig.eigenvectors.column(i).into_owned())
}

/// Homography from `a` to `b` by the direct linear transform.
fn homography_dlt(a: &[(f64, f64)], b: &[(f64, f64)]) -> Option<Matrix3<f64>> {
    let mut m = DMatrix::zeros(2 * a.len(), 9);
    for (i, (&(u1, v1), &(u2, v2))) in a.iter().zip(b).enumerate() {
        let r = 2 * i;
        m.row_mut(r)
            .copy_from_slice(&[0.0, 0.0, 0.0, -u1, -v1, -1.0, v2 * u1, v2 * v1, v2]);
        m.row_mut(r + 1)
            .copy_from_slice(&[u1, v1, 1.0, 0.0, 0.0, 0.0, -u2 * u1, -u2 * v1, -u2]);
    }
    null_space_3x3(m)
}

/// Fundamental matrix (`x_bᵀ F x_a = 0`) by the eight-point algorithm,
/// rank 2 enforced.
fn fundamental_8point(a: &[(f64, f64)], b: &[(f64, f64)]) -> Option<Matrix3<f64>> {
    let mut m = DMatrix::zeros(a.len(), 9);
    for (i, (&(u1, v1), &(u2, v2))) in a.iter().zip(b).enumerate() {
        m.row_mut(i)
            .copy_from_slice(&[u2 * u1, u2 * v1, u2, v2 * u1, v2 * v1, v2, u1, v1, 1.0]);
    }
    let f = null_space_3x3(m)?;
    let svd = f.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut w = svd.singular_values;
    // nalgebra does not promise an order: zero the smallest.
    let smallest = (0..3).min_by(|&i, &j| w[i].total_cmp(&w[j]))?;
    w[smallest] = 0.0;
    Some(u * Matrix3::from_diagonal(&w) * v_t)
}

/// A model with its RANSAC score and inlier flags.
struct Scored {
    matrix: Matrix3<f64>,
    score: f64,
    inliers: Vec<bool>,
}

fn transfer(h: &Matrix3<f64>, (u, v): (f64, f64)) -> Option<(f64, f64)> {
    let p = h * Vector3::new(u, v, 1.0);
    (p.z.abs() > 1e-12).then(|| (p.x / p.z, p.y / p.z))
}

/// Scores a model on every match: `errors` gives its two squared errors
/// (image 1, image 2, in sigmas); a match is an inlier when both pass
/// `gate`, and adds (two-degree gate - error) for each to the score, so
/// that the homography's and the fundamental matrix's scores compare.
fn score_matches(
    matrix: &Matrix3<f64>,
    x1: &[(f64, f64)],
    x2: &[(f64, f64)],
    gate: f64,
    errors: impl Fn((f64, f64), (f64, f64)) -> (f64, f64),
) -> Scored {
    let mut score = 0.0;
    let inliers = x1
        .iter()
        .zip(x2)
        .map(|(&a, &b)| {
            let (e1, e2) = errors(a, b);
            let inlier = e1 <= gate && e2 <= gate;
            if inlier {
                score += (CHI2_2DOF - e1) + (CHI2_2DOF - e2);
            }
            inlier
        })
        .collect();
    Scored {
        matrix: *matrix,
        score,
        inliers,
    }
}

/// ORB-SLAM2's CheckHomography: both transfer errors, two-degree gate.
fn score_homography(
    h21: &Matrix3<f64>,
    h12: &Matrix3<f64>,
    x1: &[(f64, f64)],
    x2: &[(f64, f64)],
    inv_sigma2: f64,
) -> Scored {
    let error = |h: &Matrix3<f64>, from: (f64, f64), to: (f64, f64)| {
        transfer(h, from)
            .map(|p| ((p.0 - to.0).powi(2) + (p.1 - to.1).powi(2)) * inv_sigma2)
            .unwrap_or(f64::INFINITY)
    };
    score_matches(h21, x1, x2, CHI2_2DOF, |a, b| {
        (error(h12, b, a), error(h21, a, b))
    })
}

/// ORB-SLAM2's CheckFundamental: distances to the epipolar lines in both
/// images, one-degree gate.
fn score_fundamental(
    f21: &Matrix3<f64>,
    x1: &[(f64, f64)],
    x2: &[(f64, f64)],
    inv_sigma2: f64,
) -> Scored {
    let line_distance = |l: Vector3<f64>, p: &Vector3<f64>| {
        let d2 = l.x * l.x + l.y * l.y;
        if d2 < 1e-24 {
            f64::INFINITY
        } else {
            l.dot(p).powi(2) / d2 * inv_sigma2
        }
    };
    score_matches(f21, x1, x2, CHI2_1DOF, |(u1, v1), (u2, v2)| {
        let (a1, a2) = (Vector3::new(u1, v1, 1.0), Vector3::new(u2, v2, 1.0));
        (
            line_distance(f21.transpose() * a2, &a1),
            line_distance(f21 * a1, &a2),
        )
    })
}

/// The four motions of an essential matrix: R in {U W Vᵀ, U Wᵀ Vᵀ}, t = ±u3.
fn decompose_essential(e: &Matrix3<f64>) -> Vec<(Matrix3<f64>, Vector3<f64>)> {
    let svd = e.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Vec::new();
    };
    let smallest = (0..3)
        .min_by(|&i, &j| svd.singular_values[i].total_cmp(&svd.singular_values[j]))
        .unwrap_or(2);
    let t = u.column(smallest).normalize();
    let w = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    // With the singular values unordered, rebuild U and V with the null
    // direction last so that W acts on the right pair.
    let order: Vec<usize> = (0..3)
        .filter(|&i| i != smallest)
        .chain([smallest])
        .collect();
    let u = Matrix3::from_columns(&[u.column(order[0]), u.column(order[1]), u.column(order[2])]);
    let v = v_t.transpose();
    let v = Matrix3::from_columns(&[v.column(order[0]), v.column(order[1]), v.column(order[2])]);
    let proper = |r: Matrix3<f64>| if r.determinant() < 0.0 { -r } else { r };
    let r1 = proper(u * w * v.transpose());
    let r2 = proper(u * w.transpose() * v.transpose());
    vec![(r1, t), (r1, -t), (r2, t), (r2, -t)]
}

/// The eight motions of a homography (Faugeras' decomposition, as
/// ORB-SLAM2's ReconstructH): `A = K⁻¹ H K = U diag(d1 d2 d3) Vᵀ`.
fn decompose_homography(k: &Matrix3<f64>, h21: &Matrix3<f64>) -> Vec<(Matrix3<f64>, Vector3<f64>)> {
    let Some(k_inv) = k.try_inverse() else {
        return Vec::new();
    };
    let a = k_inv * h21 * k;
    let svd = a.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Vec::new();
    };
    let mut order = [0usize, 1, 2];
    order.sort_by(|&i, &j| svd.singular_values[j].total_cmp(&svd.singular_values[i]));
    let u = Matrix3::from_columns(&[u.column(order[0]), u.column(order[1]), u.column(order[2])]);
    let v = v_t.transpose();
    let v = Matrix3::from_columns(&[v.column(order[0]), v.column(order[1]), v.column(order[2])]);
    let v_t = v.transpose();
    let (d1, d2, d3) = (
        svd.singular_values[order[0]],
        svd.singular_values[order[1]],
        svd.singular_values[order[2]],
    );
    if d1 / d2 < 1.00001 || d2 / d3 < 1.00001 {
        return Vec::new();
    }
    let s = u.determinant() * v_t.determinant();
    let aux1 = ((d1 * d1 - d2 * d2) / (d1 * d1 - d3 * d3)).sqrt();
    let aux3 = ((d2 * d2 - d3 * d3) / (d1 * d1 - d3 * d3)).sqrt();
    let x1 = [aux1, aux1, -aux1, -aux1];
    let x3 = [aux3, -aux3, aux3, -aux3];
    let mut out = Vec::with_capacity(8);
    // d' = d2.
    let aux_stheta = ((d1 * d1 - d2 * d2) * (d2 * d2 - d3 * d3)).sqrt() / ((d1 + d3) * d2);
    let ctheta = (d2 * d2 + d1 * d3) / ((d1 + d3) * d2);
    let stheta = [aux_stheta, -aux_stheta, -aux_stheta, aux_stheta];
    for i in 0..4 {
        let rp = Matrix3::new(
            ctheta, 0.0, -stheta[i], 0.0, 1.0, 0.0, stheta[i], 0.0, ctheta,
        );
        let r = s * u * rp * v_t;
        let tp = Vector3::new(x1[i], 0.0, -x3[i]) * (d1 - d3);
        out.push((r, (u * tp).normalize()));
    }
    // d' = -d2.
    let aux_sphi = ((d1 * d1 - d2 * d2) * (d2 * d2 - d3 * d3)).sqrt() / ((d1 - d3) * d2);
    let cphi = (d1 * d3 - d2 * d2) / ((d1 - d3) * d2);
    let sphi = [aux_sphi, -aux_sphi, -aux_sphi, aux_sphi];
    for i in 0..4 {
        let rp = Matrix3::new(cphi, 0.0, sphi[i], 0.0, -1.0, 0.0, sphi[i], 0.0, -cphi);
        let r = s * u * rp * v_t;
        let tp = Vector3::new(x1[i], 0.0, x3[i]) * (d1 + d3);
        out.push((r, (u * tp).normalize()));
    }
    out
}

/// Linear triangulation of pixel `a` in camera `p1` and `b` in `p2`.
pub fn triangulate(
    p1: &Matrix3x4<f64>,
    p2: &Matrix3x4<f64>,
    (u1, v1): (f64, f64),
    (u2, v2): (f64, f64),
) -> Option<Vector3<f64>> {
    let mut a = DMatrix::zeros(4, 4);
    a.row_mut(0).copy_from(&(p1.row(2) * u1 - p1.row(0)));
    a.row_mut(1).copy_from(&(p1.row(2) * v1 - p1.row(1)));
    a.row_mut(2).copy_from(&(p2.row(2) * u2 - p2.row(0)));
    a.row_mut(3).copy_from(&(p2.row(2) * v2 - p2.row(1)));
    let c = null_vector(a)?;
    let x = Vector4::new(c[0], c[1], c[2], c[3]);
    (x.w.abs() > 1e-12)
        .then(|| Vector3::new(x.x / x.w, x.y / x.w, x.z / x.w))
        .filter(|p| p.iter().all(|c| c.is_finite()))
}

/// How well one motion explains the inliers.
struct Checked {
    /// Inliers triangulated in front of both cameras, and those of them
    /// with parallax.
    in_front: usize,
    good: usize,
    parallax_deg: f64,
    points: Vec<Option<Vector3<f64>>>,
}

/// ORB-SLAM2's CheckRT: triangulates every inlier with motion (r, t);
/// a point counts when it lies in front of both cameras and reprojects
/// within `th2` (squared pixels) in both, and is good when its rays are
/// not nearly parallel. The parallax is the 50th smallest among those
/// that count.
fn check_motion(
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    x1: &[(f64, f64)],
    x2: &[(f64, f64)],
    inliers: &[bool],
    k: &Matrix3<f64>,
    th2: f64,
) -> Checked {
    let mut p1 = Matrix3x4::zeros();
    p1.fixed_view_mut::<3, 3>(0, 0).copy_from(k);
    let mut rt = Matrix3x4::zeros();
    rt.fixed_view_mut::<3, 3>(0, 0).copy_from(r);
    rt.fixed_view_mut::<3, 1>(0, 3).copy_from(t);
    let p2 = k * rt;
    let o2 = -r.transpose() * t;
    let project = |p: &Vector3<f64>| {
        let q = k * p;
        (q.x / q.z, q.y / q.z)
    };
    let mut points = vec![None; x1.len()];
    let mut cos_parallax = Vec::new();
    for i in (0..x1.len()).filter(|&i| inliers[i]) {
        let Some(x) = triangulate(&p1, &p2, x1[i], x2[i]) else {
            continue;
        };
        let (n1, n2) = (x.norm(), (x - o2).norm());
        let cos = x.dot(&(x - o2)) / (n1 * n2);
        let x_c2 = r * x + t;
        // In front of both cameras (ORB-SLAM2 lets nearly parallel rays
        // through here; they never become points anyway).
        if x.z <= 0.0 || x_c2.z <= 0.0 {
            continue;
        }
        let e = |(u, v): (f64, f64), (pu, pv): (f64, f64)| (u - pu).powi(2) + (v - pv).powi(2);
        if e(x1[i], project(&x)) > th2 || e(x2[i], project(&x_c2)) > th2 {
            continue;
        }
        cos_parallax.push(cos);
        if cos < 0.99998 {
            points[i] = Some(x);
        }
    }
    let good = points.iter().filter(|p| p.is_some()).count();
    let parallax_deg = if cos_parallax.is_empty() {
        0.0
    } else {
        cos_parallax.sort_by(|a, b| b.total_cmp(a));
        let idx = (cos_parallax.len() - 1).min(50);
        cos_parallax[idx].clamp(-1.0, 1.0).acos().to_degrees()
    };
    Checked {
        in_front: cos_parallax.len(),
        good,
        parallax_deg,
        points,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, UnitQuaternion};

    type Pixels = Vec<(f64, f64)>;

    fn k() -> Matrix3<f64> {
        Matrix3::new(517.3, 0.0, 318.6, 0.0, 516.5, 255.3, 0.0, 0.0, 1.0)
    }

    /// Pixels of `points` (camera-1 frame) in both cameras, with noise.
    fn views(
        points: &[Vector3<f64>],
        r: &Matrix3<f64>,
        t: &Vector3<f64>,
        noise: f64,
        seed: u64,
    ) -> (Pixels, Pixels) {
        let mut rng = SplitMix64::new(seed);
        let k = k();
        let mut px = |p: Vector3<f64>| {
            let q = k * p;
            (
                q.x / q.z + rng.uniform(-noise, noise),
                q.y / q.z + rng.uniform(-noise, noise),
            )
        };
        let a = points.iter().map(|p| px(*p)).collect();
        let b = points.iter().map(|p| px(r * p + t)).collect();
        (a, b)
    }

    fn motion() -> (Matrix3<f64>, Vector3<f64>) {
        let r = UnitQuaternion::from_euler_angles(0.02, -0.05, 0.01)
            .to_rotation_matrix()
            .into_inner();
        (r, Vector3::new(-0.3, 0.02, 0.05))
    }

    fn check(result: &TwoView, truth: &[Vector3<f64>], r: &Matrix3<f64>, t: &Vector3<f64>) {
        let angle = Rotation3::from_matrix(&(result.rotation.transpose() * r)).angle();
        assert!(
            angle.to_degrees() < 0.3,
            "rotation off by {} deg",
            angle.to_degrees()
        );
        let dir = result.translation.dot(&t.normalize());
        assert!(dir > 0.995, "translation direction off: cos {dir}");
        // The points, at the scale |t| = 1: scaled to the truth's (the
        // median ratio of distances: a small error in the direction of t
        // changes every depth by about the same factor).
        let mut ratios: Vec<f64> = result
            .points
            .iter()
            .zip(truth)
            .filter_map(|(p, x)| p.map(|p| x.norm() / p.norm()))
            .collect();
        ratios.sort_by(f64::total_cmp);
        let scale = ratios[ratios.len() / 2];
        assert!(
            (scale / t.norm() - 1.0).abs() < 0.1,
            "scale {scale} vs |t| {}",
            t.norm()
        );
        let mut errors: Vec<f64> = result
            .points
            .iter()
            .zip(truth)
            .filter_map(|(p, x)| p.map(|p| (p * scale - x).norm() / x.norm()))
            .collect();
        let good = errors.len();
        assert!(
            good as f64 > 0.8 * truth.len() as f64,
            "{good} of {} points",
            truth.len()
        );
        errors.sort_by(f64::total_cmp);
        let (median, worst) = (errors[good / 2], errors[good - 1]);
        eprintln!("{good} points, relative error median {median:.4}, worst {worst:.4}");
        assert!(
            median < 0.01 && worst < 0.1,
            "median {median}, worst {worst}"
        );
    }

    /// 300 points at 2-6 m scattered in depth, in the view of camera 1.
    fn general_scene(seed: u64) -> Vec<Vector3<f64>> {
        let mut rng = SplitMix64::new(seed);
        (0..300)
            .map(|_| {
                let z = rng.uniform(2.0, 6.0);
                Vector3::new(
                    rng.uniform(-0.55, 0.55) * z,
                    rng.uniform(-0.45, 0.45) * z,
                    z,
                )
            })
            .collect()
    }

    /// Point i of view 1 matched to point i of view 2.
    fn same_indices(n: usize) -> Vec<(usize, usize)> {
        (0..n).map(|i| (i, i)).collect()
    }

    /// A general scene (points at 2-6 m scattered in depth): the
    /// fundamental matrix explains it, and the motion and points come back.
    #[test]
    fn a_general_scene_is_reconstructed_from_the_fundamental_matrix() {
        let truth = general_scene(3);
        let (r, t) = motion();
        let (a, b) = views(&truth, &r, &t, 0.5, 9);
        let matches = same_indices(truth.len());
        let result = reconstruct(&k(), &a, &b, &matches, &TwoViewParams::default()).unwrap();
        assert_eq!(
            result.model,
            TwoViewModel::Fundamental,
            "ratio {}",
            result.score_ratio
        );
        check(&result, &truth, &r, &t);
    }

    /// A plane (a wall 3 m away, tilted): the homography explains it.
    #[test]
    fn a_plane_is_reconstructed_from_the_homography() {
        let mut rng = SplitMix64::new(4);
        let truth: Vec<Vector3<f64>> = (0..300)
            .map(|_| {
                let (x, y) = (rng.uniform(-1.5, 1.5), rng.uniform(-1.1, 1.1));
                Vector3::new(x, y, 3.0 + 0.3 * x)
            })
            .collect();
        let (r, t) = motion();
        let (a, b) = views(&truth, &r, &t, 0.5, 10);
        let matches = same_indices(truth.len());
        let result = reconstruct(&k(), &a, &b, &matches, &TwoViewParams::default()).unwrap();
        assert_eq!(
            result.model,
            TwoViewModel::Homography,
            "ratio {}",
            result.score_ratio
        );
        check(&result, &truth, &r, &t);
    }

    /// Outliers (a fifth of the matches wrong) do not stop it; a pure
    /// rotation (no parallax) and too few matches are refused.
    #[test]
    fn outliers_are_survived_and_degenerate_views_refused() {
        let truth = general_scene(5);
        let mut rng = SplitMix64::new(5);
        let (r, t) = motion();
        let (a, mut b) = views(&truth, &r, &t, 0.5, 11);
        for bi in b.iter_mut().step_by(5) {
            *bi = (rng.uniform(0.0, 640.0), rng.uniform(0.0, 480.0));
        }
        let matches = same_indices(truth.len());
        let result = reconstruct(&k(), &a, &b, &matches, &TwoViewParams::default()).unwrap();
        let angle = Rotation3::from_matrix(&(result.rotation.transpose() * r)).angle();
        assert!(angle.to_degrees() < 0.3);
        assert!(result.translation.dot(&t.normalize()) > 0.99);
        // Pure rotation: every hypothesis lacks parallax.
        let (a, b) = views(&truth, &r, &Vector3::zeros(), 0.5, 12);
        assert!(reconstruct(&k(), &a, &b, &matches, &TwoViewParams::default()).is_err());
        let few = &matches[..30];
        assert_eq!(
            reconstruct(&k(), &a, &b, few, &TwoViewParams::default()).unwrap_err(),
            TwoViewRefusal::TooFewMatches(30)
        );
    }
}
