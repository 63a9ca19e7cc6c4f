//! Files: trajectories (TUM format), point clouds (PLY), the map file, and
//! the framing binary files share.

pub mod framed;
pub mod map_file;
pub mod ply;
pub mod trajectory;
