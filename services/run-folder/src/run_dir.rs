//! The run folder: everything a run writes, and what a resumed supervisor
//! needs to continue it (the resolved config, the run id, the status file).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use pipeline_config::PipelineConfig;
use serde::{Deserialize, Serialize};

/// The resolved configuration the run uses (a resume reads it back).
pub const CONFIG_FILE: &str = "config.toml";
/// The run's identity ([`RunInfo`]).
pub const RUN_FILE: &str = "run.json";
/// Live state for people and tests ([`Status`]).
pub const STATUS_FILE: &str = "status.json";
/// One line per service restart.
pub const RESTARTS_FILE: &str = "restarts.log";
/// One line per `dynslam resume` of the run: `next_seq N`.
pub const RESUMES_FILE: &str = "resumes.log";
/// One line per start of the SLAM service after the first frame.
pub const SLAM_STARTS_FILE: &str = "slam-starts.log";
/// The SLAM service writes its map here (in the run folder) when stopped.
pub const MAP_FILE: &str = "map.ply";
/// Loop closures, one row each (written by the SLAM service as they happen).
pub const LOOPS_FILE: &str = "loops.csv";
/// The SLAM's trajectory with its loop corrections applied (written at
/// stop when a loop closed; `trajectory.txt` has the poses as published).
pub const CORRECTED_TRAJECTORY_FILE: &str = "trajectory_loop_corrected.txt";

/// Identity of a run, written once at its start.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct RunInfo {
    /// Names the run's shared-memory services.
    pub run_id: String,
    /// The input (dataset folder, camera, or the rendered default scene).
    pub dataset: PathBuf,
    /// When the run was created (Unix time, seconds).
    pub created_unix_s: u64,
    /// The camera the run uses and why ("tum-fr2: dataset folder name ...").
    #[serde(default)]
    pub camera: String,
}

/// Live state of a run for people and tests (`status.json`), rewritten
/// atomically whenever something changes.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
pub struct Status {
    /// The run ([`RunInfo::run_id`]).
    pub run_id: String,
    /// The supervisor writing this file.
    pub supervisor_pid: u32,
    /// Restarts of services by supervisors of this run (kept across resumes).
    pub restarts: u64,
    /// Frames recorded so far.
    pub frames_done: u64,
    /// Frames the input holds (None for a live camera).
    pub frames_total: Option<u64>,
    /// Each service's process.
    pub children: Vec<ChildStatus>,
    /// "running", "completed", "interrupted", "failed".
    pub state: String,
    /// Why the run failed.
    pub error: Option<String>,
}

/// One service process of a run, as `status.json` shows it.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct ChildStatus {
    /// The service's name (camera-reader, segmenter, ...).
    pub service: String,
    /// Its process id while it runs.
    pub pid: Option<u32>,
    /// "starting", "ready", "backoff", "failed", "stopped".
    pub state: String,
    /// Times it was restarted in this run.
    pub restarts: u64,
}

/// Exclusive hold on a run id for the life of its supervisor: an advisory
/// `flock` on `<tmp>/dynslam-run-<id>.lock`, which the kernel releases when
/// the holder dies (even by SIGKILL). A second supervisor of the same run id
/// (a `resume` of a live run, or a new run reusing the id from another
/// output folder, which would share its shared memory) is refused.
pub struct RunLock {
    _file: std::fs::File,
}

impl RunLock {
    /// Takes the run id's lock, or says which process holds it.
    pub fn acquire(run_id: &str) -> Result<Self> {
        use std::io::{Read, Seek, Write};
        use std::os::fd::AsRawFd;
        let path = std::env::temp_dir().join(format!("dynslam-run-{run_id}.lock"));
        let mut file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .with_context(|| format!("cannot open the run lock {}", path.display()))?;
        // SAFETY: flock(2) on a file descriptor this function owns.
        if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } != 0 {
            let mut holder = String::new();
            let _ = file.read_to_string(&mut holder);
            bail!(
                "run id {run_id} is in use by a live supervisor (pid {}; lock {}): stop it first, or pick another --run-id",
                holder.trim(),
                path.display()
            );
        }
        file.set_len(0)?;
        file.rewind()?;
        write!(file, "{}", std::process::id())?;
        Ok(Self { _file: file })
    }
}

