//! One event loop for every service, as a dora-rs node is one loop over an
//! event enum: the loop sleeps on the service's WaitSet, then hands the
//! service what arrived as its own events, one at a time and in the order
//! the service drains its receivers, then a tick for the work that waits on
//! them; a termination signal (SIGINT, SIGTERM) is the last event.
//!
//! Events are pulled one at a time ([`Service::next_event`]), not collected
//! first: a service that holds borrowed shared-memory samples makes room for
//! the next one before it takes it, within the topic's borrow limit.

use std::time::Duration;

use anyhow::Result;

use crate::transport::{wait, Waiter, Wake};

/// What the loop hands a service.
#[derive(Debug)]
pub enum Event<E> {
    /// Something arrived: a frame, a route, masks, a track, a command.
    Arrived(E),
    /// The wake-up's arrivals are handled (or the patience ran out): do the
    /// work that waits on them. Also once before the first sleep, for what
    /// the service already holds.
    Tick,
    /// A termination signal: the service's last event.
    Shutdown,
}

/// Whether the loop goes on after an event.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flow {
    /// Keep going.
    Continue,
    /// Leave the loop (after [`Event::Shutdown`] the loop ends anyway).
    Stop,
}

/// A service as the loop drives it.
pub trait Service {
    /// What arrives for it.
    type Event;

    /// The longest sleep before the next tick.
    fn patience(&self) -> Duration {
        Duration::from_secs(1)
    }

    /// A wake-up: the next [`Self::next_event`] calls drain the receivers
    /// from the first (each once per wake-up, in the service's order;
    /// [`Drain`] keeps the place).
    fn woke(&mut self);

    /// The next event of this wake-up; None when every receiver is drained.
    fn next_event(&mut self) -> Result<Option<Self::Event>>;

    /// Handles one event.
    fn handle(&mut self, event: Event<Self::Event>) -> Result<Flow>;
}

/// Runs `service` until it stops or a termination signal arrives on `ws`
/// (then its [`Event::Shutdown`] is handled last).
pub fn run<S: Service>(ws: &Waiter, service: &mut S) -> Result<()> {
    loop {
        if service.handle(Event::Tick)? == Flow::Stop {
            return Ok(());
        }
        if wait(ws, service.patience())? == Wake::Terminate {
            service.handle(Event::Shutdown)?;
            return Ok(());
        }
        service.woke();
        while let Some(event) = service.next_event()? {
            if service.handle(Event::Arrived(event))? == Flow::Stop {
                return Ok(());
            }
        }
    }
}

/// Which of a service's receivers a wake-up drains now: each in turn, once
/// per wake-up (a sample that arrives on an earlier one meanwhile wakes the
/// next round).
#[derive(Debug, Default, Clone, Copy)]
pub struct Drain {
    stage: usize,
    entered: bool,
}

impl Drain {
    /// Back to the first receiver (a new wake-up).
    pub fn restart(&mut self) {
        *self = Self::default();
    }

    /// The receiver to drain now (0: the first).
    pub fn stage(&self) -> usize {
        self.stage
    }

    /// True on the first call for the current receiver: clear its wake-ups
    /// then, so a sample that arrives while it is drained wakes the loop
    /// again.
    pub fn entering(&mut self) -> bool {
        !std::mem::replace(&mut self.entered, true)
    }

    /// The current receiver is drained: on to the next.
    pub fn advance(&mut self) {
        self.stage += 1;
        self.entered = false;
    }

    /// The next event of this wake-up from a service's `receivers`
    /// receivers, in drain order: `pull(stage, entering)` is receiver
    /// `stage`'s next event (None: drained, or a receiver the service does
    /// not have); `entering` as [`Self::entering`].
    pub fn next<E>(
        &mut self,
        receivers: usize,
        mut pull: impl FnMut(usize, bool) -> Result<Option<E>>,
    ) -> Result<Option<E>> {
        while self.stage < receivers {
            let entering = self.entering();
            if let Some(event) = pull(self.stage, entering)? {
                return Ok(Some(event));
            }
            self.advance();
        }
        Ok(None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_receiver_is_entered_once_per_wakeup_in_order() {
        let mut d = Drain::default();
        assert_eq!((d.stage(), d.entering(), d.entering()), (0, true, false));
        d.advance();
        assert_eq!((d.stage(), d.entering(), d.entering()), (1, true, false));
        d.restart();
        assert_eq!((d.stage(), d.entering()), (0, true));
    }

    #[test]
    fn next_pulls_each_receiver_until_drained_entering_it_once() {
        let mut queues = [vec![1, 2], vec![], vec![3]];
        let mut entered = Vec::new();
        let mut d = Drain::default();
        let mut got = Vec::new();
        while let Some(e) = d
            .next(3, |stage, entering| {
                if entering {
                    entered.push(stage);
                }
                Ok(queues[stage].pop())
            })
            .unwrap()
        {
            got.push(e);
        }
        assert_eq!((got, entered), (vec![2, 1, 3], vec![0, 1, 2]));
        assert_eq!(d.next(3, |_, _| Ok(Some(9))).unwrap(), None);
    }
}
