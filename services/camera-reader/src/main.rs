//! camera-reader service: plays a source into the `frames` topic.
//!
//! Lockstep: publishes frame n, waits for SLAM's Track(n), then n+1; answers
//! the supervisor's replay requests (recovery after a restart).
//! Real-time: publishes at the source's timestamps (times `speed`), never
//! waits; consumers take the newest frame and the supervisor counts drops.
//! A live V4L2 camera (`source.kind = "v4l2"`) is real time at its own rate.

use std::process::ExitCode;
use std::time::Duration;

use anyhow::Result;
use camera_reader::frame::{decode_frame, header_for, mark_bad, FrameGeometry};
use clap::Parser;
use datasets::decode::png_size;
use datasets::source::FrameEntry;
use live_camera::v4l2::{Camera, Captured};
use pipeline::clock::now_ns;
use pipeline::config::{ClockMode, SourceKind};
use pipeline::runtime::{run_service, InputError, ServiceArgs, ServiceContext};
use pipeline::service_loop::{self, Drain, Event, Flow, Service};
use pipeline::transport::{attach, waitset, Receiver, SampleMut, Sender, Svc, Waiter};
use scheduling::source::{due_ns, LockstepCursor, Publish, SourceCommand};
use shared_types::names::Topic;
use shared_types::{frame_flags, Control, FrameHeader, ServiceKind, Track};

#[derive(Debug, Parser)]
#[command(about = "dynslam camera-reader: plays frames into shared memory")]
struct Args {
    #[command(flatten)]
    service: ServiceArgs,
    /// First frame to publish (the supervisor resumes interrupted runs here).
    #[arg(long, default_value_t = 0)]
    start_seq: u64,
}

fn main() -> ExitCode {
    let args = Args::parse();
    run_service(ServiceKind::CameraReader, &args.service, |ctx| {
        run(ctx, args.start_seq)
    })
}

fn load_source(ctx: &ServiceContext) -> Result<(Vec<FrameEntry>, FrameGeometry)> {
    let src = &ctx.config.source;
    let frames = src
        .recorded_frames()
        .map_err(|e| InputError(e.to_string()))?;
    // The sequence's size, from its first frames (one odd or broken first
    // frame does not decide it); it must fit shared memory.
    let (width, height) = sequence_size(&frames)?;
    let run = &ctx.config.run;
    if width > run.max_width || height > run.max_height {
        return Err(InputError(format!(
            "{}: frames are {width}x{height}, larger than run.max_width x run.max_height = {}x{} in the pipeline config",
            frames[0].rgb.display(),
            run.max_width,
            run.max_height
        ))
        .into());
    }
    Ok((
        frames,
        FrameGeometry {
            width,
            height,
            depth_scale: src.depth_scale,
        },
    ))
}

/// Frames whose size is probed to find the sequence's.
const SIZE_PROBE: usize = 15;

/// The size most of the first `SIZE_PROBE` readable frames have (the
/// earliest of equals). Frames of another size are skipped later with
/// their reason; when none of them can be read, the first one's error.
fn sequence_size(frames: &[FrameEntry]) -> Result<(u32, u32)> {
    let mut counts: Vec<((u32, u32), usize)> = Vec::new();
    let mut first_error = None;
    for f in frames.iter().take(SIZE_PROBE) {
        match png_size(&f.rgb) {
            Ok(size) => match counts.iter_mut().find(|(s, _)| *s == size) {
                Some((_, n)) => *n += 1,
                None => counts.push((size, 1)),
            },
            Err(e) => {
                first_error.get_or_insert(e);
            }
        }
    }
    let best = counts.iter().rev().max_by_key(|(_, n)| *n).map(|&(s, _)| s);
    match (best, first_error) {
        (Some(size), _) => {
            if counts.len() > 1 || png_size(&frames[0].rgb).ok() != Some(size) {
                tracing::warn!(
                    "frames of the sequence differ in size or are unreadable among the first {}: playing {}x{} (the most common); frames of another size are skipped",
                    frames.len().min(SIZE_PROBE),
                    size.0,
                    size.1
                );
            }
            Ok(size)
        }
        (None, Some(e)) => Err(InputError(e.to_string()).into()),
        (None, None) => Err(InputError("the sequence has no frames".into()).into()),
    }
}

struct Player {
    frames: Vec<FrameEntry>,
    geometry: FrameGeometry,
    sender: Sender<[u8], FrameHeader>,
}

