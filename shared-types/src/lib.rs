//! The only place where the pipeline's shared-memory payloads live.
//!
//! Every type here is `#[repr(C)]`, self-contained (no pointers, no heap) and
//! `ZeroCopySend`, so that it can sit in an iceoryx2 sample that several
//! processes read in place. Enumerations travel as plain integers: a value
//! written by another process is decoded with `from_u32`, so a corrupt or newer
//! writer can never produce an invalid Rust enum in shared memory.
//!
//! Large pixel data travels as the `[u8]` slice payload of a sample whose user
//! header is one of the `*Header` types below (static allocation strategy, the
//! maximum size fixed by the pipeline configuration).

#![deny(missing_docs)]

use iceoryx2::prelude::ZeroCopySend;

pub mod names;
pub mod stats;
pub mod views;

/// Maximum number of object instances carried by one [`MasksHeader`].
pub const MAX_INSTANCES: usize = 32;

/// Label value of "no object" in a mask label image; instance `i` is `i + 1`.
pub const LABEL_BACKGROUND: u8 = 0;

/// CLOCK_MONOTONIC instants (nanoseconds) stamped by each stage. Every payload
/// carries the stamps of the stages it has passed so that any consumer (the
/// supervisor's latency report in particular) sees the whole history of a
/// frame without joining messages. Zero means "this stage has not happened".
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
pub struct StageStamps {
    /// Camera-reader starts producing the frame (before reading/decoding).
    pub capture_ns: u64,
    /// Camera-reader hands the finished frame to shared memory.
    pub published_ns: u64,
    /// Supervisor published the routing decision.
    pub routed_ns: u64,
    /// Segmenter or propagator starts working on the frame.
    pub masks_start_ns: u64,
    /// Segmenter or propagator published the masks.
    pub masks_done_ns: u64,
    /// SLAM process took the frame out of shared memory (transport end).
    pub slam_received_ns: u64,
    /// SLAM starts tracking (frame and masks both present).
    pub track_start_ns: u64,
    /// SLAM published the track result.
    pub track_done_ns: u64,
}

/// Pixel layout of the colour part of a frame.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelFormat {
    /// 8-bit red, green, blue, row by row without padding.
    Rgb8 = 1,
}

impl PixelFormat {
    /// The format a header's `pixel_format` names; None for a value this
    /// build does not know.
    pub fn from_u32(v: u32) -> Option<Self> {
        match v {
            1 => Some(Self::Rgb8),
            _ => None,
        }
    }
    /// Bytes per pixel of the colour part.
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            Self::Rgb8 => 3,
        }
    }
}

/// Bit flags of [`FrameHeader::flags`].
pub mod frame_flags {
    /// The source could not produce this frame (corrupt or missing file,
    /// wrong size, ...). The pixel payload is empty; the reason was logged by
    /// the camera-reader and is in `FrameHeader::error`.
    pub const BAD_INPUT: u32 = 1 << 0;
    /// No more frames will follow; `seq` is the number of frames produced.
    pub const END_OF_STREAM: u32 = 1 << 1;
    /// This frame was already published once and is published again after a
    /// service restart (lockstep recovery). Consumers that already handled it
    /// ignore it.
    pub const REPLAY: u32 = 1 << 2;
    /// Real time: the camera-reader left this frame out (not decoded, empty
    /// payload) because the pipeline was still busy with older ones, as a
    /// camera driver drops frames for a slow reader. Recorded as dropped.
    pub const DROPPED_AT_SOURCE: u32 = 1 << 3;
}

/// Length of the fixed, NUL-padded UTF-8 error text carried by headers.
pub const ERROR_TEXT_LEN: usize = 192;

