//! dynslam's SLAM core: ORB-SLAM2's RGB-D system in Rust, with dynamic-
//! object masks applied at feature detection. A library with no IPC in it:
//! feed it frames (and masks), get poses and a map. The SLAM service
//! (`services/slam`) is a thin shell that converts shared-memory frames to
//! [`frame::RgbdInput`] and results to the wire types.
//!
//! Module map (ORB-SLAM2's, one concern each):
//! - [`features`]: ORB extraction, the keypoint grid, dynamic-mask filtering.
//! - [`flow`]: grey pyramids and pyramidal Lucas-Kanade (frames between
//!   keyframes tracked without extraction; the propagator's point tracking).
//! - [`frame`]: one frame's features, undistorted, with depth.
//! - [`map`]: keyframes and points in arenas with stable ids, covisibility
//!   graph, spanning tree; the mutation API and its invariants.
//! - [`matcher`]: matching by projection, by descriptor, along epipolar lines.
//! - [`tracking`]: motion model, local map, keyframe decision,
//!   relocalisation, rolling-shutter correction.
//! - [`initialization`]: the first keyframe.
//! - [`local_mapping`]: culling, triangulation, fusion, local BA, on its own
//!   thread; map checkpoints.
//! - [`geometry`]: the RANSAC driver, Umeyama alignment, PnP.
//! - [`place_recognition`]: the ORB vocabulary (bag of words) and the
//!   keyframe database; relocalisation finds its candidates there.
//! - [`optimizer`]: motion-only pose optimisation, local bundle adjustment.
//! - [`io`]: trajectories, PLY, the map file.
//! - [`eval`]: ATE / RPE as evo defines them.
//! - [`system`]: the facade.
//!
//! - [`loop_closing`]: loop detection (bag of words, consistency), the SE(3)
//!   loop transform, loop fusion and the essential-graph correction.

#![deny(missing_docs)]

pub mod camera;
pub mod eval;
pub mod features;
pub mod flow;
pub mod frame;
pub mod geometry;
pub mod initialization;
pub mod io;
pub mod local_mapping;
pub mod loop_closing;
pub mod map;
pub mod matcher;
pub mod optimizer;
pub mod params;
pub mod place_recognition;
pub mod rng;
pub mod system;
pub mod tracking;

pub use camera::Camera;
pub use frame::RgbdInput;
pub use io::map_file::{MapFile, MapFileError};
pub use params::{Sensor, SlamParams};
pub use system::{FrameCounts, FrameResult, KeyframeTiming, Pace, System};
pub use tracking::TrackingState;
