//! `just soak MINUTES`: the whole pipeline (product config, real time) on a
//! TUM sequence played over and over (`source.repeat`) for MINUTES, as a
//! separate `dynslam run` process, the way a robot runs it. Every minute it
//! prints the resident memory (RSS) of every process of the run and the
//! SLAM map's size; at the end it interrupts the run (SIGINT, as an
//! operator would), writes `bench-results/soak.json`, and fails when a
//! process other than the SLAM grew by more than `--grow-limit-mb` after
//! its first minute (the SLAM's map is reported, its growth is the map's).
//!
//! `soak [DATASET] [--minutes M] [--grow-limit-mb MB] [--out FILE]`

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use clap::Parser;
use pipeline::config::{ClockMode, PipelineConfig};
use run_folder::run_dir::{self, Status};
use serde::Serialize;

#[derive(Debug, Parser)]
#[command(about = "Real-time soak: RSS per process per minute and the SLAM map's size")]
struct Args {
    #[arg(default_value_os_t = pipeline::provision::shared_tum())]
    dataset: PathBuf,
    /// How long the pipeline runs.
    #[arg(long, default_value_t = 10.0)]
    minutes: f64,
    /// Largest growth (MB) of a non-SLAM process after its first minute.
    #[arg(long, default_value_t = 10.0)]
    grow_limit_mb: f64,
    /// Seconds between memory samples.
    #[arg(long, default_value_t = 5.0)]
    sample_s: f64,
    /// Where the run folder goes.
    #[arg(long, default_value = "target/bench-runs")]
    output_dir: PathBuf,
    #[arg(long, default_value = "bench-results/soak.json")]
    out: PathBuf,
}

/// The processes of a run, in the order of the table.
const PROCESSES: [&str; 5] = [
    "supervisor",
    "camera-reader",
    "segmenter",
    "propagator",
    "slam",
];

/// One sample of the run.
#[derive(Debug, Clone, Serialize)]
struct Sample {
    t_s: f64,
    /// RSS in MB per process of [`PROCESSES`] (None: not running then).
    rss_mb: Vec<Option<f64>>,
    pids: Vec<Option<u32>>,
    frames_done: u64,
    /// The map's figures are filled in on the first sample of each minute.
    minute_row: bool,
    tracked: u64,
    keyframes: u64,
    map_points: u64,
}

#[derive(Debug, Serialize)]
struct Growth {
    process: String,
    /// RSS at the end of the first minute and the most after it (MB).
    after_first_minute_mb: f64,
    max_after_mb: f64,
    grew_mb: f64,
    restarted: bool,
}

#[derive(Debug, Serialize)]
struct Results {
    dataset: PathBuf,
    minutes: f64,
    grow_limit_mb: f64,
    run_dir: PathBuf,
    samples: Vec<Sample>,
    growth: Vec<Growth>,
    keyframes_per_minute: Vec<u64>,
    passed: bool,
}

fn main() -> Result<()> {
    let args = Args::parse();
    pipeline::runtime::init_logging();
    if !(args.minutes > 0.0 && args.minutes <= 24.0 * 60.0) {
        bail!(
            "--minutes {}: not a soak length (0 < M <= 1440)",
            args.minutes
        );
    }
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

    // Enough passes over the sequence to outlast the soak.
    let mut cfg = PipelineConfig::default();
    cfg.source.path = dataset.clone();
    cfg.run.mode = ClockMode::Realtime;
    let frames = cfg
        .source
        .recorded_frames()
        .with_context(|| format!("cannot list {}", dataset.display()))?;
    let span = frames.last().map_or(0.0, |l| l.timestamp) - frames[0].timestamp;
    cfg.source.repeat = ((args.minutes * 60.0 / span.max(1.0)).ceil() as u32 + 1).max(2);
    std::fs::create_dir_all(&args.output_dir)
        .with_context(|| format!("cannot create {}", args.output_dir.display()))?;
    let id = format!("soak-{}", run_dir::new_run_id());
    let config_path = args.output_dir.join(format!("{id}.toml"));
    std::fs::write(&config_path, cfg.to_toml()?)
        .with_context(|| format!("cannot write {}", config_path.display()))?;
    let dynslam = std::env::current_exe()?.with_file_name("dynslam");
    eprintln!(
        "soak: {} min of real time on {} ({} passes of {} frames), run {id}, log {}",
        args.minutes,
        dataset.display(),
        cfg.source.repeat,
        frames.len(),
        args.output_dir.join(format!("{id}.log")).display()
    );
    let log_path = args.output_dir.join(format!("{id}.log"));
    let log = std::fs::File::create(&log_path)
        .with_context(|| format!("cannot create {}", log_path.display()))?;
    let mut child = Command::new(&dynslam)
        .arg("run")
        .arg(&dataset)
        .arg("--config")
        .arg(&config_path)
        .arg("--output-dir")
        .arg(&args.output_dir)
        .args(["--run-id", &id])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .with_context(|| format!("cannot start {}", dynslam.display()))?;
    let run_dir = args.output_dir.join(&id);

    println!(
        "{:>6} {:>10} {:>13} {:>9} {:>10} {:>8} {:>8} {:>8} {:>9} {:>10}",
        "minute",
        "supervisor",
        "camera-reader",
        "segmenter",
        "propagator",
        "slam",
        "frames",
        "tracked",
        "keyframes",
        "map points"
    );
    let started = Instant::now();
    let length = Duration::from_secs_f64(args.minutes * 60.0);
    let mut samples: Vec<Sample> = Vec::new();
    let mut next_row = 1u64;
    while started.elapsed() < length {
        std::thread::sleep(Duration::from_secs_f64(args.sample_s));
        if let Some(status) = child.try_wait()? {
            bail!(
                "the run ended early ({status}) after {:.0} s; see {}",
                started.elapsed().as_secs_f64(),
                run_dir.display()
            );
        }
        let Some(mut sample) = sample(&run_dir, started.elapsed().as_secs_f64()) else {
            continue;
        };
        if sample.t_s >= next_row as f64 * 60.0 {
            // The map's size once a minute (it reads frames.csv).
            (sample.tracked, sample.keyframes, sample.map_points) = map_size(&run_dir);
            sample.minute_row = true;
            print_row(next_row, &sample);
            next_row += 1;
        }
        samples.push(sample);
    }
    // Stop it as an operator does; the outputs of the frames so far are written.
    // SAFETY: plain kill(2) of the child this process started.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let status = child.wait()?;
    if status.code() != Some(130) && !status.success() {
        bail!(
            "the run did not stop cleanly ({status}); see {}",
            run_dir.display()
        );
    }

    let growth = growth(&samples);
    let keyframes_per_minute = per_minute(&samples, |s| s.keyframes);
    println!("keyframes added per minute: {keyframes_per_minute:?}");
    let mut passed = true;
    for g in &growth {
        let over = g.grew_mb > args.grow_limit_mb;
        passed &= !over;
        println!(
            "{:<14} {:>7.1} MB after minute 1, at most {:>7.1} MB after it: {:+.1} MB{}{}",
            g.process,
            g.after_first_minute_mb,
            g.max_after_mb,
            g.grew_mb,
            if g.restarted { " (restarted)" } else { "" },
            if over { "  OVER THE LIMIT" } else { "" }
        );
    }
    if let Some(parent) = args.out.parent() {
        std::fs::create_dir_all(parent)?;
    }
    let results = Results {
        dataset,
        minutes: args.minutes,
        grow_limit_mb: args.grow_limit_mb,
        run_dir,
        samples,
        growth,
        keyframes_per_minute,
        passed,
    };
    std::fs::write(&args.out, serde_json::to_string_pretty(&results)?)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    println!("figures: {}", args.out.display());
    if !passed {
        bail!(
            "a process other than the SLAM grew by more than {} MB after its first minute",
            args.grow_limit_mb
        );
    }
    Ok(())
}