/// User header of a frame sample. The slice payload holds `width*height*3`
/// bytes of RGB followed, when `has_depth != 0`, by `width*height` native
/// endian `u16` depth values.
///
/// A public interface since external sources publish it (README "Frames
/// in", `docs/examples/publish_tum.py`): 296 bytes, 8-byte aligned; a
/// layout change comes with a new `type_name`, so that an old publisher
/// cannot open the service.
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("dynslam::FrameHeader.v1")]
pub struct FrameHeader {
    /// The frame's number in the run, from 0 (the key every other payload
    /// refers to it by).
    pub seq: u64,
    /// Timestamp of the source (TUM timestamp in seconds, or file order).
    pub source_timestamp: f64,
    /// Image width (pixels).
    pub width: u32,
    /// Image height (pixels).
    pub height: u32,
    /// A [`PixelFormat`] value.
    pub pixel_format: u32,
    /// Non-zero when the payload carries depth after the colour.
    pub has_depth: u32,
    /// Depth value per metre (5000 for TUM).
    pub depth_scale: f32,
    /// [`frame_flags`] bits.
    pub flags: u32,
    /// When each stage handled the frame so far.
    pub stamps: StageStamps,
    /// Why the frame is [`frame_flags::BAD_INPUT`] (NUL padded).
    pub error: [u8; ERROR_TEXT_LEN],
}

impl Default for FrameHeader {
    fn default() -> Self {
        Self {
            seq: 0,
            source_timestamp: 0.0,
            width: 0,
            height: 0,
            pixel_format: PixelFormat::Rgb8 as u32,
            has_depth: 0,
            depth_scale: 0.0,
            flags: 0,
            stamps: StageStamps::default(),
            error: [0; ERROR_TEXT_LEN],
        }
    }
}

impl FrameHeader {
    /// Whether [`frame_flags`] bit `flag` is set.
    pub fn has(&self, flag: u32) -> bool {
        self.flags & flag != 0
    }
    /// Whether the payload holds the frame's pixels (not a bad, left-out
    /// or end-of-stream header).
    pub fn carries_pixels(&self) -> bool {
        !self.has(frame_flags::BAD_INPUT)
            && !self.has(frame_flags::END_OF_STREAM)
            && !self.has(frame_flags::DROPPED_AT_SOURCE)
    }
    /// Bytes of the colour part of the payload.
    pub fn rgb_len(&self) -> usize {
        self.width as usize * self.height as usize * 3
    }
    /// Bytes of the depth part of the payload (0 without depth).
    pub fn depth_len(&self) -> usize {
        if self.has_depth != 0 {
            self.width as usize * self.height as usize * 2
        } else {
            0
        }
    }
}

/// Where a frame's masks come from.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RouteKind {
    /// Keyframe path: run the instance segmenter.
    Segment = 1,
    /// Ordinary frame: propagate the latest masks.
    Propagate = 2,
    /// No masks will be made (bad frame, or no mask service available); SLAM
    /// tracks the frame unmasked or marks it.
    Skip = 3,
    /// Real time: the propagator masks the frame now (SLAM tracks it with
    /// those, never waiting for the segmenter) and the segmenter segments it
    /// in the background; its result re-prompts the propagator, which carries
    /// it forward to the frame of the moment.
    SegmentBehind = 4,
    /// The supervisor refused the frame: an outside publisher's frame that
    /// does not fit the run (README "Frames in"). No masks; SLAM records it
    /// skipped without reading its pixels.
    Refuse = 5,
}

impl RouteKind {
    /// Whether the segmenter makes masks for a frame of this route.
    pub fn segments(self) -> bool {
        matches!(self, Self::Segment | Self::SegmentBehind)
    }
    /// Whether the propagator makes masks for a frame of this route.
    pub fn propagates(self) -> bool {
        matches!(self, Self::Propagate | Self::SegmentBehind)
    }
    /// Whether a mask worker makes masks for a frame of this route.
    pub fn makes_masks(self) -> bool {
        self.segments() || self.propagates()
    }
    /// The route a [`Route::kind`] names; None for an unknown value.
    pub fn from_u32(v: u32) -> Option<Self> {
        match v {
            1 => Some(Self::Segment),
            2 => Some(Self::Propagate),
            3 => Some(Self::Skip),
            4 => Some(Self::SegmentBehind),
            5 => Some(Self::Refuse),
            _ => None,
        }
    }
    /// The route's name in frames.csv.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Segment => "segment",
            Self::Propagate => "propagate",
            Self::Skip => "skip",
            Self::SegmentBehind => "segment-behind",
            Self::Refuse => "refused",
        }
    }
}