/// A frame decoded into its loaned sample, not yet published: real-time
/// playback decodes each frame ahead of its instant, as a camera's frames
/// arrive already decoded, so that the PNG codec of file playback (CPU
/// that a camera does not spend) is not part of the end-to-end latency.
struct Decoded {
    sample: SampleMut<Svc, [u8], FrameHeader>,
    header: FrameHeader,
}

impl Player {
    /// Decodes frame `seq` straight into a loaned sample (None past the
    /// end); a frame that cannot be decoded is marked BAD_INPUT with the
    /// reason and still goes out, so that every consumer and the outputs
    /// account for it.
    fn decode(&self, seq: u64) -> Result<Option<Decoded>> {
        let Some(entry) = self.frames.get(seq as usize) else {
            return Ok(None);
        };
        let mut header = header_for(seq, entry, self.geometry);
        let mut sample = self
            .sender
            .loan(self.geometry.payload_len(entry.depth.is_some()))?;
        if let Err(e) = decode_frame(entry, self.geometry, sample.payload_mut()) {
            tracing::error!(seq, "bad input frame: {e}");
            mark_bad(&mut header, &e);
        }
        Ok(Some(Decoded { sample, header }))
    }

    /// Publishes a decoded frame, captured at `capture_ns`.
    fn send(&self, decoded: Decoded, capture_ns: u64, replay: bool) -> Result<()> {
        let Decoded {
            mut sample,
            mut header,
        } = decoded;
        header.stamps.capture_ns = capture_ns;
        if replay {
            header.flags |= frame_flags::REPLAY;
        }
        header.stamps.published_ns = now_ns();
        let seq = header.seq;
        *sample.user_header_mut() = header;
        self.sender.publish(sample)?;
        tracing::debug!(seq, replay, "published frame");
        Ok(())
    }

    /// Decodes and publishes frame `seq` now (captured when its decoding
    /// began); past the end, the end of the stream.
    fn publish(&self, seq: u64, replay: bool) -> Result<()> {
        let capture_ns = now_ns();
        match self.decode(seq)? {
            Some(decoded) => self.send(decoded, capture_ns, replay),
            None => self.publish_end(),
        }
    }

    /// Frame `seq` left out (real time, the pipeline is behind): its header
    /// only, flagged, so that the run still accounts for it.
    fn publish_dropped(&self, seq: u64) -> Result<()> {
        let Some(entry) = self.frames.get(seq as usize) else {
            return Ok(());
        };
        let mut header = header_for(seq, entry, self.geometry);
        header.flags |= frame_flags::DROPPED_AT_SOURCE;
        header.stamps.capture_ns = now_ns();
        publish_header(&self.sender, header)
    }

    fn publish_end(&self) -> Result<()> {
        publish_end(&self.sender, self.frames.len() as u64)
    }
}

/// A header without pixels (a frame left out, the end of the stream),
/// stamped as published now.
fn publish_header(sender: &Sender<[u8], FrameHeader>, mut header: FrameHeader) -> Result<()> {
    header.stamps.published_ns = now_ns();
    let mut sample = sender.loan(0)?;
    *sample.user_header_mut() = header;
    sender.publish(sample)
}

/// The end of the stream after `frames` frames.
fn publish_end(sender: &Sender<[u8], FrameHeader>, frames: u64) -> Result<()> {
    publish_header(
        sender,
        FrameHeader {
            seq: frames,
            flags: frame_flags::END_OF_STREAM,
            ..Default::default()
        },
    )
}

/// The reader's ports: frames out; Tracks (real-time backlog, lockstep
/// pace) and the supervisor's replay requests in.
type Ports = (
    Sender<[u8], FrameHeader>,
    Receiver<Track, ()>,
    Receiver<Control, ()>,
);

fn ports(ctx: &ServiceContext) -> Result<Ports> {
    Ok((
        ctx.transport
            .slice_sender::<FrameHeader>(Topic::Frames, ctx.config.max_frame_bytes())?,
        ctx.transport.receiver::<Track>(Topic::Tracks)?,
        ctx.transport.receiver::<Control>(Topic::Control)?,
    ))
}

fn run(ctx: ServiceContext, start_seq: u64) -> Result<()> {
    if ctx.config.source.kind == SourceKind::V4l2 {
        return live(ctx);
    }
    let (frames, geometry) = load_source(&ctx)?;
    tracing::info!(
        frames = frames.len(),
        width = geometry.width,
        height = geometry.height,
        "source {} ready",
        ctx.config.source.path.display()
    );
    let (sender, tracks, control) = ports(&ctx)?;
    let player = Player {
        frames,
        geometry,
        sender,
    };
    let ws = waitset()?;
    let _tracks_attached = attach(&ws, &tracks)?;
    let _control_attached = attach(&ws, &control)?;
    ctx.announce_ready()?;
    let inputs = Inputs {
        tracks: &tracks,
        control: &control,
    };

    match ctx.config.run.mode {
        ClockMode::Lockstep => Lockstep::run(&player, &ws, inputs, start_seq),
        ClockMode::Realtime => Realtime::run(&player, &ws, inputs, start_seq, ctx.config.run.speed),
    }
}

