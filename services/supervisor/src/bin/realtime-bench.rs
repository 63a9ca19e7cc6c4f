//! `just bench-realtime`: the whole pipeline playing a TUM sequence in real
//! time with the product's models, at 30 fps and at 60 fps (the recorded
//! rate x2), each without and with artificial load (busy processes pinned
//! to the cores), against one lockstep run for the reference ATE.
//!
//! Per condition it prints the tracked rate (tracked frames per second of
//! the stream), dropped %, end-to-end p50/p99, the share of tracked frames
//! that had masks ("masked") and of those whose masks removed features
//! ("removing": empty masks do not), the share tracked by optical flow
//! ("flow", `services.slam.flow_frames`), and the ATE next to the lockstep
//! ATE; every run's figures go to `bench-results/realtime.json`.
//!
//! With `--bridge ENDPOINT` every run is made twice, the ROS 2 bridge off
//! and on (publishing to the Zenoh router at ENDPOINT), the two alternated
//! so that both see the same machine (`just bench-realtime-bridge`).
//!
//! Kill rows (`--slam-kills N`; `just bench-realtime` asks for 5): at 30
//! fps without load, the SLAM process SIGKILLed N times a run, 1.5 s apart,
//! without and with the warm standby (`services.slam.standby`, the two
//! alternated); they print the frames without a pose around each kill, the
//! time from the death (as the supervisor saw it) to the next pose, and the
//! CPU share and RSS of the SLAM and of its standby (sampled before the
//! first kill).
//!
//! `realtime-bench [DATASET] [--runs N] [--load N] [--only 30:0,60:2,30:2:480] [--no-lockstep] [--bridge ENDPOINT] [--slam-kills N] [--out FILE]`

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use clap::Parser;
use pipeline::config::{ClockMode, PipelineConfig};
use run_folder::outputs::{FrameLog, FrameRow};
use run_folder::run_dir;
use serde::Serialize;
use supervisor::run::execute;

#[derive(Debug, Parser)]
#[command(about = "Real-time pipeline: tracked fps, drops, latency and ATE, with and without load")]
struct Args {
    #[arg(default_value_os_t = pipeline::provision::shared_tum())]
    dataset: PathBuf,
    /// Runs per condition (the figures are their median, the worst is shown too).
    #[arg(long, default_value_t = 3)]
    runs: usize,
    /// Busy processes of the loaded conditions (one pinned per core, round robin).
    #[arg(long, default_value_t = 2)]
    load: usize,
    /// Where run folders go.
    #[arg(long, default_value = "target/bench-runs")]
    output_dir: PathBuf,
    #[arg(long, default_value = "bench-results/realtime.json")]
    out: PathBuf,
    /// Pipeline configuration the runs start from (default: the built-in
    /// defaults, i.e. the shipped configs/pipeline.toml); the bench sets
    /// the source, mode and fps on top.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Conditions to run, as FPS:BUSY or FPS:BUSY:SEGMENTER_PX (e.g.
    /// `30:0,60:2,30:2:480`; without PX the segmenter runs at real time's
    /// default input size); default: 30 and 60 fps, each without load and
    /// with `--load` busy processes, and 30 fps with `--load` busy
    /// processes and the segmenter at 480 px.
    #[arg(long, value_delimiter = ',', value_parser = parse_condition)]
    only: Vec<Condition>,
    /// Skip the lockstep reference run (no lockstep ATE in the table).
    #[arg(long)]
    no_lockstep: bool,
    /// Each run also with the ROS 2 bridge on, connected to the Zenoh
    /// router at this endpoint (`tcp/127.0.0.1:7447`), alternated with the
    /// bridge off.
    #[arg(long)]
    bridge: Option<String>,
    /// SLAM kills per run of the kill row (30 fps, no load); 0: no kill row.
    #[arg(long, default_value_t = 0)]
    slam_kills: usize,
    /// Internal: be a busy process pinned to this core (the load).
    #[arg(long, hide = true)]
    burn: Option<usize>,
}

