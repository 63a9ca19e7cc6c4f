//! The active SLAM: tracks each frame once its route and masks are known,
//! serves the bridge, writes its files at stop.

use std::time::Duration;

use anyhow::Result;
use pipeline::clock::now_ns;
use pipeline::config::ClockMode;
use pipeline::service_loop::{Drain, Event, Flow, Service};
use pipeline::transport::{Receiver, Sender};
use pipeline::views::{FrameView, MasksView};
use scheduling::{tracking, KeyframeFacts};
use shared_types::{
    frame_flags, mask_flags, FrameHeader, Pose, RouteKind, SlamCommand, StageStamps, Track,
    TrackState,
};
use slam_backend::bridge_link::BridgeLink;
use slam_backend::tracker::{TrackInput, Tracker};
use slam_core::io::ply::write_ply;
use slam_core::{KeyframeTiming, Pace};

use crate::held::{from_segmenter, take_frame, take_masks, Arrival, Ports, State};
use crate::Outputs;

/// A map of at most this many keyframes is young (the core's measure: lost,
/// it is started again): in real time a frame the keyframe rule picks goes
/// in now with the masks it was tracked with, instead of waiting for (or
/// leaving the keyframe to) segmenter masks. On a loaded machine the niced
/// segmenter may take a second or more to answer: at 60 fps with two busy
/// processes 3 of 6 runs lost tracking for good after the first keyframe
/// without this rule, 0 of 8 with it.
pub(crate) const YOUNG_MAP_KEYFRAMES: u32 = slam_core::system::YOUNG_MAP_KEYFRAMES as u32;
/// The active SLAM: tracks the frames it holds as their routes and masks
/// come, serves the bridge, and at shutdown writes its files.
pub(crate) struct Slam<'a> {
    pub(crate) st: State,
    pub(crate) tracker: Box<dyn Tracker>,
    pub(crate) bridge: Option<BridgeLink>,
    pub(crate) commands: Option<&'a Receiver<SlamCommand, ()>>,
    pub(crate) ports: &'a Ports<'a>,
    pub(crate) poses: &'a Sender<Pose, ()>,
    pub(crate) outputs: &'a Outputs,
    pub(crate) mode: ClockMode,
    pub(crate) drain: Drain,
}

impl Service for Slam<'_> {
    type Event = Arrival;

    fn patience(&self) -> Duration {
        // A map being saved for the bridge is answered soon after it is
        // written.
        match &self.bridge {
            Some(b) if b.busy() => Duration::from_millis(50),
            _ => Duration::from_secs(1),
        }
    }

    fn woke(&mut self) {
        self.drain.restart();
    }

    fn next_event(&mut self) -> Result<Option<Arrival>> {
        self.ports.next(&mut self.drain, &mut self.st, None)
    }

    fn handle(&mut self, event: Event<Arrival>) -> Result<Flow> {
        let st = &mut self.st;
        match event {
            Event::Arrived(Arrival::Frame(sample)) => take_frame(st, sample, self.ports.tracks)?,
            Event::Arrived(Arrival::Masks(sample)) => {
                take_masks(st, sample, Some(&mut *self.tracker))
            }
            Event::Arrived(Arrival::Route(r)) => {
                st.routes.insert(r.seq, r);
            }
            Event::Arrived(Arrival::Control(_)) => {}
            Event::Tick => self.tick()?,
            Event::Shutdown => {
                if let Some(b) = &mut self.bridge {
                    b.finish()?;
                }
                finish(&mut *self.tracker, self.outputs)?;
            }
        }
        Ok(Flow::Continue)
    }
}

impl Slam<'_> {
    /// Tracks the frames that are ready (a promoted standby holds some),
    /// serves the bridge, and lets a keyframe that waited too long for its
    /// segmenter masks go in without them.
    fn tick(&mut self) -> Result<()> {
        let (st, tracker) = (&mut self.st, &mut *self.tracker);
        while let Some(track) = track_next_ready(st, tracker, self.mode)? {
            self.ports.tracks.send(track)?;
            self.poses.send(Pose::of(&track))?;
            record_loops(tracker, self.outputs.loops.as_deref())?;
        }
        if let (Some(b), Some(commands)) = (&mut self.bridge, self.commands) {
            b.publish_map(tracker)?;
            if b.serve(commands, tracker)?.reset {
                st.pending_keyframe = None;
            }
        }
        if let (Some(waiting), Some(last)) = (st.pending_keyframe, st.last) {
            if tracking::keyframe_waited_too_long(waiting, last.seq) {
                tracing::warn!(
                    seq = waiting,
                    "no segmenter masks for this keyframe; inserted with its propagated ones"
                );
                tracker.complete_keyframe(None);
                st.pending_keyframe = None;
            }
        }
        Ok(())
    }
}