/// Supervisor's routing decision for one frame.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
pub struct Route {
    /// The frame routed.
    pub seq: u64,
    /// A [`RouteKind`] value.
    pub kind: u32,
    /// Non-zero when this route is re-issued after a restart.
    pub replay: u32,
    /// The frame's stamps, the routing's included.
    pub stamps: StageStamps,
}

/// Which model produced a set of masks.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum MaskSource {
    /// No masks: the frame goes unmasked.
    None = 0,
    /// The segmenter's (a keyframe's own masks).
    Segmenter = 1,
    /// The propagator's (carried from the last segmented frame).
    Propagator = 2,
}

impl MaskSource {
    /// The source a header's `source` names; None for an unknown value.
    pub fn from_u32(v: u32) -> Option<Self> {
        match v {
            0 => Some(Self::None),
            1 => Some(Self::Segmenter),
            2 => Some(Self::Propagator),
            _ => None,
        }
    }
    /// The source's name in frames.csv and masks.csv.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Segmenter => "segmenter",
            Self::Propagator => "propagator",
        }
    }
}

/// One dynamic object instance in a [`MasksHeader`].
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
pub struct Instance {
    /// Object identity kept across propagation (the segmenter assigns it).
    pub object_id: u32,
    /// Class id in the model's class list (COCO for the shipped models).
    pub class_id: u32,
    /// The model's confidence (0-1).
    pub score: f32,
    /// Bounding box x0, y0, x1, y1 in pixels of the frame.
    pub bbox: [f32; 4],
}

/// Bit flags of [`MasksHeader::flags`].
pub mod mask_flags {
    /// The worker could not produce masks for this frame (model failure);
    /// the label image is empty and SLAM tracks the frame unmasked.
    pub const FAILED: u32 = 1 << 0;
    /// Real time: the routed frame was replaced by newer ones before the
    /// worker's turn; no labels (0x0) follow. Tells SLAM's peers at once
    /// that these masks will never come.
    pub const GONE: u32 = 1 << 1;
    /// The propagator saw something move that it does not follow (a person
    /// who walked in after the keyframe): the supervisor routes the next
    /// frame to the segmenter as if SLAM had asked for a keyframe.
    pub const SEGMENT_WANTED: u32 = 1 << 2;
    /// Made by a worker on another machine (`location = "remote"`).
    pub const REMOTE: u32 = 1 << 3;
    /// `location = "remote"`: no remote worker answered, so the local model
    /// made these masks (`fallback = "local"`).
    pub const FALLBACK: u32 = 1 << 4;
    /// `location = "remote"`: no worker could take the frame (none alive, or
    /// none answered in time, and `fallback = "none"`); set with
    /// [`GONE`] (real time: the propagator carries masks) or [`FAILED`]
    /// (lockstep: the frame goes on unmasked).
    pub const UNAVAILABLE: u32 = 1 << 5;

    /// Where a set of masks was made, for frames.csv and masks.csv: "local",
    /// "remote", "fallback" (the local model standing in for a remote
    /// worker), "unavailable" (no worker could take the frame) or "none"
    /// (no masks were made).
    pub fn origin(flags: u32) -> &'static str {
        if flags & UNAVAILABLE != 0 {
            "unavailable"
        } else if flags & (FAILED | GONE) != 0 {
            "none"
        } else if flags & REMOTE != 0 {
            "remote"
        } else if flags & FALLBACK != 0 {
            "fallback"
        } else {
            "local"
        }
    }
}

/// User header of a masks sample. The slice payload is a `width*height` label
/// image: 0 is background, `i + 1` is `instances[i]`.
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend)]
pub struct MasksHeader {
    /// The frame the masks are of.
    pub seq: u64,
    /// A [`MaskSource`] value.
    pub source: u32,
    /// Label image width (pixels; 0 when no labels follow).
    pub width: u32,
    /// Label image height (pixels; 0 when no labels follow).
    pub height: u32,
    /// How many of `instances` are used.
    pub num_instances: u32,
    /// [`mask_flags`] bits.
    pub flags: u32,
    /// Inference time of the model alone (nanoseconds).
    pub inference_ns: u64,
    /// The objects, `num_instances` of them used.
    pub instances: [Instance; MAX_INSTANCES],
    /// The frame's stamps, the worker's included.
    pub stamps: StageStamps,
}

