//! The public pose stream: a program outside the pipeline (the Python example
//! on iceoryx2's PyPI binding) reads every tracked pose of a live run.

mod common;
use common::*;

use std::path::Path;
use std::process::{Command, Stdio};

#[test]
fn the_python_example_receives_every_tracked_pose_of_a_live_run() {
    let dir = scratch("poses-out");
    let run_id = format!("poses{}", std::process::id());
    let received = dir.join("received.txt");
    // The reader starts first and waits for the run to create the stream.
    let reader = Command::new(iox2_python())
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/examples/poses.py"))
        .args(["--run-id", &run_id, "--wait", "60", "--idle", "5", "--out"])
        .arg(&received)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start the Python reader");
    let config = write_config(
        &dir,
        &format!("[services.slam]\nbackend = \"scripted\"\nwork_ms = 20\n{NO_MASK_MODELS}"),
    );
    let run = run(
        &shared_tum(),
        &config,
        &dir.join("runs"),
        &run_id,
        &["--limit", "40"],
    );
    assert!(run.success(), "{}", run.stderr());
    let out = reader.wait_with_output().expect("the reader ends");
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "the reader failed: {log}");

    let rows = read_rows(&run.run_dir);
    let tracked: Vec<(u64, f64)> = rows
        .iter()
        .filter(|r| r["state"] == "ok")
        .map(|r| (r["seq"].parse().unwrap(), r["tx"].parse().unwrap()))
        .collect();
    assert_eq!(tracked.len(), 40);
    let text = std::fs::read_to_string(&received).unwrap();
    let got: Vec<(u64, String, f64)> = text
        .lines()
        .map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            // seq state keyframe | timestamp tx ...
            (
                f[0].parse().unwrap(),
                f[1].to_string(),
                f[5].parse().unwrap(),
            )
        })
        .collect();
    let seqs: Vec<u64> = got.iter().map(|g| g.0).collect();
    assert_eq!(
        seqs,
        tracked.iter().map(|t| t.0).collect::<Vec<_>>(),
        "every tracked pose, once, in order"
    );
    for ((seq, state, tx), (_, want)) in got.iter().zip(&tracked) {
        assert_eq!(state, "ok", "frame {seq}");
        assert!((tx - want).abs() < 1e-6, "frame {seq}: tx {tx} vs {want}");
    }
    assert_no_shm_left(&run_id);
    std::fs::remove_dir_all(&dir).ok();
}
