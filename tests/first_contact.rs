//! What a new user meets in the first hour: a partial config runs the
//! product, degradation is loud (exit code, status.json, report.md), an
//! image folder with the RGB-D SLAM is a clear error, the camera follows the
//! dataset folder's name, and the README's commands exist as written.
//! Needs `just setup` (part of `just test`) and ../shared/models.

mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::Command;

fn report(run_dir: &Path) -> String {
    std::fs::read_to_string(run_dir.join("report.md")).unwrap()
}

#[test]
fn a_config_with_only_a_camera_runs_the_product() {
    let dir = scratch("camera-only");
    let tum = small_tum(&dir, 12);
    let config = write_config(
        &dir,
        "[camera]\nfx = 517.306408\nfy = 516.469215\ncx = 318.643040\ncy = 255.313989\n",
    );
    let r = run(
        &tum,
        &config,
        &dir.join("runs"),
        &format!("camonly{}", std::process::id()),
        &[],
    );
    let stderr = r.stderr();
    assert!(r.success(), "{stderr}");
    assert!(
        stderr.contains("backends: slam orb-rgbd, segmenter yolov8-seg, propagator lk"),
        "{stderr}"
    );
    assert!(
        stderr.contains("segmenter ready with model 'yolov8-seg'"),
        "{stderr}"
    );
    let rows = read_rows(&r.run_dir);
    assert_eq!(rows.len(), 12);
    assert!(rows.iter().any(|r| r["mask_source"] == "segmenter"));
    assert!(rows.iter().filter(|r| r["state"] == "ok").count() >= 11);
    let md = report(&r.run_dir);
    assert!(
        md.contains("backends: SLAM `orb-rgbd`, segmenter `yolov8-seg`, propagator `lk`"),
        "{md}"
    );
    assert_eq!(read_status(&r.run_dir)["state"], "completed");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_missing_model_degrades_the_run_loudly_and_require_masks_fails_it() {
    let dir = scratch("missing-model");
    let tum = small_tum(&dir, 8);
    let config = write_config(
        &dir,
        "[services.segmenter]\nmodel_path = \"/no/such/yolov8n-seg_f32.onnx\"\n",
    );
    let r = run(
        &tum,
        &config,
        &dir.join("runs"),
        &format!("nomodel{}", std::process::id()),
        &[],
    );
    let stderr = r.stderr();
    assert_eq!(
        r.output.status.code(),
        Some(3),
        "degraded exit code:\n{stderr}"
    );
    assert!(stderr.contains("DEGRADED"), "{stderr}");
    let s = read_status(&r.run_dir);
    assert_eq!(s["state"], "degraded", "{s}");
    let error = s["error"].as_str().unwrap();
    assert!(error.contains("/no/such/yolov8n-seg_f32.onnx"), "{error}");
    let md = report(&r.run_dir);
    let opening: String = md.lines().take(4).collect::<Vec<_>>().join("\n");
    assert!(
        opening.contains("degraded or failed") && md.contains("/no/such/yolov8n-seg_f32.onnx"),
        "report.md opens with the problem:\n{md}"
    );
    // All frames still went through SLAM, unmasked.
    assert_eq!(read_rows(&r.run_dir).len(), 8);
    assert_no_shm_left(&r.run_id);

    let r = run(
        &tum,
        &config,
        &dir.join("runs"),
        &format!("nomodelreq{}", std::process::id()),
        &["--require-masks"],
    );
    assert_eq!(r.output.status.code(), Some(1), "{}", r.stderr());
    assert!(r.stderr().contains("require_masks"), "{}", r.stderr());
    assert_eq!(read_status(&r.run_dir)["state"], "failed");
    assert_no_shm_left(&r.run_id);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn an_image_folder_with_the_rgbd_slam_is_an_error_naming_the_key() {
    let dir = scratch("images-rgbd");
    let images = dir.join("images");
    std::fs::create_dir_all(&images).unwrap();
    let tum = small_tum(&dir, 2);
    std::fs::copy(rgb_file(&tum, 0), images.join("0001.png")).unwrap();
    let config = write_config(&dir, "[source]\nkind = \"images\"\n");
    let r = run(&images, &config, &dir.join("runs"), "imgrgbd", &[]);
    assert_eq!(r.output.status.code(), Some(1));
    let stderr = r.stderr();
    assert!(
        stderr.contains("source.kind") && stderr.contains("services.slam.sensor"),
        "{stderr}"
    );
    assert!(!r.run_dir.exists(), "no run folder for a config error");
    std::fs::remove_dir_all(&dir).ok();
}

fn run_dir_fx(run_dir: &Path) -> f64 {
    let text = std::fs::read_to_string(run_dir.join("config.toml")).unwrap();
    let line = text
        .lines()
        .skip_while(|l| l.trim() != "[camera]")
        .find(|l| l.starts_with("fx"))
        .unwrap();
    line.split('=').nth(1).unwrap().trim().parse().unwrap()
}

#[test]
fn the_camera_follows_the_folder_name_and_camera_overrides_it() {
    let dir = scratch("camera-preset");
    let tum = small_tum(&dir, 4);
    let fr3: PathBuf = dir.join("rgbd_dataset_freiburg3_walking_copy");
    std::fs::rename(&tum, &fr3).unwrap();
    let config = write_config(
        &dir,
        &format!("[services.slam]\nbackend = \"scripted\"\n{NO_MASK_MODELS}"),
    );
    let r = run(&fr3, &config, &dir.join("runs"), "camfr3", &[]);
    assert!(r.success(), "{}", r.stderr());
    assert!(r.stderr().contains("camera tum-fr3"), "{}", r.stderr());
    assert_eq!(run_dir_fx(&r.run_dir), 535.4);
    let md = report(&r.run_dir);
    assert!(md.contains("Camera: tum-fr3: dataset folder name"), "{md}");

    let r = run(
        &fr3,
        &config,
        &dir.join("runs"),
        "camfr1",
        &["--camera", "tum-fr1"],
    );
    assert!(r.success(), "{}", r.stderr());
    assert_eq!(run_dir_fx(&r.run_dir), 517.306408);
    assert!(report(&r.run_dir).contains("Camera: tum-fr1: --camera"));

    let bonn = dir.join("rgbd_bonn_copy");
    std::fs::rename(&fr3, &bonn).unwrap();
    let r = run(&bonn, &config, &dir.join("runs"), "cambonn", &[]);
    assert!(r.success(), "{}", r.stderr());
    assert_eq!(run_dir_fx(&r.run_dir), 542.822841);

    let r = run(
        &bonn,
        &config,
        &dir.join("runs"),
        "camfile",
        &["--camera", "/no/such.toml"],
    );
    assert_eq!(r.output.status.code(), Some(1));
    assert!(
        r.stderr().contains("--camera /no/such.toml"),
        "{}",
        r.stderr()
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// The user's guide: the README and the reference pages it sends readers to.
const GUIDE: [&str; 5] = [
    "README.md",
    "docs/interfaces.md",
    "docs/models.md",
    "docs/operations.md",
    "docs/library.md",
];

/// The `dynslam ...` and `just ...` commands in the guide's code blocks.
fn readme_commands() -> Vec<Vec<String>> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let guide: String = GUIDE
        .iter()
        .map(|f| std::fs::read_to_string(root.join(f)).unwrap())
        .collect::<Vec<_>>()
        .join("\n");
    let mut in_code = false;
    let mut out = Vec::new();
    for line in guide.lines() {
        if line.trim_start().starts_with("```") {
            in_code = !in_code;
            continue;
        }
        let l = line.trim();
        if in_code && (l.starts_with("./target/release/") || l.starts_with("just ")) {
            out.push(l.split_whitespace().map(String::from).collect());
        }
    }
    out
}

#[test]
fn every_command_of_the_readme_exists_as_written() {
    let commands = readme_commands();
    assert!(commands.len() >= 8, "{commands:?}");
    let just_recipes = String::from_utf8(
        Command::new("just")
            .arg("--summary")
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .map(|o| o.stdout)
            .unwrap_or_default(),
    )
    .unwrap();
    for c in &commands {
        if c[0] == "just" {
            if !just_recipes.is_empty() {
                assert!(
                    just_recipes.split_whitespace().any(|r| r == c[1]),
                    "README names `just {}`, the Justfile has: {just_recipes}",
                    c[1]
                );
            }
            continue;
        }
        // ./target/release/BIN [SUBCOMMAND] ...: BIN [SUBCOMMAND] --help works.
        let bin = bin_dir().join(c[0].trim_start_matches("./target/release/"));
        let mut args: Vec<&str> = Vec::new();
        if let Some(sub) = c.get(1).filter(|s| !s.starts_with('-') && !s.contains('/')) {
            args.push(sub);
        }
        args.push("--help");
        let o = Command::new(&bin).args(&args).output().unwrap_or_else(|e| {
            panic!("{}: {e}", bin.display());
        });
        assert!(
            o.status.success(),
            "{} {args:?}: {}",
            bin.display(),
            String::from_utf8_lossy(&o.stderr)
        );
        // Every --flag the README uses is one the command knows.
        let help = String::from_utf8_lossy(&o.stdout);
        for flag in c.iter().filter(|a| a.starts_with("--")) {
            let name = flag.split('=').next().unwrap();
            assert!(
                help.contains(name),
                "{c:?}: {name} is not in --help:\n{help}"
            );
        }
    }
}

#[test]
fn invalid_values_stop_the_run_before_any_process_starts() {
    let dir = scratch("invalid-values");
    let tum = small_tum(&dir, 2);
    for (i, (text, needles)) in [
        (
            "[services.segmenter]\nclasses = [\"person\", \"pedestrian\"]\n",
            vec!["services.segmenter.classes", "'pedestrian'"],
        ),
        (
            "[run]\nspeed = 1e-300\n",
            vec!["run.speed", "1e-300", "line 2"],
        ),
        (
            "[services.segmenter]\nscore_threshold = 2.0\n",
            vec!["services.segmenter.score_threshold", "0..=1"],
        ),
        (
            "[supervisor]\nready_timeout_s = 0\n",
            vec!["supervisor.ready_timeout_s"],
        ),
    ]
    .into_iter()
    .enumerate()
    {
        let config = write_config(&dir, text);
        let id = format!("invalid{i}");
        let r = run(&tum, &config, &dir.join("runs"), &id, &[]);
        assert_eq!(r.output.status.code(), Some(1), "{text}: {}", r.stderr());
        for n in needles {
            assert!(r.stderr().contains(n), "{text}: no '{n}' in {}", r.stderr());
        }
        assert!(!r.run_dir.exists(), "{text}: no run folder");
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// A run's folder and files are the user's alone by default (`run.private`):
/// other local users cannot read the frames, poses or map of a robot's run.
#[test]
fn run_folders_and_files_are_private_by_default() {
    use std::os::unix::fs::PermissionsExt;
    let dir = scratch("private");
    let tum = small_tum(&dir, 3);
    let config = write_config(
        &dir,
        "[services.slam]\nbackend = \"scripted\"\n[services.segmenter]\nbackend = \"none\"\n[services.propagator]\nbackend = \"none\"\n",
    );
    let mode = |p: &std::path::Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
    let r = run(
        &tum,
        &config,
        &dir.join("runs"),
        &format!("private{}", std::process::id()),
        &[],
    );
    assert!(r.success(), "{}", r.stderr());
    assert_eq!(mode(&r.run_dir), 0o700, "run folder");
    for f in [
        "frames.csv",
        "report.md",
        "config.toml",
        "run.json",
        "status.json",
        "trajectory.txt",
    ] {
        assert_eq!(mode(&r.run_dir.join(f)), 0o600, "{f}");
    }
    // The run's shared memory too, iceoryx2's management file included
    // (iceoryx2 makes it 0666): checked while a slower run is live.
    let slow = write_config(
        &dir.join("runs"),
        "[services.slam]\nbackend = \"scripted\"\nwork_ms = 40\n[services.segmenter]\nbackend = \"none\"\n[services.propagator]\nbackend = \"none\"\n",
    );
    let live_id = format!("privshm{}", std::process::id());
    let mut live = Command::new(dynslam())
        .arg("run")
        .arg(shared_tum())
        .args(["--config", slow.to_str().unwrap(), "--output-dir"])
        .arg(dir.join("live"))
        .args(["--run-id", &live_id, "--limit", "60"])
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let t = std::time::Instant::now();
    let mut checked = 0;
    while live.try_wait().unwrap().is_none() && t.elapsed() < std::time::Duration::from_secs(60) {
        let status = std::fs::read_to_string(dir.join("live").join(&live_id).join("status.json"));
        if status.is_ok_and(|s| s.contains("\"running\"") && !s.contains("starting")) {
            for e in std::fs::read_dir("/dev/shm").unwrap().flatten() {
                if e.file_name().to_string_lossy().contains(&live_id) {
                    if let Ok(m) = e.metadata() {
                        assert_eq!(m.permissions().mode() & 0o777, 0o600, "{:?}", e.file_name());
                        checked += 1;
                    }
                }
            }
            if checked > 0 {
                break;
            }
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    assert!(live.wait().unwrap().success());
    assert!(checked >= 10, "only {checked} shared-memory files seen");
    let open_config = write_config(&dir.join("runs"), "[run]\nprivate = false\n[services.slam]\nbackend = \"scripted\"\n[services.segmenter]\nbackend = \"none\"\n[services.propagator]\nbackend = \"none\"\n");
    let r = run(
        &tum,
        &open_config,
        &dir.join("runs"),
        &format!("open{}", std::process::id()),
        &[],
    );
    assert!(r.success(), "{}", r.stderr());
    // SAFETY: umask(2) read back at once (set, then restored).
    let umask = unsafe {
        let old = libc::umask(0o022);
        libc::umask(old);
        old
    };
    assert_eq!(
        mode(&r.run_dir),
        0o777 & !umask as u32,
        "private = false keeps the user's umask"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// The README stays a user's guide: short, no development history, and
/// every page it links to exists.
#[test]
fn the_readme_is_a_short_guide_whose_links_resolve() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
    let lines = readme.lines().count();
    assert!(
        lines <= 300,
        "README.md has {lines} lines (at most 300: details go to docs/)"
    );
    let words: Vec<&str> = readme.split_whitespace().collect();
    for w in words.windows(2) {
        let history = matches!(w[0].to_lowercase().as_str(), "stop" | "stops" | "issue")
            && w[1]
                .trim_matches(|c: char| !c.is_ascii_alphanumeric())
                .parse::<u32>()
                .is_ok();
        assert!(
            !history,
            "README.md names development history: \"{} {}\"",
            w[0], w[1]
        );
    }
    for file in GUIDE {
        let text = std::fs::read_to_string(root.join(file)).unwrap();
        for link in text.split("](").skip(1) {
            let target = link.split(')').next().unwrap_or("");
            if target.starts_with("http") || target.starts_with('#') {
                continue;
            }
            let base = Path::new(file).parent().unwrap_or(Path::new(""));
            assert!(
                root.join(base).join(target).exists(),
                "{file} links to {target}, which does not exist"
            );
        }
    }
}
