//! Trajectory evaluation: ATE after Umeyama alignment and RPE, defined as
//! the established tool `evo` defines them, so that the figures agree with
//! `evo_ape` / `evo_rpe` on the same files (tests/eval_parity.rs checks it).
//!
//! - Association: each pose of the shorter trajectory takes the nearest
//!   timestamp of the longer one within `max_diff` (evo's `nearest_time`).
//! - ATE: translation error after aligning the estimate to the reference
//!   (SE(3) for RGB-D, Sim(3) for monocular, Umeyama 1991).
//! - RPE: error of relative motions between consecutive associated poses
//!   (per frame, evo's default), and TUM-style over 1 s intervals.

use std::path::Path;

use nalgebra::{Isometry3, Point3, UnitQuaternion, Vector3};
use serde::Serialize;

use crate::geometry::alignment::{umeyama, Similarity};
use crate::io::trajectory::{Trajectory, TrajectoryError};

/// How the estimate is aligned to the reference before ATE.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Alignment {
    /// As estimated (the trajectories already share a frame).
    None,
    /// Rotation + translation (RGB-D, stereo).
    Se3,
    /// Rotation + translation + scale (monocular).
    Sim3,
}

/// Statistics of an error series, with evo's names and definitions
/// (population standard deviation).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Default)]
pub struct Stats {
    /// Root mean square.
    pub rmse: f64,
    /// Mean.
    pub mean: f64,
    /// Median.
    pub median: f64,
    /// Population standard deviation.
    pub std: f64,
    /// Smallest.
    pub min: f64,
    /// Largest.
    pub max: f64,
    /// Sum of squares.
    pub sse: f64,
    /// Number of errors.
    pub count: usize,
}

impl Stats {
    /// The statistics of `errors` (all zero for none).
    pub fn of(errors: &[f64]) -> Self {
        let n = errors.len();
        if n == 0 {
            return Self::default();
        }
        let mut sorted = errors.to_vec();
        sorted.sort_by(f64::total_cmp);
        let sse: f64 = errors.iter().map(|e| e * e).sum();
        let mean = errors.iter().sum::<f64>() / n as f64;
        let var = errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / n as f64;
        let median = if n % 2 == 1 {
            sorted[n / 2]
        } else {
            0.5 * (sorted[n / 2 - 1] + sorted[n / 2])
        };
        Self {
            rmse: (sse / n as f64).sqrt(),
            mean,
            median,
            std: var.sqrt(),
            min: sorted[0],
            max: sorted[n - 1],
            sse,
            count: n,
        }
    }
}

/// evo's nearest-time association: indices into `first` and `second` of
/// the matched poses, in order of the shorter trajectory.
pub fn associate(
    first: &Trajectory,
    second: &Trajectory,
    max_diff: f64,
) -> (Vec<usize>, Vec<usize>) {
    let second_longer = second.len() > first.len();
    let (short, long) = if second_longer {
        (first, second)
    } else {
        (second, first)
    };
    let (short_ids, long_ids) = nearest_matches(&short.stamps, &long.stamps, max_diff);
    if second_longer {
        (short_ids, long_ids)
    } else {
        (long_ids, short_ids)
    }
}

/// For each stamp of `a`, the nearest stamp of `b` within `max_diff`.
fn nearest_matches(a: &[f64], b: &[f64], max_diff: f64) -> (Vec<usize>, Vec<usize>) {
    let mut ia = Vec::new();
    let mut ib = Vec::new();
    if b.is_empty() {
        return (ia, ib);
    }
    let sorted = b.windows(2).all(|w| w[1] >= w[0]);
    for (i, &t) in a.iter().enumerate() {
        let best = if sorted {
            if t < b[0] - max_diff || t > b[b.len() - 1] + max_diff {
                continue;
            }
            // Ties go to the earlier stamp, as in evo.
            let j = b.partition_point(|&x| x <= t).min(b.len() - 1);
            let ub = b[j] - t;
            let lb = if j > 0 { t - b[j - 1] } else { f64::INFINITY };
            if ub <= max_diff && ub < lb {
                j
            } else if lb <= max_diff && lb <= ub {
                j - 1
            } else {
                continue;
            }
        } else {
            let (j, d) = b
                .iter()
                .enumerate()
                .map(|(j, &x)| (j, (x - t).abs()))
                .min_by(|p, q| p.1.total_cmp(&q.1))
                .unwrap();
            if d > max_diff {
                continue;
            }
            j
        };
        ia.push(i);
        ib.push(best);
    }
    (ia, ib)
}

