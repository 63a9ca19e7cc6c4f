//! The per-frame steps of [`System::track_with`] besides the keyframe
//! decision: the frame's keypoints (extracted, or followed by optical
//! flow), tracking in the map, the rolling-shutter correction's second
//! pass, the motion check, the trajectory, and a young map's restart.

use super::*;

impl System {
    /// The RGB-D motion check (when `params.motion_check`): the keypoints of
    /// `frame` in regions that move unlike the camera (at its pose just
    /// estimated) are dropped from the frame and its matches, so that
    /// neither the keyframe decision nor mapping sees them (the pose came
    /// from robust optimisation: such a minority is outvoted); the frame is
    /// kept whole for later frames' checks. Returns the keypoints dropped and
    /// the ms it took (0, 0 unless `checked`: a tracked frame).
    pub(super) fn drop_moving(
        &mut self,
        frame: &mut Frame,
        tracked: &mut Tracked,
        (input, checked): (&RgbdInput, bool),
    ) -> (usize, f64) {
        self.moving_regions.clear();
        if !self.params.motion_check || self.params.is_monocular() || !checked {
            return (0, 0.0);
        }
        let started = std::time::Instant::now();
        let regions = self.motion.observe(
            frame,
            input.depth,
            (&tracked.pose_cw, &tracked.matched),
            input.timestamp,
            &self.camera,
        );
        if regions.is_empty() {
            return (0, to_ms(started));
        }
        let (kept, index) = frame.without_index(|k| {
            let (u, v) = frame.un[k];
            regions.iter().any(|r| r.contains(u, v))
        });
        let dropped = frame.kps.len() - kept.kps.len();
        tracked.matched = index.iter().map(|&k| tracked.matched[k]).collect();
        tracked.inliers = tracked
            .inliers
            .min(tracked.matched.iter().flatten().count());
        *frame = kept;
        self.moving_regions = regions;
        (dropped, to_ms(started))
    }

    /// The regions the motion check found moving in the last frame
    /// (undistorted pixel boxes; empty when off, monocular or none).
    pub fn moving_regions(&self) -> &[MovingRegion] {
        &self.moving_regions
    }

    /// Whether the frame at `timestamp` may be tracked by optical flow: the
    /// SLAM is behind ([`Pace::Behind`]), the last result did not ask for a
    /// keyframe, and [`Tracking::may_follow`].
    pub(super) fn may_follow(&self, timestamp: f64) -> bool {
        self.pace == Pace::Behind && !self.keyframe_hinted && self.tracking.may_follow(timestamp)
    }

    /// The frame's features: the last tracked frame's inliers followed by
    /// optical flow where `follow` ([`Tracking::may_follow`]) and there are
    /// any, else ORB extraction; with a rolling shutter, keypoints moved to
    /// the middle row's instant and their raw positions kept for the second
    /// pass. The third value: the map point of each followed keypoint (None:
    /// extracted).
    pub(super) fn features(
        &mut self,
        input: &RgbdInput,
        follow: bool,
    ) -> (Frame, Option<RawKeypoints>, Option<Vec<usize>>) {
        let height = input.height;
        let bounds = self.bounds(input.width, height);
        let context = FrameContext {
            camera: &self.camera,
            params: &self.params,
            bounds,
            level_scales: self.extractor.level_scales(),
            flow_pyramid: self.params.flow_on() && self.pace == Pace::Behind,
        };
        let motion = self.tracking.shutter_motion(None);
        let (mut raw, mut followed) = (None, None);
        let (tracking, extractor) = (&self.tracking, &self.extractor);
        let frame = Frame::with_keypoints(
            input,
            |gray, pyramid, keep| {
                let by_flow = pyramid
                    .filter(|_| follow)
                    .and_then(|p| tracking.follow(p, keep, input.timestamp));
                if let Some((detected, points)) = by_flow {
                    followed = Some(points);
                    return detected;
                }
                let (kps, descs, masked) = extractor.extract(gray, keep);
                Detected { kps, descs, masked }
            },
            &context,
            |kps, un, depth| {
                if let Some(motion) = motion {
                    raw = Some((un.to_vec(), depth.to_vec()));
                    tracking.undo_rolling_shutter(kps, un, depth, height, motion);
                }
            },
        );
        (frame, raw, followed)
    }

