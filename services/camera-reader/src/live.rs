//! A live V4L2 camera played into the `frames` topic, real time at the
//! camera's own rate.

use std::time::Duration;

use anyhow::Result;
use live_camera::v4l2::{Camera, Captured};
use pipeline::clock::now_ns;
use pipeline::runtime::{InputError, ServiceContext};
use pipeline::service_loop::{self, Drain, Event, Flow, Service};
use pipeline::transport::{attach, waitset, Sender};
use shared_types::{frame_flags, FrameHeader};

use crate::frame::{mark_bad, FrameGeometry};
use crate::ports::{next_arrival, ports, publish_end, publish_header, Arrival, Backlog, Inputs};

/// How long one wait for the camera lasts before the loop looks at its
/// other inputs (Tracks, a stop request).
const CAMERA_POLL: Duration = Duration::from_millis(50);

/// Seconds since the Unix epoch of a CLOCK_MONOTONIC instant: a live frame's
/// timestamp (trajectory.txt), comparable with other programs' clocks.
fn wall_seconds(monotonic_ns: u64) -> f64 {
    let since_epoch = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default()
        .as_secs_f64();
    since_epoch - now_ns().saturating_sub(monotonic_ns) as f64 * 1e-9
}

/// A live V4L2 camera, frame after frame as it sends them, until stopped
/// (or `source.limit` frames); then the end of the stream.
pub(crate) fn play(ctx: ServiceContext) -> Result<()> {
    let src = &ctx.config.source;
    let camera = Camera::open(src).map_err(|e| InputError(e.to_string()))?;
    let (width, height) = camera.size();
    let run = &ctx.config.run;
    if width > run.max_width || height > run.max_height {
        return Err(InputError(format!(
            "camera {}: streams {width}x{height}, larger than run.max_width x run.max_height = {}x{} in the pipeline config",
            src.v4l2.device.display(),
            run.max_width,
            run.max_height
        ))
        .into());
    }
    let geometry = FrameGeometry {
        width,
        height,
        depth_scale: src.depth_scale,
    };
    let (sender, tracks, control) = ports(&ctx)?;
    let ws = waitset()?;
    let _tracks_attached = attach(&ws, &tracks)?;
    let _control_attached = attach(&ws, &control)?;
    ctx.announce_ready()?;
    tracing::info!(
        "camera {} streaming {width}x{height}{}",
        src.v4l2.device.display(),
        if camera.has_depth() {
            " with depth"
        } else {
            ", colour only"
        }
    );
    service_loop::run(
        &ws,
        &mut Live {
            camera,
            geometry,
            sender: &sender,
            inputs: Inputs {
                tracks: &tracks,
                control: &control,
            },
            backlog: Backlog::default(),
            seq: 0,
            limit: src.limit,
            ended: false,
            drain: Drain::default(),
        },
    )
}

/// A live camera's stream: one frame a tick, the camera's own wait its
/// pace (the loop does not sleep while it streams).
struct Live<'a> {
    camera: Camera,
    geometry: FrameGeometry,
    sender: &'a Sender<[u8], FrameHeader>,
    inputs: Inputs<'a>,
    backlog: Backlog,
    /// The next frame's number, and how many to stream (0: no limit).
    seq: u64,
    limit: u64,
    /// The end of the stream is out.
    ended: bool,
    drain: Drain,
}

impl Live<'_> {
    /// A frame's header, arrived at `arrived` (CLOCK_MONOTONIC).
    fn header(&self, arrived: u64, depth: bool) -> FrameHeader {
        FrameHeader {
            seq: self.seq,
            source_timestamp: wall_seconds(arrived),
            width: self.geometry.width,
            height: self.geometry.height,
            pixel_format: shared_types::PixelFormat::Rgb8 as u32,
            has_depth: depth as u32,
            depth_scale: self.geometry.depth_scale,
            ..Default::default()
        }
    }

    /// The next frame the camera sends, published (or left out, its header
    /// only, when the pipeline is behind).
    fn next_frame(&mut self) -> Result<()> {
        if self.backlog.full() {
            let Some(arrived) = self.camera.skip(CAMERA_POLL, now_ns)? else {
                return Ok(());
            };
            let mut h = self.header(arrived, false);
            h.flags |= frame_flags::DROPPED_AT_SOURCE;
            h.stamps.capture_ns = arrived;
            publish_header(self.sender, h)?;
            self.seq += 1;
            return Ok(());
        }
        let mut slot = None;
        let len = self.geometry.payload_len(self.camera.has_depth());
        let sender = self.sender;
        let captured = self.camera.next(CAMERA_POLL, now_ns, || {
            let sample = slot.insert(sender.loan(len)?);
            Ok(sample.payload_mut())
        })?;
        let (Some((arrived, captured)), Some(mut sample)) = (captured, slot) else {
            return Ok(());
        };
        let mut h = match captured {
            Captured::Frame { depth } => self.header(arrived, depth),
            Captured::Bad(why) => {
                tracing::error!(seq = self.seq, "bad camera frame: {why}");
                let mut h = self.header(arrived, false);
                mark_bad(&mut h, &why);
                h
            }
        };
        h.stamps.capture_ns = arrived;
        h.stamps.published_ns = now_ns();
        *sample.user_header_mut() = h;
        self.sender.publish(sample)?;
        self.backlog.published(self.seq);
        self.seq += 1;
        Ok(())
    }

    fn end(&mut self) -> Result<()> {
        publish_end(self.sender, self.seq)?;
        tracing::info!(frames = self.seq, "camera stream ended");
        self.ended = true;
        Ok(())
    }
}

impl Service for Live<'_> {
    type Event = Arrival;

    fn patience(&self) -> Duration {
        if self.ended {
            Duration::from_secs(1)
        } else {
            Duration::ZERO
        }
    }

    fn woke(&mut self) {
        self.drain.restart();
    }

    fn next_event(&mut self) -> Result<Option<Arrival>> {
        next_arrival(
            &mut self.drain,
            self.inputs.control,
            Some(self.inputs.tracks),
        )
    }

    fn handle(&mut self, event: Event<Arrival>) -> Result<Flow> {
        match event {
            Event::Arrived(Arrival::Control(c)) => self.backlog.note_control(&c),
            Event::Arrived(Arrival::Track(t)) => self.backlog.0.on_track(t.seq),
            Event::Tick if self.ended => {}
            Event::Tick if self.limit != 0 && self.seq >= self.limit => self.end()?,
            Event::Tick => self.next_frame()?,
            Event::Shutdown if !self.ended => self.end()?,
            Event::Shutdown => {}
        }
        Ok(Flow::Continue)
    }
}
