//! Child processes: spawning, exit classification and the restart policy.

use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::Duration;

use anyhow::{bail, Context, Result};
use pipeline::config::{PipelineConfig, SourceKind, SupervisorConfig};
use pipeline::runtime::exit_code;
use shared_types::ServiceKind;

/// Exponential backoff, and crash-loop detection: a service that dies
/// `limit` times in a row, each time before staying up `reset_after`, is
/// given up on. Staying up that long resets both the delay and the count.
#[derive(Debug, Clone)]
pub struct RestartPolicy {
    initial: Duration,
    max: Duration,
    reset_after: Duration,
    limit: u32,
    next_delay: Duration,
    consecutive: u32,
}

/// What to do after a service died.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RestartDecision {
    /// Start it again after this delay.
    RestartAfter(Duration),
    /// It died too often in a row: leave it dead.
    GiveUp {
        /// Deaths without a long enough life between them.
        deaths_in_a_row: u32,
    },
}

impl RestartPolicy {
    /// The policy `cfg` describes (delays, limit, reset).
    pub fn new(cfg: &SupervisorConfig) -> Self {
        Self {
            initial: Duration::from_millis(cfg.restart_backoff_initial_ms),
            max: Duration::from_millis(cfg.restart_backoff_max_ms),
            reset_after: Duration::from_secs(cfg.restart_backoff_reset_s),
            limit: cfg.restart_limit,
            next_delay: Duration::from_millis(cfg.restart_backoff_initial_ms),
            consecutive: 0,
        }
    }

    /// A service that was up for `uptime`, and ready for `ready_for` of it
    /// (None: it never was), died. The backoff is for start-up crash loops:
    /// a service that served [`SERVED_BEFORE_DEATH`] is restarted at once
    /// (a killed SLAM waiting 100, 200, 400 ms... cost that many frames
    /// without a pose). Deaths in a row still count towards the limit.
    pub fn on_death(&mut self, uptime: Duration, ready_for: Option<Duration>) -> RestartDecision {
        if uptime >= self.reset_after {
            self.next_delay = self.initial;
            self.consecutive = 0;
        }
        self.consecutive += 1;
        if self.consecutive > self.limit {
            return RestartDecision::GiveUp {
                deaths_in_a_row: self.consecutive,
            };
        }
        if ready_for.is_some_and(|r| r >= SERVED_BEFORE_DEATH) {
            self.next_delay = self.initial;
            return RestartDecision::RestartAfter(Duration::ZERO);
        }
        let delay = self.next_delay;
        self.next_delay = (self.next_delay * 2).min(self.max);
        RestartDecision::RestartAfter(delay)
    }
}

/// A service ready for this long before it died was not crash-looping at
/// start: it is restarted without delay.
pub const SERVED_BEFORE_DEATH: Duration = Duration::from_secs(1);

/// How a child ended, in words for logs and reports.
pub fn describe_exit(status: ExitStatus) -> String {
    match (status.code(), status.signal()) {
        (Some(c), _) => format!("exit code {c}"),
        (None, Some(s)) => format!("signal {s} ({})", signal_name(s)),
        _ => "unknown status".into(),
    }
}

fn signal_name(s: i32) -> &'static str {
    match s {
        libc::SIGKILL => "SIGKILL",
        libc::SIGTERM => "SIGTERM",
        libc::SIGINT => "SIGINT",
        libc::SIGSEGV => "SIGSEGV",
        libc::SIGABRT => "SIGABRT",
        _ => "signal",
    }
}

/// True when the child said its input cannot work (restarting cannot help).
pub fn is_input_error(status: ExitStatus) -> bool {
    status.code() == Some(exit_code::INPUT as i32)
}

