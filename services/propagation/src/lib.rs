//! Mask propagation: each keyframe instance (a prompt from the segmenter) is
//! followed to later frames by tracking points inside and along its mask.
//!
//! - [`pyramid`]: grey images and their pyramids.
//! - [`lk`]: pyramidal Lucas-Kanade point tracking (Bouguet's formulation).
//! - [`propagate`]: the objects followed from prompt to prompt, catching up
//!   with late prompts; a `MaskModel`.
//! - [`warp`]: one object's motion (robust affine + interpolated residual
//!   motion, so that non-rigid parts follow) and its mask warped.
//! - [`newcomers`]: regions that move unlike the camera outside every
//!   followed object: an early segmenter request.
//! - [`models`]: the backends by name, as `[services.propagator]` selects.
//! - [`sam2`]: the `sam2` backend, SAM 2's image encoder and prompt/mask
//!   decoder through ONNX Runtime, for users who have its weights.

#![deny(missing_docs)]

pub mod models;
pub mod newcomers;
pub mod propagate;
pub mod sam2;
pub mod synthetic;
pub mod warp;

/// Pyramidal Lucas-Kanade (in the SLAM core, whose tracking uses it too).
pub use slam_core::flow::lk;
/// Grey images and pyramids (in the SLAM core, whose tracking uses them too).
pub use slam_core::flow::pyramid;
