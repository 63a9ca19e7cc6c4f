//! SIGKILL of every service kind at random moments, the supervisor included
//! (the test resumes it, as an operator or systemd would): the run
//! completes, every frame is recorded exactly once, the restart count equals
//! the number of services killed, and nothing of the run stays in /dev/shm.

mod common;
use common::*;

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const KINDS: [&str; 5] = [
    "camera-reader",
    "segmenter",
    "propagator",
    "slam",
    "supervisor",
];
const TARGET_KILLS: usize = 24;

/// Small deterministic generator (xorshift), seeded from the clock; the seed
/// is printed so a failing sequence can be replayed.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

fn child_entry<'a>(s: &'a serde_json::Value, kind: &str) -> Option<&'a serde_json::Value> {
    s["children"]
        .as_array()?
        .iter()
        .find(|c| c["service"] == kind)
}

fn all_ready(s: &serde_json::Value) -> bool {
    KINDS[..4]
        .iter()
        .all(|k| child_entry(s, k).is_some_and(|c| c["state"] == "ready"))
}

fn start_supervisor(args: &[&str], log: &Path) -> Child {
    let log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(log)
        .unwrap();
    Command::new(dynslam())
        .args(args)
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .unwrap()
}

/// `dynslam run DATASET` into `dir/runs/<run_id>` in the background, and
/// the `dynslam resume` arguments a storm restarts it with.
fn start_storm_run(
    dataset: &Path,
    config: &Path,
    dir: &Path,
    run_id: &str,
    log: &Path,
) -> (Child, Vec<String>) {
    let runs = dir.join("runs");
    let supervisor = start_supervisor(
        &[
            "run",
            dataset.to_str().unwrap(),
            "--config",
            config.to_str().unwrap(),
            "--output-dir",
            runs.to_str().unwrap(),
            "--run-id",
            run_id,
        ],
        log,
    );
    let resume = vec!["resume".into(), runs.join(run_id).display().to_string()];
    (supervisor, resume)
}

/// The run a kill storm strikes.
struct StormRun<'a> {
    run_dir: &'a Path,
    run_id: &'a str,
    /// `dynslam resume RUN_DIR`, for after a supervisor kill.
    resume_args: &'a [String],
    log: &'a Path,
    /// How long the pipeline works before each kill: at least `pause_ms.0`
    /// plus a random share of `pause_ms.1` (milliseconds).
    pause_ms: (u64, u64),
}

/// What a kill storm did.
struct Storm {
    supervisor: Child,
    child_kills: u64,
    kills_by_kind: std::collections::HashMap<&'static str, u64>,
}

