//! dynslam's timing and routing decisions, one home for them: each is a
//! pure function or state machine of what a service knows (data in,
//! decision out), with no IPC and no clock of its own (instants are passed
//! in), so that every rule is tested without processes and a frame's
//! timeline can be read in one place.
//!
//! A frame's life, and who asks which module:
//! - [`source`]: the camera-reader publishes it (lockstep: once the frame
//!   before is tracked; real time: at its instant, left out undecoded when
//!   the pipeline is behind);
//! - [`ledger`]: the supervisor notes it, decides when it is routed and
//!   how many are in flight, records its fate exactly once (tracked or
//!   dropped, and why), replays it after a restart, names the stage of a
//!   stall; [`routing`] picks the worker;
//! - [`worker`]: a mask worker takes it from its queue, or passes it over
//!   when newer frames replaced it;
//! - [`tracking`]: the SLAM tracks the oldest (lockstep) or newest (real
//!   time) ready frame, and [`keyframe_timing`] says when a keyframe goes in;
//! - [`mode`]: the clock modes and their defaults.
#![deny(missing_docs)]

pub mod keyframe_timing;
pub mod ledger;
pub mod mode;
pub mod routing;
pub mod source;
pub mod tracking;
pub mod worker;

pub use keyframe_timing::{keyframe_timing, KeyframeFacts, KeyframeWhen};
pub use ledger::Ledger;
pub use mode::ClockMode;
pub use routing::{Availability, Router, RoutingConfig};
