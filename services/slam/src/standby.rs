//! The warm standby: holds what the SLAM would hold, tracks nothing, until
//! the supervisor promotes it.

use anyhow::Result;
use pipeline::service_loop::{Drain, Event, Flow, Service};
use pipeline::transport::Receiver;
use shared_types::{control_kind, Control};

use crate::held::{take_frame, take_masks, Arrival, Ports, State};

/// Routes a standby keeps: those of the newest frames (a route may come
/// before its frame).
pub(crate) const STANDBY_ROUTES: usize = 16;

/// The warm standby: holds the newest frames, masks and routes (bounded as
/// the active SLAM holds them) without tracking, until the supervisor's
/// PROMOTE for this process.
pub(crate) struct Standby<'a> {
    pub(crate) st: &'a mut State,
    pub(crate) ports: &'a Ports<'a>,
    pub(crate) control: &'a Receiver<Control, ()>,
    /// The first frame it may track, once promoted.
    pub(crate) promoted_from: Option<u64>,
    pub(crate) drain: Drain,
}

impl Service for Standby<'_> {
    type Event = Arrival;

    fn woke(&mut self) {
        self.drain.restart();
    }

    fn next_event(&mut self) -> Result<Option<Arrival>> {
        self.ports
            .next(&mut self.drain, self.st, Some(self.control))
    }

    fn handle(&mut self, event: Event<Arrival>) -> Result<Flow> {
        match event {
            Event::Arrived(Arrival::Frame(sample)) => {
                take_frame(self.st, sample, self.ports.tracks)?
            }
            Event::Arrived(Arrival::Masks(sample)) => take_masks(self.st, sample, None),
            Event::Arrived(Arrival::Route(r)) => {
                self.st.routes.insert(r.seq, r);
                // The newest routes stay (trimmed as they come: the same
                // ones as trimming after the wake-up's last).
                while self.st.routes.len() > STANDBY_ROUTES {
                    let oldest = *self.st.routes.keys().min().expect("not empty");
                    self.st.routes.remove(&oldest);
                }
            }
            Event::Arrived(Arrival::Control(c)) => {
                if c.kind == control_kind::PROMOTE && c.pid == std::process::id() {
                    self.promoted_from = Some(c.seq);
                    return Ok(Flow::Stop);
                }
            }
            Event::Tick | Event::Shutdown => {}
        }
        Ok(Flow::Continue)
    }
}
