//! Frames in from a program outside the pipeline (`source.kind =
//! "external"`, README "Frames in"): the Python example publishes shared
//! TUM frames into a live run through iceoryx2's PyPI binding, and a
//! publisher's mistakes become recorded bad frames, not a crashed worker.

mod common;
use common::*;

use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use pipeline::transport::Transport;
use shared_types::names::{RunNames, Topic};
use shared_types::{frame_flags, FrameHeader};

const EXTERNAL: &str = "[run]\nmode = \"realtime\"\n[source]\nkind = \"external\"\n";

/// `dynslam run --config CFG` with no dataset: the frames come from outside.
fn start_run(config: &Path, out: &Path, run_id: &str) -> Child {
    Command::new(dynslam())
        .arg("run")
        .arg("--config")
        .arg(config)
        .arg("--output-dir")
        .arg(out)
        .args(["--run-id", run_id])
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start dynslam run")
}

fn finish(child: Child, what: &str) -> Output {
    let out = child.wait_with_output().expect(what);
    assert!(
        out.status.success(),
        "{what} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// TUM rgb.txt timestamps of the first `n` frames, in order.
fn rgb_timestamps(tum: &Path, n: usize) -> Vec<f64> {
    std::fs::read_to_string(tum.join("rgb.txt"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .take(n)
        .map(|l| l.split_whitespace().next().unwrap().parse().unwrap())
        .collect()
}

/// The bar for an outside source: a Python program publishes into
/// a live run and the real SLAM tracks what it sent (colour and depth read
/// right: the trajectory matches the ground truth).
#[test]
fn the_python_publisher_feeds_a_live_run_that_tracks_its_frames() {
    let dir = scratch("frames-in");
    let run_id = format!("framesin{}", std::process::id());
    let frames = 60;
    let config = write_config(&dir, &format!("{EXTERNAL}{NO_MASK_MODELS}"));
    let run = start_run(&config, &dir.join("runs"), &run_id);
    // Half speed: a busy 2-core CI machine still tracks most of them.
    let publisher = Command::new(iox2_python())
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/examples/publish_tum.py"))
        .args(["--run-id", &run_id, "--wait", "120", "--speed", "0.5"])
        .args(["--limit", &frames.to_string(), "--folder"])
        .arg(shared_tum())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start the Python publisher");
    let published = finish(publisher, "the Python publisher");
    let log = String::from_utf8_lossy(&published.stderr);
    assert!(log.contains(&format!("{frames} frames published")), "{log}");
    let run_out = finish(run, "the external run");
    let run_log = String::from_utf8_lossy(&run_out.stderr);
    assert!(
        run_log.contains("ready for frames from an external publisher"),
        "{run_log}"
    );

    let run_dir = dir.join("runs").join(&run_id);
    let rows = read_rows(&run_dir);
    assert_eq!(rows.len(), frames, "every published frame has a row");
    let want = rgb_timestamps(&shared_tum(), frames);
    for (i, (r, t)) in rows.iter().zip(&want).enumerate() {
        let got: f64 = r["timestamp"].parse().unwrap();
        assert_eq!(r["seq"], i.to_string());
        assert!((got - t).abs() < 1e-6, "frame {i}: timestamp {got} vs {t}");
        assert!(r["state"] != "skipped", "frame {i} was refused: {r:?}");
    }
    let tracked = rows.iter().filter(|r| r["state"] == "ok").count();
    eprintln!("external source: {tracked}/{frames} tracked");
    assert!(tracked * 2 >= frames, "{tracked} of {frames} tracked");
    let s = eval_json(
        &shared_tum().join("groundtruth.txt"),
        &run_dir.join("trajectory.txt"),
        &[],
    );
    let ate = json_f64(&s, "ate_rmse_m");
    eprintln!("external source: ATE {ate:.4} m over {} poses", s["pairs"]);
    assert!(
        ate < 0.03,
        "ATE {ate} m: the published pixels were misread?"
    );
    assert_no_shm_left(&run_id);
    std::fs::remove_dir_all(&dir).ok();
}

/// Waits for the run's status to show it waiting for an outside publisher.
fn wait_until_external(run_dir: &Path) {
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        if let Ok(text) = std::fs::read_to_string(run_dir.join("status.json")) {
            if text.contains("\"external\"") {
                return;
            }
        }
        assert!(Instant::now() < deadline, "the run never became ready");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A publisher's mistakes (a short payload, a depth scale the config does
/// not use, a second frame size) are recorded per frame with the reason;
/// the good frames around them are tracked and the run ends normally.
#[test]
fn bad_external_frames_are_recorded_with_their_reason() {
    let dir = scratch("frames-in-bad");
    let run_id = format!("framesbad{}", std::process::id());
    let config = write_config(
        &dir,
        &format!("{EXTERNAL}[services.slam]\nbackend = \"scripted\"\n{NO_MASK_MODELS}"),
    );
    let run = start_run(&config, &dir.join("runs"), &run_id);
    let run_dir = dir.join("runs").join(&run_id);
    wait_until_external(&run_dir);

    let names = RunNames::new(&run_id).unwrap();
    let transport = Transport::open(&names, "test-publisher").unwrap();
    let (w, h) = (64u32, 48u32);
    let full = (w * h * 5) as usize;
    let sender = transport
        .slice_sender::<FrameHeader>(Topic::Frames, full)
        .unwrap();
    let header = |seq: u64| FrameHeader {
        seq,
        source_timestamp: seq as f64 * 0.1,
        width: w,
        height: h,
        has_depth: 1,
        depth_scale: 5000.0,
        ..Default::default()
    };
    let send = |header: FrameHeader, len: usize| {
        let mut sample = sender.loan(len).unwrap();
        *sample.user_header_mut() = header;
        sender.publish(sample).unwrap();
        // Real time: give the scripted SLAM the time to take each one.
        std::thread::sleep(Duration::from_millis(150));
    };
    send(header(0), full);
    send(header(1), full / 2);
    let mut scaled = header(2);
    scaled.depth_scale = 1000.0;
    send(scaled, full);
    let mut resized = header(3);
    resized.width = 32;
    send(resized, full);
    send(header(4), full);
    let mut end = header(5);
    end.flags = frame_flags::END_OF_STREAM;
    send(end, 0);
    let out = finish(run, "the external run");
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(!log.contains("panicked"), "{log}");
    drop(sender);

    let rows = read_rows(&run_dir);
    assert_eq!(rows.len(), 5, "every frame has a row: {rows:?}");
    let reasons = [
        (1, "payload has 7680 bytes"),
        (2, "depth_scale 1000"),
        (3, "started at 64x48"),
    ];
    for (seq, why) in reasons {
        let r = &rows[seq];
        assert_eq!(r["state"], "skipped", "{r:?}");
        assert!(
            r["note"].contains(why),
            "frame {seq}: '{}' lacks '{why}'",
            r["note"]
        );
        assert!(log.contains(why), "the log lacks '{why}':\n{log}");
    }
    for seq in [0, 4] {
        assert_eq!(rows[seq]["state"], "ok", "frame {seq}: {:?}", rows[seq]);
    }
    assert_no_shm_left(&run_id);
    std::fs::remove_dir_all(&dir).ok();
}

/// A publisher killed mid-stream (no end of stream): the run does not hang.
/// After `supervisor.stall_timeout_s` it fails naming the publisher, with
/// the frames it had recorded and the map written, nothing left in shared
/// memory.
#[test]
fn a_publisher_killed_mid_stream_fails_the_run_with_its_frames_kept() {
    let dir = scratch("frames-in-killed");
    let run_id = format!("framesdead{}", std::process::id());
    let config = write_config(
        &dir,
        &format!("{EXTERNAL}[supervisor]\nstall_timeout_s = 3\n{NO_MASK_MODELS}"),
    );
    let run = start_run(&config, &dir.join("runs"), &run_id);
    let run_dir = dir.join("runs").join(&run_id);
    let mut publisher = Command::new(iox2_python())
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/examples/publish_tum.py"))
        .args(["--run-id", &run_id, "--wait", "120", "--folder"])
        .arg(shared_tum())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start the Python publisher");
    let deadline = Instant::now() + Duration::from_secs(120);
    while std::fs::read_to_string(run_dir.join("status.json"))
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .and_then(|s| s["frames_done"].as_u64())
        .unwrap_or(0)
        < 10
    {
        assert!(Instant::now() < deadline, "no frames recorded");
        std::thread::sleep(Duration::from_millis(50));
    }
    // SIGKILL: no end of stream, no clean-up of its own.
    publisher.kill().unwrap();
    publisher.wait().unwrap();
    let out = run.wait_with_output().unwrap();
    let log = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{log}");
    assert!(
        log.contains("the external publisher sent no frame after"),
        "{log}"
    );
    let rows = read_rows(&run_dir);
    assert!(rows.len() >= 10, "{} rows", rows.len());
    assert!(run_dir.join("trajectory.txt").is_file());
    assert!(run_dir.join("map.ply").is_file());
    assert_no_shm_left(&run_id);
    std::fs::remove_dir_all(&dir).ok();
}
