//! The service shared by the segmenter and the propagator, on the one
//! service loop ([`crate::service_loop`]): routes, frames and masks arrive
//! as events, each tick works through the queue.
//!
//! A mask worker holds the last few frames in place (borrowed samples, no
//! copies), takes the routes addressed to it, runs its [`MaskModel`] on the
//! routed frame and publishes a label image plus instances on `masks`. The
//! propagator also listens to the segmenter's masks: they are its prompts.

use std::collections::VecDeque;

use anyhow::Result;
use iceoryx2::sample::Sample;
use scheduling::worker::{Next, WorkQueue};
use shared_types::names::Topic;
use shared_types::{
    mask_flags, FrameHeader, MaskSource, MasksHeader, Route, RouteKind, MAX_INSTANCES,
};

use crate::clock::now_ns;
use crate::runtime::ServiceContext;
use crate::service_loop::{self, Drain, Event, Flow, Service};
use crate::transport::{attach, waitset, Receiver, Sender, Svc};
use crate::views::{FrameView, MasksView};

pub use mask_model::{model_from_config, MaskModel, ModelFactory, NoObjects, Unavailable};

/// Frames a worker keeps borrowed (bounded by the frames topic's QoS).
const HELD_FRAMES: usize = 3;

type FrameSample = Sample<Svc, [u8], FrameHeader>;
type MasksSample = Sample<Svc, [u8], MasksHeader>;

/// Mask sets the segmenter keeps (within the masks topic's borrow limit):
/// in real time the propagator publishes newer frames' masks while a
/// keyframe is segmented, and the one before the keyframe must still be
/// there.
const RECENT_MASKS: usize = 3;

/// A mask worker's state between wake-ups.
struct Worker {
    role: MaskSource,
    model: Box<dyn MaskModel>,
    /// Routes to work on (the scheduling crate's queue rule).
    queue: WorkQueue<Route>,
    /// The newest frames, held in place (not copied).
    held: VecDeque<FrameSample>,
    /// The segmenter's newest masks (held in place, not copied).
    recent: VecDeque<MasksSample>,
    /// Propagator: frames the segmenter works on whose routes came before
    /// them; kept when they arrive.
    keep_on_arrival: VecDeque<u64>,
    /// Routed frames already replaced by newer ones (real time): counted and
    /// said once at the end instead of a warning per frame.
    not_held: u64,
    published: u64,
}

/// Runs a mask worker until SIGTERM.
pub fn run(ctx: ServiceContext, role: MaskSource, model: Box<dyn MaskModel>) -> Result<()> {
    let frames = ctx.transport.slice_receiver::<FrameHeader>(Topic::Frames)?;
    let routes = ctx.transport.receiver::<Route>(Topic::Routes)?;
    // Both read masks: the propagator the segmenter's (its prompts), the
    // segmenter the newest before the frame it segments (`infer_after`).
    let masks_in = ctx.transport.slice_receiver::<MasksHeader>(Topic::Masks)?;
    let masks_out = ctx
        .transport
        .slice_sender::<MasksHeader>(Topic::Masks, ctx.config.max_mask_bytes())?;
    let ws = waitset()?;
    let _a = attach(&ws, &frames)?;
    let _b = attach(&ws, &routes)?;
    let _c = attach(&ws, &masks_in)?;
    ctx.announce_ready()?;
    tracing::info!("{} ready with model '{}'", role.as_str(), model.name());
    let worker = Worker {
        role,
        model,
        queue: WorkQueue::new(ctx.config.run.mode),
        held: VecDeque::new(),
        recent: VecDeque::new(),
        keep_on_arrival: VecDeque::new(),
        not_held: 0,
        published: 0,
    };
    service_loop::run(
        &ws,
        &mut WorkerLoop {
            worker,
            routes: &routes,
            frames: &frames,
            masks_in: &masks_in,
            masks_out: &masks_out,
            drain: Drain::default(),
        },
    )
}

/// What arrives for a mask worker, in the order a wake-up drains it.
enum Arrival {
    Route(Route),
    Frame(FrameSample),
    Masks(MasksSample),
}

/// A mask worker with its ports, as the service loop drives it.
struct WorkerLoop<'a> {
    worker: Worker,
    routes: &'a Receiver<Route, ()>,
    frames: &'a Receiver<[u8], FrameHeader>,
    masks_in: &'a Receiver<[u8], MasksHeader>,
    masks_out: &'a Sender<[u8], MasksHeader>,
    drain: Drain,
}