impl Default for MasksHeader {
    fn default() -> Self {
        Self {
            seq: 0,
            source: MaskSource::None as u32,
            width: 0,
            height: 0,
            num_instances: 0,
            flags: 0,
            inference_ns: 0,
            instances: [Instance::default(); MAX_INSTANCES],
            stamps: StageStamps::default(),
        }
    }
}

impl MasksHeader {
    /// Whether [`mask_flags`] bit `flag` is set.
    pub fn has(&self, flag: u32) -> bool {
        self.flags & flag != 0
    }
    /// The instances used (never more than [`MAX_INSTANCES`], whatever
    /// `num_instances` says).
    pub fn instances(&self) -> &[Instance] {
        &self.instances[..(self.num_instances as usize).min(MAX_INSTANCES)]
    }
    /// Holds the first [`MAX_INSTANCES`] of `instances` (a header has room
    /// for no more); returns how many it holds.
    pub fn set_instances(&mut self, instances: &[Instance]) -> usize {
        let n = instances.len().min(MAX_INSTANCES);
        self.instances[..n].copy_from_slice(&instances[..n]);
        self.num_instances = n as u32;
        n
    }
}

/// Tracking state of one frame.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TrackState {
    /// No map yet (the start waits for a frame with enough features with
    /// depth; monocular: for two views with enough parallax).
    NotInitialised = 0,
    /// Tracked in the map.
    Ok = 1,
    /// Not tracked: no pose for this frame.
    Lost = 2,
    /// Found again in the map after being lost (it has a pose).
    Relocalised = 3,
    /// The frame was not tracked (bad input); see the run's log.
    Skipped = 4,
    /// Monocular: the camera turned away from the map on the spot; the
    /// turn comes from the images, the position is the last one in the map
    /// (it has a pose, rougher than a tracked one's).
    Turning = 5,
}

impl TrackState {
    /// The state a [`Track::state`] names; None for an unknown value.
    pub fn from_u32(v: u32) -> Option<Self> {
        match v {
            0 => Some(Self::NotInitialised),
            1 => Some(Self::Ok),
            2 => Some(Self::Lost),
            3 => Some(Self::Relocalised),
            4 => Some(Self::Skipped),
            5 => Some(Self::Turning),
            _ => None,
        }
    }
    /// The state's name in frames.csv.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::NotInitialised => "not_initialised",
            Self::Ok => "ok",
            Self::Lost => "lost",
            Self::Relocalised => "relocalised",
            Self::Skipped => "skipped",
            Self::Turning => "turning",
        }
    }
    /// True when the frame has a valid pose.
    pub fn is_tracked(self) -> bool {
        matches!(self, Self::Ok | Self::Relocalised | Self::Turning)
    }
}

/// Per-frame counts reported by SLAM.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
pub struct TrackCounts {
    /// ORB features of the frame (after the masks and the motion check).
    pub features: u32,
    /// Features dropped because they fell inside a dynamic mask.
    pub features_masked: u32,
    /// Features dropped after tracking because they moved unlike the
    /// camera (the SLAM's motion check).
    pub features_moving: u32,
    /// Features matched to map points that the pose optimisation kept.
    pub inliers: u32,
    /// Map points in the map after this frame.
    pub map_points: u32,
    /// Keyframes in the map after this frame.
    pub keyframes: u32,
    /// Time of feature extraction for this frame (microseconds); the rest
    /// of the tracking span is matching and pose optimisation.
    pub extract_us: u32,
    /// Time of local mapping of the keyframe whose mapping finished during
    /// this frame (microseconds; on the local-mapping thread, overlapping
    /// extraction).
    pub mapping_us: u32,
    /// 1: the frame was tracked by following the last frame's points with
    /// optical flow, without ORB extraction (`services.slam.flow_frames`).
    pub tracked_by_flow: u32,
}