/// The program (and leading arguments) of a service: the configured
/// `command`, or the binary of that name next to the running `dynslam`.
pub fn service_program(config: &PipelineConfig, kind: ServiceKind) -> Result<Vec<String>> {
    // The bridge binary has two roles: the ROS 2 outputs, and a ROS 2
    // camera in the camera-reader's place.
    let ros2_camera = kind == ServiceKind::CameraReader && config.source.kind == SourceKind::Ros2;
    let (cmd, binary, role) = match kind {
        ServiceKind::Bridge => (config.bridge.command.as_slice(), "bridge", Some("publish")),
        _ if ros2_camera => (
            config.bridge.command.as_slice(),
            "bridge",
            Some("camera-in"),
        ),
        // A remote segmenter: the link plays the segmenter's part here.
        ServiceKind::Segmenter if config.services.segmenter.location == "remote" => {
            (config.process(kind).command, "mask-link", None)
        }
        // The standby is the SLAM binary, told to stand by.
        ServiceKind::SlamStandby => (config.process(kind).command, "slam", Some("--standby")),
        _ => (config.process(kind).command, kind.as_str(), None),
    };
    if !cmd.is_empty() {
        return Ok(cmd.iter().cloned().chain(role.map(String::from)).collect());
    }
    let exe = std::env::current_exe().context("cannot locate the running dynslam executable")?;
    let dir = exe.parent().map(Path::to_path_buf).unwrap_or_default();
    let bin: PathBuf = dir.join(binary);
    if !bin.is_file() {
        bail!(
            "service binary {} not found (build all services: cargo build --release --workspace)",
            bin.display()
        );
    }
    Ok(std::iter::once(bin.to_string_lossy().into_owned())
        .chain(role.map(String::from))
        .collect())
}

/// Starts a service process. It gets its own process group (a Ctrl-C in the
/// terminal reaches only the supervisor, which then stops the services in
/// order) and SIGTERM when the supervisor dies, so no orphan outlives it.
/// Its stderr is piped: the supervisor forwards it and remembers the last
/// error line, to quote it when it gives up on the service. `nice` (the
/// service's `nice` key) sets its scheduling niceness.
pub fn spawn(program: &[String], extra_args: &[String], nice: Option<i32>) -> Result<Child> {
    let (bin, leading) = program.split_first().context("empty service command")?;
    let parent = std::process::id() as libc::pid_t;
    let mut cmd = Command::new(bin);
    cmd.args(leading)
        .args(extra_args)
        .stdin(Stdio::null())
        .stderr(Stdio::piped());
    // SAFETY: the closure only calls async-signal-safe libc functions.
    unsafe {
        cmd.pre_exec(move || {
            libc::setpgid(0, 0);
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            // The supervisor may have died between fork and prctl.
            if libc::getppid() != parent {
                libc::_exit(1);
            }
            if let Some(n) = nice {
                if libc::setpriority(libc::PRIO_PROCESS, 0, n) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
            }
            Ok(())
        });
    }
    cmd.spawn().with_context(|| format!("cannot start {bin}"))
}