impl Service for WorkerLoop<'_> {
    type Event = Arrival;

    fn woke(&mut self) {
        self.drain.restart();
    }

    fn next_event(&mut self) -> Result<Option<Arrival>> {
        let (routes, frames, masks_in) = (self.routes, self.frames, self.masks_in);
        self.drain.next(3, |stage, entering| {
            Ok(match stage {
                0 => routes.entered(entering).next()?.map(Arrival::Route),
                1 => frames.entered(entering).next_sample()?.map(Arrival::Frame),
                _ => masks_in
                    .entered(entering)
                    .next_sample()?
                    .map(Arrival::Masks),
            })
        })
    }

    fn handle(&mut self, event: Event<Arrival>) -> Result<Flow> {
        match event {
            Event::Arrived(Arrival::Route(r)) => self.worker.on_route(r),
            Event::Arrived(Arrival::Frame(sample)) => self.worker.take_frame(sample),
            Event::Arrived(Arrival::Masks(sample)) => self.worker.take_masks(sample)?,
            Event::Tick => self.worker.work(self.masks_out)?,
            Event::Shutdown => self.worker.say_summary(),
        }
        Ok(Flow::Continue)
    }
}

impl Worker {
    fn mine(&self, kind: RouteKind) -> bool {
        match self.role {
            MaskSource::Segmenter => kind.segments(),
            _ => kind.propagates(),
        }
    }

    fn on_route(&mut self, r: Route) {
        tracing::debug!(seq = r.seq, kind = r.kind, held = self.held.len(), "route");
        let kind = RouteKind::from_u32(r.kind);
        if self.role == MaskSource::Propagator && kind.is_some_and(|k| k.segments()) {
            // Kept as soon as the frame is here: in real time newer
            // frames may replace it before this worker's turn, and its
            // prompt then found no image (under load 6-9 of 24 prompts
            // a run, 30 fps with 2 busy processes).
            match held_frame(&self.held, r.seq) {
                Some(frame) => self.model.keep(&frame),
                None => {
                    self.keep_on_arrival.push_back(r.seq);
                    if self.keep_on_arrival.len() > HELD_FRAMES {
                        self.keep_on_arrival.pop_front();
                    }
                }
            }
        }
        if kind.is_some_and(|k| self.mine(k)) {
            self.queue.on_route(r.seq, r);
        }
    }

    /// A frame published since the last wake-up, held (the newest
    /// [`HELD_FRAMES`]).
    fn take_frame(&mut self, sample: FrameSample) {
        let h = sample.user_header();
        if !h.carries_pixels() {
            return;
        }
        self.held.retain(|s| s.user_header().seq != h.seq);
        if let Some(i) = self.keep_on_arrival.iter().position(|&s| s == h.seq) {
            self.keep_on_arrival.remove(i);
            if let Ok(frame) = FrameView::new(h, sample.payload()) {
                self.model.keep(&frame);
            }
        }
        self.held.push_back(sample);
        while self.held.len() > HELD_FRAMES {
            self.held.pop_front();
        }
    }

    /// Masks published since the last wake-up: the propagator's prompts;
    /// the segmenter keeps the newest ones.
    fn take_masks(&mut self, sample: MasksSample) -> Result<()> {
        let h = sample.user_header();
        if h.has(mask_flags::GONE) || h.has(mask_flags::FAILED) {
            return Ok(()); // no masks came for that frame
        }
        match self.role {
            MaskSource::Propagator => {
                let masks = MasksView::new(h, sample.payload())?;
                if masks.source() == MaskSource::Segmenter {
                    let frame = held_frame(&self.held, masks.header.seq);
                    self.model.prompt(frame.as_ref(), &masks);
                }
            }
            _ => {
                self.recent.retain(|s| s.user_header().seq != h.seq);
                self.recent.push_back(sample);
                while self.recent.len() > RECENT_MASKS {
                    self.recent.pop_front();
                }
            }
        }
        Ok(())
    }

    /// Works through the queue as far as the held frames allow; routes the
    /// queue passes over are told gone in real time.
    fn work(&mut self, out: &Sender<[u8], MasksHeader>) -> Result<()> {
        for route in self.queue.keep_newest() {
            publish_gone(out, self.role, &route, 0)?;
        }
        loop {
            let oldest = self.held.front().map(|s| s.user_header().seq);
            let held = &self.held;
            let is_held = |seq| held.iter().any(|s| s.user_header().seq == seq);
            let route = match self.queue.next(is_held, oldest) {
                Next::Work(route) => route,
                Next::PassOver { route, tell_gone } => {
                    self.not_held += 1;
                    if tell_gone {
                        // Real time: expected under load, counted at the end.
                        tracing::debug!(seq = route.seq, "routed frame no longer held; skipping");
                        publish_gone(out, self.role, &route, 0)?;
                    } else {
                        tracing::warn!(seq = route.seq, "routed frame no longer held; skipping");
                    }
                    continue;
                }
                Next::Wait => return Ok(()),
            };
            let sample = self
                .held
                .iter()
                .find(|s| s.user_header().seq == route.seq)
                .expect("the queue works only on held frames");
            tracing::debug!(seq = route.seq, "making masks");
            let previous = self
                .recent
                .iter()
                .filter(|m| m.user_header().seq < route.seq)
                .max_by_key(|m| m.user_header().seq)
                .and_then(|m| MasksView::new(m.user_header(), m.payload()).ok());
            let made = MaskJob {
                role: self.role,
                route: &route,
                sample,
                previous,
                realtime: self.queue.mode().is_realtime(),
            };
            // Frames no worker could take are counted by the model that
            // said so (the remote link's summary).
            if publish_masks(out, &mut *self.model, made)? {
                self.published += 1;
            }
        }
    }