/// Rotation angle of a relative rotation, in degrees (robust near 0).
fn angle_deg(r: &UnitQuaternion<f64>) -> f64 {
    r.angle().to_degrees()
}

/// Relative pose errors between the index pairs.
fn relative_errors(
    reference: &[Isometry3<f64>],
    estimate: &[Isometry3<f64>],
    pairs: &[(usize, usize)],
) -> (Vec<f64>, Vec<f64>) {
    pairs
        .iter()
        .map(|&(i, j)| {
            let q_rel = reference[i].inverse() * reference[j];
            let p_rel = estimate[i].inverse() * estimate[j];
            let e = q_rel.inverse() * p_rel;
            (e.translation.vector.norm(), angle_deg(&e.rotation))
        })
        .unzip()
}

/// Options of [`evaluate`].
#[derive(Debug, Clone, Copy)]
pub struct EvalOptions {
    /// How the estimate is aligned before ATE.
    pub alignment: Alignment,
    /// Association tolerance (seconds); the TUM benchmark uses 0.02.
    pub max_diff: f64,
    /// Interval of the time-based RPE (seconds).
    pub rpe_interval_s: f64,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            alignment: Alignment::Se3,
            max_diff: 0.02,
            rpe_interval_s: 1.0,
        }
    }
}

/// Everything `dynslam eval` reports.
#[derive(Debug, Clone, Serialize)]
pub struct EvalSummary {
    /// The alignment used.
    pub alignment: Alignment,
    /// Scale of the alignment (1 unless Sim(3)).
    pub scale: f64,
    /// Estimated poses associated with a ground-truth pose.
    pub pairs: usize,
    /// Poses in the ground truth.
    pub gt_poses: usize,
    /// Poses in the estimate.
    pub est_poses: usize,
    /// ATE: root mean square of the position errors (metres).
    pub ate_rmse_m: f64,
    /// ATE: mean (metres).
    pub ate_mean_m: f64,
    /// ATE: median (metres).
    pub ate_median_m: f64,
    /// ATE: standard deviation (metres).
    pub ate_std_m: f64,
    /// ATE: smallest error (metres).
    pub ate_min_m: f64,
    /// ATE: largest error (metres).
    pub ate_max_m: f64,
    /// Per-frame RPE (consecutive associated poses), as `evo_rpe`'s default.
    pub rpe_trans_rmse_m: f64,
    /// Per-frame RPE: mean translation error (metres).
    pub rpe_trans_mean_m: f64,
    /// Per-frame RPE: root mean square of the rotation error (degrees).
    pub rpe_rot_rmse_deg: f64,
    /// Per-frame RPE: mean rotation error (degrees).
    pub rpe_rot_mean_deg: f64,
    /// RPE over `rpe_interval_s` (TUM's per-second drift).
    pub rpe_interval_s: f64,
    /// Pose pairs `rpe_interval_s` apart.
    pub rpe_interval_pairs: usize,
    /// Interval RPE: root mean square of the translation error (metres).
    pub rpe_interval_trans_rmse_m: f64,
    /// Interval RPE: root mean square of the rotation error (degrees).
    pub rpe_interval_rot_rmse_deg: f64,
    /// Per associated pose: timestamp, ATE (m); for plots and reports.
    #[serde(skip)]
    pub ate_series: Vec<(f64, f64)>,
    /// Associated reference and aligned estimate positions.
    #[serde(skip)]
    pub positions: Vec<(Point3<f64>, Point3<f64>)>,
}

/// Why a trajectory could not be evaluated.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// A trajectory file could not be read.
    #[error(transparent)]
    Trajectory(#[from] TrajectoryError),
    /// Too few estimated poses have a ground-truth pose at their time.
    #[error("only {pairs} poses of the estimate match ground-truth timestamps within {max_diff} s; at least 3 are needed")]
    TooFewPairs {
        /// Associated poses.
        pairs: usize,
        /// The association tolerance (seconds).
        max_diff: f64,
    },
    /// All associated positions coincide: no alignment.
    #[error("the alignment is degenerate (all associated positions coincide)")]
    Degenerate,
}

