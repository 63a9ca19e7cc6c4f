//! Least-squares optimisers: motion-only pose optimisation (tracking,
//! relocalisation) and local bundle adjustment (keyframe poses and points).

pub mod local_ba;
pub mod pose;