/// What a run is played at: input rate, busy processes beside it, and the
/// segmenter's input size when not the mode's default.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Condition {
    fps: u32,
    busy: usize,
    segmenter_px: Option<u32>,
}

/// One real-time run's figures.
#[derive(Debug, Clone, Serialize)]
struct RunFigures {
    fps_in: f64,
    busy_processes: usize,
    /// The segmenter's input size when the condition set one (else the
    /// mode's default).
    segmenter_px: Option<u32>,
    /// The ROS 2 bridge ran (`--bridge`).
    bridge: bool,
    frames: usize,
    tracked: usize,
    /// Tracked frames per second of stream time.
    tracked_fps: f64,
    dropped_pct: f64,
    /// Share of tracked frames that had masks (segmenter or propagator).
    masked_share: f64,
    /// Share of tracked frames whose masks removed at least one feature:
    /// masks that were there but empty (a propagator that lost every
    /// object) count in `masked_share`, not here.
    masks_removed_features_share: f64,
    /// Share of tracked frames tracked by optical flow, without ORB
    /// extraction (`services.slam.flow_frames`; 0 when off).
    by_flow_share: f64,
    /// Keyframes the run made: in real time a keyframe waits for its
    /// frame's segmenter masks, and under load the segmenter's pace caps
    /// them (docs/measurements.md, "What real time adds, separated").
    keyframes: usize,
    end_to_end_p50_ms: Option<f64>,
    end_to_end_p99_ms: Option<f64>,
    ate_rmse_m: Option<f64>,
    /// The SLAM kills of the run (the kill row).
    slam_kills: usize,
    /// Per SLAM death: frames without a pose around it.
    frames_without_pose: Vec<u64>,
    /// Per SLAM death: from the death seen to the next pose, ms.
    death_to_pose_ms: Vec<f64>,
    /// The run had the warm standby SLAM.
    standby: bool,
    /// Before the first kill: the active SLAM's and the standby's CPU
    /// share of one core over their lives, and RSS (MB).
    slam_cost: Option<ProcessCost>,
    standby_cost: Option<ProcessCost>,
    run_dir: PathBuf,
}

/// A process's CPU share of one core since it started, and its RSS.
#[derive(Debug, Clone, Copy, Serialize)]
struct ProcessCost {
    cpu_pct: f64,
    rss_mb: f64,
}

impl ProcessCost {
    /// From /proc (None: the process is gone).
    fn of(pid: u32) -> Option<Self> {
        let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
        // The fields after the command name: state is field 3, utime 14,
        // stime 15, starttime 22.
        let rest: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
        let field = |n: usize| rest.get(n - 3)?.parse::<f64>().ok();
        // SAFETY: sysconf has no preconditions.
        let tick = unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64;
        let uptime: f64 = std::fs::read_to_string("/proc/uptime")
            .ok()?
            .split_whitespace()
            .next()?
            .parse()
            .ok()?;
        let alive_s = uptime - field(22)? / tick;
        let cpu_s = (field(14)? + field(15)?) / tick;
        let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
        let rss_kb: f64 = status
            .lines()
            .find_map(|l| l.strip_prefix("VmRSS:"))?
            .trim()
            .trim_end_matches("kB")
            .trim()
            .parse()
            .ok()?;
        Some(Self {
            cpu_pct: 100.0 * cpu_s / alive_s.max(1e-3),
            rss_mb: rss_kb / 1024.0,
        })
    }
}

#[derive(Debug, Serialize)]
struct Results {
    dataset: PathBuf,
    lockstep_ate_rmse_m: Option<f64>,
    lockstep_keyframes: Option<usize>,
    runs: Vec<RunFigures>,
}

