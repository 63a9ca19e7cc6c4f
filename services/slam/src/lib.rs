//! The SLAM library. It is usable without any IPC: feed it frames and masks,
//! get poses. The SLAM service (`main.rs`) is a thin shell around a
//! [`tracker::Tracker`].

pub mod core;
pub mod eval;
pub mod ply;
pub mod rgbd_tracker;
pub mod scripted;
pub mod tracker;
pub mod trajectory;
