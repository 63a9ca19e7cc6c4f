//! What the SLAM holds between wake-ups (frames, masks, routes) and how a
//! wake-up drains its receivers into it.

use std::collections::{HashMap, VecDeque};

use anyhow::Result;
use iceoryx2::sample::Sample;
use pipeline::clock::now_ns;
use pipeline::service_loop::Drain;
use pipeline::transport::{Receiver, Sender, Svc};
use pipeline::views::MasksView;
use scheduling::tracking;
use shared_types::{
    frame_flags, mask_flags, Control, FrameHeader, MaskSource, MasksHeader, Route, Track,
};
use slam_backend::tracker::Tracker;

pub(crate) type FrameSample = Sample<Svc, [u8], FrameHeader>;
pub(crate) type MasksSample = Sample<Svc, [u8], MasksHeader>;

pub(crate) struct HeldFrame {
    pub(crate) sample: FrameSample,
    pub(crate) received_ns: u64,
}

/// What the service remembers between wake-ups.
#[derive(Default)]
pub(crate) struct State {
    pub(crate) frames: VecDeque<HeldFrame>,
    pub(crate) masks: VecDeque<MasksSample>,
    pub(crate) routes: HashMap<u64, Route>,
    pub(crate) last: Option<Track>,
    /// Real time: the frame whose keyframe waits for its segmenter masks.
    pub(crate) pending_keyframe: Option<u64>,
    /// Real time: the newest frame the segmenter answered for.
    pub(crate) last_segmented: Option<u64>,
    /// Real time: the segmenter's newest answer found no object (and did
    /// not fail).
    pub(crate) segmented_empty: bool,
    /// Real time: the newest frame on which the propagator saw something
    /// move that it does not follow ([`mask_flags::SEGMENT_WANTED`]).
    pub(crate) last_moved: Option<u64>,
    /// Real time: whether the pipeline is behind the camera (frames may
    /// then be tracked by optical flow).
    pub(crate) flow_pace: scheduling::tracking::FlowPace,
}

impl State {
    /// Nothing dynamic in view as far as the masks tell: the segmenter's
    /// newest answer was empty and nothing moved since.
    pub(crate) fn scene_empty(&self) -> bool {
        self.segmented_empty
            && self
                .last_moved
                .is_none_or(|m| self.last_segmented.is_some_and(|s| m < s))
    }
}

/// What arrives for the SLAM, in the order a wake-up drains it.
pub(crate) enum Arrival {
    Frame(FrameSample),
    Masks(MasksSample),
    Route(Route),
    Control(Control),
}

/// The receivers the SLAM (and its standby) drain, the Tracks sender a
/// replayed frame is answered on, and how many frames and masks may be held
/// (within the topics' borrow limits).
pub(crate) struct Ports<'a> {
    pub(crate) frames: &'a Receiver<[u8], FrameHeader>,
    pub(crate) masks: &'a Receiver<[u8], MasksHeader>,
    pub(crate) routes: &'a Receiver<Route, ()>,
    pub(crate) tracks: &'a Sender<Track, ()>,
    pub(crate) max_frames: usize,
    pub(crate) max_masks: usize,
}

impl Ports<'_> {
    /// The next arrival of this wake-up: frames, then masks, then routes,
    /// then (a standby's) commands. Room for a frame or masks is made
    /// before it is taken: the oldest held goes.
    pub(crate) fn next(
        &self,
        drain: &mut Drain,
        st: &mut State,
        control: Option<&Receiver<Control, ()>>,
    ) -> Result<Option<Arrival>> {
        drain.next(4, |stage, entering| {
            Ok(match stage {
                0 => make_room_and_take(
                    self.frames.entered(entering),
                    &mut st.frames,
                    self.max_frames,
                )?
                .map(Arrival::Frame),
                1 => {
                    make_room_and_take(self.masks.entered(entering), &mut st.masks, self.max_masks)?
                        .map(Arrival::Masks)
                }
                2 => self.routes.entered(entering).next()?.map(Arrival::Route),
                _ => match control {
                    Some(control) => control.entered(entering).next()?.map(Arrival::Control),
                    None => None,
                },
            })
        })
    }
}