/// At stop: the tracker's files (a keyframe still waiting for its masks
/// goes in), the loops, the loop-corrected trajectory and the map.
pub(crate) fn finish(tracker: &mut dyn Tracker, outputs: &Outputs) -> Result<()> {
    tracker.finish().map_err(anyhow::Error::msg)?;
    record_loops(tracker, outputs.loops.as_deref())?;
    if let Some(path) = &outputs.corrected_trajectory {
        if let Some(trajectory) = tracker.corrected_trajectory() {
            std::fs::write(path, trajectory.to_tum())
                .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
            tracing::info!("loop-corrected trajectory written to {}", path.display());
        }
    }
    if let Some(path) = &outputs.map {
        let points = tracker.map_points();
        write_ply(path, &points)
            .map_err(|e| anyhow::anyhow!("cannot write the map to {}: {e}", path.display()))?;
        tracing::info!(points = points.len(), "map written to {}", path.display());
    }
    Ok(())
}

/// Tracks one ready frame ([`tracking::next_frame`]: oldest first in
/// lockstep, newest in real time).
pub(crate) fn track_next_ready(
    st: &mut State,
    tracker: &mut dyn Tracker,
    mode: ClockMode,
) -> Result<Option<Track>> {
    let ready: Vec<bool> = st
        .frames
        .iter()
        .map(|f| {
            let seq = f.sample.user_header().seq;
            let route = st
                .routes
                .get(&seq)
                .and_then(|r| RouteKind::from_u32(r.kind));
            tracking::frame_ready(route, st.masks.iter().any(|m| m.user_header().seq == seq))
        })
        .collect();
    let index = tracking::next_frame(mode, &ready);
    let Some(index) = index else { return Ok(None) };
    let timing = keyframe_timing(st, index, mode.is_realtime());
    let pace = if st.flow_pace.behind(mode) {
        Pace::Behind
    } else {
        Pace::KeepingUp
    };
    let (track, waiting) = make_track(st, index, tracker, timing, pace)?;
    st.flow_pace.tracked(track.seq);
    // Everything up to this frame is consumed.
    let seq = track.seq;
    match waiting {
        WaitingKeyframe::ThisFrame => st.pending_keyframe = Some(seq),
        WaitingKeyframe::InsertedWithout => st.pending_keyframe = None,
        WaitingKeyframe::Unchanged => {}
    }
    st.last = Some(track);
    st.frames.retain(|f| f.sample.user_header().seq > seq);
    st.masks.retain(|m| m.user_header().seq > seq);
    st.routes.retain(|&s, _| s > seq);
    Ok(Some(track))
}

/// Appends the loops the tracker closed since the last call to `path`
/// (`loops.csv`; the SLAM core logs each one as it closes).
pub(crate) fn record_loops(
    tracker: &mut dyn Tracker,
    path: Option<&std::path::Path>,
) -> Result<()> {
    let loops = tracker.take_loops();
    match path {
        Some(path) if !loops.is_empty() => run_folder::loops_csv::append(path, &loops)
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display())),
        _ => Ok(()),
    }
}