/// Sets the niceness of every thread of a service started by [`spawn`] (it
/// leads its own process group; `setpriority` on its pid alone would
/// reach only its main thread, not its worker threads).
pub fn renice(pid: u32, nice: i32) -> std::io::Result<()> {
    // SAFETY: setpriority(2) on a process group we started has no memory
    // effects.
    if unsafe { libc::setpriority(libc::PRIO_PGRP, pid as libc::id_t, nice) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}

/// Sends a signal to a process; a process that is already gone is fine.
pub fn signal(pid: u32, sig: i32) {
    // SAFETY: kill(2) with a pid we started (or read from our own status file
    // and verified) has no memory effects.
    unsafe {
        libc::kill(pid as libc::pid_t, sig);
    }
}

/// True while `pid` exists and its command line mentions `needle` (guards
/// against signalling a recycled pid).
pub fn process_matches(pid: u32, needle: &str) -> bool {
    std::fs::read(format!("/proc/{pid}/cmdline"))
        .map(|c| String::from_utf8_lossy(&c).contains(needle))
        .unwrap_or(false)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn policy() -> RestartPolicy {
        RestartPolicy::new(&SupervisorConfig {
            restart_backoff_initial_ms: 100,
            restart_backoff_max_ms: 500,
            restart_backoff_reset_s: 10,
            restart_limit: 4,
            ..Default::default()
        })
    }

    #[test]
    fn backoff_doubles_up_to_the_cap() {
        let mut p = policy();
        let delays: Vec<_> = (0..4)
            .map(|_| p.on_death(Duration::from_millis(5), None))
            .collect();
        let ms = |d: u64| RestartDecision::RestartAfter(Duration::from_millis(d));
        assert_eq!(delays, vec![ms(100), ms(200), ms(400), ms(500)]);
    }

    #[test]
    fn gives_up_on_a_crash_loop_but_not_on_a_service_that_stays_up() {
        let mut p = policy();
        for _ in 0..4 {
            assert!(matches!(
                p.on_death(Duration::ZERO, None),
                RestartDecision::RestartAfter(_)
            ));
        }
        assert_eq!(
            p.on_death(Duration::ZERO, None),
            RestartDecision::GiveUp { deaths_in_a_row: 5 }
        );
        // A service that was up long enough starts over.
        let mut p = policy();
        for _ in 0..20 {
            assert!(
                matches!(p.on_death(Duration::from_secs(11), None), RestartDecision::RestartAfter(d) if d == Duration::from_millis(100))
            );
        }
    }

    #[test]
    fn a_service_that_served_is_restarted_at_once_and_a_start_up_crash_backs_off() {
        let mut p = RestartPolicy::new(&SupervisorConfig {
            restart_backoff_initial_ms: 100,
            restart_backoff_max_ms: 500,
            restart_backoff_reset_s: 10,
            restart_limit: 6,
            ..Default::default()
        });
        let ms = |d: u64| RestartDecision::RestartAfter(Duration::from_millis(d));
        let served = Some(SERVED_BEFORE_DEATH);
        let s = Duration::from_secs(2);
        assert_eq!(p.on_death(s, served), ms(0), "killed while serving");
        assert_eq!(p.on_death(s, served), ms(0), "and again, 2 s later");
        let early = Some(Duration::from_millis(50));
        assert_eq!(
            p.on_death(s, early),
            ms(100),
            "died just after it was ready"
        );
        assert_eq!(p.on_death(s, None), ms(200), "died before it was ready");
        assert_eq!(p.on_death(s, served), ms(0));
        assert_eq!(
            p.on_death(s, None),
            ms(100),
            "served: the backoff starts over"
        );
        assert_eq!(
            p.on_death(s, served),
            RestartDecision::GiveUp { deaths_in_a_row: 7 },
            "deaths in a row still count"
        );
    }

    #[test]
    fn exits_are_described() {
        let killed = ExitStatus::from_raw(libc::SIGKILL);
        assert_eq!(describe_exit(killed), "signal 9 (SIGKILL)");
        let input = ExitStatus::from_raw(2 << 8);
        assert!(is_input_error(input));
        assert_eq!(describe_exit(input), "exit code 2");
    }

    #[test]
    fn spawned_child_gets_its_own_group_and_dies_with_us_by_signal() {
        let mut child =
            spawn(&["/bin/sh".into(), "-c".into(), "exit 7".into()], &[], None).unwrap();
        let status = child.wait().unwrap();
        assert_eq!(status.code(), Some(7));
        assert!(spawn(&["/no/such/binary".into()], &[], None).is_err());
    }

    #[test]
    fn spawned_child_runs_at_the_configured_niceness() {
        // Field 19 of /proc/self/stat is the niceness (of `cut`, which
        // inherits the shell's).
        let script = r#"exit $(cut -d" " -f19 /proc/self/stat)"#;
        let mut child = spawn(
            &["/bin/sh".into(), "-c".into(), script.into()],
            &[],
            Some(7),
        )
        .unwrap();
        assert_eq!(child.wait().unwrap().code(), Some(7));
    }

    #[test]
    fn renice_reaches_what_a_running_child_had_started_before() {
        // The shell starts a background sleep at once, waits for the
        // renice, then exits with the sleep's niceness (a task that existed
        // before the call, as a service's worker threads do).
        let script =
            r#"sleep 2 & p=$!; sleep 0.5; n=$(cut -d" " -f19 /proc/$p/stat); kill $p; exit $n"#;
        let mut child = spawn(&["/bin/sh".into(), "-c".into(), script.into()], &[], None).unwrap();
        std::thread::sleep(std::time::Duration::from_millis(200));
        renice(child.id(), 6).unwrap();
        assert_eq!(child.wait().unwrap().code(), Some(6));
    }
}
