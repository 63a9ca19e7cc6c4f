//! Mask workers on another machine over Zenoh (README "Workers on another
//! machine").
//!
//! - [`wire`]: what crosses the network (frames and masks, encoded) and
//!   its checked decoding.
//! - [`session`]: the Zenoh session of either end and the keys they meet on.
//! - [`link`]: the robot's end, a `MaskModel` in the segmenter's place
//!   (`mask-link`), with the local fallback.
//! - [`serve`]: the other machine's end (`mask-worker`, run by
//!   `dynslam worker segmenter`).
//! - [`relay`]: a TCP relay that delays each byte (network latency for the
//!   tests and `just bench-remote`).

#![deny(missing_docs)]

pub mod link;
pub mod relay;
pub mod serve;
pub mod session;
pub mod wire;

/// The log filter of the remote binaries where `RUST_LOG` is unset: Zenoh's
/// own warnings (one per timed-out query and per late reply while a link is
/// down) left out; the link says and counts what happened itself.
pub const LOG_FILTER: &str = "info,zenoh=error";