    /// Tracks `frame` in the map. A frame whose keypoints were followed by
    /// flow (`followed`) and did not hold is extracted in full and tracked
    /// again (`followed` then None, the extraction added to `extract_ms`).
    pub(super) fn track_in_map(
        &mut self,
        input: &RgbdInput,
        (frame, raw): (&mut Frame, &mut Option<RawKeypoints>),
        followed: &mut Option<Vec<usize>>,
        extract_ms: &mut f64,
    ) -> Tracked {
        if let Some(points) = followed.as_deref() {
            let reference = self
                .pending_keyframe
                .as_ref()
                .map_or(self.tracking.reference_inliers(), |p| p.inliers);
            if let Some(tracked) =
                self.tracking
                    .track_followed(&self.map, frame, (points, reference), input.timestamp)
            {
                return tracked;
            }
            *followed = None;
            let t = std::time::Instant::now();
            (*frame, *raw, _) = self.features(input, false);
            *extract_ms += to_ms(t);
        }
        self.tracking.track(&mut self.map, frame, input.timestamp)
    }

    /// RGB-D: a map of this run that is still young ([`YOUNG_MAP_KEYFRAMES`])
    /// and has been lost for [`RESTART_AFTER_LOST_S`] is given up: its
    /// keyframes are culled (the frames tracked in it keep their poses) and
    /// `frame` starts the map again at the last tracked pose. True when it
    /// did (`tracked` is then the new start's).
    pub(super) fn restart_young_map(
        &mut self,
        frame: &Frame,
        tracked: &mut Tracked,
        timestamp: f64,
    ) -> bool {
        if tracked.state != TrackingState::Lost {
            self.lost_in_a_row = (0, 0.0);
            return false;
        }
        let (n, since) = &mut self.lost_in_a_row;
        if *n == 0 {
            *since = timestamp;
        }
        *n += 1;
        let long_enough =
            *n >= RESTART_AFTER_LOST_FRAMES && timestamp - *since >= RESTART_AFTER_LOST_S;
        let young = self.map.live_keyframes().count() <= YOUNG_MAP_KEYFRAMES;
        let allowed = self.map_started_here && !self.localize_only && !self.params.is_monocular();
        let Some(last) = self.tracking.last_pose() else {
            return false;
        };
        if !long_enough || !young || !allowed {
            return false;
        }
        let Some(with_depth) = points_to_start(frame) else {
            return false;
        };
        // A keyframe still waiting for its masks belongs to the old map.
        self.pending_keyframe = None;
        self.mapped_keyframe = None;
        let live: Vec<usize> = self.map.live_keyframes().map(|(k, _)| k).collect();
        for k in live {
            self.map.cull_keyframe(k);
        }
        self.tracking.reset();
        start_rgbd_at(&mut self.tracking, &mut self.map, frame, with_depth, &last);
        self.lost_in_a_row = (0, 0.0);
        self.map_restarts += 1;
        tracing::warn!(
            "tracking lost for {RESTART_AFTER_LOST_S} s in a map of at most \
             {YOUNG_MAP_KEYFRAMES} keyframes: map started again at the last tracked pose"
        );
        *tracked = Tracked {
            state: TrackingState::Ok,
            pose_cw: last,
            inliers: frame.kps.len(),
            matched: Vec::new(),
        };
        true
    }

    /// The rolling-shutter correction's second pass on a tracked frame (with
    /// `raw`, its keypoints before the first): the pose and the readout's
    /// motion together. A relocalised frame too: in a fast turn it needs
    /// the correction as much as any (it has the motion history unless the
    /// frame before was lost). slam-bench on every 3rd shared frame: ATE
    /// 0.0203 -> 0.0142 m; every frame and every 2nd unchanged.
    pub(super) fn refine_for_shutter(
        &mut self,
        frame: &mut Frame,
        raw: Option<&RawKeypoints>,
        tracked: &mut Tracked,
        timestamp: f64,
    ) {
        let (TrackingState::Ok | TrackingState::Relocalised, Some(raw)) = (tracked.state, raw)
        else {
            return;
        };
        if let Some(refined) = self.tracking.refine_for_shutter(
            &self.map,
            frame,
            raw,
            &tracked.pose_cw,
            &tracked.matched,
            timestamp,
        ) {
            tracked.pose_cw = refined;
        }
    }

    /// Keeps a tracked frame's pose for the trajectory, relative to the
    /// newest keyframe, so that the trajectory follows the keyframes when a
    /// loop correction moves them.
    pub(super) fn record_pose(&mut self, tracked: &Tracked, timestamp: f64) {
        if !tracked.state.is_tracked() {
            return;
        }
        if let Some(reference) = self.map.keyframes.len().checked_sub(1) {
            let relative = tracked.pose_cw * self.map.keyframes[reference].pose_cw.inverse();
            self.tracked_frames.push((timestamp, reference, relative));
        }
    }
}