    /// At stop: what the worker did, in one or three lines.
    fn say_summary(&self) {
        let role = self.role.as_str();
        tracing::info!("{role}: masks published: {}", self.published);
        if let Some(summary) = self.model.summary() {
            tracing::info!("{role}: {summary}");
        }
        if self.not_held > 0 {
            tracing::info!(
                "{role}: {} routed frames had been replaced by newer ones before their turn (real time: the supervisor counts them as dropped)",
                self.not_held
            );
        }
    }
}

/// Frame `seq` among the held samples, as a view.
fn held_frame(held: &VecDeque<FrameSample>, seq: u64) -> Option<FrameView<'_>> {
    held.iter()
        .find(|s| s.user_header().seq == seq)
        .and_then(|s| FrameView::new(s.user_header(), s.payload()).ok())
}

/// Real time: no masks will come for `route`'s frame (replaced before this
/// worker's turn, or `extra_flags` says why).
fn publish_gone(
    out: &Sender<[u8], MasksHeader>,
    role: MaskSource,
    route: &Route,
    extra_flags: u32,
) -> Result<()> {
    let mut sample = out.loan(0)?;
    *sample.user_header_mut() = MasksHeader {
        seq: route.seq,
        source: role as u32,
        flags: mask_flags::GONE | extra_flags,
        stamps: route.stamps,
        ..Default::default()
    };
    out.publish(sample)
}

/// One frame to make masks for.
struct MaskJob<'a> {
    role: MaskSource,
    route: &'a Route,
    sample: &'a FrameSample,
    previous: Option<MasksView<'a>>,
    realtime: bool,
}

/// Makes and publishes the masks of `job`; false when no worker could take
/// the frame ([`Unavailable`]).
fn publish_masks(
    out: &Sender<[u8], MasksHeader>,
    model: &mut dyn MaskModel,
    job: MaskJob,
) -> Result<bool> {
    let MaskJob {
        role,
        route,
        sample,
        previous,
        realtime,
    } = job;
    let start_ns = now_ns();
    let fh = sample.user_header();
    let mut header = MasksHeader {
        seq: route.seq,
        source: role as u32,
        width: fh.width,
        height: fh.height,
        ..Default::default()
    };
    header.stamps = route.stamps;
    header.stamps.masks_start_ns = start_ns;
    let mut out_sample = out.loan(fh.width as usize * fh.height as usize)?;
    // Masks (or a failure: the frame goes unmasked) rather than "no worker
    // could take it" ([`Unavailable`]).
    let mut masked = true;
    let result = FrameView::new(fh, sample.payload())
        .and_then(|frame| model.infer_after(&frame, previous.as_ref(), out_sample.payload_mut()));
    match result {
        Ok(instances) => {
            if header.set_instances(&instances) < instances.len() {
                tracing::warn!(
                    seq = route.seq,
                    found = instances.len(),
                    "keeping the first {MAX_INSTANCES} instances"
                );
            }
            if model.wants_segment() {
                header.flags |= mask_flags::SEGMENT_WANTED;
            }
            header.flags |= model.origin_flags();
        }
        Err(e) if e.is::<Unavailable>() => {
            tracing::debug!(seq = route.seq, "{e:#}");
            if realtime {
                // The propagator carries masks; the segmenter is free again.
                drop(out_sample);
                publish_gone(out, role, route, mask_flags::UNAVAILABLE)?;
                return Ok(false);
            }
            // Lockstep: the frame goes on unmasked, as after a failure.
            out_sample.payload_mut().fill(0);
            header.flags |= mask_flags::FAILED | mask_flags::UNAVAILABLE;
            masked = false;
        }
        Err(e) => {
            // The frame goes on unmasked rather than stalling the pipeline.
            tracing::error!(seq = route.seq, "{} failed: {e:#}", model.name());
            out_sample.payload_mut().fill(0);
            header.flags |= mask_flags::FAILED;
        }
    }
    let done = now_ns();
    header.inference_ns = done - start_ns;
    header.stamps.masks_done_ns = done;
    *out_sample.user_header_mut() = header;
    out.publish(out_sample)?;
    Ok(masked)
}
