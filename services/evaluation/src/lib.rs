#![deny(missing_docs)]
//! Offline tools over run folders and datasets: the run's report and its
//! plots, `dynslam masks-eval` (mask IoU against ground truth), vocabulary
//! training. Nothing here runs the pipeline: the supervisor does, and calls
//! [`report::write`] when a run ends.

pub mod mask_eval;
pub mod plots;
pub mod report;
pub mod vocab;