fn main() -> Result<()> {
    let args = Args::parse();
    if let Some(core) = args.burn {
        burn(core);
    }
    pipeline::runtime::init_logging();
    if !args.dataset.join("rgb.txt").is_file() {
        bail!(
            "{}: not a TUM RGB-D folder (no rgb.txt)",
            args.dataset.display()
        );
    }
    let dataset = args
        .dataset
        .canonicalize()
        .with_context(|| args.dataset.display().to_string())?;
    let base = PipelineConfig::load_or_default(args.config.as_deref())?;
    let batch = run_dir::new_run_id();
    let lockstep = if args.no_lockstep {
        None
    } else {
        let lockstep = run_once(
            &base,
            &dataset,
            &args.output_dir,
            &format!("rtb-{batch}-lockstep"),
            |c| c.run.mode = ClockMode::Lockstep,
            0,
        )?;
        eprintln!(
            "lockstep: {}/{} tracked, {} keyframes, ATE {}",
            lockstep.tracked,
            lockstep.frames,
            lockstep.keyframes,
            fmt_m(lockstep.ate_rmse_m)
        );
        Some(lockstep)
    };
    let lockstep_ate = lockstep.as_ref().and_then(|l| l.ate_rmse_m);
    let lockstep_keyframes = lockstep.as_ref().map(|l| l.keyframes);
    let conditions = if args.only.is_empty() {
        let at = |fps, busy, segmenter_px| Condition {
            fps,
            busy,
            segmenter_px,
        };
        vec![
            at(30, 0, None),
            at(30, args.load, None),
            at(60, 0, None),
            at(60, args.load, None),
            // The larger segmenter input with the motion check (on by
            // default) on a loaded machine: what the CPU has to spare.
            at(30, args.load, Some(480)),
        ]
    } else {
        args.only.clone()
    };
    let mut runs = Vec::new();
    // The recorded sequence is 30 fps: other rates play it faster or slower.
    for &Condition {
        fps: fps_in,
        busy: load,
        segmenter_px,
    } in &conditions
    {
        let (fps, speed) = (f64::from(fps_in), f64::from(fps_in) / 30.0);
        let px_tag = segmenter_px.map_or(String::new(), |px| format!("-{px}"));
        for i in 0..args.runs {
            // Bridge off and on alternate which goes first.
            let arms = match (&args.bridge, i % 2) {
                (None, _) => vec![None],
                (Some(e), 0) => vec![None, Some(e.clone())],
                (Some(e), _) => vec![Some(e.clone()), None],
            };
            for bridge in arms {
                let burners = start_load(load)?;
                let on = bridge.is_some();
                let id = format!(
                    // Run ids are at most 32 characters.
                    "rtb-{batch}-{fps}fps-l{load}{px_tag}-{i}{}",
                    if on { "-br" } else { "" }
                );
                let result = run_once(
                    &base,
                    &dataset,
                    &args.output_dir,
                    &id,
                    |c| {
                        c.run.mode = ClockMode::Realtime;
                        c.run.speed = speed;
                        if segmenter_px.is_some() {
                            c.services.segmenter.input_size = segmenter_px;
                        }
                        if let Some(endpoint) = bridge {
                            c.bridge.enabled = true;
                            c.bridge.connect = vec![endpoint];
                        }
                    },
                    0,
                );
                stop_load(burners);
                let mut f = result?;
                f.fps_in = fps;
                f.busy_processes = load;
                f.segmenter_px = segmenter_px;
                f.bridge = on;
                eprintln!(
                    "{fps} fps, {load} busy{}{}: {:.1} tracked fps, {:.1} % dropped, e2e p99 {}, ATE {}",
                    segmenter_px.map_or(String::new(), |px| format!(", segmenter {px} px")),
                    if on { ", bridge on" } else { "" },
                    f.tracked_fps,
                    f.dropped_pct,
                    fmt_ms(f.end_to_end_p99_ms),
                    fmt_m(f.ate_rmse_m)
                );
                runs.push(f);
            }
        }
    }
    let mut kill_runs = Vec::new();
    let kill_row_runs = if args.slam_kills > 0 { args.runs } else { 0 };
    for i in 0..kill_row_runs {
        // Standby off and on alternate which goes first.
        let arms = if i % 2 == 0 {
            [false, true]
        } else {
            [true, false]
        };
        for standby in arms {
            let id = format!("rtb-{batch}-kills{i}{}", if standby { "-sb" } else { "" });
            let kills = args.slam_kills;
            let f = run_once(
                &base,
                &dataset,
                &args.output_dir,
                &id,
                |c| {
                    c.run.mode = ClockMode::Realtime;
                    c.run.speed = 1.0;
                    c.services.slam.standby = Some(standby);
                },
                kills,
            )?;
            eprintln!(
                "30 fps, {kills} SLAM kills, standby {}: frames without a pose per kill {:?}, death to next pose {:?} ms, ATE {}",
                if standby { "on" } else { "off" },
                f.frames_without_pose,
                f.death_to_pose_ms
                    .iter()
                    .map(|m| m.round() as i64)
                    .collect::<Vec<_>>(),
                fmt_m(f.ate_rmse_m)
            );
            kill_runs.push(f);
        }
    }
    println!(
        "real time on {} ({} runs per condition; figures: median, worst run in brackets)",
        dataset.display(),
        args.runs
    );
    println!(
        "{:>6} {:>5} {:>6} {:>6} {:>18} {:>9} {:>10} {:>10} {:>8} {:>9} {:>6} {:>14} {:>22}",
        "fps in",
        "busy",
        "seg px",
        "bridge",
        "tracked fps",
        "dropped",
        "e2e p50",
        "e2e p99",
        "masked",
        "removing",
        "flow",
        "kf (lockstep)",
        "ATE (lockstep)"
    );
    let arms: &[bool] = if args.bridge.is_some() {
        &[false, true]
    } else {
        &[false]
    };
    for (condition, &bridge) in conditions
        .iter()
        .flat_map(|c| arms.iter().map(move |b| (c, b)))
    {
        let (fps, load) = (f64::from(condition.fps), condition.busy);
        let group: Vec<&RunFigures> = runs
            .iter()
            .filter(|r| {
                r.fps_in == fps
                    && r.busy_processes == load
                    && r.segmenter_px == condition.segmenter_px
                    && r.bridge == bridge
            })
            .collect();
        let med = |f: &dyn Fn(&RunFigures) -> Option<f64>| {
            let mut v: Vec<f64> = group.iter().filter_map(|r| f(r)).collect();
            v.sort_by(f64::total_cmp);
            (!v.is_empty()).then(|| v[v.len() / 2])
        };
        let worst_fps = group
            .iter()
            .map(|r| r.tracked_fps)
            .fold(f64::INFINITY, f64::min);
        println!(
            "{:>6} {:>5} {:>6} {:>6} {:>10.1} ({:>5.1}) {:>8.1}% {:>10} {:>10} {:>7.0}% {:>8.0}% {:>5.0}% {:>6.0} ({:>5}) {:>10} ({})",
            fps,
            load,
            condition
                .segmenter_px
                .map_or("-".to_string(), |px| px.to_string()),
            if bridge { "on" } else { "off" },
            med(&|r| Some(r.tracked_fps)).unwrap_or(0.0),
            worst_fps,
            med(&|r| Some(r.dropped_pct)).unwrap_or(0.0),
            fmt_ms(med(&|r| r.end_to_end_p50_ms)),
            fmt_ms(med(&|r| r.end_to_end_p99_ms)),
            100.0 * med(&|r| Some(r.masked_share)).unwrap_or(0.0),
            100.0 * med(&|r| Some(r.masks_removed_features_share)).unwrap_or(0.0),
            100.0 * med(&|r| Some(r.by_flow_share)).unwrap_or(0.0),
            med(&|r| Some(r.keyframes as f64)).unwrap_or(0.0),
            lockstep_keyframes.map_or("-".to_string(), |k| k.to_string()),
            fmt_m(med(&|r| r.ate_rmse_m)),
            fmt_m(lockstep_ate)
        );
    }
    for standby in [false, true] {
        let arm: Vec<RunFigures> = kill_runs
            .iter()
            .filter(|r| r.standby == standby)
            .cloned()
            .collect();
        if !arm.is_empty() {
            print_kill_row(&arm);
        }
    }
    runs.extend(kill_runs);
    if let Some(parent) = args.out.parent() {
        std::fs::create_dir_all(parent)?;
    }
    let results = Results {
        dataset,
        lockstep_ate_rmse_m: lockstep_ate,
        lockstep_keyframes,
        runs,
    };
    std::fs::write(&args.out, serde_json::to_string_pretty(&results)?)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    println!("figures: {}", args.out.display());
    Ok(())
}

