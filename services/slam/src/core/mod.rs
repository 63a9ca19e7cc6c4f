//! The SLAM core (RGB-D), usable without any IPC.
//!
//! - [`orb`]: ORB features with the dynamic mask applied at detection.
//! - `kornia_orb` (feature `kornia`): kornia-imgproc's ORB behind the same call.
//! - [`camera`]: intrinsics, distortion, the RGB-D virtual baseline.
//! - [`grid`]: keypoints bucketed for radius search.
//! - [`optimize`]: motion-only pose optimisation.
//! - [`map`]: keyframes, points, covisibility; what local mapping does to them.
//! - [`triangulation`]: new points from keypoints two keyframes saw without depth.
//! - [`fusion`]: duplicate points merged across covisible keyframes.
//! - [`local_mapping`]: the thread local mapping runs on.
//! - [`local_ba`]: local bundle adjustment (keyframe poses and points).
//! - [`pnp`]: pose from 2D-3D matches (relocalisation without depth).
//! - [`system`]: tracking, keyframes, map, relocalisation.

pub mod camera;
pub mod fusion;
pub mod grid;
#[cfg(feature = "kornia")]
pub mod kornia_orb;
pub mod local_ba;
pub mod local_mapping;
pub mod map;
pub mod optimize;
pub mod orb;
pub mod pnp;
pub mod system;
pub mod triangulation;