/// Evaluates `estimate` against `reference`.
pub fn evaluate(
    reference: &Trajectory,
    estimate: &Trajectory,
    opts: EvalOptions,
) -> Result<EvalSummary, EvalError> {
    let (ri, ei) = associate(reference, estimate, opts.max_diff);
    if ri.len() < 3 {
        return Err(EvalError::TooFewPairs {
            pairs: ri.len(),
            max_diff: opts.max_diff,
        });
    }
    let gt = reference.select(&ri);
    let est = estimate.select(&ei);
    let xs: Vec<Vector3<f64>> = est.poses.iter().map(|p| p.translation.vector).collect();
    let ys: Vec<Vector3<f64>> = gt.poses.iter().map(|p| p.translation.vector).collect();
    let align = match opts.alignment {
        Alignment::None => Similarity::identity(),
        Alignment::Se3 => umeyama(&xs, &ys, false).ok_or(EvalError::Degenerate)?,
        Alignment::Sim3 => umeyama(&xs, &ys, true).ok_or(EvalError::Degenerate)?,
    };
    let aligned: Vec<Isometry3<f64>> = est.poses.iter().map(|p| align.apply_pose(p)).collect();
    let ate: Vec<f64> = aligned
        .iter()
        .zip(&gt.poses)
        .map(|(e, g)| (e.translation.vector - g.translation.vector).norm())
        .collect();
    let ate_stats = Stats::of(&ate);

    let consecutive: Vec<(usize, usize)> = (1..gt.len()).map(|j| (j - 1, j)).collect();
    let (rpe_t, rpe_r) = relative_errors(&gt.poses, &aligned, &consecutive);
    // Pairs `rpe_interval_s` apart by the estimate's timestamps, the one
    // closest to it (as the TUM benchmark's evaluate_rpe.py picks them).
    let stamps = &est.stamps;
    let last = stamps.last().copied().unwrap_or(f64::NEG_INFINITY);
    let interval: Vec<(usize, usize)> = (0..est.len())
        .filter_map(|i| {
            let target = stamps[i] + opts.rpe_interval_s;
            if target > last + opts.max_diff {
                return None;
            }
            let j = stamps.partition_point(|&t| t < target);
            let j = [j.checked_sub(1), Some(j)]
                .into_iter()
                .flatten()
                .filter(|&j| j > i && j < stamps.len())
                .min_by(|&a, &b| {
                    (stamps[a] - target)
                        .abs()
                        .total_cmp(&(stamps[b] - target).abs())
                })?;
            Some((i, j))
        })
        .collect();
    let (int_t, int_r) = relative_errors(&gt.poses, &aligned, &interval);
    let (st, sr, it, ir) = (
        Stats::of(&rpe_t),
        Stats::of(&rpe_r),
        Stats::of(&int_t),
        Stats::of(&int_r),
    );
    Ok(EvalSummary {
        alignment: opts.alignment,
        scale: align.scale,
        pairs: gt.len(),
        gt_poses: reference.len(),
        est_poses: estimate.len(),
        ate_rmse_m: ate_stats.rmse,
        ate_mean_m: ate_stats.mean,
        ate_median_m: ate_stats.median,
        ate_std_m: ate_stats.std,
        ate_min_m: ate_stats.min,
        ate_max_m: ate_stats.max,
        rpe_trans_rmse_m: st.rmse,
        rpe_trans_mean_m: st.mean,
        rpe_rot_rmse_deg: sr.rmse,
        rpe_rot_mean_deg: sr.mean,
        rpe_interval_s: opts.rpe_interval_s,
        rpe_interval_pairs: interval.len(),
        rpe_interval_trans_rmse_m: it.rmse,
        rpe_interval_rot_rmse_deg: ir.rmse,
        ate_series: gt.stamps.iter().copied().zip(ate).collect(),
        positions: gt
            .poses
            .iter()
            .zip(&aligned)
            .map(|(g, e)| {
                (
                    Point3::from(g.translation.vector),
                    Point3::from(e.translation.vector),
                )
            })
            .collect(),
    })
}

