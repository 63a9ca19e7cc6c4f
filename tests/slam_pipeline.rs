//! The real SLAM core (`orb-rgbd`) inside the multi-process pipeline: it
//! tracks the shared TUM frames and its keyframe wishes route the next frame
//! to the segmenter.

mod common;
use common::*;

#[test]
fn slam_keyframe_flags_drive_the_routing() {
    let dir = scratch("orb-pipeline");
    let config = write_config(
        &dir,
        "[services.slam]\nbackend = \"orb-rgbd\"\n\
         [services.segmenter]\nbackend = \"none\"\n\
         [services.propagator]\nbackend = \"none\"\n",
    );
    let r = run(
        &shared_tum(),
        &config,
        &dir.join("runs"),
        &format!("orb{}", std::process::id()),
        &["--limit", "90"],
    );
    assert!(r.success(), "{}", r.stderr());
    let rows = read_rows(&r.run_dir);
    assert_eq!(rows.len(), 90);
    let tracked = rows.iter().filter(|r| r["state"] == "ok").count();
    assert!(tracked >= 89, "{tracked} of 90 tracked");
    let mut wishes = 0;
    for pair in rows.windows(2) {
        if pair[0]["next_keyframe"] == "1" {
            wishes += 1;
            assert_eq!(
                pair[1]["route"], "segment",
                "frame {} after a keyframe wish",
                pair[1]["seq"]
            );
        }
    }
    assert!(
        wishes >= 2,
        "SLAM asked for {wishes} keyframes in 90 frames"
    );
    // Real poses: the camera of fr1_rpy rotates a lot but moves little.
    let last = rows.last().unwrap();
    let q: f64 = last["qw"].parse().unwrap();
    assert!(q.abs() < 0.999, "the pose never rotated: qw = {q}");
    assert_no_shm_left(&format!("orb{}", std::process::id()));
}

/// The SLAM issue's bar on the shared sequence: the whole pipeline with the
/// product's configuration (segmenter on keyframes, propagator otherwise)
/// tracks at least 99 % of the 300 frames, and `dynslam eval` scores its
/// trajectory at ATE <= 0.025 m (SE(3) aligned).
#[test]
fn full_run_on_fr1_rpy_meets_the_ate_target() {
    let dir = scratch("fr1-full");
    let run_id = format!("fr1full{}", std::process::id());
    let r = run(
        &shared_tum(),
        std::path::Path::new("configs/pipeline.toml"),
        &dir.join("runs"),
        &run_id,
        &[],
    );
    assert!(r.success(), "{}", r.stderr());
    let rows = read_rows(&r.run_dir);
    assert_eq!(rows.len(), 300);
    let tracked = rows.iter().filter(|r| r["state"] == "ok").count();
    assert!(tracked >= 297, "{tracked} of 300 tracked");
    let s = eval_json(
        &shared_tum().join("groundtruth.txt"),
        &r.run_dir.join("trajectory.txt"),
        &[],
    );
    let ate = s["ate_rmse_m"].as_f64().unwrap();
    eprintln!("fr1_rpy full run: {tracked}/300 tracked, ATE {ate:.4} m");
    assert!(s["pairs"].as_u64().unwrap() >= 297, "{s}");
    assert!(ate <= 0.025, "ATE {ate} m");
    assert_no_shm_left(&run_id);
    let _ = std::fs::remove_dir_all(&dir);
}
