//! Least-squares alignment of point sets: Umeyama's similarity (rotation,
//! translation, optional scale). The one home of it: relocalisation's
//! 3D-3D fits, the loop transform and `dynslam eval`'s trajectory
//! alignment all use it. [`Similarity`] is also the Sim(3) of monocular
//! loop closing: a camera-from-world pose whose world is off in scale.

use std::ops::Mul;

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// A similarity transform `y = scale * R x + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity {
    /// Rotation.
    pub rotation: Rotation3<f64>,
    /// Translation.
    pub translation: Vector3<f64>,
    /// Scale (1 for a rigid transform).
    pub scale: f64,
}

impl Similarity {
    /// The transform that changes nothing.
    pub fn identity() -> Self {
        Self {
            rotation: Rotation3::identity(),
            translation: Vector3::zeros(),
            scale: 1.0,
        }
    }

    /// `s R p + t`.
    pub fn apply_point(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.scale * (self.rotation * p) + self.translation
    }

    /// Applies the transform to a pose (scales its translation).
    pub fn apply_pose(&self, pose: &Isometry3<f64>) -> Isometry3<f64> {
        let t = self.apply_point(&pose.translation.vector);
        let r = UnitQuaternion::from_rotation_matrix(&self.rotation) * pose.rotation;
        Isometry3::from_parts(t.into(), r)
    }

    /// A rigid transform as a similarity of scale 1.
    pub fn from_isometry(t: &Isometry3<f64>) -> Self {
        Self {
            rotation: t.rotation.to_rotation_matrix(),
            translation: t.translation.vector,
            scale: 1.0,
        }
    }

    /// Read as a camera-from-world pose `x_c = s R x_w + t`: the rigid pose
    /// of the same camera once the world is measured in the similarity's
    /// scale (rotation R, translation t / s). That is how a Sim(3) loop
    /// correction becomes keyframe poses again (ORB-SLAM2's CorrectLoop).
    pub fn to_pose(&self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(self.translation / self.scale),
            UnitQuaternion::from_rotation_matrix(&self.rotation),
        )
    }

    /// The transform that undoes this one.
    pub fn inverse(&self) -> Self {
        let rotation = self.rotation.inverse();
        let scale = 1.0 / self.scale;
        Self {
            rotation,
            translation: -(scale * (rotation * self.translation)),
            scale,
        }
    }
}

/// `a * b` applies `b` first, then `a`.
impl Mul for Similarity {
    type Output = Similarity;

    fn mul(self, b: Similarity) -> Similarity {
        Similarity {
            rotation: self.rotation * b.rotation,
            translation: self.apply_point(&b.translation),
            scale: self.scale * b.scale,
        }
    }
}

/// Umeyama's least-squares similarity mapping points `x` onto `y`
/// (same as evo's `umeyama_alignment`).
pub fn umeyama(x: &[Vector3<f64>], y: &[Vector3<f64>], with_scale: bool) -> Option<Similarity> {
    let n = x.len();
    if n < 3 || y.len() != n {
        return None;
    }
    let mean_x = x.iter().sum::<Vector3<f64>>() / n as f64;
    let mean_y = y.iter().sum::<Vector3<f64>>() / n as f64;
    let sigma_x = x.iter().map(|p| (p - mean_x).norm_squared()).sum::<f64>() / n as f64;
    let mut cov = Matrix3::zeros();
    for (px, py) in x.iter().zip(y) {
        cov += (py - mean_y) * (px - mean_x).transpose();
    }
    cov /= n as f64;
    let svd = cov.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let d = svd.singular_values;
    // Reflection guard on the smallest singular value (numpy sorts them;
    // nalgebra does not).
    let mut s = Vector3::new(1.0, 1.0, 1.0);
    if u.determinant() * v_t.determinant() < 0.0 {
        s[d.imin()] = -1.0;
    }
    let r = u * Matrix3::from_diagonal(&s) * v_t;
    let scale = if with_scale {
        if sigma_x <= 0.0 {
            return None;
        }
        d.component_mul(&s).sum() / sigma_x
    } else {
        1.0
    };
    let rotation = Rotation3::from_matrix_unchecked(r);
    Some(Similarity {
        rotation,
        translation: mean_y - scale * (rotation * mean_x),
        scale,
    })
}

