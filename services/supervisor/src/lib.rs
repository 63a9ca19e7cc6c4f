//! The supervisor: launches, watches and restarts the services, routes each
//! frame by SLAM's keyframe flag, records every frame's fate (in the run
//! folder, see the `run-folder` crate) and reports per-stage latency. The
//! `dynslam` binary is its command line; the offline tools it offers live in
//! the `evaluation` crate.

#![deny(missing_docs)]

pub mod ablation;
pub mod children;
pub mod default_scene;
pub mod external;
pub mod map_files;
pub mod ros2_camera;
pub mod run;
