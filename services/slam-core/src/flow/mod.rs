//! Optical flow: grey float images, their pyramids and pyramidal
//! Lucas-Kanade point tracking. Tracking follows the map points between
//! keyframes with it (`SlamParams::flow_frames`); the propagator follows
//! objects' points with it.

pub mod lk;
pub mod pyramid;
