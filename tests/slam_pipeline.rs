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

/// The persistent-map issue's bar: a run over frames 0-149 of the shared
/// sequence saves its map; a second run over frames 150-299 (their own
/// folder) loads it and tracks >= 95 % of its frames in the first run's
/// world frame: the two trajectories concatenated, with one SE(3)
/// alignment against the ground truth, have ATE <= 0.02 m. Both with and
/// without --localize-only, which adds no keyframe.
#[test]
fn a_saved_map_is_gone_on_in_by_the_next_run() {
    let dir = scratch("map-reuse");
    let first = tum_slice(&dir, "first", 0, 150);
    let second = tum_slice(&dir, "second", 150, 150);
    let map = dir.join("fr1.map");
    let pid = std::process::id();
    let config = std::path::Path::new("configs/pipeline.toml");
    let saving = run(
        &first,
        config,
        &dir.join("runs"),
        &format!("mapsave{pid}"),
        &["--save-map", map.to_str().unwrap()],
    );
    assert!(saving.success(), "{}", saving.stderr());
    assert!(map.is_file(), "no map file written");
    let saved_keyframes = slam_core::MapFile::read(&map)
        .unwrap()
        .map
        .live_keyframes()
        .count() as u32;
    let first_traj = std::fs::read_to_string(saving.run_dir.join("trajectory.txt")).unwrap();
    for (name, extra) in [("mapload", vec![]), ("mapfixed", vec!["--localize-only"])] {
        let mut args = vec!["--load-map", map.to_str().unwrap()];
        args.extend(extra.iter().copied());
        let r = run(
            &second,
            config,
            &dir.join("runs"),
            &format!("{name}{pid}"),
            &args,
        );
        assert!(r.success(), "{}", r.stderr());
        let rows = read_rows(&r.run_dir);
        assert_eq!(rows.len(), 150);
        let tracked = rows
            .iter()
            .filter(|r| r["state"] == "ok" || r["state"] == "relocalised");
        let tracked = tracked.count();
        let keyframes: u32 = rows.last().unwrap()["keyframes"].parse().unwrap();
        let both = dir.join(format!("{name}.txt"));
        let second_traj = std::fs::read_to_string(r.run_dir.join("trajectory.txt")).unwrap();
        let second_poses: String = second_traj
            .lines()
            .filter(|l| !l.starts_with('#'))
            .map(|l| format!("{l}\n"))
            .collect();
        std::fs::write(&both, format!("{first_traj}{second_poses}")).unwrap();
        let s = eval_json(&shared_tum().join("groundtruth.txt"), &both, &[]);
        let ate = json_f64(&s, "ate_rmse_m");
        eprintln!(
            "{name}: {tracked}/150 tracked, keyframes {saved_keyframes} saved -> {keyframes}, ATE of both runs in one alignment {ate:.4} m ({} poses)",
            s["pairs"]
        );
        assert!(tracked >= 143, "{name}: {tracked} of 150 tracked");
        assert!(ate <= 0.02, "{name}: ATE {ate} m");
        if name == "mapfixed" {
            assert_eq!(
                keyframes, saved_keyframes,
                "localization mode added keyframes"
            );
            assert!(
                !r.run_dir.join("checkpoint.map").exists(),
                "the map does not change"
            );
        } else {
            assert!(keyframes > saved_keyframes, "the map did not grow");
        }
    }
    std::fs::remove_dir_all(&dir).ok();
}
