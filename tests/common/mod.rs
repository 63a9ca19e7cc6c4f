//! Helpers of the workspace-level tests: run the real `dynslam` binary and
//! read what it wrote.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use pipeline::transport::run_files;
use shared_types::names::RunNames;

/// target/release (the tests run from target/release/deps).
pub fn bin_dir() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let dir = exe.parent().unwrap().parent().unwrap().to_path_buf();
    assert!(
        dir.join("dynslam").is_file(),
        "{} has no dynslam binary: build first (cargo build --release --workspace)",
        dir.display()
    );
    dir
}

pub fn dynslam() -> PathBuf {
    bin_dir().join("dynslam")
}

/// `dynslam eval --gt GT --est EST --json [extra]`: its JSON summary
/// (the command must succeed).
pub fn eval_json(gt: &Path, est: &Path, extra: &[&str]) -> serde_json::Value {
    let out = Command::new(dynslam())
        .arg("eval")
        .arg("--gt")
        .arg(gt)
        .arg("--est")
        .arg(est)
        .arg("--json")
        .args(extra)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// `key` of a JSON summary as a number (panics naming the key and the summary).
pub fn json_f64(summary: &serde_json::Value, key: &str) -> f64 {
    summary[key]
        .as_f64()
        .unwrap_or_else(|| panic!("{key}: {summary}"))
}

pub fn shared_tum() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/tum/rgbd_dataset_freiburg1_rpy_first300")
}

/// The Python of the repo's `.cache/<venv>`, which `just <recipe>` (part
/// of `just test`) makes.
pub fn venv_python(venv: &str, recipe: &str) -> PathBuf {
    let python = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(".cache")
        .join(venv)
        .join("bin/python");
    assert!(
        python.is_file(),
        "{} missing: `just {recipe}` (part of `just test`) installs it",
        python.display()
    );
    python
}

/// The Python of `.cache/iox2-venv` (iceoryx2's binding and Pillow).
pub fn iox2_python() -> PathBuf {
    venv_python("iox2-venv", "pyiceoryx2")
}

