//! The camera-reader's library: what the service does with a frame before
//! it is published. The recorded inputs themselves (lists, PNG decoding)
//! are the `datasets` crate's and the live camera the `live-camera` crate's,
//! shared with the tools.
//!
//! - [`frame`]: a dataset frame decoded straight into the loaned
//!   shared-memory sample.

#![deny(missing_docs)]

pub mod frame;
