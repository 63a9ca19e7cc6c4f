//! What the SLAM service runs, as a library: the seam between the service and a SLAM
//! implementation ([`tracker::Tracker`]), the `orb-rgbd` backend over the
//! SLAM core (the `slam-core` crate, which has no IPC in it), the
//! `scripted` test double, what it shares with the ROS 2
//! bridge ([`bridge_link`]), and the conversions between the pipeline's
//! configuration and wire types and the core's own.

#![deny(missing_docs)]

pub mod bridge_link;
pub mod convert;
pub mod rgbd_tracker;
pub mod scripted;
pub mod tracker;