/// When the frame at `index` may become a keyframe
/// ([`scheduling::keyframe_timing`]), from what this service knows of its masks.
pub(crate) fn keyframe_timing(st: &State, index: usize, realtime: bool) -> KeyframeTiming {
    let seq = st.frames[index].sample.user_header().seq;
    // At most one masks sample per frame is held (a frame's segmenter
    // masks replace its propagated ones).
    let own_masks = st.masks.iter().find(|m| m.user_header().seq == seq);
    slam_backend::convert::keyframe_timing(scheduling::keyframe_timing(KeyframeFacts {
        realtime,
        route: st
            .routes
            .get(&seq)
            .and_then(|r| RouteKind::from_u32(r.kind)),
        segmented: own_masks.is_some_and(from_segmenter),
        young_map: st
            .last
            .is_some_and(|t| (1..=YOUNG_MAP_KEYFRAMES).contains(&t.counts.keyframes)),
        segmenter_alive: tracking::segmenter_alive(seq, st.last_segmented),
        scene_empty: st.scene_empty()
            && own_masks.is_some_and(|m| m.user_header().num_instances == 0),
        asked_before: st.last.is_some_and(|t| t.next_needs_keyframe != 0),
    }))
}

/// The Track of the ready frame at `index`: tracked with its masks, or
/// skipped when the reader marked it bad (answered only once routed, so the
/// supervisor has the reason on file); with it, what became of the keyframe
/// waiting for the segmenter's masks.
pub(crate) fn make_track(
    st: &State,
    index: usize,
    tracker: &mut dyn Tracker,
    keyframe: KeyframeTiming,
    pace: Pace,
) -> Result<(Track, WaitingKeyframe)> {
    let held = &st.frames[index];
    let header = held.sample.user_header();
    let seq = header.seq;
    let route = st.routes[&seq];
    let mut stamps = route.stamps;
    // Refused: the supervisor found an external frame unusable (recorded
    // why); its pixels are not read.
    if header.has(frame_flags::BAD_INPUT)
        || RouteKind::from_u32(route.kind) == Some(RouteKind::Refuse)
    {
        return Ok((skipped_track(header, stamps), WaitingKeyframe::Unchanged));
    }
    // Not refused yet malformed (the supervisor missed a frame?): skipped
    // with a warning, this process stays up.
    let frame = match FrameView::new(header, held.sample.payload()) {
        Ok(frame) => frame,
        Err(e) => {
            tracing::warn!(seq, "not tracking a malformed frame: {e:#}");
            return Ok((skipped_track(header, stamps), WaitingKeyframe::Unchanged));
        }
    };
    let masks_sample = st.masks.iter().find(|m| m.user_header().seq == seq);
    let masks_view = match masks_sample {
        Some(m) if RouteKind::from_u32(route.kind) != Some(RouteKind::Skip) => {
            stamps = m.user_header().stamps;
            let failed = m.user_header().has(mask_flags::FAILED);
            (!failed)
                .then(|| MasksView::new(m.user_header(), m.payload()))
                .transpose()?
        }
        _ => None,
    };
    stamps.slam_received_ns = held.received_ns;
    stamps.track_start_ns = now_ns();
    let outcome = tracker.track(&TrackInput {
        seq,
        frame: &frame,
        masks: masks_view.as_ref(),
        keyframe,
        pace,
    });
    stamps.track_done_ns = now_ns();
    let track = Track {
        seq,
        source_timestamp: header.source_timestamp,
        pose: outcome.pose,
        state: outcome.state as u32,
        keyframe_inserted: outcome.keyframe_inserted as u32,
        next_needs_keyframe: outcome.next_needs_keyframe as u32,
        mask_source: masks_view.map(|m| m.source() as u32).unwrap_or(0),
        mask_flags: masks_view.map(|m| m.header.flags).unwrap_or(0),
        counts: outcome.counts,
        stamps,
    };
    let waiting = if outcome.keyframe_pending {
        WaitingKeyframe::ThisFrame
    } else if outcome.waiting_keyframe_inserted {
        WaitingKeyframe::InsertedWithout
    } else {
        WaitingKeyframe::Unchanged
    };
    Ok((track, waiting))
}

/// What tracking a frame did to the keyframe waiting for segmenter masks.
pub(crate) enum WaitingKeyframe {
    Unchanged,
    /// This frame's keyframe waits for them now.
    ThisFrame,
    /// The waiting one went in without them (tracking weakened).
    InsertedWithout,
}

pub(crate) fn skipped_track(h: &FrameHeader, mut stamps: StageStamps) -> Track {
    stamps.track_done_ns = now_ns();
    Track {
        seq: h.seq,
        source_timestamp: h.source_timestamp,
        state: TrackState::Skipped as u32,
        stamps,
        ..Default::default()
    }
}
