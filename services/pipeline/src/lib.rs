//! The IPC platform every dynslam service shares.
//!
//! - [`config`]: the pipeline configuration (`configs/pipeline.toml`, the
//!   `pipeline-config` crate), parsed strictly (unknown keys are rejected
//!   with their path) and layered over the built-in defaults, which are the
//!   shipped file.
//! - [`cameras`]: camera presets and the choice of a run's camera.
//! - [`transport`]: iceoryx2 topics (publish-subscribe + event wake-ups) with
//!   the per-run prefix, and the stale-resource cleanup of a run.
//! - [`clock`]: CLOCK_MONOTONIC stamps comparable across processes.
//! - [`runtime`]: what every service binary does at start (logging, exit
//!   codes the supervisor understands, readiness handshake).
//! - [`service_loop`]: the one event loop every service runs (its events
//!   one at a time, a tick, shutdown).
//! - [`mask_worker`]: the segmenter's and the propagator's service over a
//!   model (the `mask-model` crate's seam).

#![deny(missing_docs)]

pub mod cameras;
pub mod clock;
pub mod mask_worker;
pub mod runtime;
pub mod service_loop;
pub mod transport;

/// Finding and checking model files and the ONNX Runtime library (its own
/// crate, so the model crates use it without the IPC platform).
pub use ::provision;

/// The configuration (its own crate, so tools and model crates read it
/// without the IPC platform).
pub use pipeline_config as config;

/// Typed views over the frames, masks and map in shared memory.
pub use shared_types::views;

/// Percentiles for the latency report and the benchmarks.
pub use shared_types::stats;

/// A progress line for long offline work.
pub use datasets::progress;