/// A fresh run id: 8 hex digits from the clock and the pid.
pub fn new_run_id() -> String {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    let mixed = (nanos as u64) ^ ((std::process::id() as u64) << 32);
    format!(
        "{:08x}",
        (mixed ^ (mixed >> 29)).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 32
    )
}

/// Creates `output_dir/<run id>` with the resolved config and run info;
/// `camera` says which camera the config's `[camera]` is and why.
pub fn create(
    output_dir: &Path,
    run_id: &str,
    config: &PipelineConfig,
    camera: &str,
) -> Result<PathBuf> {
    let dir = output_dir.join(run_id);
    if dir.exists() {
        bail!("run folder {} already exists", dir.display());
    }
    std::fs::create_dir_all(output_dir)
        .with_context(|| format!("cannot create output folder {}", output_dir.display()))?;
    keep_private(config);
    use std::os::unix::fs::DirBuilderExt;
    std::fs::DirBuilder::new()
        .mode(if config.run.private { 0o700 } else { 0o777 })
        .create(&dir)
        .with_context(|| format!("cannot create run folder {}", dir.display()))?;
    std::fs::write(
        dir.join(CONFIG_FILE),
        config.to_toml().context("cannot write the run's config")?,
    )?;
    let info = RunInfo {
        run_id: run_id.to_string(),
        dataset: config.source.path.clone(),
        created_unix_s: std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(0),
        camera: camera.to_string(),
    };
    std::fs::write(dir.join(RUN_FILE), serde_json::to_string_pretty(&info)?)?;
    Ok(dir)
}

/// With `run.private`, every file this process and its children create
/// from now on is the user's alone (umask 077; the services inherit it).
pub fn keep_private(config: &PipelineConfig) {
    if config.run.private {
        // SAFETY: umask(2) only sets this process's file-creation mask.
        unsafe { libc::umask(0o077) };
    }
}

/// Reads an existing run folder (for resume).
pub fn open(dir: &Path) -> Result<(RunInfo, PipelineConfig)> {
    let info = read_info(dir)?;
    let config = PipelineConfig::load(&dir.join(CONFIG_FILE))?;
    Ok((info, config))
}

/// The run's identity (`run.json`).
pub fn read_info(dir: &Path) -> Result<RunInfo> {
    if !dir.is_dir() {
        bail!("run folder {} does not exist", dir.display());
    }
    let info_path = dir.join(RUN_FILE);
    let text = std::fs::read_to_string(&info_path).with_context(|| {
        format!(
            "{} is not a dynslam run folder (no {RUN_FILE})",
            dir.display()
        )
    })?;
    serde_json::from_str(&text).with_context(|| format!("{}: malformed", info_path.display()))
}

/// The run's `status.json`, if it has a readable one.
pub fn read_status(dir: &Path) -> Option<Status> {
    let text = std::fs::read_to_string(dir.join(STATUS_FILE)).ok()?;
    serde_json::from_str(&text).ok()
}

/// Writes `status.json` via a temporary file and a rename, so readers never
/// see a half-written file. When the temporary cannot be written (a full
/// disk) it is removed and the file is rewritten in place: the pages the
/// old status frees are the ones the new one needs, and a run that fails
/// for want of space must still say so.
pub fn write_status(dir: &Path, status: &Status) -> Result<()> {
    let text = serde_json::to_string_pretty(status)?;
    let path = dir.join(STATUS_FILE);
    let tmp = dir.join(format!("{STATUS_FILE}.tmp"));
    let replaced = std::fs::write(&tmp, &text).and_then(|()| std::fs::rename(&tmp, &path));
    if let Err(e) = replaced {
        let _ = std::fs::remove_file(&tmp);
        std::fs::write(&path, &text)
            .with_context(|| format!("cannot write {} ({e})", path.display()))?;
    }
    Ok(())
}

fn append_line(dir: &Path, file: &str, line: &str) -> Result<()> {
    use std::io::Write;
    let path = dir.join(file);
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .with_context(|| format!("cannot open {}", path.display()))?;
    writeln!(f, "{line}").with_context(|| format!("cannot write {}", path.display()))
}