/// One pipeline run on `dataset` with the `base` configuration changed by
/// `apply`, its SLAM killed `slam_kills` times; its figures from the run
/// folder.
fn run_once(
    base: &PipelineConfig,
    dataset: &Path,
    output_dir: &Path,
    id: &str,
    apply: impl FnOnce(&mut PipelineConfig),
    slam_kills: usize,
) -> Result<RunFigures> {
    let mut cfg = base.clone();
    cfg.source.path = dataset.to_path_buf();
    apply(&mut cfg);
    let dir = run_dir::create(output_dir, id, &cfg, "config (realtime-bench)")?;
    let done = Arc::new(AtomicBool::new(false));
    let killer = (slam_kills > 0).then(|| {
        let (dir, done) = (dir.clone(), done.clone());
        std::thread::spawn(move || kill_slam(&dir, slam_kills, &done))
    });
    let summary = execute(&dir).with_context(|| format!("run {}", dir.display()));
    done.store(true, Ordering::Relaxed);
    let kills = killer.and_then(|k| k.join().ok()).unwrap_or_default();
    let killed = kills.killed;
    let summary = summary?;
    let (_, rows) = FrameLog::open(&dir)?;
    let outages = run_folder::outages::slam_outages(&dir, &rows);
    let report = summary.report.as_ref();
    let stage = |name: &str, p99: bool| {
        report.and_then(|r| {
            r.latency
                .iter()
                .find(|s| s.stage == name && s.count > 0)
                .map(|s| if p99 { s.p99_ms } else { s.p50_ms })
        })
    };
    let mut f = figures(&rows, cfg.run.speed, dir.clone());
    f.end_to_end_p50_ms = stage("end_to_end", false);
    f.end_to_end_p99_ms = stage("end_to_end", true);
    f.ate_rmse_m = report.and_then(|r| r.eval.as_ref()).map(|e| e.ate_rmse_m);
    f.slam_kills = killed;
    f.standby = cfg.services.slam.has_standby(cfg.run.mode);
    f.slam_cost = kills.slam_cost;
    f.standby_cost = kills.standby_cost;
    f.frames_without_pose = outages
        .iter()
        .filter_map(|o| o.frames_without_pose)
        .collect();
    f.death_to_pose_ms = outages.iter().filter_map(|o| o.death_to_pose_ms).collect();
    if killed < slam_kills {
        eprintln!("{id}: only {killed} of {slam_kills} SLAM kills happened before the run ended");
    }
    Ok(f)
}

