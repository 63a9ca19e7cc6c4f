//! Recorded inputs, as every service and tool reads them: no IPC, no
//! configuration types, so that the SLAM library, the workers' benches and
//! the evaluation tools read a dataset the way the camera-reader plays it.
//!
//! - [`source`]: what to play (TUM RGB-D folders, plain image folders, a
//!   folder's ground-truth masks) as a list of [`source::FrameEntry`],
//!   validated up front so that a malformed list fails at start with the
//!   file and line; [`source::repeated`] plays a list several times.
//! - [`decode`]: PNG decoding straight into the destination bytes (the
//!   loaned shared-memory sample, in the camera-reader).
//! - [`fuzz`]: cheap random texts for the parser robustness tests.
//! - [`progress`]: the progress line of long offline work over a dataset
//!   (synthesis, lockstep runs, evaluations).

#![deny(missing_docs)]

pub mod decode;
pub mod fuzz;
pub mod progress;
pub mod source;