/// The rigid transform (no scale) mapping points `from` onto `to` in the
/// least-squares sense; None for fewer than three pairs or a degenerate set.
pub fn fit_rigid(pairs: &[(Vector3<f64>, Vector3<f64>)]) -> Option<Isometry3<f64>> {
    let (from, to): (Vec<_>, Vec<_>) = pairs.iter().copied().unzip();
    let s = umeyama(&from, &to, false)?;
    let rotation = UnitQuaternion::from_rotation_matrix(&s.rotation);
    Some(Isometry3::from_parts(s.translation.into(), rotation))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Translation3};

    #[test]
    fn a_rigid_motion_is_recovered_exactly() {
        let truth = Isometry3::from_parts(
            Translation3::new(0.3, -0.1, 0.2),
            UnitQuaternion::from_euler_angles(0.1, 0.2, -0.3),
        );
        let pairs: Vec<(Vector3<f64>, Vector3<f64>)> = (0..10)
            .map(|i| {
                let f = i as f64;
                let a = Vector3::new(f.sin(), (0.7 * f).cos(), 1.0 + 0.03 * f);
                (a, (truth * Point3::from(a)).coords)
            })
            .collect();
        let t = fit_rigid(&pairs).unwrap();
        assert!((t.translation.vector - truth.translation.vector).norm() < 1e-9);
        assert!(t.rotation.angle_to(&truth.rotation) < 1e-9);
        assert!(fit_rigid(&pairs[..2]).is_none());
    }

    #[test]
    fn similarities_compose_invert_and_give_poses() {
        let a = Similarity {
            rotation: Rotation3::from_euler_angles(0.1, -0.2, 0.3),
            translation: Vector3::new(0.5, -0.1, 2.0),
            scale: 2.0,
        };
        let b = Similarity {
            rotation: Rotation3::from_euler_angles(-0.3, 0.1, 0.05),
            translation: Vector3::new(-1.0, 0.4, 0.2),
            scale: 0.7,
        };
        let x = Vector3::new(0.3, 1.2, -0.8);
        let ab = a * b;
        assert!((ab.apply_point(&x) - a.apply_point(&b.apply_point(&x))).norm() < 1e-12);
        assert!((a.inverse().apply_point(&a.apply_point(&x)) - x).norm() < 1e-12);
        // The pose of a camera whose world is scaled by 2: it sees x where
        // the similarity puts it, at half the depth.
        let seen = a.to_pose() * Point3::from(x);
        assert!((2.0 * seen.coords - a.apply_point(&x)).norm() < 1e-12);
        let rigid = Isometry3::from_parts(
            Translation3::new(0.1, 0.2, 0.3),
            UnitQuaternion::from_euler_angles(0.2, 0.0, -0.1),
        );
        let back = Similarity::from_isometry(&rigid).to_pose();
        assert!((back.translation.vector - rigid.translation.vector).norm() < 1e-12);
        assert!(back.rotation.angle_to(&rigid.rotation) < 1e-12);
    }

    #[test]
    fn a_scaled_copy_gives_its_scale() {
        let x: Vec<Vector3<f64>> = (0..8)
            .map(|i| Vector3::new(i as f64, (i * i) as f64 * 0.1, (i as f64).cos()))
            .collect();
        let y: Vec<Vector3<f64>> = x
            .iter()
            .map(|p| 2.5 * p + Vector3::new(1.0, 2.0, 3.0))
            .collect();
        let s = umeyama(&x, &y, true).unwrap();
        assert!((s.scale - 2.5).abs() < 1e-9);
        assert!((s.apply_point(&x[3]) - y[3]).norm() < 1e-9);
    }
}
