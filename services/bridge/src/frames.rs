//! Coordinate frames: the SLAM's world-from-camera poses as REP-105 frames.
//!
//! The SLAM's world frame is the first camera's optical frame (x right,
//! y down, z forward). The robot is `base_frame`, the camera is mounted on
//! it by `camera_xyz` / `camera_rpy` (base -> camera). The published pose of
//! the base in the map is
//!
//! `map_T_base = map_T_world * world_T_camera * (base_T_camera)^-1`
//!
//! with `map_T_world` the identity for `world_frame = "optical"`, and the
//! mounting itself for `"ros"`: the map is then the base frame at the first
//! frame, REP-103's x forward, y left, z up for a robot that stands upright.

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};

use crate::msgs::RosPose;

/// The frames of a run, fixed by its config.
#[derive(Debug, Clone)]
pub struct Frames {
    /// `map` from the SLAM's world frame.
    pub map_t_world: Isometry3<f64>,
    /// The robot's base from the camera's optical frame.
    pub base_t_camera: Isometry3<f64>,
}

/// base -> camera from a translation and roll, pitch, yaw (radians, about
/// the fixed x, y, z axes: tf2's `setRPY`).
pub fn mounting(xyz: [f64; 3], rpy: [f64; 3]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(xyz[0], xyz[1], xyz[2]),
        UnitQuaternion::from_euler_angles(rpy[0], rpy[1], rpy[2]),
    )
}

/// A TUM pose (tx ty tz qx qy qz qw) as an isometry; `None` when its
/// quaternion is not a rotation (zero or not a number).
pub fn from_tum(p: &[f64; 7]) -> Option<Isometry3<f64>> {
    if p.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let q = Quaternion::new(p[6], p[3], p[4], p[5]);
    if q.norm() < 1e-9 {
        return None;
    }
    Some(Isometry3::from_parts(
        Translation3::new(p[0], p[1], p[2]),
        UnitQuaternion::from_quaternion(q),
    ))
}

/// A pose as ROS 2 writes it (position, quaternion x y z w).
pub fn to_ros(t: &Isometry3<f64>) -> RosPose {
    let q = t.rotation.quaternion();
    RosPose {
        position: [t.translation.x, t.translation.y, t.translation.z],
        orientation: [q.i, q.j, q.k, q.w],
    }
}

impl Frames {
    /// `world_frame`: "ros" or "optical" (validated with the config).
    pub fn new(world_frame: &str, base_t_camera: Isometry3<f64>) -> Self {
        let map_t_world = if world_frame == "optical" {
            Isometry3::identity()
        } else {
            base_t_camera
        };
        Self {
            map_t_world,
            base_t_camera,
        }
    }

    /// The base in the map from the SLAM's world-from-camera pose.
    pub fn map_t_base(&self, world_t_camera: &Isometry3<f64>) -> Isometry3<f64> {
        self.map_t_world * world_t_camera * self.base_t_camera.inverse()
    }
}

/// Velocity between two poses of the base `dt` seconds apart, in the base's
/// own axes (nav_msgs/Odometry's twist is in `child_frame_id`).
pub fn twist(before: &Isometry3<f64>, after: &Isometry3<f64>, dt: f64) -> ([f64; 3], [f64; 3]) {
    let rel = before.inverse() * after;
    let v: Vector3<f64> = rel.translation.vector / dt;
    let w: Vector3<f64> = rel.rotation.scaled_axis() / dt;
    ([v.x, v.y, v.z], [w.x, w.y, w.z])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
        (a.translation.vector - b.translation.vector).norm() < 1e-12
            && a.rotation.angle_to(&b.rotation) < 1e-12
    }

    #[test]
    fn the_default_mounting_points_the_optical_axis_forward() {
        let m = mounting(
            [0.0; 3],
            [
                -std::f64::consts::FRAC_PI_2,
                0.0,
                -std::f64::consts::FRAC_PI_2,
            ],
        );
        let forward = m.rotation * Vector3::z();
        let right = m.rotation * Vector3::x();
        let down = m.rotation * Vector3::y();
        assert!((forward - Vector3::x()).norm() < 1e-12);
        assert!((right + Vector3::y()).norm() < 1e-12);
        assert!((down + Vector3::z()).norm() < 1e-12);
    }

    #[test]
    fn the_ros_map_is_the_base_at_the_first_frame() {
        let m = mounting([0.1, 0.0, 0.3], [-1.2, 0.1, -1.5]);
        let f = Frames::new("ros", m);
        assert!(close(
            &f.map_t_base(&Isometry3::identity()),
            &Isometry3::identity()
        ));
        // A camera that moved 1 m along its optical axis: the base moved 1 m
        // along the map's x for the optical default mounting.
        let f = Frames::new(
            "ros",
            mounting(
                [0.0; 3],
                [
                    -std::f64::consts::FRAC_PI_2,
                    0.0,
                    -std::f64::consts::FRAC_PI_2,
                ],
            ),
        );
        let moved = Isometry3::translation(0.0, 0.0, 1.0);
        let b = f.map_t_base(&moved);
        assert!((b.translation.vector - Vector3::x()).norm() < 1e-12);
        // "optical" with the identity mounting is the SLAM's pose itself.
        let f = Frames::new("optical", Isometry3::identity());
        let p = from_tum(&[1.0, 2.0, 3.0, 0.0, 0.0, 0.6, 0.8]).unwrap();
        assert!(close(&f.map_t_base(&p), &p));
    }

    #[test]
    fn bad_quaternions_are_refused_and_twists_are_in_the_base_frame() {
        assert!(from_tum(&[0.0; 7]).is_none());
        assert!(from_tum(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, f64::NAN]).is_none());
        let a = Isometry3::from_parts(
            Translation3::new(0.0, 0.0, 0.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2),
        );
        // Facing +y in the map, it moved 0.5 m along the map's +y: forward.
        let b = Isometry3::from_parts(Translation3::new(0.0, 0.5, 0.0), a.rotation);
        let (v, w) = twist(&a, &b, 0.5);
        assert!((v[0] - 1.0).abs() < 1e-12 && v[1].abs() < 1e-12);
        assert!(w.iter().all(|x| x.abs() < 1e-12));
    }
}
