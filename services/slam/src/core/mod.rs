//! The SLAM core (RGB-D), usable without any IPC.
//!
//! - [`orb`]: ORB features with the dynamic mask applied at detection.
//! - [`camera`]: intrinsics, distortion, the RGB-D virtual baseline.
//! - [`optimize`]: motion-only pose optimisation.
//! - [`local_ba`]: local bundle adjustment (keyframe poses and points).
//! - [`system`]: tracking, keyframes, map, relocalisation.

pub mod camera;
pub mod local_ba;
pub mod optimize;
pub mod orb;
pub mod system;