/// RSS of every process of the run and the map's size, now.
fn sample(run_dir: &Path, t_s: f64) -> Option<Sample> {
    let text = std::fs::read_to_string(run_dir.join(run_dir::STATUS_FILE)).ok()?;
    let status: Status = serde_json::from_str(&text).ok()?;
    let pids: Vec<Option<u32>> = PROCESSES
        .iter()
        .map(|&p| {
            if p == "supervisor" {
                Some(status.supervisor_pid)
            } else {
                status
                    .children
                    .iter()
                    .find(|c| c.service == p)
                    .and_then(|c| c.pid)
            }
        })
        .collect();
    Some(Sample {
        t_s,
        rss_mb: pids.iter().map(|p| p.and_then(rss_mb)).collect(),
        pids,
        frames_done: status.frames_done,
        minute_row: false,
        tracked: 0,
        keyframes: 0,
        map_points: 0,
    })
}

/// Resident set size of `pid` (MB), from /proc.
fn rss_mb(pid: u32) -> Option<f64> {
    let text = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = text.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// Tracked frames so far, and the keyframes and map points of the newest
/// tracked frame (from the tail of `frames.csv`).
fn map_size(run_dir: &Path) -> (u64, u64, u64) {
    let Ok(rows) = run_folder::outputs::read_rows(run_dir) else {
        return (0, 0, 0);
    };
    let tracked = rows.iter().filter(|r| r.is_tracked()).count() as u64;
    rows.iter()
        .rev()
        .find(|r| r.is_tracked())
        .map_or((tracked, 0, 0), |r| {
            (tracked, r.keyframes as u64, r.map_points as u64)
        })
}

fn print_row(minute: u64, s: &Sample) {
    let mb = |i: usize| s.rss_mb[i].map_or("-".to_string(), |v| format!("{v:.1} MB"));
    println!(
        "{:>6} {:>10} {:>13} {:>9} {:>10} {:>8} {:>8} {:>8} {:>9} {:>10}",
        minute,
        mb(0),
        mb(1),
        mb(2),
        mb(3),
        mb(4),
        s.frames_done,
        s.tracked,
        s.keyframes,
        s.map_points
    );
}

/// Growth of each non-SLAM process from the end of its first minute.
fn growth(samples: &[Sample]) -> Vec<Growth> {
    let mut out = Vec::new();
    for (i, &process) in PROCESSES.iter().enumerate() {
        if process == "slam" {
            continue;
        }
        let after: Vec<&Sample> = samples.iter().filter(|s| s.t_s >= 60.0).collect();
        let Some(base) = after.iter().find_map(|s| s.rss_mb[i]) else {
            continue;
        };
        let max = after
            .iter()
            .filter_map(|s| s.rss_mb[i])
            .fold(base, f64::max);
        let mut pids: Vec<u32> = after.iter().filter_map(|s| s.pids[i]).collect();
        pids.dedup();
        out.push(Growth {
            process: process.to_string(),
            after_first_minute_mb: base,
            max_after_mb: max,
            grew_mb: max - base,
            restarted: pids.len() > 1,
        });
    }
    out
}

/// How much `value` rose in each whole minute of the samples.
fn per_minute(samples: &[Sample], value: impl Fn(&Sample) -> u64) -> Vec<u64> {
    let mut out = Vec::new();
    let mut last = 0u64;
    for s in samples.iter().filter(|s| s.minute_row) {
        out.push(value(s).saturating_sub(last));
        last = value(s);
    }
    out
}
