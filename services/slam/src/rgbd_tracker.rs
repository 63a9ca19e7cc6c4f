//! The `orb-rgbd` backend of the SLAM service: the SLAM core
//! ([`slam_core::System`]) behind the service's [`Tracker`] seam.

use pipeline::config::PipelineConfig;
use shared_types::TrackState;
use slam_core::io::ply::ColouredPoint;
use slam_core::System;

use crate::convert;
use crate::tracker::{TrackInput, TrackOutcome, Tracker};

pub struct RgbdTracker {
    system: System,
    /// The frame's depth as u16 (the shared-memory payload is bytes).
    depth: Vec<u16>,
    /// `mask_mode = "blackout"`: masked pixels are painted black instead of
    /// filtering keypoints (an ablation: the paint's edges become corners).
    blackout: bool,
    /// The painted copy of the frame in blackout mode.
    painted: Vec<u8>,
}

impl RgbdTracker {
    pub fn new(config: &PipelineConfig) -> Self {
        let camera = convert::camera(&config.camera, config.source.depth_scale as f64);
        Self {
            system: System::new(convert::params(config), camera),
            depth: Vec::new(),
            blackout: config.services.slam.mask_mode == "blackout",
            painted: Vec::new(),
        }
    }
}

impl Tracker for RgbdTracker {
    fn name(&self) -> &str {
        "orb-rgbd"
    }

    fn track(&mut self, input: &TrackInput) -> TrackOutcome {
        let frame = input.frame;
        let (w, h) = (frame.width(), frame.height());
        self.depth.clear();
        match frame.depth {
            Some(bytes) => self.depth.extend(
                bytes
                    .chunks_exact(2)
                    .map(|b| u16::from_ne_bytes([b[0], b[1]])),
            ),
            // An image-only source: no depth anywhere (tracked as lost until
            // the monocular initialisation exists).
            None => self.depth.resize(w * h, 0),
        }
        let mut mask = input.masks.map(|m| m.labels);
        let mut rgb = frame.rgb;
        if let (true, Some(labels)) = (self.blackout, mask) {
            self.painted.clear();
            self.painted.extend_from_slice(frame.rgb);
            for (px, &l) in self.painted.chunks_exact_mut(3).zip(labels) {
                if l != 0 {
                    px.fill(0);
                }
            }
            rgb = &self.painted;
            mask = None;
        }
        let r = self
            .system
            .track_rgbd(rgb, &self.depth, mask, w, h, frame.header.source_timestamp);
        let (t, q) = (r.pose_wc.translation.vector, r.pose_wc.rotation);
        TrackOutcome {
            pose: [t.x, t.y, t.z, q.i, q.j, q.k, q.w],
            state: convert::track_state(r.state),
            keyframe_inserted: r.keyframe_inserted,
            // Lost frames ask for the segmenter too: relocalising on
            // fresh masks is what a dynamic scene needs.
            next_needs_keyframe: r.next_needs_keyframe
                || convert::track_state(r.state) == TrackState::Lost,
            counts: convert::counts(&r.counts),
        }
    }

    fn map_points(&mut self) -> Vec<ColouredPoint> {
        self.system
            .map()
            .live_points()
            .map(|(_, p)| ColouredPoint {
                position: p.position.into(),
                colour: p.colour,
            })
            .collect()
    }
}
