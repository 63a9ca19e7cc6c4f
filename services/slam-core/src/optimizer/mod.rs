//! Least-squares optimisers: motion-only pose optimisation (tracking,
//! relocalisation), local bundle adjustment (keyframe poses and points)
//! and pose-graph optimisation (the essential graph after a loop closure).

pub mod local_ba;
pub mod pose;
pub mod pose_graph;
