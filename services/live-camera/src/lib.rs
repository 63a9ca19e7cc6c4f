//! A live V4L2 camera (`source.kind = "v4l2"`), for the camera-reader that
//! plays it and for the supervisor that lists and probes cameras before a
//! run starts.
//!
//! - [`v4l2`]: listing, probing, format choice and capture.
//! - [`convert`]: a camera's pixel formats (YUYV, MJPEG, Z16) into the
//!   frame's RGB and depth bytes.

#![deny(missing_docs)]

pub mod convert;
pub mod v4l2;