/// What [`kill_slam`] did and saw.
#[derive(Debug, Default)]
struct Kills {
    killed: usize,
    /// The SLAM's and the standby's cost just before the first kill.
    slam_cost: Option<ProcessCost>,
    standby_cost: Option<ProcessCost>,
}

/// SIGKILLs the run's SLAM process `n` times, 1.5 s apart, the first once
/// 40 frames are recorded (each time the process is ready and not one
/// already killed), until `done`.
fn kill_slam(dir: &Path, n: usize, done: &AtomicBool) -> Kills {
    let mut kills = Kills::default();
    let mut killed: Vec<u32> = Vec::new();
    let rows = || std::fs::read_to_string(dir.join("frames.csv")).map_or(0, |t| t.lines().count());
    let ready = |service: &str| {
        run_dir::read_status(dir).and_then(|s| {
            s.children
                .into_iter()
                .find(|c| c.service == service && c.state == "ready")
                .and_then(|c| c.pid)
        })
    };
    while !done.load(Ordering::Relaxed) && killed.len() < n {
        match ready("slam") {
            Some(pid) if rows() > 40 && !killed.contains(&pid) => {
                if killed.is_empty() {
                    kills.slam_cost = ProcessCost::of(pid);
                    kills.standby_cost = ready("slam-standby").and_then(ProcessCost::of);
                }
                // SAFETY: kill(2) of the run's SLAM pid from its status file.
                unsafe { libc::kill(pid as i32, libc::SIGKILL) };
                killed.push(pid);
                std::thread::sleep(Duration::from_millis(1500));
            }
            _ => std::thread::sleep(Duration::from_millis(10)),
        }
    }
    kills.killed = killed.len();
    kills
}

