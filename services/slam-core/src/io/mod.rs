//! Files: trajectories (TUM format), point clouds (PLY) and the map file.

pub mod map_file;
pub mod ply;
pub mod trajectory;
