//! Dynamic scenes with exact ground truth.
//!
//! - [`sprites`]: real photographs of people with alpha masks, embedded in
//!   the binary (public domain / CC0, provenance in `assets/PROVENANCE.md`).
//! - [`walkers`]: where each person is at a given time: smooth walks at
//!   about 1 m/s across the view, fixed in the world frame.
//! - [`composite`]: draws people into one RGB-D frame with depth-consistent
//!   occlusion and writes their instance ids into a label image.
//! - [`room`]: the embedded default input, a rendered textured room with a
//!   moving camera and exact depth and poses, people walked through it.
//! - [`sensor`]: what a real camera does to a render: depth noise, holes
//!   and quantisation (Kinect, RealSense), motion blur.
//! - [`truth`]: scoring predicted masks against those ground-truth masks.
//! - [`synth`]: `dynslam synth`, a TUM folder in, a dynamic TUM folder with
//!   per-frame ground-truth masks and the objects' paths out.

#![deny(missing_docs)]

pub mod composite;
pub mod room;
pub mod sensor;
pub mod sprites;
pub mod synth;
pub mod truth;
pub mod walkers;
