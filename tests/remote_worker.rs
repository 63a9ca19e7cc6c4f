//! The segmenter on another machine over Zenoh, on real network links:
//! the robot's run and the worker each in a network namespace this test
//! makes (a veth pair between them, addresses only inside those
//! namespaces), with a TCP relay in the robot's namespace that delays every
//! byte 20 ms each way (this kernel has no `tc netem`). The worker runs the
//! real YOLOv8n-seg model. Needs root (CI is) and `just setup`.

mod common;
use common::*;

use std::net::SocketAddr;
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use remote::relay::Relay;

/// One pipeline and worker at a time: they share two cores.
fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(|p| p.into_inner())
}

const RUN: &str = "robot1";
const WORKER_PORT: u16 = 7447;

fn sh(args: &[&str]) {
    let out = Command::new(args[0]).args(&args[1..]).output().unwrap();
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Two network namespaces joined by a veth pair: the robot's and the
/// worker's. Dropped: every process in them killed, both deleted.
struct Net {
    robot: String,
    worker: String,
    worker_if: String,
    worker_ip: String,
}

impl Net {
    fn new() -> Self {
        static N: AtomicU32 = AtomicU32::new(0);
        let n = N.fetch_add(1, Ordering::Relaxed);
        let id = format!("{}{n}", std::process::id() % 100_000);
        let subnet = (std::process::id() + n) % 250 + 1;
        let net = Self {
            robot: format!("dsr{id}"),
            worker: format!("dsw{id}"),
            worker_if: format!("dsw{id}"),
            worker_ip: format!("10.213.{subnet}.2"),
        };
        let robot_if = format!("dsr{id}");
        sh(&["ip", "netns", "add", &net.robot]);
        sh(&["ip", "netns", "add", &net.worker]);
        sh(&[
            "ip",
            "link",
            "add",
            &robot_if,
            "netns",
            &net.robot,
            "type",
            "veth",
            "peer",
            "name",
            &net.worker_if,
            "netns",
            &net.worker,
        ]);
        for (ns, ifname, ip) in [
            (&net.robot, &robot_if, format!("10.213.{subnet}.1/24")),
            (&net.worker, &net.worker_if, format!("{}/24", net.worker_ip)),
        ] {
            sh(&["ip", "-n", ns, "addr", "add", &ip, "dev", ifname]);
            sh(&["ip", "-n", ns, "link", "set", ifname, "up"]);
            sh(&["ip", "-n", ns, "link", "set", "lo", "up"]);
        }
        net
    }

    fn worker_endpoint(&self) -> String {
        format!("tcp/{}:{WORKER_PORT}", self.worker_ip)
    }

    /// Takes the worker's side of the link down or up.
    fn set_link(&self, up: bool) {
        let state = if up { "up" } else { "down" };
        sh(&[
            "ip",
            "-n",
            &self.worker,
            "link",
            "set",
            &self.worker_if,
            state,
        ]);
    }

    /// `program args` inside namespace `ns`.
    fn command(ns: &str, program: &Path) -> Command {
        let mut c = Command::new("ip");
        c.args(["netns", "exec", ns]).arg(program);
        c
    }
}

impl Drop for Net {
    fn drop(&mut self) {
        for ns in [&self.robot, &self.worker] {
            let _ = Command::new("ip")
                .args(["netns", "pids", ns])
                .output()
                .map(|o| {
                    for pid in String::from_utf8_lossy(&o.stdout).split_whitespace() {
                        let _ = Command::new("kill").args(["-9", pid]).status();
                    }
                });
            let _ = Command::new("ip").args(["netns", "del", ns]).status();
        }
    }
}

/// The crate's delaying TCP relay, made in the robot's namespace (on its
/// loopback): a thread enters the namespace and starts it there, so its
/// sockets and threads live in it.
fn relay_in(ns: &str, target: SocketAddr, delay: Duration) -> Relay {
    let ns_path = format!("/var/run/netns/{ns}");
    std::thread::spawn(move || {
        let f = std::fs::File::open(&ns_path).unwrap();
        // SAFETY: setns on a namespace file this thread opened.
        let rc = unsafe { libc::setns(f.as_raw_fd(), libc::CLONE_NEWNET) };
        assert_eq!(rc, 0, "setns {ns_path}");
        Relay::start("127.0.0.1:0".parse().unwrap(), target, delay).unwrap()
    })
    .join()
    .unwrap()
}

fn ort_line() -> String {
    format!(
        "[onnxruntime]\nlibrary = \"{}\"\n",
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(pipeline::provision::ORT_CACHE)
            .display()
    )
}

/// The worker's configuration: the real segmenter at 320 px.
fn worker_config(dir: &Path) -> PathBuf {
    let path = dir.join("worker.toml");
    std::fs::write(
        &path,
        format!("[services.segmenter]\ninput_size = 320\n{}", ort_line()),
    )
    .unwrap();
    path
}

/// `dynslam worker segmenter` listening in the worker's namespace.
fn start_worker(net: &Net, dir: &Path, log: &str) -> Child {
    let out = std::fs::File::create(dir.join(log)).unwrap();
    Net::command(&net.worker, &dynslam())
        .args(["worker", "segmenter", "--run", RUN, "--listen"])
        .arg(format!("tcp/0.0.0.0:{WORKER_PORT}"))
        .arg("--config")
        .arg(worker_config(dir))
        .stdout(Stdio::null())
        .stderr(out)
        .spawn()
        .unwrap()
}

/// A worker serving in its namespace, and the 20 ms relay to it in the
/// robot's.
fn worker_behind_relay(net: &Net, dir: &Path) -> (Child, Relay) {
    let worker = start_worker(net, dir, "worker.log");
    wait_serving(dir, "worker.log");
    let target: SocketAddr = format!("{}:{WORKER_PORT}", net.worker_ip).parse().unwrap();
    (
        worker,
        relay_in(&net.robot, target, Duration::from_millis(20)),
    )
}

/// Waits until the worker's log says it serves.
fn wait_serving(dir: &Path, log: &str) {
    let deadline = Instant::now() + Duration::from_secs(60);
    while !std::fs::read_to_string(dir.join(log))
        .unwrap_or_default()
        .contains("serving run")
    {
        assert!(Instant::now() < deadline, "the worker did not start: {log}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The robot's configuration: the segmenter remote, reached at `endpoint`.
fn robot_config(dir: &Path, endpoint: &str, remote_extra: &str, segmenter_extra: &str) -> PathBuf {
    write_config(
        dir,
        &format!(
            "[services.segmenter]\nlocation = \"remote\"\ninput_size = 320\n{segmenter_extra}\n\
             [remote]\nrun = \"{RUN}\"\nlisten = []\nconnect = [\"{endpoint}\"]\n{remote_extra}\n{}",
            ort_line()
        ),
    )
}

/// `dynslam run` in the robot's namespace, started.
fn start_robot(
    net: &Net,
    dataset: Option<&Path>,
    config: &Path,
    dir: &Path,
    id: &str,
    extra: &[&str],
) -> Child {
    let mut c = Net::command(&net.robot, &dynslam());
    c.arg("run");
    if let Some(d) = dataset {
        c.arg(d);
    }
    c.arg("--config")
        .arg(config)
        .arg("--output-dir")
        .arg(dir.join("runs"))
        .args(["--run-id", id])
        .args(extra)
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(dir.join(format!("{id}.log"))).unwrap())
        .spawn()
        .unwrap()
}

/// Kills a worker and reaps it.
fn stop(mut worker: Child) {
    let _ = worker.kill();
    let _ = worker.wait();
}

fn finish(mut robot: Child, dir: &Path, id: &str) -> (PathBuf, String) {
    let status = robot.wait().unwrap();
    let log = std::fs::read_to_string(dir.join(format!("{id}.log"))).unwrap();
    assert!(status.success(), "{id}: {status}\n{log}");
    (dir.join("runs").join(id), log)
}

/// masks.csv rows: (seq, source, instances, masked_px, origin).
fn mask_rows(run_dir: &Path) -> Vec<(u64, String, u32, u64, String)> {
    std::fs::read_to_string(run_dir.join("masks.csv"))
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (
                f[0].parse().unwrap(),
                f[1].to_string(),
                f[2].parse().unwrap(),
                f[3].parse().unwrap(),
                f[5].to_string(),
            )
        })
        .collect()
}

/// The link's "segmenter: remote: ..." summary line.
fn link_summary(log: &str) -> String {
    log.lines()
        .find(|l| l.contains("segmenter: remote:"))
        .unwrap_or_else(|| panic!("no link summary in\n{log}"))
        .to_string()
}

/// The number before `what` in the link's summary.
fn count(summary: &str, what: &str) -> u64 {
    let before = &summary[..summary
        .find(what)
        .unwrap_or_else(|| panic!("{what}: {summary}"))];
    before
        .split(|c: char| !c.is_ascii_digit())
        .rfind(|s| !s.is_empty())
        .unwrap()
        .parse()
        .unwrap()
}

/// Keyframe masks come from the worker in the other namespace through the
/// 20 ms relay, and with PNG they are the local segmenter's, byte for byte:
/// the same masks and the same trajectory (lockstep, the embedded scene of
/// people walking).
#[test]
fn keyframe_masks_come_from_the_remote_worker_and_equal_the_local_ones() {
    let _serial = one_at_a_time();
    let dir = scratch("remote-masks");
    let local_config = write_config(
        &dir,
        &format!("[services.segmenter]\ninput_size = 320\n{}", ort_line()),
    );
    let local = run_local(&dir, &local_config);
    let net = Net::new();
    let (worker, relay) = worker_behind_relay(&net, &dir);
    let config = robot_config(
        &dir,
        &relay.endpoint(),
        "encoding = \"png\"",
        "fallback = \"none\"",
    );
    let robot = start_robot(&net, None, &config, &dir, "remote", &["--limit", "60"]);
    let (run_dir, log) = finish(robot, &dir, "remote");
    stop(worker);

    let remote = mask_rows(&run_dir);
    let segmented: Vec<_> = remote.iter().filter(|r| r.1 == "segmenter").collect();
    assert!(segmented.len() >= 5, "{} segmenter sets", segmented.len());
    assert!(
        segmented.iter().all(|r| r.4 == "remote"),
        "every segmenter set made remotely: {segmented:?}"
    );
    assert!(segmented.iter().any(|r| r.2 > 0), "people were found");
    let strip = |rows: &[(u64, String, u32, u64, String)]| {
        rows.iter()
            .map(|r| (r.0, r.1.clone(), r.2, r.3))
            .collect::<Vec<_>>()
    };
    assert_eq!(strip(&remote), strip(&mask_rows(&local)), "the local masks");
    let trajectory = |d: &Path| std::fs::read_to_string(d.join("trajectory.txt")).unwrap();
    assert_eq!(trajectory(&run_dir), trajectory(&local));
    // Frames tracked with segmenter masks say where they were made.
    let rows = read_rows(&run_dir);
    assert!(rows
        .iter()
        .filter(|r| r["mask_source"] == "segmenter")
        .all(|r| r["mask_origin"] == "remote"));
    let summary = link_summary(&log);
    assert_eq!(
        count(&summary, "frames masked by remote"),
        segmented.len() as u64
    );
    let report = std::fs::read_to_string(run_dir.join("report.md")).unwrap();
    assert!(
        report.contains(&format!("{} sets of masks made remotely, 0 by the local fallback; 0 segmenter frames went without", segmented.len())),
        "{report}"
    );
}

fn run_local(dir: &Path, config: &Path) -> PathBuf {
    let out = Command::new(dynslam())
        .args(["run", "--limit", "60", "--run-id", "local", "--config"])
        .arg(config)
        .arg("--output-dir")
        .arg(dir.join("runs"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    dir.join("runs/local")
}

/// Real time at 30 fps through the 20 ms relay, the link taken down for
/// 2 s mid-run and back up: every frame is recorded exactly once, the
/// remote masks resume, and the frames the segmenter could not take are
/// counted (fallback "none": the propagator carried the masks).
#[test]
fn a_link_down_for_two_seconds_loses_no_frame_and_the_masks_resume() {
    let _serial = one_at_a_time();
    let dir = scratch("remote-linkdown");
    let net = Net::new();
    let (worker, relay) = worker_behind_relay(&net, &dir);
    let config = robot_config(
        &dir,
        &relay.endpoint(),
        "timeout_ms = 400",
        "fallback = \"none\"",
    );
    let robot = start_robot(
        &net,
        Some(&shared_tum()),
        &config,
        &dir,
        "linkdown",
        &["--mode", "realtime"],
    );
    let frames_csv = dir.join("runs/linkdown/frames.csv");
    let recorded = || {
        std::fs::read_to_string(&frames_csv)
            .map(|t| t.lines().count().saturating_sub(1))
            .unwrap_or(0)
    };
    let deadline = Instant::now() + Duration::from_secs(60);
    while recorded() < 60 {
        assert!(Instant::now() < deadline, "the run did not get going");
        std::thread::sleep(Duration::from_millis(20));
    }
    let down_at = recorded() as u64;
    net.set_link(false);
    std::thread::sleep(Duration::from_secs(2));
    net.set_link(true);
    let up_at = recorded() as u64;
    let (run_dir, log) = finish(robot, &dir, "linkdown");
    stop(worker);

    let rows = read_rows(&run_dir);
    // Rows are written as each frame's fate is known: in real time not in
    // frame order.
    let mut seqs: Vec<u64> = rows.iter().map(|r| r["seq"].parse().unwrap()).collect();
    seqs.sort_unstable();
    assert_eq!(seqs, (0..300).collect::<Vec<u64>>(), "every frame once");
    let masks = mask_rows(&run_dir);
    let segmenter: Vec<_> = masks.iter().filter(|r| r.1 == "segmenter").collect();
    let unavailable = segmenter.iter().filter(|r| r.4 == "unavailable").count();
    assert!(
        unavailable >= 1,
        "frames without fresh segmenter masks: {segmenter:?}"
    );
    assert!(
        segmenter.iter().any(|r| r.4 == "remote" && r.0 < down_at),
        "remote masks before the link went down (frame {down_at}): {segmenter:?}"
    );
    assert!(
        segmenter.iter().any(|r| r.4 == "remote" && r.0 > up_at),
        "remote masks after it came back (frame {up_at}): {segmenter:?}"
    );
    let summary = link_summary(&log);
    assert_eq!(
        count(&summary, "without masks"),
        unavailable as u64,
        "{summary}"
    );
    let report = std::fs::read_to_string(run_dir.join("report.md")).unwrap();
    assert!(
        report.contains(&format!(
            "{unavailable} segmenter frames went without fresh segmenter masks (no worker answered): the propagator carried the masks"
        )),
        "{report}"
    );
    // The propagator masked every tracked frame meanwhile.
    assert!(rows
        .iter()
        .filter(|r| r["state"] == "ok")
        .all(|r| r["mask_source"] != "none"));
}

/// The remote worker killed (SIGKILL) and restarted ten times during a
/// lockstep run: no frame is lost (every one tracked), the local fallback
/// covers the gaps and the remote worker's masks come back each time.
#[test]
fn the_remote_worker_killed_ten_times_loses_no_frame() {
    let _serial = one_at_a_time();
    let dir = scratch("remote-kills");
    let net = Net::new();
    let mut worker = start_worker(&net, &dir, "worker-0.log");
    wait_serving(&dir, "worker-0.log");
    let config = robot_config(&dir, &net.worker_endpoint(), "", "fallback = \"local\"");
    let mut robot = start_robot(&net, Some(&shared_tum()), &config, &dir, "kills", &[]);
    for kill in 1..=10 {
        std::thread::sleep(Duration::from_millis(400));
        // `ip netns exec` execs: the child's pid is the worker's.
        unsafe { libc::kill(worker.id() as i32, libc::SIGKILL) };
        let _ = worker.wait();
        worker = start_worker(&net, &dir, &format!("worker-{kill}.log"));
        assert!(
            robot.try_wait().unwrap().is_none(),
            "the run ended before kill {kill}: kill the worker sooner"
        );
    }
    wait_serving(&dir, "worker-10.log");
    let (run_dir, log) = finish(robot, &dir, "kills");
    stop(worker);

    let rows = read_rows(&run_dir);
    assert_eq!(rows.len(), 300, "every frame of the shared sequence");
    assert!(
        rows.iter().all(|r| r["state"] == "ok"),
        "every frame tracked"
    );
    let masks = mask_rows(&run_dir);
    let origins = |o: &str| {
        masks
            .iter()
            .filter(|r| r.1 == "segmenter" && r.4 == o)
            .count()
    };
    assert!(origins("remote") >= 2, "{masks:?}");
    assert!(origins("fallback") >= 1, "{masks:?}");
    assert_eq!(origins("unavailable"), 0);
    let summary = link_summary(&log);
    assert_eq!(
        count(&summary, "by the local fallback"),
        origins("fallback") as u64
    );
}

/// A Zenoh client we did not write (eclipse-zenoh, PyPI) sends the worker
/// hostile queries (empty, random, 16 MB, a header lying about its sizes):
/// each is refused with an error reply and counted, and the worker goes on
/// to serve a robot's run.
#[test]
fn hostile_queries_are_refused_and_counted_and_the_worker_goes_on() {
    let _serial = one_at_a_time();
    let dir = scratch("remote-hostile");
    let net = Net::new();
    let mut worker = start_worker(&net, &dir, "worker.log");
    wait_serving(&dir, "worker.log");
    let out = Net::command(&net.robot, &venv_python("ros2-venv", "ros2py"))
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/remote/hostile.py"))
        .args(["--endpoint", &net.worker_endpoint(), "--run", RUN])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let replies: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for name in ["empty", "random", "huge", "lying"] {
        let r = replies[name].as_array().unwrap();
        assert_eq!(r.len(), 1, "{name}: {replies}");
        let err = r[0]["err"].as_str().unwrap_or_default();
        assert!(err.starts_with("refused: "), "{name}: {replies}");
    }
    // The same worker then serves a robot.
    let config = robot_config(&dir, &net.worker_endpoint(), "", "fallback = \"none\"");
    let robot = start_robot(
        &net,
        Some(&shared_tum()),
        &config,
        &dir,
        "after",
        &["--limit", "20"],
    );
    let (run_dir, _) = finish(robot, &dir, "after");
    assert!(mask_rows(&run_dir)
        .iter()
        .any(|r| r.1 == "segmenter" && r.4 == "remote"));
    unsafe { libc::kill(worker.id() as i32, libc::SIGTERM) };
    assert!(worker.wait().unwrap().success());
    let log = std::fs::read_to_string(dir.join("worker.log")).unwrap();
    assert!(log.contains("refused a request (4 so far)"), "{log}");
    assert!(log.contains("4 requests refused"), "{log}");
}

/// The worker's command line and the robot's configuration say what is
/// wrong and what to give.
#[test]
fn bad_worker_arguments_and_remote_settings_are_named() {
    let worker = |args: &[&str]| {
        let out = Command::new(dynslam())
            .arg("worker")
            .args(args)
            .output()
            .unwrap();
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let (code, err) = worker(&["segmenter", "--run", "a/b", "--connect", "tcp/127.0.0.1:1"]);
    assert_eq!(code, Some(2));
    assert!(err.contains("--run: 'a/b' is not a run name"), "{err}");
    let (code, err) = worker(&["segmenter", "--run", "r1"]);
    assert_eq!(code, Some(2));
    assert!(err.contains("give --connect ENDPOINT"), "{err}");
    let (code, err) = worker(&["painter", "--run", "r1"]);
    assert_eq!(code, Some(2));
    assert!(err.contains("invalid value 'painter'"), "{err}");

    let dir = scratch("remote-bad-config");
    let cases = [
        (
            "[services.segmenter]\nlocation = \"remote\"\n",
            "key `remote.run`: empty",
        ),
        (
            "[services.segmenter]\nlocation = \"gpu\"\n",
            "key `services.segmenter.location`: 'gpu' is not one of local, remote",
        ),
        (
            "[services.segmenter]\nlocation = \"remote\"\n[remote]\nrun = \"r\"\nencoding = \"webp\"\n",
            "key `remote.encoding`: 'webp' is not one of jpeg, png, raw",
        ),
    ];
    for (toml, expected) in cases {
        let config = write_config(&dir, toml);
        let out = Command::new(dynslam())
            .args(["run", "--limit", "1", "--config"])
            .arg(&config)
            .arg("--output-dir")
            .arg(dir.join("runs"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && err.contains(expected),
            "{expected}: {err}"
        );
    }
}

/// Mutual TLS with the shipped examples (configs/zenoh/robot-mtls.json5 and
/// worker-mtls.json5, test certificates in place): the worker's masks come
/// through; a worker whose certificate the CA signed but with another
/// common name is refused by the robot's access control, so the robot
/// never hears it (loopback: the examples name localhost).
#[test]
fn mutual_tls_with_the_shipped_examples_admits_the_worker_and_not_an_intruder() {
    let _serial = one_at_a_time();
    let dir = scratch("remote-tls");
    test_certificates(
        &dir,
        &[
            ("robot", "localhost", "DNS:localhost,IP:127.0.0.1"),
            ("worker", "dynslam-worker", "DNS:dynslam-worker"),
            ("intruder", "intruder", "DNS:intruder"),
        ],
    );
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let robot_zenoh = shipped_zenoh_config("robot-mtls.json5", &dir, port);
    let worker_zenoh = shipped_zenoh_config("worker-mtls.json5", &dir, port);
    let intruder_zenoh = dir.join("intruder-mtls.json5");
    std::fs::write(
        &intruder_zenoh,
        std::fs::read_to_string(&worker_zenoh)
            .unwrap()
            .replace("worker.key", "intruder.key")
            .replace("worker.pem", "intruder.pem"),
    )
    .unwrap();
    let config = write_config(
        &dir,
        &format!(
            "[services.segmenter]\nlocation = \"remote\"\nfallback = \"none\"\ninput_size = 320\n\
             [remote]\nrun = \"{RUN}\"\nzenoh_config = \"{}\"\nstartup_wait_s = 4\n\
             [supervisor]\nrestart_limit = 1\n{}",
            robot_zenoh.display(),
            ort_line()
        ),
    );
    let run = |id: &str, worker_zenoh: &Path| {
        let out = std::fs::File::create(dir.join(format!("{id}-worker.log"))).unwrap();
        let worker = Command::new(dynslam())
            .args(["worker", "segmenter", "--run", RUN, "--zenoh-config"])
            .arg(worker_zenoh)
            .arg("--config")
            .arg(worker_config(&dir))
            .stdout(Stdio::null())
            .stderr(out)
            .spawn()
            .unwrap();
        let result = common::run(
            &shared_tum(),
            &config,
            &dir.join("runs"),
            id,
            &["--limit", "20"],
        );
        stop(worker);
        result
    };
    let admitted = run("tls-worker", &worker_zenoh);
    assert!(admitted.success(), "{}", admitted.stderr());
    assert!(mask_rows(&admitted.run_dir)
        .iter()
        .any(|r| r.1 == "segmenter" && r.4 == "remote"));

    let refused = run("tls-intruder", &intruder_zenoh);
    assert_eq!(
        refused.output.status.code(),
        Some(3),
        "{}",
        refused.stderr()
    );
    assert!(
        refused
            .stderr()
            .contains("no remote segmenter worker for run 'robot1' appeared within 4 s"),
        "{}",
        refused.stderr()
    );
    assert!(!mask_rows(&refused.run_dir).iter().any(|r| r.4 == "remote"));
}
