//! dynslam's timing and routing decisions, one home for them: each is a
//! pure function or state machine of what a service knows (data in,
//! decision out), with no IPC and no clock of its own, so that every rule
//! is tested without processes and a frame's timeline can be read in one
//! place.
//!
//! - [`routing`]: which worker makes a frame's masks (the supervisor asks);
//! - [`keyframe_timing`]: when a frame the keyframe rule picks becomes a
//!   keyframe (the SLAM service asks).
//!
//! Still elsewhere (to move here in the next steps): the lockstep gate and
//! in-flight limits (supervisor `run.rs`), the reader's backlog rule
//! (camera-reader), the workers' drop rules (`pipeline::mask_worker`), the
//! SLAM's newest-ready-frame rule and segmenter patience (slam `main.rs`)
//! and the per-mode defaults (`pipeline::config`, segmenter input size).

pub mod keyframe_timing;
pub mod routing;

pub use keyframe_timing::{keyframe_timing, KeyframeFacts, KeyframeWhen};
pub use routing::{Availability, Router, RoutingConfig};