/// SLAM's result for one frame, and its wish for the next one.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
pub struct Track {
    /// The frame tracked.
    pub seq: u64,
    /// Its source timestamp (seconds), as the frame header had it.
    pub source_timestamp: f64,
    /// World-from-camera pose: tx ty tz qx qy qz qw (TUM order).
    pub pose: [f64; 7],
    /// A [`TrackState`] value.
    pub state: u32,
    /// Non-zero when this frame was inserted as a keyframe.
    pub keyframe_inserted: u32,
    /// Non-zero when SLAM wants the *next* frame to be a keyframe (routing).
    pub next_needs_keyframe: u32,
    /// The [`MaskSource`] of the masks used for this frame.
    pub mask_source: u32,
    /// The [`mask_flags`] of those masks (where they were made).
    pub mask_flags: u32,
    /// What the frame cost and produced.
    pub counts: TrackCounts,
    /// The frame's stamps, the SLAM's included.
    pub stamps: StageStamps,
}

/// Which service a [`Lifecycle`] message is about.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ServiceKind {
    /// Plays the dataset or camera into shared memory.
    CameraReader = 1,
    /// Keyframe masks.
    Segmenter = 2,
    /// Masks of the other frames.
    Propagator = 3,
    /// Tracking and mapping.
    Slam = 4,
    /// The ROS 2 bridge: optional, off the frame path (not in [`Self::ALL`],
    /// the services every run has).
    Bridge = 5,
    /// The warm standby SLAM (`services.slam.standby`): optional, holds the
    /// newest frames without tracking them until it is promoted, then is
    /// the SLAM.
    SlamStandby = 6,
}

impl ServiceKind {
    /// The services every run has.
    pub const ALL: [ServiceKind; 4] = [
        ServiceKind::Slam,
        ServiceKind::Segmenter,
        ServiceKind::Propagator,
        ServiceKind::CameraReader,
    ];
    /// The service a [`Lifecycle::service`] names; None for an unknown value.
    pub fn from_u32(v: u32) -> Option<Self> {
        match v {
            1 => Some(Self::CameraReader),
            2 => Some(Self::Segmenter),
            3 => Some(Self::Propagator),
            4 => Some(Self::Slam),
            5 => Some(Self::Bridge),
            6 => Some(Self::SlamStandby),
            _ => None,
        }
    }
    /// The name used for binaries, configuration sections and logs.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::CameraReader => "camera-reader",
            Self::Segmenter => "segmenter",
            Self::Propagator => "propagator",
            Self::Slam => "slam",
            Self::Bridge => "bridge",
            Self::SlamStandby => "slam-standby",
        }
    }
}

/// Layout version of [`Pose`]; a change of layout gets a new version (and
/// a new `type_name`, so that an old subscriber cannot open the service).
pub const POSE_VERSION: u32 = 1;

/// One pose of the public pose stream, service `dynslam/<run id>/poses`
/// (iceoryx2 publish-subscribe, file prefix `dsl_<run id>_`, user header
/// `()`): what SLAM answered for one frame, for programs outside the
/// pipeline (README "Poses out"; `docs/examples/poses.py` reads it from
/// Python). 88 bytes, 8-byte aligned, native byte order. The stream keeps
/// the last 16 poses for a subscriber that connects late.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("dynslam::Pose.v1")]
pub struct Pose {
    /// [`POSE_VERSION`].
    pub version: u32,
    /// A [`TrackState`] value: 0 not initialised, 1 ok, 2 lost, 3
    /// relocalised, 4 skipped (bad input); not ok: the pose is the last
    /// known one.
    pub state: u32,
    /// Frame sequence number (0 = first frame of the run).
    pub seq: u64,
    /// The frame's source timestamp (seconds; the camera's clock).
    pub timestamp: f64,
    /// World from camera: tx ty tz (metres) qx qy qz qw (TUM order).
    pub pose: [f64; 7],
    /// 1 when the frame became a keyframe.
    pub keyframe: u32,
    /// Zero (keeps the layout 8-byte aligned; room for a later field).
    pub reserved: u32,
}

impl Pose {
    /// The published pose of a SLAM result.
    pub fn of(track: &Track) -> Self {
        Self {
            version: POSE_VERSION,
            state: track.state,
            seq: track.seq,
            timestamp: track.source_timestamp,
            pose: track.pose,
            keyframe: track.keyframe_inserted,
            reserved: 0,
        }
    }
}

/// Readiness handshake: a service announces that all its ports are open.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
pub struct Lifecycle {
    /// A [`ServiceKind`] value.
    pub service: u32,
    /// The announcing process.
    pub pid: u32,
    /// When it became ready (CLOCK_MONOTONIC, nanoseconds).
    pub ready_ns: u64,
}

