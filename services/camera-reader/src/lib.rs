//! The camera-reader: plays a source into the `frames` topic.
//!
//! Lockstep: publishes frame n, waits for SLAM's Track(n), then n+1; answers
//! the supervisor's replay requests (recovery after a restart).
//! Real-time: publishes at the source's timestamps (times `speed`), never
//! waits; consumers take the newest frame and the supervisor counts drops.
//! A live V4L2 camera (`source.kind = "v4l2"`) is real time at its own rate.
//! The recorded inputs themselves (lists, PNG decoding) are the `datasets`
//! crate's and the live camera the `live-camera` crate's, shared with the
//! tools.
//!
//! - [`frame`]: a dataset frame decoded straight into the loaned
//!   shared-memory sample.
//! - `recorded` / `live`: the service loops of a recorded sequence and a
//!   camera; `ports`: what they share.

#![deny(missing_docs)]

pub mod frame;
mod live;
mod ports;
mod recorded;

use anyhow::Result;
use pipeline::config::SourceKind;
use pipeline::runtime::ServiceContext;

/// The service: plays the configured source from frame `start_seq` (a
/// camera from its first) until its end or a stop request.
pub fn run(ctx: ServiceContext, start_seq: u64) -> Result<()> {
    if ctx.config.source.kind == SourceKind::V4l2 {
        live::play(ctx)
    } else {
        recorded::play(ctx, start_seq)
    }
}
