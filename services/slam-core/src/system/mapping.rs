//! The map's hand-over between tracking and the threads behind it: local
//! mapping takes the map after each keyframe and gives it back before the
//! next frame is tracked in it; loop closing works on its own copy and its
//! corrections are merged when the map comes back.

use super::*;

impl System {
    /// The map, once local mapping has given it back and loop closing has
    /// finished.
    pub fn map(&mut self) -> &Map {
        self.finish_loops();
        &self.map
    }

    /// Points local mapping triangulated and fused so far (once it has
    /// given the map back).
    pub fn mapping_counts(&mut self) -> MappingCounts {
        self.settle();
        self.mapped
    }

    /// Local mapping for keyframe `id`: on the mapping thread (the map goes
    /// with it until `settle`) or, without one, here and now. Every
    /// `every_keyframes`-th keyframe, the mapped map is copied for the
    /// checkpoint writer.
    pub(super) fn start_mapping(&mut self, id: usize) {
        let checkpoint = self
            .checkpointer
            .as_ref()
            .filter(|c| self.keyframes_inserted.is_multiple_of(c.every_keyframes()))
            .map(Checkpointer::sender);
        let snapshot = self.snapshots.as_mut().map(|(slot, period, last)| {
            let due = last.is_none_or(|t| t.elapsed() >= *period);
            if due {
                *last = Some(std::time::Instant::now());
            }
            SnapshotRequest {
                slot: slot.clone(),
                due,
            }
        });
        self.mapped_keyframe = Some((id, self.map.keyframes[id].pose_cw));
        if let Some(mapper) = &self.mapper {
            match mapper.submit(
                std::mem::take(&mut self.map),
                id,
                checkpoint.clone(),
                snapshot.clone(),
            ) {
                Ok(()) => {
                    self.mapping = Mapping::OnThread;
                    return;
                }
                Err(map) => {
                    tracing::error!("local mapping thread gone: mapping inline from now on");
                    self.map = map;
                    self.mapper = None;
                }
            }
        }
        let report = map_keyframe(
            &mut self.map,
            id,
            &self.camera,
            &self.params,
            &self.vocabulary,
            &mut self.inline_loops,
        );
        if let Some(to_writer) = checkpoint {
            to_writer.offer(&self.map);
        }
        if let Some(request) = snapshot {
            request.fulfil(&self.map, id, &report);
        }
        self.mapping_ms = report.ms;
        self.mapping = Mapping::Inline(report);
    }

    /// Takes the map back from local mapping (waiting for it) and applies
    /// what it did: after local bundle adjustment tracking goes on from the
    /// newest keyframe's adjusted pose (that keyframe is the last tracked
    /// frame). If the mapping thread died the map is lost: tracking starts
    /// a new one with the next frame.
    pub(super) fn settle(&mut self) {
        let report = match std::mem::replace(&mut self.mapping, Mapping::Idle) {
            Mapping::Idle => return,
            Mapping::Inline(report) => report,
            Mapping::OnThread => match self.mapper.as_ref().and_then(|m| m.collect()) {
                Some((map, report)) => {
                    self.map = map;
                    self.mapping_ms = report.ms;
                    report
                }
                None => {
                    tracing::error!(
                        "local mapping thread died: map lost, starting a new one (mapping inline)"
                    );
                    self.mapper = None;
                    self.map = Map::default();
                    self.tracking.reset();
                    return;
                }
            },
        };
        self.mapped += report.counts;
        for r in &report.loops {
            self.loop_reports.push(*r);
            if let Some(closed) = r.closed {
                tracing::info!(
                    "loop closed: keyframe {} with {} ({} inliers), corrected {:.3} m / {:.2} deg \
                     (correction {:.0} ms, global BA {:.0} ms)",
                    closed.keyframe,
                    closed.matched,
                    closed.inliers,
                    closed.correction_m,
                    closed.correction_deg,
                    r.correct_ms,
                    r.global_ba_ms,
                );
                self.loops.push(closed);
            }
        }
        if let Some((id, before)) = self.mapped_keyframe.take() {
            if let Some(kf) = self.map.keyframes.get(id).filter(|_| report.adjusted) {
                self.tracking.follow_keyframe(&before, &kf.pose_cw);
            }
        }
    }

    /// Settles local mapping, then waits for the loop-closing thread to
    /// finish what it was given and merges its corrections.
    pub(super) fn finish_loops(&mut self) {
        self.settle();
        let Some(mapper) = &self.mapper else {
            return;
        };
        if !self.params.loop_closing {
            return;
        }
        if let Some(id) = self.map.keyframes.len().checked_sub(1) {
            self.mapped_keyframe = Some((id, self.map.keyframes[id].pose_cw));
        }
        match mapper.flush(std::mem::take(&mut self.map)) {
            Ok(()) => self.mapping = Mapping::OnThread,
            Err(map) => self.map = map,
        }
        self.settle();
    }
}