/// Supervisor's commands to the camera-reader (the scheduling crate's
/// `SourceCommand` on the wire).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
pub struct Control {
    /// A [`control_kind`] value.
    pub kind: u32,
    /// The process the command is for (`PROMOTE`: the standby SLAM's pid).
    pub pid: u32,
    /// The frame the command is about (`REPLAY`: the frame; `PROMOTE`: the
    /// first frame the promoted SLAM may track).
    pub seq: u64,
}

/// What a [`Control`] message asks of the camera-reader.
pub mod control_kind {
    /// Publish frame `seq` again (lockstep recovery after a restart).
    pub const REPLAY: u32 = 1;
    /// Real time: the SLAM restarted; stop waiting for the Tracks of the
    /// frames published before it.
    pub const FORGET_BACKLOG: u32 = 2;
    /// To the standby SLAM with pid `pid`: the active one died; track from
    /// frame `seq` on.
    pub const PROMOTE: u32 = 3;
}

/// User header of a map snapshot (slam -> bridge, throttled): the map as
/// local mapping left it. The slice payload holds `keyframes` poses
/// ([`MAP_KEYFRAME_BYTES`] each: world-from-camera tx ty tz qx qy qz qw as
/// native `f64`) followed by `points` points ([`MAP_POINT_BYTES`] each:
/// x y z as native `f32`, r g b and a pad byte, and the index of the
/// keyframe that observed it first as native `u32`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
pub struct MapHeader {
    /// Snapshots of this SLAM process so far (1, 2, ...).
    pub version: u64,
    /// Capture time of the newest keyframe's frame (seconds, camera clock).
    pub stamp: f64,
    /// Loops closed so far (each moved keyframes).
    pub loops: u32,
    /// Keyframe poses in the payload.
    pub keyframes: u32,
    /// Points in the payload.
    pub points: u32,
    /// Points left out: the sample had no room for them.
    pub points_left_out: u32,
}

/// Bytes of one keyframe pose in a map payload (7 `f64`).
pub const MAP_KEYFRAME_BYTES: usize = 56;
/// Bytes of one point in a map payload (3 `f32`, 4 colour bytes, a `u32`).
pub const MAP_POINT_BYTES: usize = 20;

impl MapHeader {
    /// Bytes the payload must hold.
    pub fn payload_len(&self) -> usize {
        self.keyframes as usize * MAP_KEYFRAME_BYTES + self.points as usize * MAP_POINT_BYTES
    }
}

/// What the bridge asks the SLAM (ROS 2 services).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum SlamCommandKind {
    /// Write the map to `name` (a file name, checked by the SLAM too) in
    /// `bridge.maps_dir`.
    SaveMap = 1,
    /// Drop the map and start a new one with the next frame.
    Reset = 2,
    /// ORB-SLAM2's localization mode on (`flag` 1) or off (0).
    SetLocalizationMode = 3,
}

impl SlamCommandKind {
    /// The command a [`SlamCommand::kind`] names; None for an unknown value.
    pub fn from_u32(v: u32) -> Option<Self> {
        match v {
            1 => Some(Self::SaveMap),
            2 => Some(Self::Reset),
            3 => Some(Self::SetLocalizationMode),
            _ => None,
        }
    }
}

/// Length of a command's name and of a reply's message.
pub const COMMAND_TEXT_LEN: usize = ERROR_TEXT_LEN;

/// bridge -> slam: one command, answered by a [`SlamReply`] with its id.
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend)]
pub struct SlamCommand {
    /// The bridge's number for the command, echoed by the reply.
    pub id: u64,
    /// A [`SlamCommandKind`] value.
    pub kind: u32,
    /// The command's switch (`SetLocalizationMode`: 1 on, 0 off).
    pub flag: u32,
    /// NUL-padded UTF-8 ([`write_error_text`]).
    pub name: [u8; COMMAND_TEXT_LEN],
}

impl Default for SlamCommand {
    fn default() -> Self {
        Self {
            id: 0,
            kind: 0,
            flag: 0,
            name: [0; COMMAND_TEXT_LEN],
        }
    }
}