/// The next sample of `receiver`, the oldest of `held` let go first when
/// `max` are held (the topic's borrow limit).
fn make_room_and_take<H: std::fmt::Debug + iceoryx2::prelude::ZeroCopySend, T>(
    receiver: &Receiver<[u8], H>,
    held: &mut VecDeque<T>,
    max: usize,
) -> Result<Option<Sample<Svc, [u8], H>>> {
    if !receiver.has_samples()? {
        return Ok(None);
    }
    if held.len() >= max {
        held.pop_front();
    }
    receiver.next_sample()
}

/// A frame published since the last wake-up, held; a replayed frame
/// already tracked gets its Track again.
pub(crate) fn take_frame(
    st: &mut State,
    sample: FrameSample,
    tracks: &Sender<Track, ()>,
) -> Result<()> {
    let h = *sample.user_header();
    if h.has(frame_flags::END_OF_STREAM) || h.has(frame_flags::DROPPED_AT_SOURCE) {
        return Ok(());
    }
    if let Some(last) = st.last.filter(|l| h.seq <= l.seq) {
        if h.seq == last.seq {
            tracks.send(last)?; // replayed frame: answer again
        }
        return Ok(());
    }
    st.frames.retain(|f| f.sample.user_header().seq != h.seq);
    st.frames.push_back(HeldFrame {
        sample,
        received_ns: now_ns(),
    });
    Ok(())
}

/// Masks published since the last wake-up, held (a frame's segmenter
/// masks beat its propagated ones); segmenter masks complete the keyframe
/// waiting for them (`tracker`: None for a standby).
pub(crate) fn take_masks(st: &mut State, sample: MasksSample, tracker: Option<&mut dyn Tracker>) {
    if sample.user_header().has(mask_flags::GONE) {
        return; // that frame will not be tracked (the supervisor drops it)
    }
    let header = sample.user_header();
    let seq = header.seq;
    let segmented = from_segmenter(&sample);
    if header.has(mask_flags::SEGMENT_WANTED) {
        st.last_moved = st.last_moved.max(Some(seq));
    }
    if segmented {
        if st.last_segmented.is_none_or(|s| seq > s) {
            st.segmented_empty = header.num_instances == 0 && !header.has(mask_flags::FAILED);
            st.last_segmented = Some(seq);
        }
        let waiting = st
            .pending_keyframe
            .filter(|&k| tracking::completes_waiting_keyframe(k, seq));
        // A standby has no tracker and no keyframe waiting.
        if let (Some(waiting), Some(tracker)) = (waiting, tracker) {
            // The pending keyframe's own masks (or a newer frame's:
            // its own will not come) complete it.
            let own = waiting == seq;
            let view = MasksView::new(sample.user_header(), sample.payload());
            let failed = sample.user_header().has(mask_flags::FAILED);
            let masks = view.ok().filter(|_| own && !failed);
            tracker.complete_keyframe(masks.as_ref());
            st.pending_keyframe = None;
            tracing::debug!(seq = waiting, own, "pending keyframe inserted");
        }
    }
    if st.last.is_some_and(|l| seq <= l.seq) {
        // Real time: the segmenter's result for a frame already
        // tracked with propagated masks (the propagator takes it as
        // its prompt), or a propagator's after the segmenter's.
        return;
    }
    let segmented_held = |m: &MasksSample| m.user_header().seq == seq && from_segmenter(m);
    if !segmented && st.masks.iter().any(segmented_held) {
        return; // a frame's segmenter masks beat its propagated ones
    }
    st.masks.retain(|m| m.user_header().seq != seq);
    st.masks.push_back(sample);
}

pub(crate) fn from_segmenter(m: &MasksSample) -> bool {
    m.user_header().source == MaskSource::Segmenter as u32
}
