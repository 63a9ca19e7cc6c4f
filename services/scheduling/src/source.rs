//! The camera-reader's timing: in lockstep the next frame once the current
//! one is tracked; in real time each frame at its instant, left out
//! undecoded when the pipeline is behind.

use shared_types::{control_kind, Control};

/// Real time: decoded frames newer than SLAM's newest Track beyond which
/// the next one is left out undecoded (decoding a frame nobody will track
/// takes the cores the pipeline needs; a 60 fps PNG source costs most of one).
pub const SOURCE_BACKLOG: u64 = 3;

/// A decoded frame that no Track has passed for this long no longer counts
/// towards the backlog: it was lost on the way (a worker restarted, a queue
/// overflowed), and waiting for its Track would leave every later frame out.
pub const BACKLOG_TIMEOUT_NS: u64 = 1_000_000_000;

/// Real time: the frames decoded and published that SLAM has not passed.
#[derive(Debug, Default, Clone)]
pub struct Backlog {
    newest_tracked: Option<u64>,
    /// (seq, when published, ns).
    decoded: Vec<(u64, u64)>,
}

impl Backlog {
    /// SLAM answered for `seq` (a Track).
    pub fn on_track(&mut self, seq: u64) {
        self.newest_tracked = self.newest_tracked.max(Some(seq));
    }

    /// Whether the next frame is to be left out at `now_ns`:
    /// [`SOURCE_BACKLOG`] decoded frames newer than the newest tracked one
    /// (and younger than [`BACKLOG_TIMEOUT_NS`]) wait. Until SLAM answers
    /// at all (models still warming up) nothing is left out.
    pub fn full(&mut self, now_ns: u64) -> bool {
        let newest = self.newest_tracked;
        self.decoded.retain(|&(d, at)| {
            newest.is_none_or(|t| d > t) && now_ns.saturating_sub(at) < BACKLOG_TIMEOUT_NS
        });
        newest.is_some() && self.decoded.len() as u64 >= SOURCE_BACKLOG
    }

    /// Frame `seq` was published at `now_ns`.
    pub fn published(&mut self, seq: u64, now_ns: u64) {
        self.decoded.push((seq, now_ns));
    }

    /// The SLAM restarted ([`SourceCommand::ForgetBacklog`]): the frames
    /// published so far never reach the new process (frames keep no
    /// history), so none of them is waited for; without this the reader
    /// left out every frame for [`BACKLOG_TIMEOUT_NS`] after each SLAM kill.
    pub fn forget(&mut self) {
        self.decoded.clear();
    }
}

/// What the supervisor tells the reader (the `Control` message).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SourceCommand {
    /// Lockstep: publish frame `seq` again (a service restarted with it in
    /// flight).
    Replay(u64),
    /// Real time: the SLAM restarted; stop waiting for the Tracks of the
    /// frames published so far ([`Backlog::forget`]).
    ForgetBacklog,
}

impl SourceCommand {
    /// The command as its message.
    pub fn to_control(self) -> Control {
        match self {
            Self::Replay(seq) => Control {
                kind: control_kind::REPLAY,
                pid: 0,
                seq,
            },
            Self::ForgetBacklog => Control {
                kind: control_kind::FORGET_BACKLOG,
                pid: 0,
                seq: 0,
            },
        }
    }

    /// The command a message carries (None: a kind this build does not know).
    pub fn from_control(c: &Control) -> Option<Self> {
        match c.kind {
            control_kind::REPLAY => Some(Self::Replay(c.seq)),
            control_kind::FORGET_BACKLOG => Some(Self::ForgetBacklog),
            _ => None,
        }
    }
}

/// Real time: when frame `timestamp` of a recording is due, in ns of the
/// monotonic clock, when the first played frame (`first_timestamp`) was
/// due at `start_ns` and the recording plays at `speed`.
pub fn due_ns(start_ns: u64, first_timestamp: f64, timestamp: f64, speed: f64) -> u64 {
    start_ns + ((timestamp - first_timestamp) / speed * 1e9) as u64
}

/// Lockstep: the frame the reader publishes, one at a time.
#[derive(Debug, Clone)]
pub struct LockstepCursor {
    current: u64,
    total: u64,
}

/// What the lockstep reader does next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Publish {
    /// Frame `seq` for the first time (`seq == total`: the end of the stream).
    Next(u64),
    /// Frame `seq` again: a service restarted with it in flight.
    Replay(u64),
}

impl LockstepCursor {
    /// A reader starting at `start_seq` of a `total`-frame stream; its
    /// first frame is [`Self::current`].
    pub fn new(start_seq: u64, total: u64) -> Self {
        Self {
            current: start_seq.min(total),
            total,
        }
    }

    /// The frame published and not yet tracked (`total`: the end).
    pub fn current(&self) -> u64 {
        self.current
    }

    /// The supervisor asks for `seq` again: replayed if it is the current one.
    pub fn on_replay(&self, seq: u64) -> Option<Publish> {
        (seq == self.current).then_some(Publish::Replay(seq))
    }

    /// Tracks arrived for `seqs`: the next frame once the current is among them.
    pub fn on_tracks(&mut self, seqs: impl IntoIterator<Item = u64>) -> Option<Publish> {
        let done = seqs.into_iter().any(|s| s == self.current);
        if done && self.current < self.total {
            self.current += 1;
            return Some(Publish::Next(self.current));
        }
        None
    }
}
