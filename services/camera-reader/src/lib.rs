//! The camera-reader's library: what the service does with a frame before
//! it is published. The recorded inputs themselves (lists, PNG decoding)
//! are the `datasets` crate's, shared with every tool.
//!
//! - [`frame`]: a dataset frame decoded straight into the loaned
//!   shared-memory sample.
//! - [`convert`]: a camera's pixel formats (YUYV, MJPEG, Z16) likewise.
//! - [`v4l2`]: a live V4L2 camera (`source.kind = "v4l2"`).

pub mod convert;
pub mod frame;
pub mod v4l2;
