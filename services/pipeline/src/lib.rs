//! The plumbing every dynslam service shares.
//!
//! - [`config`]: the pipeline configuration (`configs/pipeline.toml`), parsed
//!   strictly (unknown keys are rejected with their path) and layered over
//!   the built-in defaults, which are the shipped file.
//! - [`cameras`]: camera presets and the choice of a run's camera.
//! - [`transport`]: iceoryx2 topics (publish-subscribe + event wake-ups) with
//!   the per-run prefix, and the stale-resource cleanup of a run.
//! - [`clock`]: CLOCK_MONOTONIC stamps comparable across processes.
//! - [`runtime`]: what every service binary does at start (logging, exit
//!   codes the supervisor understands, readiness handshake).

pub mod cameras;
pub mod clock;
pub mod config;
pub mod mask_worker;
pub mod progress;
pub mod runtime;
pub mod stats;
pub mod transport;
pub mod views;

/// Finding and checking model files and the ONNX Runtime library (its own
/// crate, so the model crates use it without the IPC platform).
pub use ::provision;
