//! A killed SLAM in real time: how many frames go without a pose. Its own
//! test binary, so that no other test loads the machine during the
//! real-time runs (the binaries run one after another).

mod common;
use common::*;

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

fn status(run_dir: &Path) -> Option<serde_json::Value> {
    let text = std::fs::read_to_string(run_dir.join("status.json")).ok()?;
    serde_json::from_str(&text).ok()
}

/// The pid of the SLAM process while it is ready.
fn ready_slam(run_dir: &Path) -> Option<u32> {
    let s = status(run_dir)?;
    let slam = s["children"]
        .as_array()?
        .iter()
        .find(|c| c["service"] == "slam")?;
    (slam["state"] == "ready")
        .then(|| slam["pid"].as_u64().map(|p| p as u32))
        .flatten()
}

fn kill9(pid: u32) {
    // SAFETY: plain kill(2) of a pid read from the run's status file.
    unsafe { libc::kill(pid as i32, libc::SIGKILL) };
}

/// `dynslam run` of the shared sequence in the background, into
/// `dir/runs/<run_id>`, logging to `dir/supervisor.log`.
fn start_run(dir: &Path, config: &Path, run_id: &str) -> (Child, std::path::PathBuf) {
    let log = dir.join("supervisor.log");
    let sup = Command::new(dynslam())
        .arg("run")
        .arg(shared_tum())
        .arg("--config")
        .arg(config)
        .arg("--output-dir")
        .arg(dir.join("runs"))
        .args(["--run-id", run_id])
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log).unwrap())
        .spawn()
        .unwrap();
    (sup, log)
}