/// slam -> bridge: the outcome of command `id`.
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend)]
pub struct SlamReply {
    /// The command answered.
    pub id: u64,
    /// 1: done.
    pub ok: u32,
    /// Zero (keeps the layout 8-byte aligned).
    pub reserved: u32,
    /// What was done, or why not (NUL-padded UTF-8).
    pub message: [u8; COMMAND_TEXT_LEN],
}

impl Default for SlamReply {
    fn default() -> Self {
        Self {
            id: 0,
            ok: 0,
            reserved: 0,
            message: [0; COMMAND_TEXT_LEN],
        }
    }
}

impl SlamReply {
    /// The reply to command `id`: what was done, or why not.
    pub fn new(id: u64, result: Result<String, String>) -> Self {
        let mut reply = Self {
            id,
            ok: result.is_ok() as u32,
            ..Self::default()
        };
        let text = match &result {
            Ok(t) | Err(t) => t,
        };
        write_error_text(&mut reply.message, text);
        reply
    }
}

/// Writes `text` into a fixed NUL-padded buffer, cutting at a char boundary.
pub fn write_error_text(buf: &mut [u8; ERROR_TEXT_LEN], text: &str) {
    *buf = [0; ERROR_TEXT_LEN];
    let mut end = text.len().min(ERROR_TEXT_LEN - 1);
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    buf[..end].copy_from_slice(&text.as_bytes()[..end]);
}

/// Reads a NUL-padded text written by [`write_error_text`].
pub fn read_error_text(buf: &[u8; ERROR_TEXT_LEN]) -> String {
    let end = buf.iter().position(|&b| b == 0).unwrap_or(buf.len());
    String::from_utf8_lossy(&buf[..end]).into_owned()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn error_text_round_trips_and_truncates_on_char_boundary() {
        let mut buf = [0u8; ERROR_TEXT_LEN];
        write_error_text(&mut buf, "rgb/1.png: corrupt");
        assert_eq!(read_error_text(&buf), "rgb/1.png: corrupt");
        let long = "é".repeat(200);
        write_error_text(&mut buf, &long);
        let back = read_error_text(&buf);
        assert!(back.len() < ERROR_TEXT_LEN);
        assert!(back.chars().all(|c| c == 'é'));
    }

    #[test]
    fn enums_reject_unknown_values() {
        assert_eq!(RouteKind::from_u32(2), Some(RouteKind::Propagate));
        assert_eq!(RouteKind::from_u32(0), None);
        assert_eq!(TrackState::from_u32(99), None);
        assert_eq!(ServiceKind::from_u32(4), Some(ServiceKind::Slam));
    }

    #[test]
    fn a_masks_header_holds_at_most_max_instances() {
        let many: Vec<Instance> = (0..MAX_INSTANCES as u32 + 3)
            .map(|i| Instance {
                object_id: i + 1,
                ..Default::default()
            })
            .collect();
        let mut h = MasksHeader::default();
        assert_eq!(h.set_instances(&many[..2]), 2);
        assert_eq!(h.instances().len(), 2);
        assert_eq!(h.set_instances(&many), MAX_INSTANCES);
        assert_eq!(h.num_instances as usize, MAX_INSTANCES);
        assert_eq!(
            h.instances().last().unwrap().object_id,
            MAX_INSTANCES as u32
        );
    }

    #[test]
    fn frame_lengths_follow_header() {
        let h = FrameHeader {
            width: 4,
            height: 2,
            has_depth: 1,
            ..Default::default()
        };
        assert_eq!(h.rgb_len(), 24);
        assert_eq!(h.depth_len(), 16);
    }

    #[test]
    fn the_public_layouts_are_the_documented_ones() {
        // README "Frames in" / "Poses out" and the Python examples' ctypes
        // structures rely on these; a change needs a new type_name.
        assert_eq!(std::mem::size_of::<FrameHeader>(), 296);
        assert_eq!(std::mem::align_of::<FrameHeader>(), 8);
        assert_eq!(std::mem::offset_of!(FrameHeader, stamps), 40);
        assert_eq!(std::mem::offset_of!(FrameHeader, error), 104);
        assert_eq!(std::mem::size_of::<Pose>(), 88);
    }
}