/// The kill row: frames without a pose per SLAM kill and the time from each
/// death to the next pose, over every kill of every run.
fn print_kill_row(runs: &[RunFigures]) {
    let mut frames: Vec<f64> = runs
        .iter()
        .flat_map(|r| r.frames_without_pose.iter().map(|&n| n as f64))
        .collect();
    let mut ms: Vec<f64> = runs
        .iter()
        .flat_map(|r| r.death_to_pose_ms.clone())
        .collect();
    let kills: usize = runs.iter().map(|r| r.slam_kills).sum();
    let spread = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        match (v.first(), v.get(v.len() / 2), v.last()) {
            (Some(lo), Some(med), Some(hi)) => format!("{med:.0} ({lo:.0}-{hi:.0})"),
            _ => "-".into(),
        }
    };
    let mut ate: Vec<f64> = runs.iter().filter_map(|r| r.ate_rmse_m).collect();
    ate.sort_by(f64::total_cmp);
    let cost = |pick: &dyn Fn(&RunFigures) -> Option<ProcessCost>| {
        let mut cpu: Vec<f64> = runs.iter().filter_map(pick).map(|c| c.cpu_pct).collect();
        let mut rss: Vec<f64> = runs.iter().filter_map(pick).map(|c| c.rss_mb).collect();
        format!("CPU {} %, RSS {} MB", spread(&mut cpu), spread(&mut rss))
    };
    let standby = runs.iter().any(|r| r.standby);
    println!(
        "SLAM kills at 30 fps, standby {}: {kills} kills in {} runs; frames without a pose per kill {}; death to next pose {} ms; ATE {}; SLAM {}{}",
        if standby { "on" } else { "off" },
        runs.len(),
        spread(&mut frames),
        spread(&mut ms),
        fmt_m(ate.get(ate.len() / 2).copied()),
        cost(&|r| r.slam_cost),
        if standby {
            format!(", standby {}", cost(&|r| r.standby_cost))
        } else {
            String::new()
        }
    );
}

/// Rates from a run's frame rows; the stream lasts from its first to its
/// last frame's timestamp, played `speed` times as fast.
fn figures(rows: &[FrameRow], speed: f64, run_dir: PathBuf) -> RunFigures {
    let tracked: Vec<&FrameRow> = rows.iter().filter(|r| r.is_tracked()).collect();
    // A frame the supervisor never saw (a queue overflowed at camera rate)
    // is recorded without a timestamp (0).
    let stamps = || rows.iter().map(|r| r.timestamp).filter(|&t| t > 0.0);
    let (first, last) = (
        stamps().fold(f64::INFINITY, f64::min),
        stamps().fold(f64::NEG_INFINITY, f64::max),
    );
    let seconds = ((last - first) / speed).max(1e-9);
    let dropped = rows.iter().filter(|r| r.state == "dropped").count();
    let masked = tracked.iter().filter(|r| r.mask_source != "none").count();
    let removing = tracked.iter().filter(|r| r.features_masked > 0).count();
    RunFigures {
        fps_in: 0.0,
        busy_processes: 0,
        segmenter_px: None,
        bridge: false,
        frames: rows.len(),
        tracked: tracked.len(),
        tracked_fps: tracked.len() as f64 / seconds,
        dropped_pct: 100.0 * dropped as f64 / rows.len().max(1) as f64,
        masked_share: masked as f64 / tracked.len().max(1) as f64,
        masks_removed_features_share: removing as f64 / tracked.len().max(1) as f64,
        by_flow_share: tracked.iter().filter(|r| r.tracked_by_flow).count() as f64
            / tracked.len().max(1) as f64,
        keyframes: tracked.iter().filter(|r| r.keyframe).count(),
        end_to_end_p50_ms: None,
        end_to_end_p99_ms: None,
        ate_rmse_m: None,
        slam_kills: 0,
        frames_without_pose: Vec::new(),
        death_to_pose_ms: Vec::new(),
        standby: false,
        slam_cost: None,
        standby_cost: None,
        run_dir,
    }
}