/// Waits for the supervisor to exit successfully, without a panic logged.
fn finish_cleanly(supervisor: &mut Child, log: &Path, limit: Duration) {
    let t = Instant::now();
    let exit = loop {
        if let Some(st) = supervisor.try_wait().unwrap() {
            break st;
        }
        assert!(
            t.elapsed() < limit,
            "run did not finish; see {}",
            log.display()
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    let log_text = std::fs::read_to_string(log).unwrap();
    assert!(exit.success(), "supervisor failed: {exit}\n{log_text}");
    assert!(
        !log_text.contains("panicked"),
        "a process panicked:\n{log_text}"
    );
}

/// The frames without a pose around each SLAM death of a finished run,
/// counted from its `restarts.log` and `frames.csv` (independently of the
/// report's own count): from the dead process's last pose to its
/// successor's first.
fn frames_without_pose_per_slam_death(run_dir: &Path, rows: &[Row]) -> Vec<u64> {
    let tracked: Vec<u64> = rows
        .iter()
        .filter(|r| r["state"] == "ok" || r["state"] == "relocalised")
        .map(|r| r["seq"].parse().unwrap())
        .collect();
    std::fs::read_to_string(run_dir.join("restarts.log"))
        .unwrap()
        .lines()
        .filter(|l| l.starts_with("slam "))
        .map(|l| {
            let w: Vec<&str> = l.split_whitespace().collect();
            let at = w.iter().position(|w| *w == "next_seq").unwrap();
            let next_seq: u64 = w[at + 1].parse().unwrap();
            let last = tracked.iter().rev().find(|&&s| s < next_seq).copied();
            let first = tracked.iter().find(|&&s| s >= next_seq).copied();
            let first =
                first.unwrap_or_else(|| panic!("nothing tracked after the death at {next_seq}"));
            first - last.map_or(0, |l| l + 1)
        })
        .collect()
}

/// The cold restart in real time: the shared sequence at 30 fps, the real
/// SLAM killed 5 times, 1.5 s apart. Each kill costs at most 15 frames
/// (0.5 s) without a pose (before the restarted SLAM was told that the
/// dead one's frames will never be tracked and was restarted without
/// backoff, each cost 30 or more), every frame is recorded once, one world
/// frame, and the ATE stays within 1.2x of an unkilled run's (same test).
#[test]
fn a_killed_slam_costs_a_few_frames_in_real_time() {
    let dir = scratch("slam-kills-realtime");
    let config = write_config(&dir, "[run]\nmode = \"realtime\"\n");
    let tum = shared_tum();
    let gt = tum.join("groundtruth.txt");
    let calm_id = format!("rtcalm{}", std::process::id());
    let calm = run(&tum, &config, &dir.join("runs"), &calm_id, &[]);
    assert!(calm.success(), "{}", calm.stderr());
    let calm_ate = json_f64(
        &eval_json(&gt, &calm.run_dir.join("trajectory.txt"), &[]),
        "ate_rmse_m",
    );

    let run_id = format!("rtkill{}", std::process::id());
    let run_dir = dir.join("runs").join(&run_id);
    let (mut supervisor, log) = start_run(&dir, &config, &run_id);
    // The first kill once SLAM has tracked for a while.
    let deadline = Instant::now() + Duration::from_secs(120);
    while std::fs::read_to_string(run_dir.join("frames.csv")).map_or(0, |t| t.lines().count()) < 40
    {
        assert!(Instant::now() < deadline, "the run never started tracking");
        std::thread::sleep(Duration::from_millis(20));
    }
    const KILLS: usize = 5;
    let mut killed = Vec::new();
    while killed.len() < KILLS {
        match ready_slam(&run_dir) {
            Some(pid) if !killed.contains(&pid) => {
                kill9(pid);
                killed.push(pid);
                std::thread::sleep(Duration::from_millis(1500));
            }
            _ => std::thread::sleep(Duration::from_millis(10)),
        }
        assert!(
            supervisor.try_wait().unwrap().is_none(),
            "the run ended after {} kills",
            killed.len()
        );
    }
    finish_cleanly(&mut supervisor, &log, Duration::from_secs(120));

    let rows = read_rows(&run_dir);
    let mut seqs: Vec<u64> = rows.iter().map(|r| r["seq"].parse().unwrap()).collect();
    seqs.sort_unstable();
    assert_eq!(
        seqs,
        (0..300).collect::<Vec<u64>>(),
        "every frame exactly once"
    );
    let s = read_status(&run_dir);
    assert_eq!(s["state"], "completed");
    assert_eq!(s["restarts"].as_u64().unwrap(), KILLS as u64);
    let starts = std::fs::read_to_string(run_dir.join("slam-starts.log")).unwrap();
    assert!(
        starts.lines().count() == KILLS && starts.lines().all(|l| l.ends_with("checkpoint")),
        "one world frame: every SLAM start goes on from the checkpoint:\n{starts}"
    );
    let gaps = frames_without_pose_per_slam_death(&run_dir, &rows);
    let ate = json_f64(
        &eval_json(&gt, &run_dir.join("trajectory.txt"), &[]),
        "ate_rmse_m",
    );
    println!(
        "frames without a pose per SLAM kill: {gaps:?}; ATE {ate:.4} m killed, {calm_ate:.4} m unkilled (x{:.2})",
        ate / calm_ate
    );
    assert_eq!(gaps.len(), KILLS);
    assert!(
        gaps.iter().all(|&g| g <= 15),
        "a SLAM kill cost more than 15 frames (0.5 s) without a pose: {gaps:?}"
    );
    let report = std::fs::read_to_string(run_dir.join("report.md")).unwrap();
    let line = report
        .lines()
        .find(|l| l.starts_with("SLAM deaths: 5;"))
        .unwrap_or_else(|| panic!("no SLAM deaths line in the report:\n{report}"));
    let listed: Vec<String> = gaps.iter().map(|g| g.to_string()).collect();
    assert!(
        line.contains(&format!(": {};", listed.join(", "))),
        "{line}"
    );
    assert!(
        ate <= 1.2 * calm_ate,
        "killed run ATE {ate} m is more than 1.2x the unkilled run's {calm_ate} m"
    );
    assert_no_shm_left(&run_id);
    std::fs::remove_dir_all(&dir).ok();
}
