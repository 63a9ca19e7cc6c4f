//! The camera-reader's library: frame sources and PNG decoding into a
//! caller-provided buffer (the loaned shared-memory sample).
//!
//! - [`source`]: what to play (TUM RGB-D folders, plain image folders) as a
//!   list of [`source::FrameEntry`], validated up front so that a malformed
//!   list fails at start with the file and line.
//! - [`decode`]: PNG decoding straight into the destination bytes.
//! - [`convert`]: a camera's pixel formats (YUYV, MJPEG, Z16) likewise.
//! - [`v4l2`]: a live V4L2 camera (`source.kind = "v4l2"`).

pub mod convert;
pub mod decode;
pub mod frame;
pub mod source;
pub mod v4l2;
