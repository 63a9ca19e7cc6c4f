//! Between the pipeline's configuration and wire types and the SLAM core's
//! own (the core knows nothing of either).

use pipeline::config::{CameraConfig, PipelineConfig};
use shared_types::{TrackCounts, TrackState};
use slam_core::{Camera, FrameCounts, SlamParams, TrackingState};

/// The core's camera for the configured one (depth in `depth_scale` units
/// per metre).
pub fn camera(c: &CameraConfig, depth_scale: f64) -> Camera {
    Camera::new(
        [c.fx, c.fy, c.cx, c.cy],
        c.distortion,
        depth_scale,
        c.readout_s,
    )
}

/// The core's parameters for a run's configuration.
pub fn params(config: &PipelineConfig) -> SlamParams {
    let mut params = if config.services.slam.is_monocular() {
        SlamParams::monocular()
    } else {
        SlamParams::default()
    };
    if let Some(t) = config.services.slam.threads {
        params.orb.threads = t.max(1);
    }
    params.loop_closing = config.services.slam.loop_closing;
    params.motion_check = config.services.slam.motion_check;
    params.flow_frames = config.services.slam.flow_frames;
    params
}

/// The scheduling crate's keyframe decision as the SLAM core takes it.
pub fn keyframe_timing(when: scheduling::KeyframeWhen) -> slam_core::KeyframeTiming {
    match when {
        scheduling::KeyframeWhen::Now => slam_core::KeyframeTiming::Now,
        scheduling::KeyframeWhen::AfterBetterMasks => slam_core::KeyframeTiming::AfterBetterMasks,
        scheduling::KeyframeWhen::NotThisFrame => slam_core::KeyframeTiming::NotThisFrame,
    }
}

/// The core's tracking state as the wire's.
pub fn track_state(s: TrackingState) -> TrackState {
    match s {
        TrackingState::NotInitialised => TrackState::NotInitialised,
        TrackingState::Ok => TrackState::Ok,
        TrackingState::Relocalised => TrackState::Relocalised,
        TrackingState::Lost => TrackState::Lost,
        TrackingState::Skipped => TrackState::Skipped,
        TrackingState::Turning => TrackState::Turning,
    }
}

/// The core's per-frame counts as the wire's.
pub fn counts(c: &FrameCounts) -> TrackCounts {
    TrackCounts {
        features: c.features,
        features_masked: c.features_masked,
        features_moving: c.features_moving,
        inliers: c.inliers,
        map_points: c.map_points,
        keyframes: c.keyframes,
        extract_us: c.extract_us,
        mapping_us: c.mapping_us,
        tracked_by_flow: c.tracked_by_flow as u32,
    }
}