/// Lockstep: frame n is published, then n + 1 once SLAM's Track(n) came;
/// the supervisor's replay requests (recovery after a restart) are answered
/// at once.
struct Lockstep<'a> {
    player: &'a Player,
    tracks: &'a Receiver<Track, ()>,
    control: &'a Receiver<Control, ()>,
    cursor: LockstepCursor,
    /// Frames tracked since the last tick.
    tracked: Vec<u64>,
    drain: Drain,
}

/// The reader's receivers: SLAM's Tracks (lockstep's pace, real time's
/// backlog) and the supervisor's commands.
#[derive(Clone, Copy)]
struct Inputs<'a> {
    tracks: &'a Receiver<Track, ()>,
    control: &'a Receiver<Control, ()>,
}

/// What arrives for the reader, in the order a wake-up drains it.
enum Arrival {
    Control(Control),
    Track(Track),
}

impl Lockstep<'_> {
    fn run(player: &Player, ws: &Waiter, inputs: Inputs, start_seq: u64) -> Result<()> {
        let cursor = LockstepCursor::new(start_seq, player.frames.len() as u64);
        player.publish(cursor.current(), false)?;
        service_loop::run(
            ws,
            &mut Lockstep {
                player,
                tracks: inputs.tracks,
                control: inputs.control,
                cursor,
                tracked: Vec::new(),
                drain: Drain::default(),
            },
        )
    }
}

impl Service for Lockstep<'_> {
    type Event = Arrival;

    fn woke(&mut self) {
        self.drain.restart();
    }

    fn next_event(&mut self) -> Result<Option<Arrival>> {
        next_arrival(&mut self.drain, self.control, Some(self.tracks))
    }

    fn handle(&mut self, event: Event<Arrival>) -> Result<Flow> {
        match event {
            Event::Arrived(Arrival::Control(c)) => {
                // Real-time commands do not apply.
                if let Some(SourceCommand::Replay(seq)) = SourceCommand::from_control(&c) {
                    if let Some(Publish::Replay(seq)) = self.cursor.on_replay(seq) {
                        tracing::info!(seq, "replaying frame after a restart");
                        self.player.publish(seq, true)?;
                    }
                }
            }
            Event::Arrived(Arrival::Track(t)) => self.tracked.push(t.seq),
            Event::Tick => {
                let tracked = std::mem::take(&mut self.tracked);
                if let Some(Publish::Next(seq)) = self.cursor.on_tracks(tracked) {
                    self.player.publish(seq, false)?;
                }
            }
            Event::Shutdown => {}
        }
        Ok(Flow::Continue)
    }
}

/// The next command, then (where given) the next Track, of this wake-up.
fn next_arrival(
    drain: &mut Drain,
    control: &Receiver<Control, ()>,
    tracks: Option<&Receiver<Track, ()>>,
) -> Result<Option<Arrival>> {
    loop {
        let entering = drain.entering();
        let next = match (drain.stage(), tracks) {
            (0, _) => {
                if entering {
                    control.clear_wakeups();
                }
                control.next()?.map(Arrival::Control)
            }
            (1, Some(tracks)) => {
                if entering {
                    tracks.clear_wakeups();
                }
                tracks.next()?.map(Arrival::Track)
            }
            _ => return Ok(None),
        };
        if next.is_some() {
            return Ok(next);
        }
        drain.advance();
    }
}

/// Real time: the frames decoded and published that SLAM has not passed
/// (the rule is [`scheduling::source::Backlog`]'s).
#[derive(Default)]
struct Backlog(scheduling::source::Backlog);

impl Backlog {
    fn note_tracks(&mut self, tracks: &Receiver<Track, ()>) -> Result<()> {
        for t in tracks.drain()? {
            self.0.on_track(t.seq);
        }
        Ok(())
    }

    /// A supervisor's command: a restarted SLAM clears the backlog
    /// (replays do not apply at camera rate).
    fn note_control(&mut self, c: &Control) {
        if SourceCommand::from_control(c) == Some(SourceCommand::ForgetBacklog) {
            tracing::debug!("the SLAM restarted: not waiting for its predecessor's Tracks");
            self.0.forget();
        }
    }