/// SIGKILLs services of the live run in `run_dir` (and its supervisor,
/// which is then resumed with `resume_args`) at random moments once the
/// whole pipeline is up, until `enough` says the kills so far suffice.
/// `pick` chooses the next kind from the kills so far and a random number.
fn storm(
    mut supervisor: Child,
    StormRun {
        run_dir,
        run_id,
        resume_args,
        log,
        pause_ms,
    }: StormRun,
    time_limit: Duration,
    pick: impl Fn(&std::collections::HashMap<&'static str, u64>, &mut Rng) -> &'static str,
    enough: impl Fn(&std::collections::HashMap<&'static str, u64>) -> bool,
) -> Storm {
    let seed = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64
        | 1;
    println!("kill sequence seed {seed}");
    let mut rng = Rng(seed);
    let mut child_kills = 0u64;
    let mut supervisor_kills = 0u64;
    let mut kills_by_kind: std::collections::HashMap<&'static str, u64> =
        std::collections::HashMap::new();
    let deadline = Instant::now() + time_limit;

    while !enough(&kills_by_kind) {
        assert!(
            Instant::now() < deadline,
            "kills took too long; see {}",
            log.display()
        );
        // Wait until the whole pipeline is up again.
        let s = loop {
            if let Some(s) = status(run_dir) {
                if s["state"] == "completed" {
                    break s;
                }
                if s["state"] == "running"
                    && all_ready(&s)
                    && s["supervisor_pid"] == supervisor.id()
                {
                    break s;
                }
            }
            assert!(
                Instant::now() < deadline,
                "pipeline did not recover; see {}",
                log.display()
            );
            std::thread::sleep(Duration::from_millis(5));
        };
        assert_ne!(
            s["state"],
            "completed",
            "run ended after only {} kills ({kills_by_kind:?}); make it longer",
            child_kills + supervisor_kills
        );
        // Let it work for a random moment, then strike.
        std::thread::sleep(Duration::from_millis(pause_ms.0 + rng.below(pause_ms.1)));
        let kind = pick(&kills_by_kind, &mut rng);
        let Some(s) = status(run_dir) else { continue };
        if s["state"] != "running" || !all_ready(&s) {
            continue;
        }
        if kind == "supervisor" {
            kill9(supervisor.id());
            supervisor.wait().unwrap();
            supervisor_kills += 1;
            *kills_by_kind.entry(kind).or_insert(0) += 1;
            // The services follow their supervisor (SIGTERM on parent death).
            let t = Instant::now();
            while !processes_mentioning(&format!("--run-id {run_id}").replace(' ', "\0")).is_empty()
                && t.elapsed() < Duration::from_secs(5)
            {
                std::thread::sleep(Duration::from_millis(10));
            }
            supervisor = start_supervisor(
                &resume_args.iter().map(String::as_str).collect::<Vec<_>>(),
                log,
            );
            continue;
        }
        let entry = child_entry(&s, kind).unwrap();
        let pid = entry["pid"].as_u64().unwrap() as u32;
        let before = s["restarts"].as_u64().unwrap();
        kill9(pid);
        child_kills += 1;
        *kills_by_kind.entry(kind).or_insert(0) += 1;
        // The supervisor notices and counts the restart.
        let t = Instant::now();
        loop {
            let s = status(run_dir).unwrap();
            if s["restarts"].as_u64().unwrap() > before || s["state"] == "completed" {
                break;
            }
            assert!(
                t.elapsed() < Duration::from_secs(10),
                "kill of {kind} not noticed"
            );
            std::thread::sleep(Duration::from_millis(5));
        }
    }
    Storm {
        supervisor,
        child_kills,
        kills_by_kind,
    }
}

/// The kind of `kinds` killed least so far.
fn least_killed(
    kills: &std::collections::HashMap<&'static str, u64>,
    kinds: &[&'static str],
) -> &'static str {
    kinds
        .iter()
        .copied()
        .min_by_key(|k| kills.get(k).copied().unwrap_or(0))
        .unwrap()
}

#[test]
fn kill_any_service_at_any_moment_and_the_run_completes() {
    let dir = scratch("faults");
    let run_id = format!("kill{}", std::process::id());
    let run_dir = dir.join("runs").join(&run_id);
    let log = dir.join("supervisor.log");
    // A slow-ish SLAM keeps the run long enough for the kills; short backoff.
    let config = write_config(
        &dir,
        "[services.slam]\nbackend = \"scripted\"\nkeyframe_every = 5\nwork_ms = 30\n\
         [services.segmenter]\nbackend = \"none\"\nwork_ms = 3\n\
         [services.propagator]\nbackend = \"none\"\n\
         [supervisor]\nrestart_backoff_initial_ms = 20\nrestart_backoff_max_ms = 160\nrestart_limit = 100\n",
    );
    let tum = shared_tum();
    let (supervisor, resume_args) = start_storm_run(&tum, &config, &dir, &run_id, &log);

    let Storm {
        mut supervisor,
        child_kills,
        kills_by_kind,
    } = storm(
        supervisor,
        StormRun {
            run_dir: &run_dir,
            run_id: &run_id,
            resume_args: &resume_args,
            log: &log,
            pause_ms: (20, 150),
        },
        Duration::from_secs(240),
        |kills, rng| {
            // Kinds in a shuffled round so that every kind is hit.
            let total: u64 = kills.values().sum();
            if (total as usize).is_multiple_of(KINDS.len()) || rng.below(2) == 1 {
                KINDS[rng.below(KINDS.len() as u64) as usize]
            } else {
                least_killed(kills, &KINDS)
            }
        },
        |kills| kills.values().sum::<u64>() >= TARGET_KILLS as u64,
    );
    let supervisor_kills = kills_by_kind.get("supervisor").copied().unwrap_or(0);
    println!("kills: {kills_by_kind:?}");

    finish_cleanly(&mut supervisor, &log, Duration::from_secs(180));

    for kind in KINDS {
        assert!(
            kills_by_kind.get(kind).copied().unwrap_or(0) >= 1,
            "{kind} never killed: {kills_by_kind:?}"
        );
    }
    assert!(child_kills + supervisor_kills >= 20);

    // Every frame exactly once, in order, with its state.
    let rows = read_rows(&run_dir);
    let seqs: Vec<u64> = rows.iter().map(|r| r["seq"].parse().unwrap()).collect();
    assert_eq!(seqs, (0..300).collect::<Vec<u64>>());
    assert!(
        rows.iter().all(|r| r["state"] == "ok"),
        "lockstep loses no frame"
    );

    let s = status(&run_dir).unwrap();
    assert_eq!(s["state"], "completed");
    assert_eq!(
        s["restarts"].as_u64().unwrap(),
        child_kills,
        "one restart per killed service"
    );
    let restart_lines = std::fs::read_to_string(run_dir.join("restarts.log"))
        .unwrap()
        .lines()
        .count() as u64;
    assert_eq!(restart_lines, child_kills);

    assert_no_shm_left(&run_id);
    assert!(
        processes_mentioning(&run_id).is_empty(),
        "processes of the run outlived it"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// The persistent-map issue's bar: the real SLAM (`orb-rgbd`) with the
/// product's models in a lockstep run over the 300 shared frames, killed at
/// least 10 times, and every other kind at least once (the supervisor
/// included). Every restart goes on from the map checkpoint in the one
/// world frame: every frame recorded exactly once, restarts == kills, and
/// the ATE of the killed run <= 0.025 m and <= 1.5x the unkilled run's
/// (same config, same test); the ratio and the frames each restart lost
/// before relocalising are printed.
#[test]
fn the_real_slam_killed_again_and_again_goes_on_in_one_world_frame() {
    let dir = scratch("slam-faults");
    let config = write_config(
        &dir,
        "[supervisor]\nrestart_backoff_initial_ms = 20\nrestart_backoff_max_ms = 160\nrestart_limit = 100\n",
    );
    let tum = shared_tum();
    let gt = tum.join("groundtruth.txt");
    let calm_id = format!("calm{}", std::process::id());
    let calm = run(&tum, &config, &dir.join("runs"), &calm_id, &[]);
    assert!(calm.success(), "{}", calm.stderr());
    let calm_ate = json_f64(
        &eval_json(&gt, &calm.run_dir.join("trajectory.txt"), &[]),
        "ate_rmse_m",
    );

    let run_id = format!("slamkill{}", std::process::id());
    let run_dir = dir.join("runs").join(&run_id);
    let log = dir.join("supervisor.log");
    let (supervisor, resume_args) = start_storm_run(&tum, &config, &dir, &run_id, &log);
    const SLAM_KILLS: u64 = 10;
    let others = ["camera-reader", "segmenter", "propagator", "supervisor"];
    let killed = |kills: &std::collections::HashMap<&'static str, u64>, k: &str| {
        kills.get(k).copied().unwrap_or(0)
    };
    let Storm {
        mut supervisor,
        child_kills,
        kills_by_kind,
    } = storm(
        supervisor,
        StormRun {
            run_dir: &run_dir,
            run_id: &run_id,
            resume_args: &resume_args,
            log: &log,
            // Spread over the run (about 20 s of frames at 15 fps here).
            pause_ms: (100, 700),
        },
        Duration::from_secs(400),
        |kills, rng| {
            if killed(kills, "slam") < SLAM_KILLS && rng.below(3) != 0 {
                "slam"
            } else {
                least_killed(kills, &others)
            }
        },
        |kills| killed(kills, "slam") >= SLAM_KILLS && others.iter().all(|k| killed(kills, k) >= 1),
    );
    println!("kills: {kills_by_kind:?}");
    finish_cleanly(&mut supervisor, &log, Duration::from_secs(300));

    let rows = read_rows(&run_dir);
    let seqs: Vec<u64> = rows.iter().map(|r| r["seq"].parse().unwrap()).collect();
    assert_eq!(
        seqs,
        (0..300).collect::<Vec<u64>>(),
        "every frame exactly once"
    );
    let s = status(&run_dir).unwrap();
    assert_eq!(s["state"], "completed");
    assert_eq!(
        s["restarts"].as_u64().unwrap(),
        child_kills,
        "one restart per killed service"
    );

    // One world frame: every SLAM start after the first went on from the
    // checkpoint (a supervisor kill takes the SLAM with it: a start too).
    let starts = std::fs::read_to_string(run_dir.join("slam-starts.log")).unwrap();
    let starts: Vec<(u64, bool)> = starts
        .lines()
        .map(|l| {
            let w: Vec<&str> = l.split_whitespace().collect();
            (w[1].parse().unwrap(), w[3] == "checkpoint")
        })
        .collect();
    assert!(starts.len() as u64 >= SLAM_KILLS, "{starts:?}");
    assert!(
        starts.iter().all(|s| s.1),
        "a SLAM start without its checkpoint: {starts:?}"
    );
    let tracked = |r: &&Row| r["state"] == "ok" || r["state"] == "relocalised";
    let lost: Vec<String> = starts
        .iter()
        .map(|&(at, _)| {
            let n = rows[at as usize..]
                .iter()
                .take_while(|r| !tracked(r))
                .count();
            format!("{n} at {at}")
        })
        .collect();
    println!(
        "frames lost after each SLAM start before relocalising: {}",
        lost.join(", ")
    );
    let n_tracked = rows.iter().filter(tracked).count();
    let ate = json_f64(
        &eval_json(&gt, &run_dir.join("trajectory.txt"), &[]),
        "ate_rmse_m",
    );
    println!(
        "killed run: {n_tracked}/300 tracked, ATE {ate:.4} m; unkilled run ATE {calm_ate:.4} m (x{:.2})",
        ate / calm_ate
    );
    assert!(n_tracked >= 270, "{n_tracked} of 300 tracked");
    let report = std::fs::read_to_string(run_dir.join("report.md")).unwrap();
    assert!(
        report.contains("went on from its map checkpoint, in the same world frame"),
        "{report}"
    );
    assert!(!report.contains("Several world frames"), "{report}");
    // Each restart resumed its predecessor's motion from the supervisor's
    // record of the last tracked frames.
    assert!(
        run_dir.join("slam-resume-poses.txt").is_file(),
        "no resume poses were handed to a restarted SLAM"
    );
    // Before the supervisor handed the restarted SLAM its predecessor's last
    // poses and the keyframe rule had its reference back, the ratio was
    // x1.14-x1.75 over seven runs; since, x0.91, x0.91, x1.06.
    assert!(
        ate <= 1.5 * calm_ate,
        "killed run ATE {ate} m is more than 1.5x the unkilled run's {calm_ate} m"
    );
    assert!(ate <= 0.025, "ATE {ate} m against {calm_ate} m unkilled");
    assert_no_shm_left(&run_id);
    assert!(
        processes_mentioning(&run_id).is_empty(),
        "processes of the run outlived it"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// The reliability issue's storm: at least 100 SIGKILLs spread over every
/// kind (the supervisor included) in one lockstep run of the product config
/// (real SLAM with its checkpoints, the real models) over the shared
/// sequence played five times (1500 frames; each new pass is a jump the
/// SLAM relocalises from; 100 kills took 37 s of a 74 s run of 1200 here). Every frame is recorded exactly once, the run
/// completes (no hang), restarts == kills, every SLAM start after the first
/// goes on from its checkpoint, nothing of the run outlives it.
#[test]
fn a_hundred_kills_of_every_kind_with_the_product_config() {
    let dir = scratch("storm100");
    let config = write_config(
        &dir,
        "[source]\nrepeat = 5\n\
         [supervisor]\nrestart_backoff_initial_ms = 20\nrestart_backoff_max_ms = 160\nrestart_limit = 1000\n",
    );
    let tum = shared_tum();
    let run_id = format!("storm{}", std::process::id());
    let run_dir = dir.join("runs").join(&run_id);
    let log = dir.join("supervisor.log");
    let (supervisor, resume_args) = start_storm_run(&tum, &config, &dir, &run_id, &log);
    const KILLS: u64 = 100;
    let started = Instant::now();
    let Storm {
        mut supervisor,
        child_kills,
        kills_by_kind,
    } = storm(
        supervisor,
        StormRun {
            run_dir: &run_dir,
            run_id: &run_id,
            resume_args: &resume_args,
            log: &log,
            pause_ms: (30, 200),
        },
        Duration::from_secs(600),
        |kills, rng| {
            if rng.below(2) == 1 {
                KINDS[rng.below(KINDS.len() as u64) as usize]
            } else {
                least_killed(kills, &KINDS)
            }
        },
        |kills| kills.values().sum::<u64>() >= KILLS,
    );
    let storm_s = started.elapsed().as_secs_f64();
    finish_cleanly(&mut supervisor, &log, Duration::from_secs(400));
    println!(
        "kills: {kills_by_kind:?} in {storm_s:.0} s; run done after {:.0} s",
        started.elapsed().as_secs_f64()
    );
    for kind in KINDS {
        assert!(
            kills_by_kind.get(kind).copied().unwrap_or(0) >= 5,
            "{kind} killed too rarely: {kills_by_kind:?}"
        );
    }
    let rows = read_rows(&run_dir);
    let seqs: Vec<u64> = rows.iter().map(|r| r["seq"].parse().unwrap()).collect();
    assert_eq!(
        seqs,
        (0..1500).collect::<Vec<u64>>(),
        "every frame exactly once"
    );
    let s = status(&run_dir).unwrap();
    assert_eq!(s["state"], "completed");
    assert_eq!(s["restarts"].as_u64().unwrap(), child_kills);
    let starts = std::fs::read_to_string(run_dir.join("slam-starts.log")).unwrap();
    assert!(
        starts.lines().all(|l| l.ends_with("checkpoint")),
        "a SLAM start without its checkpoint:\n{starts}"
    );
    let tracked = rows
        .iter()
        .filter(|r| r["state"] == "ok" || r["state"] == "relocalised")
        .count();
    println!("{tracked}/1500 frames tracked");
    assert_no_shm_left(&run_id);
    assert!(
        processes_mentioning(&run_id).is_empty(),
        "processes of the run outlived it"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// `dynslam run` of the first `limit` shared frames in the background, into
/// `dir/runs/<run_id>`, logging to `dir/supervisor.log`.
fn start_run(dir: &Path, config: &Path, run_id: &str, limit: u32) -> (Child, std::path::PathBuf) {
    let log = dir.join("supervisor.log");
    let limit = limit.to_string();
    let sup = start_supervisor(
        &[
            "run",
            shared_tum().to_str().unwrap(),
            "--config",
            config.to_str().unwrap(),
            "--output-dir",
            dir.join("runs").to_str().unwrap(),
            "--run-id",
            run_id,
            "--limit",
            &limit,
        ],
        &log,
    );
    (sup, log)
}

/// A lockstep run whose mask worker is killed and given up on
/// (`restart_limit = 0`) while a frame routed to it is in flight: that
/// frame goes on unmasked instead of the run waiting for it forever.
fn given_up_worker_with_a_frame_in_flight(worker: &str, routing: &str) {
    let dir = scratch(&format!("orphan-{worker}"));
    let run_id = format!("orphan{worker}{}", std::process::id());
    let run_dir = dir.join("runs").join(&run_id);
    let config = write_config(
        &dir,
        &format!(
            "[services.slam]\nbackend = \"scripted\"\nkeyframe_every = 1000\n\
             [services.segmenter]\nbackend = \"none\"\nwork_ms = 40\n\
             [services.propagator]\nbackend = \"none\"\nwork_ms = 40\n\
             [supervisor]\nrestart_limit = 0\n{routing}"
        ),
    );
    let (mut sup, log) = start_run(&dir, &config, &run_id, 60);
    // Kill the worker once 20 frames are done (each then spends 40 ms in it,
    // so a frame is in flight).
    let deadline = Instant::now() + Duration::from_secs(60);
    let pid = loop {
        assert!(Instant::now() < deadline, "the run did not reach frame 20");
        if let Some(s) = status(&run_dir) {
            let done = s["frames_done"].as_u64().unwrap_or(0);
            let pid = child_entry(&s, worker).and_then(|c| c["pid"].as_u64());
            if let (true, Some(pid)) = (done >= 20, pid) {
                break pid as u32;
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    kill9(pid);
    let code = loop {
        if let Some(status) = sup.try_wait().unwrap() {
            break status.code();
        }
        if Instant::now() > deadline {
            let _ = sup.kill();
            let _ = sup.wait();
            for pid in processes_mentioning(&run_id) {
                kill9(pid);
            }
            panic!(
                "the run hangs after the {worker} was given up on:\n{}",
                std::fs::read_to_string(&log).unwrap_or_default()
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let text = std::fs::read_to_string(&log).unwrap();
    assert_eq!(code, Some(3), "a degraded run:\n{text}");
    let rows = read_rows(&run_dir);
    assert_eq!(rows.len(), 60, "every frame recorded");
    let seqs: std::collections::BTreeSet<u64> =
        rows.iter().map(|r| r["seq"].parse().unwrap()).collect();
    assert_eq!(seqs.len(), 60, "each once");
    assert!(rows.iter().all(|r| r["state"] == "ok"));
    let orphaned = rows
        .iter()
        .filter(|r| r["note"].contains(&format!("the {worker} was given up on while")))
        .count();
    eprintln!("{worker}: {orphaned} frame(s) re-routed in flight");
    assert!(orphaned <= 1, "at most the one in-flight frame");
    // The frames after it are routed around the given-up worker.
    let its_route = if worker == "segmenter" {
        "segment"
    } else {
        "propagate"
    };
    let late: Vec<_> = rows
        .iter()
        .filter(|r| r["seq"].parse::<u64>().unwrap() >= 40)
        .collect();
    assert!(late.iter().all(|r| r["route"] != its_route), "{late:?}");
    assert_no_shm_left(&run_id);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_segmenter_given_up_on_with_a_frame_in_flight_does_not_hang_the_run() {
    given_up_worker_with_a_frame_in_flight("segmenter", "[routing]\nsegment_every_frame = true\n");
}

#[test]
fn a_propagator_given_up_on_with_a_frame_in_flight_does_not_hang_the_run() {
    given_up_worker_with_a_frame_in_flight("propagator", "");
}

#[test]
fn a_live_run_cannot_be_resumed_or_its_run_id_reused() {
    let dir = scratch("live-lock");
    let run_id = format!("live{}", std::process::id());
    let run_dir = dir.join("runs").join(&run_id);
    let config = write_config(
        &dir,
        &format!("[services.slam]\nbackend = \"scripted\"\nwork_ms = 30\n{NO_MASK_MODELS}"),
    );
    let tum = shared_tum();
    let (mut sup, log) = start_run(&dir, &config, &run_id, 80);
    let deadline = Instant::now() + Duration::from_secs(60);
    while status(&run_dir)
        .and_then(|s| s["frames_done"].as_u64())
        .unwrap_or(0)
        < 5
    {
        assert!(Instant::now() < deadline, "the run did not start");
        std::thread::sleep(Duration::from_millis(10));
    }
    // Resume of the live run: refused, and it touches nothing of it.
    let resume = Command::new(dynslam())
        .args(["resume", run_dir.to_str().unwrap()])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&resume.stderr);
    assert_eq!(resume.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("in use by a live supervisor"), "{stderr}");
    // The same run id from another output folder: refused before a folder is made.
    let other = dir.join("other");
    let again = Command::new(dynslam())
        .args([
            "run",
            tum.to_str().unwrap(),
            "--config",
            config.to_str().unwrap(),
        ])
        .args(["--output-dir", other.to_str().unwrap(), "--run-id", &run_id])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&again.stderr);
    assert_eq!(again.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("in use by a live supervisor"), "{stderr}");
    assert!(!other.join(&run_id).exists());
    // The live run completes untouched.
    let status_code = loop {
        if let Some(s) = sup.try_wait().unwrap() {
            break s.code();
        }
        assert!(Instant::now() < deadline, "the run did not finish");
        std::thread::sleep(Duration::from_millis(20));
    };
    assert_eq!(
        status_code,
        Some(0),
        "{}",
        std::fs::read_to_string(&log).unwrap_or_default()
    );
    assert_eq!(read_rows(&run_dir).len(), 80);
    assert_no_shm_left(&run_id);
    std::fs::remove_dir_all(&dir).ok();
}

/// A service that hangs (SIGSTOP: alive, holding its frame, answering
/// nothing) in a lockstep run: the watchdog names the stage the frame is
/// stuck in after `supervisor.stall_timeout_s`, kills the hung service,
/// and the run completes with every frame recorded once.
fn a_hung_service_is_named_and_restarted(kind: &str, stage: &str) {
    let dir = scratch(&format!("hang-{kind}"));
    let run_id = format!("hang{}{}", kind.replace('-', ""), std::process::id());
    let run_dir = dir.join("runs").join(&run_id);
    let config = write_config(
        &dir,
        "[services.slam]\nbackend = \"scripted\"\nkeyframe_every = 1000\n\
         [services.segmenter]\nbackend = \"none\"\nwork_ms = 5\n\
         [services.propagator]\nbackend = \"none\"\nwork_ms = 5\n\
         [supervisor]\nstall_timeout_s = 2\n",
    );
    let (mut sup, log) = start_run(&dir, &config, &run_id, 60);
    let deadline = Instant::now() + Duration::from_secs(60);
    let pid = loop {
        assert!(Instant::now() < deadline, "the run did not reach frame 20");
        if let Some(s) = status(&run_dir) {
            let done = s["frames_done"].as_u64().unwrap_or(0);
            let pid = child_entry(&s, kind).and_then(|c| c["pid"].as_u64());
            if let (true, Some(pid)) = (done >= 20, pid) {
                break pid as u32;
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    // SAFETY: plain kill(2) of a pid read from the run's status file.
    unsafe { libc::kill(pid as i32, libc::SIGSTOP) };
    let code = loop {
        if let Some(status) = sup.try_wait().unwrap() {
            break status.code();
        }
        if Instant::now() > deadline {
            let _ = sup.kill();
            let _ = sup.wait();
            for pid in processes_mentioning(&run_id) {
                kill9(pid);
            }
            panic!(
                "the run hangs with the {kind} stopped:\n{}",
                std::fs::read_to_string(&log).unwrap_or_default()
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let text = std::fs::read_to_string(&log).unwrap();
    assert_eq!(code, Some(0), "{text}");
    let line = text
        .lines()
        .find(|l| l.contains("stalled: no frame recorded for 2 s"))
        .unwrap_or_else(|| panic!("no watchdog line:\n{text}"));
    assert!(line.contains(stage), "{line}");
    assert!(
        line.contains(&format!("killing {kind} (pid {pid})")),
        "{line}"
    );
    let rows = read_rows(&run_dir);
    let seqs: Vec<u64> = rows.iter().map(|r| r["seq"].parse().unwrap()).collect();
    assert_eq!(seqs, (0..60).collect::<Vec<u64>>(), "every frame once");
    assert_eq!(status(&run_dir).unwrap()["restarts"], 1);
    assert_no_shm_left(&run_id);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_hung_propagator_is_named_and_restarted() {
    a_hung_service_is_named_and_restarted(
        "propagator",
        "waiting for its masks from the propagator",
    );
}

#[test]
fn a_hung_slam_is_named_and_restarted() {
    a_hung_service_is_named_and_restarted("slam", "waiting for its Track from slam");
}