/// Appends one restart record; the number of lines is the run's restart count.
pub fn log_restart(dir: &Path, line: &str) -> Result<()> {
    append_line(dir, RESTARTS_FILE, line)
}

/// Records that a supervisor resumed the run at `next_seq`.
pub fn log_resume(dir: &Path, next_seq: u64) -> Result<()> {
    append_line(dir, RESUMES_FILE, &format!("next_seq {next_seq}"))
}

/// Records that the SLAM service started again (a restart or a resume) at
/// frame `next_seq`, going on from its map checkpoint or with an empty map.
pub fn log_slam_start(dir: &Path, next_seq: u64, from: &str) -> Result<()> {
    append_line(
        dir,
        SLAM_STARTS_FILE,
        &format!("next_seq {next_seq} from {from}"),
    )
}

/// A start of the SLAM service after the run's first frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SlamStart {
    /// The first frame it was given.
    pub next_seq: u64,
    /// It went on from the map checkpoint (same world frame); else an
    /// empty map (a new world frame).
    pub from_checkpoint: bool,
}

/// The SLAM service's starts after the first frame, in order.
pub fn slam_starts(dir: &Path) -> Vec<SlamStart> {
    std::fs::read_to_string(dir.join(SLAM_STARTS_FILE))
        .unwrap_or_default()
        .lines()
        .filter_map(|l| {
            let mut words = l.split_whitespace();
            words.position(|w| w == "next_seq")?;
            let next_seq = words.next()?.parse().ok()?;
            words.position(|w| w == "from")?;
            Some(SlamStart {
                next_seq,
                from_checkpoint: words.next()? == "checkpoint",
            })
        })
        .collect()
}

/// How many service restarts the run has logged.
pub fn restart_count(dir: &Path) -> u64 {
    std::fs::read_to_string(dir.join(RESTARTS_FILE))
        .map(|t| t.lines().filter(|l| !l.trim().is_empty()).count() as u64)
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_id_is_held_by_one_supervisor_at_a_time() {
        let id = format!("locktest{}", std::process::id());
        let lock = RunLock::acquire(&id).unwrap();
        // flock is per open file: a second open in the same process conflicts too.
        let err = RunLock::acquire(&id).err().unwrap().to_string();
        assert!(err.contains("in use by a live supervisor"), "{err}");
        assert!(err.contains(&std::process::id().to_string()), "{err}");
        drop(lock);
        RunLock::acquire(&id).unwrap();
    }

    #[test]
    fn run_ids_are_valid_names() {
        let id = new_run_id();
        assert_eq!(id.len(), 8);
        shared_types::names::RunNames::new(&id).unwrap();
    }

    #[test]
    fn create_then_open_round_trips() {
        let base = std::env::temp_dir().join(format!("dynslam-rundir-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&base);
        let mut cfg = PipelineConfig::parse("").unwrap();
        cfg.source.path = PathBuf::from("/data/x");
        let dir = create(&base, "abc", &cfg, "tum-fr1").unwrap();
        let (info, back) = open(&dir).unwrap();
        assert_eq!(info.run_id, "abc");
        assert_eq!(info.camera, "tum-fr1");
        assert_eq!(back, cfg);
        assert!(create(&base, "abc", &cfg, "tum-fr1").is_err());
        log_restart(&dir, "segmenter pid 7 killed by signal 9 next_seq 12").unwrap();
        log_restart(&dir, "slam pid 8 killed by signal 9 next_seq 40").unwrap();
        assert_eq!(restart_count(&dir), 2);
        log_slam_start(&dir, 25, "empty").unwrap();
        log_slam_start(&dir, 40, "checkpoint").unwrap();
        let starts = slam_starts(&dir);
        assert_eq!(
            starts.iter().map(|s| s.next_seq).collect::<Vec<_>>(),
            [25, 40]
        );
        assert_eq!(
            starts.iter().map(|s| s.from_checkpoint).collect::<Vec<_>>(),
            [false, true]
        );
        std::fs::remove_dir_all(&base).ok();
    }
}