    /// Whether the next frame is to be left out now.
    fn full(&mut self) -> bool {
        self.0.full(now_ns())
    }

    /// Frame `seq` decoded now, unless the pipeline is behind (a frame
    /// left out is never decoded). The Tracks that came are read first.
    fn decode_if_room(
        &mut self,
        player: &Player,
        tracks: &Receiver<Track, ()>,
        seq: u64,
    ) -> Result<Option<Decoded>> {
        self.note_tracks(tracks)?;
        if self.full() {
            Ok(None)
        } else {
            player.decode(seq)
        }
    }

    fn published(&mut self, seq: u64) {
        self.0.published(seq, now_ns());
    }
}

/// Real time: each frame published at its instant (the source's
/// timestamps times `speed`), decoded ahead of it as soon as the pipeline
/// has room (a Track wakes the loop), left out when the pipeline is behind.
/// Tracks are read where room is decided; the supervisor's commands arrive
/// as events.
struct Realtime<'a> {
    player: &'a Player,
    tracks: &'a Receiver<Track, ()>,
    control: &'a Receiver<Control, ()>,
    backlog: Backlog,
    /// When playback started, and the first frame's timestamp.
    t0: u64,
    first_ts: f64,
    speed: f64,
    /// The next frame to publish, and that frame decoded ahead.
    seq: u64,
    ahead: Option<Decoded>,
    /// Every frame is out, and the end of the stream.
    ended: bool,
    drain: Drain,
}

impl Realtime<'_> {
    fn run(player: &Player, ws: &Waiter, inputs: Inputs, start_seq: u64, speed: f64) -> Result<()> {
        let first_ts = player
            .frames
            .get(start_seq as usize)
            .map(|f| f.timestamp)
            .unwrap_or(0.0);
        service_loop::run(
            ws,
            &mut Realtime {
                player,
                tracks: inputs.tracks,
                control: inputs.control,
                backlog: Backlog::default(),
                t0: now_ns(),
                first_ts,
                speed,
                seq: start_seq,
                ahead: None,
                ended: false,
                drain: Drain::default(),
            },
        )
    }

    /// The instant frame `seq` is due.
    fn due(&self) -> u64 {
        let ts = self.player.frames[self.seq as usize].timestamp;
        due_ns(self.t0, self.first_ts, ts, self.speed)
    }

    /// Publishes every frame that is due, decodes the next one ahead if
    /// there is room; after the last, the end of the stream.
    fn play(&mut self) -> Result<()> {
        let total = self.player.frames.len() as u64;
        while !self.ended {
            if self.seq >= total {
                self.player.publish_end()?;
                self.ended = true;
                break;
            }
            if now_ns() < self.due() {
                if self.ahead.is_none() {
                    self.ahead = self
                        .backlog
                        .decode_if_room(self.player, self.tracks, self.seq)?;
                    if self.ahead.is_some() {
                        continue; // the decoding took time
                    }
                }
                return Ok(()); // the loop sleeps until it is due
            }
            let captured = now_ns();
            if self.ahead.is_none() {
                // Not decoded ahead: decoded now, its latency counted.
                self.ahead = self
                    .backlog
                    .decode_if_room(self.player, self.tracks, self.seq)?;
            }
            match self.ahead.take() {
                Some(decoded) => {
                    self.player.send(decoded, captured, false)?;
                    self.backlog.published(self.seq);
                }
                None => self.player.publish_dropped(self.seq)?,
            }
            self.seq += 1;
        }
        // After the end the Tracks still come: read, so they do not keep
        // waking the loop.
        self.tracks.drain()?;
        Ok(())
    }
}

impl Service for Realtime<'_> {
    type Event = Arrival;

    fn patience(&self) -> Duration {
        if self.ended {
            Duration::from_secs(1)
        } else {
            Duration::from_nanos(self.due().saturating_sub(now_ns()))
        }
    }

    fn woke(&mut self) {
        self.drain.restart();
    }

    fn next_event(&mut self) -> Result<Option<Arrival>> {
        next_arrival(&mut self.drain, self.control, None)
    }

    fn handle(&mut self, event: Event<Arrival>) -> Result<Flow> {
        match event {
            Event::Arrived(Arrival::Control(c)) => self.backlog.note_control(&c),
            Event::Arrived(Arrival::Track(_)) | Event::Shutdown => {}
            Event::Tick => self.play()?,
        }
        Ok(Flow::Continue)
    }
}

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
fn live(ctx: ServiceContext) -> Result<()> {
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
