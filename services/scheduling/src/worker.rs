//! A mask worker's queue of routed frames (segmenter or propagator): which
//! routed frame it works on next, which it passes over, and which it tells
//! the supervisor it will never mask.

use std::collections::VecDeque;

use crate::mode::ClockMode;

/// The routes a worker has been given and not worked on; `R` is the route
/// as the worker holds it, kept with its frame number.
#[derive(Debug, Clone)]
pub struct WorkQueue<R> {
    mode: ClockMode,
    routes: VecDeque<(u64, R)>,
}

/// What the worker does next.
#[derive(Debug, Clone, PartialEq)]
pub enum Next<R> {
    /// Make the masks of this route's frame (it is held).
    Work(R),
    /// The frame is no longer held (newer frames replaced it): passed over.
    /// `tell_gone`: in real time the supervisor is told (it records the
    /// frame dropped); in lockstep a frame cannot be replaced unless a
    /// service restarted, and the replay brings it again.
    PassOver {
        /// The route passed over.
        route: R,
        /// Publish a "gone" notice for it.
        tell_gone: bool,
    },
    /// The front route's frame has not arrived yet.
    Wait,
}

impl<R> WorkQueue<R> {
    /// An empty queue for a run in `mode`.
    pub fn new(mode: ClockMode) -> Self {
        Self {
            mode,
            routes: VecDeque::new(),
        }
    }

    /// The run's clock mode.
    pub fn mode(&self) -> ClockMode {
        self.mode
    }

    /// Routes waiting.
    pub fn len(&self) -> usize {
        self.routes.len()
    }

    /// No route waits.
    pub fn is_empty(&self) -> bool {
        self.routes.is_empty()
    }

    /// A route for frame `seq` (one for the same frame replaces it: a
    /// replay, or the supervisor's second route).
    pub fn on_route(&mut self, seq: u64, route: R) {
        self.routes.retain(|(s, _)| *s != seq);
        self.routes.push_back((seq, route));
    }

    /// Real time: at camera rate only the newest routed frame is worth the
    /// work; the others are returned, to be told gone (the supervisor
    /// records them dropped). Lockstep keeps every route.
    pub fn keep_newest(&mut self) -> Vec<R> {
        if !self.mode.is_realtime() || self.routes.len() <= 1 {
            return Vec::new();
        }
        let newest = self.routes.pop_back();
        let replaced = self.routes.drain(..).map(|(_, r)| r).collect();
        self.routes.extend(newest);
        replaced
    }

    /// The next step, given which frames the worker holds (`held`) and the
    /// oldest of them: the front route is worked on if its frame is held,
    /// passed over if the worker holds only newer frames, else waited for.
    pub fn next(&mut self, held: impl Fn(u64) -> bool, oldest_held: Option<u64>) -> Next<R> {
        let Some(&(seq, _)) = self.routes.front() else {
            return Next::Wait;
        };
        if held(seq) {
            let (_, route) = self.routes.pop_front().expect("front exists");
            return Next::Work(route);
        }
        if oldest_held.is_some_and(|o| o > seq) {
            let (_, route) = self.routes.pop_front().expect("front exists");
            return Next::PassOver {
                route,
                tell_gone: self.mode.is_realtime(),
            };
        }
        Next::Wait
    }
}
