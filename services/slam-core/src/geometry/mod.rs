//! Geometry shared by tracking, relocalisation and evaluation: the one
//! RANSAC driver, the one least-squares alignment (Umeyama), PnP, and a
//! pose as a matrix for moving many points.

use nalgebra::{Isometry3, Matrix3, Vector3};

pub mod alignment;
pub mod pnp;
pub mod ransac;

/// A pose as its rotation matrix and translation: the pose optimisation
/// and the search by projection move hundreds of points by one pose, and a
/// matrix product is 9 multiplications a point where the quaternion's is ~30.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PoseMatrix {
    rotation: Matrix3<f64>,
    translation: Vector3<f64>,
}

impl PoseMatrix {
    pub(crate) fn of(pose: &Isometry3<f64>) -> Self {
        Self {
            rotation: *pose.rotation.to_rotation_matrix().matrix(),
            translation: pose.translation.vector,
        }
    }

    /// `world` in the camera frame.
    pub(crate) fn apply(&self, world: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * world + self.translation
    }
}
