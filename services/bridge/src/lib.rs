//! The ROS 2 bridge: dynslam's poses, TF, path, state and diagnostics as
//! ROS 2 topics, the map as a point cloud and an occupancy grid, map
//! services, in rmw_zenoh's wire format (README "ROS 2").
//!
//! - [`cdr`]: the CDR encoding of ROS 2 messages (writer and a checked reader);
//! - [`msgs`]: the messages, their DDS names and RIHS01 type hashes;
//! - [`rmw`]: rmw_zenoh's key expressions, liveliness tokens and attachments;
//! - [`frames`]: REP-103 / REP-105 frames from the SLAM's camera poses;
//! - [`node`]: a ROS 2 node on a Zenoh session;
//! - [`odom`]: the robot's `odom -> base_link` from `/tf` (REP-105);
//! - [`outputs`]: what is published when, and what survives a restart;
//! - [`publish`]: the service loop of `bridge publish` (the run out, the
//!   map services in);
//! - [`grid`]: the occupancy grid projected from the map's points;
//! - [`services`]: `save_map`, `reset`, `set_localization_mode` (queryables
//!   answered by the SLAM);
//! - [`camera_in`]: a ROS 2 camera's topics as the run's frames (`source.kind = "ros2"`).

#![deny(missing_docs)]

pub mod camera_in;
pub mod cdr;
pub mod frames;
pub mod grid;
pub mod msgs;
pub mod node;
pub mod odom;
pub mod outputs;
pub mod publish;
pub mod rmw;
pub mod services;