/// A fresh scratch folder for one test.
pub fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("dynslam-it-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Config lines that replace both mask workers by the `none` test double
/// (the built-in defaults run the real models).
pub const NO_MASK_MODELS: &str =
    "[services.segmenter]\nbackend = \"none\"\n[services.propagator]\nbackend = \"none\"\n";

/// Writes a pipeline config; `extra` is appended TOML.
pub fn write_config(dir: &Path, extra: &str) -> PathBuf {
    let path = dir.join("pipeline.toml");
    std::fs::write(&path, extra).unwrap();
    path
}

/// A run folder's `status.json`.
pub fn read_status(run_dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(run_dir.join("status.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

/// Result of one `dynslam run`.
pub struct RunResult {
    pub output: Output,
    pub run_dir: PathBuf,
    pub run_id: String,
}

impl RunResult {
    pub fn stderr(&self) -> String {
        String::from_utf8_lossy(&self.output.stderr).into_owned()
    }
    pub fn success(&self) -> bool {
        self.output.status.success()
    }
}

/// Runs `dynslam run DATASET --config CFG` to completion.
pub fn run(dataset: &Path, config: &Path, out: &Path, run_id: &str, extra: &[&str]) -> RunResult {
    let output = Command::new(dynslam())
        .arg("run")
        .arg(dataset)
        .arg("--config")
        .arg(config)
        .arg("--output-dir")
        .arg(out)
        .args(["--run-id", run_id])
        .args(extra)
        .env("RUST_LOG", "info")
        .output()
        .unwrap();
    RunResult {
        output,
        run_dir: out.join(run_id),
        run_id: run_id.to_string(),
    }
}

/// A frames.csv row as name -> value.
pub type Row = std::collections::HashMap<String, String>;

pub fn read_rows(run_dir: &Path) -> Vec<Row> {
    let mut reader = csv::Reader::from_path(run_dir.join("frames.csv")).unwrap();
    reader.deserialize().map(|r| r.unwrap()).collect()
}

/// Asserts that nothing of the run is left in shared memory.
pub fn assert_no_shm_left(run_id: &str) {
    let names = RunNames::new(run_id).unwrap();
    let left = run_files(&names);
    assert!(left.is_empty(), "run {run_id} left files behind: {left:?}");
}

/// Pids of live processes whose command line mentions `needle`.
pub fn processes_mentioning(needle: &str) -> Vec<u32> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(pid) = entry.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        if let Ok(cmd) = std::fs::read(format!("/proc/{pid}/cmdline")) {
            let cmd = String::from_utf8_lossy(&cmd);
            let state = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
            let zombie = state.split_whitespace().nth(2) == Some("Z");
            if cmd.contains(needle) && !zombie && pid != std::process::id() {
                out.push(pid);
            }
        }
    }
    out
}

/// Makes a small TUM folder from the first `n` frames of the shared sequence
/// (files copied, lists rewritten), to be damaged by a test.
pub fn small_tum(dir: &Path, n: usize) -> PathBuf {
    let tum = tum_slice(dir, "tum", 0, n);
    // Without ground truth (tests of what needs it rely on that).
    std::fs::remove_file(tum.join("groundtruth.txt")).unwrap();
    tum
}

/// A TUM folder `dir/name` of the shared frames `skip..skip + n` (by the
/// shared association), with the ground truth.
pub fn tum_slice(dir: &Path, name: &str, skip: usize, n: usize) -> PathBuf {
    let src = shared_tum();
    let dst = dir.join(name);
    std::fs::create_dir_all(dst.join("rgb")).unwrap();
    std::fs::create_dir_all(dst.join("depth")).unwrap();
    let assoc = std::fs::read_to_string(src.join("associations.txt")).unwrap();
    let mut rgb_txt = String::from("# color images\n");
    let mut depth_txt = String::from("# depth images\n");
    for line in assoc
        .lines()
        .filter(|l| !l.starts_with('#'))
        .skip(skip)
        .take(n)
    {
        let f: Vec<&str> = line.split_whitespace().collect();
        std::fs::copy(src.join(f[1]), dst.join(f[1])).unwrap();
        std::fs::copy(src.join(f[3]), dst.join(f[3])).unwrap();
        rgb_txt.push_str(&format!("{} {}\n", f[0], f[1]));
        depth_txt.push_str(&format!("{} {}\n", f[2], f[3]));
    }
    std::fs::write(dst.join("rgb.txt"), rgb_txt).unwrap();
    std::fs::write(dst.join("depth.txt"), depth_txt).unwrap();
    std::fs::copy(src.join("groundtruth.txt"), dst.join("groundtruth.txt")).unwrap();
    dst
}

/// The rgb file of frame `i` of a small TUM folder.
pub fn rgb_file(tum: &Path, i: usize) -> PathBuf {
    let text = std::fs::read_to_string(tum.join("rgb.txt")).unwrap();
    let line = text.lines().filter(|l| !l.starts_with('#')).nth(i).unwrap();
    tum.join(line.split_whitespace().nth(1).unwrap())
}

pub fn depth_file(tum: &Path, i: usize) -> PathBuf {
    let text = std::fs::read_to_string(tum.join("depth.txt")).unwrap();
    let line = text.lines().filter(|l| !l.starts_with('#')).nth(i).unwrap();
    tum.join(line.split_whitespace().nth(1).unwrap())
}

/// Makes a CA (`ca.pem`) in `dir` and a certificate it signs for each
/// `(name, common name, subjectAltName)`: `name.key`, `name.pem`, with
/// openssl (the TLS tests of the bridge and the remote workers).
pub fn test_certificates(dir: &Path, certs: &[(&str, &str, &str)]) {
    let sh = |script: &str| {
        let out = Command::new("bash")
            .arg("-euc")
            .arg(script)
            .current_dir(dir)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    };
    sh(
        "openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes \
        -keyout ca.key -out ca.pem -days 2 -subj '/CN=dynslam test CA' 2>/dev/null",
    );
    for (name, cn, san) in certs {
        sh(&format!(
            "openssl req -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes \
             -keyout {name}.key -out {name}.csr -subj '/CN={cn}' 2>/dev/null
             printf 'subjectAltName={san}\\nbasicConstraints=CA:FALSE\\n' > {name}.ext
             openssl x509 -req -in {name}.csr -CA ca.pem -CAkey ca.key -CAcreateserial \
             -out {name}.pem -days 2 -extfile {name}.ext 2>/dev/null"
        ));
    }
}

/// A shipped Zenoh example (`configs/zenoh/NAME`) with the test's
/// certificates (in `dir`) and port in place of the example's.
pub fn shipped_zenoh_config(name: &str, dir: &Path, port: u16) -> PathBuf {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("configs/zenoh")
            .join(name),
    )
    .unwrap()
    .replace("/etc/dynslam/tls/", &format!("{}/", dir.display()))
    .replace("tls/localhost:7447", &format!("tls/localhost:{port}"));
    let out = dir.join(name);
    std::fs::write(&out, text).unwrap();
    out
}

/// A run folder's `status.json`; None while it is missing or unreadable.
pub fn status(run_dir: &Path) -> Option<serde_json::Value> {
    let text = std::fs::read_to_string(run_dir.join("status.json")).ok()?;
    serde_json::from_str(&text).ok()
}

/// SIGKILL to `pid`.
pub fn kill9(pid: u32) {
    // SAFETY: plain kill(2) of a pid read from the run's status file.
    unsafe { libc::kill(pid as i32, libc::SIGKILL) };
}

/// Waits up to `limit` for the supervisor to exit, then checks that it
/// succeeded and that no process panicked (its log, `log`, says).
pub fn finish_cleanly(
    supervisor: &mut std::process::Child,
    log: &Path,
    limit: std::time::Duration,
) {
    let t = std::time::Instant::now();
    let exit = loop {
        if let Some(st) = supervisor.try_wait().unwrap() {
            break st;
        }
        assert!(
            t.elapsed() < limit,
            "run did not finish; see {}",
            log.display()
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    let log_text = std::fs::read_to_string(log).unwrap();
    assert!(exit.success(), "supervisor failed: {exit}\n{log_text}");
    assert!(
        !log_text.contains("panicked"),
        "a process panicked:\n{log_text}"
    );
}
