//! What the reader's three modes share: its ports, the events a wake-up
//! drains, the real-time backlog, and the headers without pixels.

use anyhow::Result;
use pipeline::clock::now_ns;
use pipeline::runtime::ServiceContext;
use pipeline::service_loop::Drain;
use pipeline::transport::{Receiver, Sender};
use scheduling::source::SourceCommand;
use shared_types::names::Topic;
use shared_types::{frame_flags, Control, FrameHeader, Track};

/// A header without pixels (a frame left out, the end of the stream),
/// stamped as published now.
pub(crate) fn publish_header(
    sender: &Sender<[u8], FrameHeader>,
    mut header: FrameHeader,
) -> Result<()> {
    header.stamps.published_ns = now_ns();
    let mut sample = sender.loan(0)?;
    *sample.user_header_mut() = header;
    sender.publish(sample)
}

/// The end of the stream after `frames` frames.
pub(crate) fn publish_end(sender: &Sender<[u8], FrameHeader>, frames: u64) -> Result<()> {
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
pub(crate) type Ports = (
    Sender<[u8], FrameHeader>,
    Receiver<Track, ()>,
    Receiver<Control, ()>,
);

pub(crate) fn ports(ctx: &ServiceContext) -> Result<Ports> {
    Ok((
        ctx.transport
            .slice_sender::<FrameHeader>(Topic::Frames, ctx.config.max_frame_bytes())?,
        ctx.transport.receiver::<Track>(Topic::Tracks)?,
        ctx.transport.receiver::<Control>(Topic::Control)?,
    ))
}

/// The reader's receivers: SLAM's Tracks (lockstep's pace, real time's
/// backlog) and the supervisor's commands.
#[derive(Clone, Copy)]
pub(crate) struct Inputs<'a> {
    pub(crate) tracks: &'a Receiver<Track, ()>,
    pub(crate) control: &'a Receiver<Control, ()>,
}

/// What arrives for the reader, in the order a wake-up drains it.
pub(crate) enum Arrival {
    Control(Control),
    Track(Track),
}

/// The next command, then (where given) the next Track, of this wake-up.
pub(crate) fn next_arrival(
    drain: &mut Drain,
    control: &Receiver<Control, ()>,
    tracks: Option<&Receiver<Track, ()>>,
) -> Result<Option<Arrival>> {
    drain.next(2, |stage, entering| {
        Ok(match (stage, tracks) {
            (0, _) => control.entered(entering).next()?.map(Arrival::Control),
            (_, Some(tracks)) => tracks.entered(entering).next()?.map(Arrival::Track),
            (_, None) => None,
        })
    })
}

/// Real time: the frames decoded and published that SLAM has not passed
/// (the rule is [`scheduling::source::Backlog`]'s).
#[derive(Default)]
pub(crate) struct Backlog(pub(crate) scheduling::source::Backlog);

impl Backlog {
    pub(crate) fn note_tracks(&mut self, tracks: &Receiver<Track, ()>) -> Result<()> {
        for t in tracks.drain()? {
            self.0.on_track(t.seq);
        }
        Ok(())
    }

    /// A supervisor's command: a restarted SLAM clears the backlog
    /// (replays do not apply at camera rate).
    pub(crate) fn note_control(&mut self, c: &Control) {
        if SourceCommand::from_control(c) == Some(SourceCommand::ForgetBacklog) {
            tracing::debug!("the SLAM restarted: not waiting for its predecessor's Tracks");
            self.0.forget();
        }
    }

    /// Whether the next frame is to be left out now.
    pub(crate) fn full(&mut self) -> bool {
        self.0.full(now_ns())
    }

    pub(crate) fn published(&mut self, seq: u64) {
        self.0.published(seq, now_ns());
    }
}
