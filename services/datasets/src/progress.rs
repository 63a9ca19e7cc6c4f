//! A progress line for long offline work (synthesis, lockstep runs,
//! evaluations) on stderr: redrawn in place on a terminal, a line per 10 %
//! otherwise so that CI logs stay short.

use std::io::{IsTerminal, Write};
use std::time::Instant;

/// One progress line: a label, a bar, done of total, elapsed and estimated time left.
pub struct Progress {
    label: String,
    total: u64,
    done: u64,
    started: Instant,
    terminal: bool,
    last_decile: u64,
}

impl Progress {
    /// A line for `total` items.
    pub fn new(label: impl Into<String>, total: u64) -> Self {
        Self {
            label: label.into(),
            total: total.max(1),
            done: 0,
            started: Instant::now(),
            terminal: std::io::stderr().is_terminal(),
            last_decile: 0,
        }
    }

    /// Sets the number of finished items and redraws when useful.
    pub fn set(&mut self, done: u64) {
        self.done = done.min(self.total);
        let decile = self.done * 10 / self.total;
        if self.terminal {
            eprint!("\r{}", self.line());
            let _ = std::io::stderr().flush();
        } else if decile > self.last_decile {
            eprintln!("{}", self.line());
        }
        self.last_decile = decile;
    }

    /// One more step done.
    pub fn inc(&mut self) {
        self.set(self.done + 1);
    }

    /// Ends the line (on a terminal the bar stays visible).
    pub fn finish(&mut self) {
        if self.terminal {
            eprintln!();
        }
    }

    fn line(&self) -> String {
        const WIDTH: u64 = 30;
        let filled = (self.done * WIDTH / self.total) as usize;
        let elapsed = self.started.elapsed().as_secs_f64();
        let eta = if self.done > 0 {
            elapsed * (self.total - self.done) as f64 / self.done as f64
        } else {
            0.0
        };
        format!(
            "{} [{}{}] {}/{} {:.1} s (eta {:.0} s)",
            self.label,
            "#".repeat(filled),
            "-".repeat(WIDTH as usize - filled),
            self.done,
            self.total,
            elapsed,
            eta
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_shows_fraction_and_bar() {
        let mut p = Progress::new("synth", 4);
        p.terminal = false;
        p.set(2);
        let line = p.line();
        assert!(
            line.starts_with("synth [###############---------------] 2/4"),
            "{line}"
        );
        p.set(10);
        assert!(p.line().contains("4/4"));
    }
}
