#![deny(missing_docs)]
//! The run folder: what a run writes (the resolved config, `frames.csv`, the
//! trajectories, per-stage latency, the masks, the loops the SLAM closed,
//! outages, status) and how the
//! supervisor, a resumed run and the offline tools read it back. One crate
//! for the format, so the run loop and the report cannot disagree on it.

pub mod ignore;
pub mod latency;
pub mod loops_csv;
pub mod mask_record;
pub mod outages;
pub mod outputs;
pub mod run_dir;
