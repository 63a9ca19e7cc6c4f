//! The keyframe decision (ORB-SLAM2's rule, deferred while masks are
//! awaited) and what inserting a keyframe sets going.

use super::*;

impl System {
    /// Moves the motion model on with a tracked frame and inserts it as a
    /// keyframe when ORB-SLAM2's rule asks (never in localization mode,
    /// not while another keyframe is pending; `timing` may defer it); an
    /// untracked frame marks tracking lost.
    pub(super) fn decide_keyframe(
        &mut self,
        tracked: &Tracked,
        frame: &Frame,
        timestamp: f64,
        started: bool,
        timing: KeyframeTiming,
    ) -> Decision {
        if !tracked.state.is_tracked() {
            if !self.map.keyframes.is_empty() {
                self.tracking.mark_lost();
            }
            return Decision::None;
        }
        self.tracking.accept(tracked, timestamp);
        self.tracking.remember_image(frame, &self.moving_regions);
        if started {
            return Decision::Inserted;
        }
        let wanted = !self.localize_only
            && tracked.state.is_in_map()
            && self.pending_keyframe.is_none()
            && self.tracking.need_keyframe(tracked, frame, &self.map);
        if wanted && timing == KeyframeTiming::Now {
            self.tracking.insert_keyframe(
                &mut self.map,
                frame,
                &tracked.pose_cw,
                &tracked.matched,
                tracked.inliers,
            );
            return Decision::Inserted;
        }
        self.tracking.count_frame();
        match (wanted, timing) {
            (true, KeyframeTiming::AfterBetterMasks) => Decision::Pending,
            (true, KeyframeTiming::NotThisFrame) => Decision::Wanted,
            _ => Decision::None,
        }
    }

    /// Whether tracking has weakened ([`WEAKENED`]) with `tracked`.
    pub(super) fn weakened(&mut self, tracked: &Tracked) -> bool {
        let reference = self
            .pending_keyframe
            .as_ref()
            .map_or(self.tracking.reference_inliers(), |p| p.inliers);
        let weak =
            tracked.state.is_in_map() && (tracked.inliers as f64) < WEAKENED * reference as f64;
        let weakened = weak && self.weak_before;
        self.weak_before = weak;
        weakened
    }

    /// Whether a keyframe waits for [`System::complete_keyframe`].
    pub fn keyframe_pending(&self) -> bool {
        self.pending_keyframe.is_some()
    }

    /// Inserts the pending keyframe, without its features inside `mask`
    /// (its better masks: labels, non-zero dynamic, the frame's size;
    /// `None`: they never came, it goes in as tracked). Its map points that
    /// local mapping culled meanwhile are not observed. True when a
    /// keyframe was inserted.
    pub fn complete_keyframe(&mut self, mask: Option<&[u8]>) -> bool {
        let Some(pending) = self.pending_keyframe.take() else {
            return false;
        };
        self.settle();
        let PendingKeyframe {
            frame,
            pose_cw,
            matched,
            inliers,
            timestamp,
            frames_counted,
        } = pending;
        let (frame, matched) = match mask.filter(|m| m.len() == frame.width * frame.height) {
            Some(labels) => {
                let mask = DynamicMask::new(
                    labels,
                    frame.width,
                    frame.height,
                    self.params.mask_dilation_px,
                );
                let (kept, index) = frame.without(|k| !mask.keeps(k.x, k.y));
                let matched = index.iter().map(|&k| matched[k]).collect();
                (kept, matched)
            }
            None => (frame, matched),
        };
        let matched: Vec<Option<usize>> = matched
            .into_iter()
            .map(|m| m.filter(|&p| self.map.points.get(p).is_some_and(|p| p.is_live())))
            .collect();
        let inliers = inliers.min(matched.iter().flatten().count());
        // The frames tracked while it waited count towards the next
        // keyframe: the cadence runs from the keyframe's own frame, as in
        // lockstep, not from when its masks came (at 60 fps the segmenter
        // takes 5-8 frames: real-time maps had 21 keyframes where lockstep
        // has 33).
        let waited = self
            .tracking
            .frames_since_keyframe()
            .saturating_sub(frames_counted);
        self.tracking
            .insert_keyframe(&mut self.map, &frame, &pose_cw, &matched, inliers);
        self.tracking.backdate_keyframe(waited, timestamp);
        self.keyframes_inserted += 1;
        self.start_mapping(self.map.keyframes.len() - 1);
        true
    }

    /// This frame became a keyframe: local mapping starts on it, and the
    /// map's first keyframe (`started`) is checkpointed at once.
    pub(super) fn keyframe_inserted(&mut self, started: bool) {
        self.keyframes_inserted += 1;
        if started {
            if let Some(c) = &self.checkpointer {
                c.write_now(&self.map);
            }
        }
        self.start_mapping(self.map.keyframes.len() - 1);
    }

    /// Whether the next frame should be a keyframe (no keyframe went in or
    /// waits), as the result's hint to the supervisor.
    pub(super) fn hint_keyframe(&mut self, decision: Decision, inliers: usize) -> bool {
        if self.localize_only {
            // No keyframes come: the hint asks for fresh masks at the
            // keyframe cadence (and when lost).
            self.tracking.refresh_due()
        } else {
            // The rule picked a frame that could not be one
            // (`NotThisFrame`): the hint asks for the next.
            decision == Decision::Wanted || self.tracking.next_needs_keyframe(inliers)
        }
    }
}