/// Loads both files and evaluates.
pub fn evaluate_files(gt: &Path, est: &Path, opts: EvalOptions) -> Result<EvalSummary, EvalError> {
    let reference = Trajectory::load_tum(gt)?;
    let estimate = Trajectory::load_tum(est)?;
    evaluate(&reference, &estimate, opts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    fn circle(n: usize, dt: f64) -> Trajectory {
        let poses = (0..n)
            .map(|i| {
                let a = i as f64 * 0.05;
                Isometry3::from_parts(
                    Vector3::new(a.cos(), a.sin(), 0.1 * a).into(),
                    UnitQuaternion::from_euler_angles(0.1 * a, 0.2, a),
                )
            })
            .collect();
        Trajectory {
            stamps: (0..n).map(|i| 100.0 + i as f64 * dt).collect(),
            poses,
        }
    }

    #[test]
    fn umeyama_recovers_a_similarity() {
        let truth = Similarity {
            rotation: Rotation3::from_euler_angles(0.3, -0.2, 1.1),
            translation: Vector3::new(1.0, -2.0, 0.5),
            scale: 2.5,
        };
        let x: Vec<Vector3<f64>> = (0..20)
            .map(|i| Vector3::new((i as f64).sin(), (i as f64 * 0.7).cos(), i as f64 * 0.1))
            .collect();
        let y: Vec<Vector3<f64>> = x.iter().map(|p| truth.apply_point(p)).collect();
        let est = umeyama(&x, &y, true).unwrap();
        assert!((est.scale - 2.5).abs() < 1e-9);
        assert!((est.translation - truth.translation).norm() < 1e-9);
        assert!((est.rotation.matrix() - truth.rotation.matrix()).norm() < 1e-9);
        let rigid = umeyama(&x, &y, false).unwrap();
        assert_eq!(rigid.scale, 1.0);
    }

    #[test]
    fn rigidly_moved_copy_has_zero_ate_and_rpe() {
        let gt = circle(200, 0.01);
        let moved = Similarity {
            rotation: Rotation3::from_euler_angles(0.5, 0.1, -0.7),
            translation: Vector3::new(3.0, 1.0, -1.0),
            scale: 1.0,
        };
        let est = Trajectory {
            stamps: gt.stamps.iter().map(|t| t + 0.003).collect(),
            poses: gt.poses.iter().map(|p| moved.apply_pose(p)).collect(),
        };
        let s = evaluate(&gt, &est, EvalOptions::default()).unwrap();
        assert_eq!(s.pairs, 200);
        assert!(s.ate_rmse_m < 1e-9, "{}", s.ate_rmse_m);
        assert!(s.rpe_trans_rmse_m < 1e-9 && s.rpe_rot_rmse_deg < 1e-6);
        // Without alignment the offset shows.
        let raw = evaluate(
            &gt,
            &est,
            EvalOptions {
                alignment: Alignment::None,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(raw.ate_rmse_m > 1.0);
    }

    #[test]
    fn sim3_corrects_scale_and_se3_does_not() {
        let gt = circle(100, 0.03);
        let est = Trajectory {
            stamps: gt.stamps.clone(),
            poses: gt
                .poses
                .iter()
                .map(|p| Isometry3::from_parts((p.translation.vector * 0.5).into(), p.rotation))
                .collect(),
        };
        let sim = evaluate(
            &gt,
            &est,
            EvalOptions {
                alignment: Alignment::Sim3,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(sim.ate_rmse_m < 1e-9 && (sim.scale - 2.0).abs() < 1e-9);
        let se3 = evaluate(&gt, &est, EvalOptions::default()).unwrap();
        assert!(se3.ate_rmse_m > 0.1);
    }

    #[test]
    fn association_takes_nearest_within_tolerance_like_evo() {
        let a = [1.0, 2.0, 3.0, 4.0];
        let b = [0.995, 1.5, 2.012, 2.988, 3.03];
        let (ia, ib) = nearest_matches(&a, &b, 0.02);
        assert_eq!(ia, vec![0, 1, 2]);
        assert_eq!(ib, vec![0, 2, 3]);
        // A tie goes to the earlier stamp.
        let (_, ib) = nearest_matches(&[2.0], &[1.5, 2.5], 0.5);
        assert_eq!(ib, vec![0]);
    }

    #[test]
    fn too_few_pairs_is_an_error() {
        let gt = circle(10, 0.01);
        let far = Trajectory {
            stamps: gt.stamps.iter().map(|t| t + 50.0).collect(),
            poses: gt.poses.clone(),
        };
        let err = evaluate(&gt, &far, EvalOptions::default()).unwrap_err();
        assert!(err.to_string().contains("only 0 poses"), "{err}");
    }

    #[test]
    fn stats_match_numpy_definitions() {
        let s = Stats::of(&[1.0, 2.0, 3.0, 4.0]);
        assert!((s.rmse - (30.0f64 / 4.0).sqrt()).abs() < 1e-12);
        assert_eq!(s.median, 2.5);
        assert!((s.std - 1.25f64.sqrt()).abs() < 1e-12);
        assert_eq!((s.min, s.max, s.sse), (1.0, 4.0, 30.0));
    }
}
