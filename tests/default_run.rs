//! `dynslam run` with no dataset, as `just run` calls it on a fresh clone:
//! the embedded default scene is rendered, the whole pipeline (real
//! processes, the real YOLOv8n-seg model through ONNX Runtime, LK
//! propagation, the ORB RGB-D SLAM core) runs on it, and the run folder
//! holds the report, its plots and the map. Then the ablation on a short
//! cut of the same scene, and the report command.
//! Needs `just setup` (part of `just test`) and ../shared/models.

mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::Command;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `dynslam ARGS` run from the repository root, as the Justfile does.
fn dynslam_in_repo(args: &[&str]) -> std::process::Output {
    Command::new(dynslam())
        .current_dir(repo())
        .args(args)
        .output()
        .unwrap()
}

fn png_size(path: &Path) -> (u32, u32) {
    image::image_dimensions(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn default_run_renders_the_scene_runs_every_service_and_writes_the_report() {
    let dir = scratch("default-run");
    let out = dir.join("runs");
    let id = format!("default{}", std::process::id());
    // From a folder outside the repo: the built-in config, the models and
    // ONNX Runtime are found from the binary's place, not the working directory.
    let o = Command::new(dynslam())
        .current_dir(&dir)
        .args(["run", "--output-dir", "runs", "--run-id", &id])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(
        stderr.contains("rendering the embedded default scene"),
        "{stderr}"
    );
    let run_dir = out.join(&id);
    assert_eq!(
        String::from_utf8_lossy(&o.stdout).trim(),
        format!("runs/{id}"),
        "the run folder is printed last (as given: relative to the working directory)"
    );
    assert!(
        stderr.contains("segmenter ready with model 'yolov8-seg'"),
        "{stderr}"
    );
    assert_no_shm_left(&id);

    let rows = read_rows(&run_dir);
    assert_eq!(rows.len(), 150);
    let tracked = rows
        .iter()
        .filter(|r| r["state"] == "ok" || r["state"] == "relocalised")
        .count();
    assert!(tracked >= 149, "tracked {tracked}/150");
    assert!(rows.iter().any(|r| r["mask_source"] == "segmenter"));
    assert!(rows.iter().any(|r| r["mask_source"] == "propagator"));
    assert!(
        rows.iter()
            .map(|r| r["features_masked"].parse::<u64>().unwrap())
            .sum::<u64>()
            > 1000,
        "people's features are removed"
    );

    // Accuracy against the rendered ground truth, as the report states it.
    let eval: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run_dir.join("eval.json")).unwrap()).unwrap();
    let ate = eval["ate_rmse_m"].as_f64().unwrap();
    assert_eq!(eval["pairs"], 150);
    assert!(ate < 0.05, "ATE {ate} m on the default scene");

    let report = std::fs::read_to_string(run_dir.join("report.md")).unwrap();
    for needle in [
        "ATE RMSE (SE(3) aligned)",
        &format!("{ate:.4} m"),
        "segmenter (keyframes)",
        "plots/trajectory.png",
        "plots/masks.png",
        "plots/latency.png",
        "map.ply`: ",
    ] {
        assert!(
            report.contains(needle),
            "report lacks '{needle}':\n{report}"
        );
    }
    for (png, size) in [
        ("trajectory.png", (1100, 520)),
        ("ate_over_time.png", (900, 320)),
        ("mask_iou.png", (900, 320)),
        ("masks.png", (960, 64 + 480)),
    ] {
        assert_eq!(png_size(&run_dir.join("plots").join(png)), size, "{png}");
    }
    // One latency histogram per stage that ran (end to end, track, SLAM's
    // feature extraction, segmenter, propagator, decode) under a title.
    assert_eq!(
        png_size(&run_dir.join("plots/latency.png")),
        (900, 40 + 6 * 200)
    );
    // The report names the backends, the camera and the world frame.
    for needle in [
        "backends: SLAM `orb-rgbd`, segmenter `yolov8-seg`, propagator `lk`",
        "Camera: config",
        "optical frame of the camera at the first tracked frame",
    ] {
        assert!(
            report.contains(needle),
            "report lacks '{needle}':\n{report}"
        );
    }
    // SLAM's own steps are in frames.csv and the latency summary.
    assert!(rows
        .iter()
        .all(|r| r["slam_extract_us"].parse::<u64>().unwrap() > 1000));
    assert!(rows
        .iter()
        .all(|r| r["slam_mapping_us"].parse::<u64>().is_ok()));

    // Every frame's masks are on record and scored against the ground
    // truth; the images kept are the segmenter's (run.save_masks =
    // "keyframes"); the map has coloured points.
    let masks_csv = std::fs::read_to_string(run_dir.join("masks.csv")).unwrap();
    assert_eq!(masks_csv.lines().count(), 151, "header + one row per frame");
    let mut kept = 0;
    for line in masks_csv.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let image = run_dir.join(format!("masks/{:0>6}.png", f[0]));
        assert_eq!(image.is_file(), f[1] == "segmenter", "{line}");
        assert_eq!(f[4].is_empty(), f[1] != "segmenter", "{line}");
        kept += image.is_file() as usize;
    }
    assert!((5..150).contains(&kept), "{kept} segmenter images");
    let ious = std::fs::read_to_string(run_dir.join("mask_iou.csv")).unwrap();
    assert!(ious.lines().any(|l| l.contains(",propagator,")), "{ious}");
    let map = slam_core::io::ply::read_ply(&run_dir.join("map.ply")).unwrap();
    assert!(map.len() > 1000, "{} map points", map.len());
    assert!(map
        .iter()
        .all(|p| p.position.iter().all(|c| c.abs() < 10.0)));

    // The report can be written again from the folder alone.
    std::fs::remove_file(run_dir.join("report.md")).unwrap();
    let o = dynslam_in_repo(&["report", run_dir.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        std::fs::read_to_string(run_dir.join("report.md")).unwrap(),
        report
    );

    // Ablation on the first 40 frames of the same scene: no masks,
    // ground-truth masks (IoU 1 by construction), blackout.
    let scene = out.join("default-scene-v2/scene");
    let abl = dir.join("ablation");
    let o = dynslam_in_repo(&[
        "ablate",
        scene.to_str().unwrap(),
        "--limit",
        "40",
        "--only",
        "a,b,e",
        "--output-dir",
        abl.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let rows: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(abl.join("ablation.json")).unwrap()).unwrap();
    let rows = rows.as_array().unwrap();
    assert_eq!(
        rows.iter()
            .map(|r| r["key"].as_str().unwrap())
            .collect::<Vec<_>>(),
        ["a", "b", "e"]
    );
    for r in rows {
        assert_eq!(r["frames"], 40, "{r}");
        assert!(r["ate_rmse_m"].as_f64().is_some(), "{r}");
    }
    assert!(rows[1]["mask_iou"].as_f64().unwrap() > 0.999, "{}", rows[1]);
    let table = std::fs::read_to_string(abl.join("ablation.md")).unwrap();
    assert!(
        table.contains("| (b) ground-truth masks, every frame |"),
        "{table}"
    );

    // Mask quality of the real models on the first 45 frames (4 keyframes):
    // on this scene the targets hold (segmenter 0.886, propagator
    // 0.821 when written; fr1's are checked in tests/synth.rs).
    let o = dynslam_in_repo(&[
        "masks-eval",
        scene.to_str().unwrap(),
        "--limit",
        "45",
        "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let scores: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let score = |key: &str| json_f64(&scores, key);
    assert!(score("segmenter_iou") >= 0.8, "{scores}");
    assert!(score("propagator_iou") >= 0.7, "{scores}");
    assert!(
        score("propagator_iou_found") >= score("propagator_iou"),
        "{scores}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn ablate_and_report_name_bad_arguments() {
    let dir = scratch("ablate-bad");
    let missing = dir.join("no-such-sequence");
    let o = dynslam_in_repo(&["ablate", missing.to_str().unwrap()]);
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("no-such-sequence") && e.contains("does not exist"),
        "{e}"
    );

    let o = dynslam_in_repo(&["ablate", dir.to_str().unwrap(), "--only", "a,z"]);
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("--only: unknown row 'z'"), "{e}");

    let o = dynslam_in_repo(&["report", missing.to_str().unwrap()]);
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("no-such-sequence") && e.contains("does not exist"),
        "{e}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn ground_truth_backend_without_masks_is_named_and_the_run_goes_on_degraded() {
    let dir = scratch("gt-backend");
    let tum = small_tum(&dir, 8);
    let config = write_config(
        &dir,
        "[services.slam]\nbackend = \"scripted\"\nkeyframe_every = 2\n\
         [services.segmenter]\nbackend = \"ground-truth\"\n\
         [services.propagator]\nbackend = \"none\"\n",
    );
    let id = format!("gtbackend{}", std::process::id());
    let r = run(&tum, &config, &dir.join("runs"), &id, &[]);
    assert_eq!(r.output.status.code(), Some(3), "degraded: {}", r.stderr());
    assert!(
        r.stderr().contains("has no masks.txt"),
        "the segmenter says why it stopped: {}",
        r.stderr()
    );
    assert_eq!(read_rows(&r.run_dir).len(), 8);
    std::fs::remove_dir_all(&dir).ok();
}
