//! Features: the ORB extractor (ours, or kornia-imgproc's behind the
//! `kornia` feature), the grid keypoints are searched in, and the dynamic
//! mask applied at detection.

pub mod brief;
pub mod fast;
pub mod grid;
#[cfg(feature = "kornia")]
pub mod kornia_orb;
pub mod mask;
pub mod orb;
pub mod simd;
