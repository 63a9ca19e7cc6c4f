//! A recorded sequence (TUM, image folders) played into the `frames` topic.
//!
//! Lockstep: publishes frame n, waits for SLAM's Track(n), then n+1; answers
//! the supervisor's replay requests (recovery after a restart).
//! Real-time: publishes at the source's timestamps (times `speed`), never
//! waits; consumers take the newest frame and the supervisor counts drops.

use std::time::Duration;

use anyhow::Result;
use datasets::decode::png_size;
use datasets::source::FrameEntry;
use pipeline::clock::now_ns;
use pipeline::config::ClockMode;
use pipeline::runtime::{InputError, ServiceContext};
use pipeline::service_loop::{self, Drain, Event, Flow, Service};
use pipeline::transport::{attach, waitset, Receiver, SampleMut, Sender, Svc, Waiter};
use scheduling::source::{due_ns, LockstepCursor, Publish, SourceCommand};
use shared_types::{frame_flags, Control, FrameHeader, Track};

use crate::frame::{decode_frame, header_for, mark_bad, FrameGeometry};
use crate::ports::{next_arrival, ports, publish_end, publish_header, Arrival, Backlog, Inputs};

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

/// Plays the recorded sequence from frame `start_seq`, in the run's mode.
pub(crate) fn play(ctx: ServiceContext, start_seq: u64) -> Result<()> {
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

    /// The next frame decoded now, unless the pipeline is behind (a frame
    /// left out is never decoded). The Tracks that came are read first.
    fn decode_if_room(&mut self) -> Result<Option<Decoded>> {
        self.backlog.note_tracks(self.tracks)?;
        if self.backlog.full() {
            Ok(None)
        } else {
            self.player.decode(self.seq)
        }
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
                    self.ahead = self.decode_if_room()?;
                    if self.ahead.is_some() {
                        continue; // the decoding took time
                    }
                }
                return Ok(()); // the loop sleeps until it is due
            }
            let captured = now_ns();
            if self.ahead.is_none() {
                // Not decoded ahead: decoded now, its latency counted.
                self.ahead = self.decode_if_room()?;
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