/// `n` busy processes (this binary with `--burn CORE`), one per core in
/// turn, so that the pipeline competes for every core as on a loaded robot
/// computer.
fn start_load(n: usize) -> Result<Vec<Child>> {
    let exe = std::env::current_exe().context("cannot find this binary to start the load")?;
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut children = Vec::new();
    for i in 0..n {
        let child = Command::new(&exe)
            .args(["--burn", &(i % cores).to_string()])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .context("cannot start a busy process")?;
        children.push(child);
    }
    // Let them get going before the pipeline starts.
    std::thread::sleep(Duration::from_millis(200));
    Ok(children)
}

fn stop_load(children: Vec<Child>) {
    for mut c in children {
        let _ = c.kill();
        let _ = c.wait();
    }
}

/// A busy loop pinned to `core`; dies with the bench (never returns).
fn burn(core: usize) -> ! {
    // SAFETY: plain syscalls on this process; a zeroed cpu_set_t is a
    // valid empty set and CPU_SET writes inside it.
    unsafe {
        libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL);
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(core, &mut set);
        libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set);
    }
    let mut x = 0u64;
    loop {
        x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
    }
}

/// `FPS:BUSY[:SEGMENTER_PX]` of `--only`.
fn parse_condition(s: &str) -> Result<Condition, String> {
    let (fps, rest) = s.split_once(':').ok_or_else(|| {
        format!("'{s}': expected FPS:BUSY or FPS:BUSY:PX, e.g. 30:0, 60:2 or 30:2:480")
    })?;
    let (busy, px) = match rest.split_once(':') {
        Some((busy, px)) => (busy, Some(px)),
        None => (rest, None),
    };
    let segmenter_px = px
        .map(|px| {
            px.trim()
                .parse::<u32>()
                .ok()
                .filter(|&p| (32..=4096).contains(&p) && p % 32 == 0)
                .ok_or_else(|| {
                    format!("'{s}': the segmenter input size '{px}' is not a multiple of 32 in 32..=4096")
                })
        })
        .transpose()?;
    let fps: u32 =
        fps.trim().parse().ok().filter(|&f| f > 0).ok_or_else(|| {
            format!("'{s}': the frame rate '{fps}' is not a positive whole number")
        })?;
    let busy: usize = busy
        .trim()
        .parse()
        .map_err(|_| format!("'{s}': the busy process count '{busy}' is not a whole number"))?;
    Ok(Condition {
        fps,
        busy,
        segmenter_px,
    })
}

fn fmt_m(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.4} m"))
}

fn fmt_ms(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.0} ms"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conditions_parse_with_and_without_a_segmenter_size_and_bad_ones_are_named() {
        let c = |fps, busy, segmenter_px| Condition {
            fps,
            busy,
            segmenter_px,
        };
        assert_eq!(parse_condition("30:2"), Ok(c(30, 2, None)));
        assert_eq!(parse_condition(" 60 : 0 "), Ok(c(60, 0, None)));
        assert_eq!(parse_condition("30:2:480"), Ok(c(30, 2, Some(480))));
        for (bad, says) in [
            ("30", "expected FPS:BUSY"),
            ("0:2", "frame rate '0'"),
            ("30:x", "busy process count 'x'"),
            ("30:2:500", "input size '500'"),
            ("30:2:", "input size ''"),
        ] {
            let e = parse_condition(bad).unwrap_err();
            assert!(e.contains(says), "{bad}: {e}");
        }
    }
}
