//! The one RANSAC driver. Relocalisation's 3D-3D fit and PnP differ only
//! in how a model is fitted to a sample and what an inlier is; sampling,
//! scoring and the choice of the best hypothesis live here. Seeded, so a
//! run is repeatable. The rigid 3D-3D search (relocalisation on depth, the
//! loop transform) is [`rigid_ransac`].

use nalgebra::{Isometry3, Point3, Vector3};

use super::alignment::{fit_rigid, umeyama, Similarity};
use crate::rng::SplitMix64;

/// The rigid transform mapping the first point of each pair onto the
/// second, by RANSAC over 3-point fits (inliers within `threshold`),
/// refitted on its inliers; with the inliers' indices.
pub(crate) fn rigid_ransac(
    pairs: &[(Vector3<f64>, Vector3<f64>)],
    threshold: f64,
    iterations: usize,
    seed: u64,
) -> Option<(Isometry3<f64>, Vec<usize>)> {
    let search = Ransac {
        sample: 3,
        iterations,
        seed,
    };
    let (_, inliers) = search.run(
        pairs.len(),
        |s| fit_rigid(&s.iter().map(|&i| pairs[i]).collect::<Vec<_>>()),
        |t, i| ((t * Point3::from(pairs[i].0)).coords - pairs[i].1).norm() < threshold,
    )?;
    let refit = fit_rigid(&inliers.iter().map(|&i| pairs[i]).collect::<Vec<_>>())?;
    Some((refit, inliers))
}

/// The similarity mapping the first point of each pair onto the second, by
/// RANSAC over 3-point Umeyama fits with scale (what an inlier is, the
/// caller says: a monocular map's distances have no unit), refitted on its
/// inliers; with the inliers' indices.
pub(crate) fn similarity_ransac(
    pairs: &[(Vector3<f64>, Vector3<f64>)],
    iterations: usize,
    seed: u64,
    mut is_inlier: impl FnMut(&Similarity, usize) -> bool,
) -> Option<(Similarity, Vec<usize>)> {
    let fit = |s: &[usize]| {
        let (from, to): (Vec<_>, Vec<_>) = s.iter().map(|&i| pairs[i]).unzip();
        umeyama(&from, &to, true)
    };
    let search = Ransac {
        sample: 3,
        iterations,
        seed,
    };
    let (_, inliers) = search.run(pairs.len(), fit, &mut is_inlier)?;
    let refit = fit(&inliers)?;
    // The refit keeps only the inliers it still explains.
    let kept: Vec<usize> = inliers
        .into_iter()
        .filter(|&i| is_inlier(&refit, i))
        .collect();
    Some((refit, kept))
}

/// What one RANSAC search is asked for.
#[derive(Debug, Clone, Copy)]
pub struct Ransac {
    /// Elements per sample (drawn without repetition).
    pub sample: usize,
    /// Hypotheses tried.
    pub iterations: usize,
    /// Seed of the samples (runs repeat exactly).
    pub seed: u64,
}

impl Ransac {
    /// Over `n` elements: fits a model to each sample (`fit`, None for a
    /// degenerate sample) and counts the elements `is_inlier` accepts; the
    /// model with most inliers wins (the first of equals). Returns it with
    /// its inliers' indices, or None when `n` is below a sample or no
    /// sample gave a model.
    pub fn run<M>(
        &self,
        n: usize,
        mut fit: impl FnMut(&[usize]) -> Option<M>,
        mut is_inlier: impl FnMut(&M, usize) -> bool,
    ) -> Option<(M, Vec<usize>)> {
        if n < self.sample || self.sample == 0 {
            return None;
        }
        let mut rng = SplitMix64::new(self.seed);
        let mut sample = vec![0usize; self.sample];
        let mut best: Option<(M, Vec<usize>)> = None;
        for _ in 0..self.iterations {
            for i in 0..self.sample {
                sample[i] = loop {
                    let j = rng.below(n);
                    if !sample[..i].contains(&j) {
                        break j;
                    }
                };
            }
            let Some(model) = fit(&sample) else {
                continue;
            };
            let inliers: Vec<usize> = (0..n).filter(|&i| is_inlier(&model, i)).collect();
            if best.as_ref().is_none_or(|b| inliers.len() > b.1.len()) {
                best = Some((model, inliers));
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A line y = a x + b through 30 points, 10 of them far off it.
    #[test]
    fn finds_the_model_most_elements_agree_with() {
        let points: Vec<(f64, f64)> = (0..40)
            .map(|i| {
                let x = i as f64;
                if i % 4 == 0 {
                    (x, 100.0 - x)
                } else {
                    (x, 2.0 * x + 1.0)
                }
            })
            .collect();
        let search = Ransac {
            sample: 2,
            iterations: 50,
            seed: 1,
        };
        let (line, inliers) = search
            .run(
                points.len(),
                |s| {
                    let ((x0, y0), (x1, y1)) = (points[s[0]], points[s[1]]);
                    let a = (y1 - y0) / (x1 - x0);
                    a.is_finite().then_some((a, y0 - a * x0))
                },
                |&(a, b), i| (points[i].1 - (a * points[i].0 + b)).abs() < 1e-6,
            )
            .unwrap();
        assert!((line.0 - 2.0).abs() < 1e-9 && (line.1 - 1.0).abs() < 1e-9);
        assert_eq!(inliers.len(), 30);
        assert!(search.run(1, |_| Some(()), |_, _| true).is_none());
    }
}
