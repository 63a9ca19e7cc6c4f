//! Replays SLAM restarts in the library, for studying what a kill costs:
//! the shared sequence is tracked with a checkpoint after every keyframe;
//! at each frame listed in `RESTARTS` the system is dropped and a new one
//! goes on from the checkpoint with the last three tracked poses (what the
//! SLAM service does after a kill), and the ATE of the whole run is printed.
//! A pipeline kill test prints the frames its restarts happened at.
//!
//! `RESTARTS=11,36,65 cargo test --release -p slam-core --test restart_replay -- --ignored --nocapture`

mod common;
use common::{load, tum};
use slam_core::eval::{evaluate_files, EvalOptions};
use slam_core::io::trajectory::Trajectory;
use slam_core::local_mapping::checkpoint::CheckpointPolicy;
use slam_core::{Camera, MapFile, SlamParams, System};

#[test]
#[ignore]
fn replay_restarts() {
    let data = load(usize::MAX);
    let restarts: Vec<usize> = std::env::var("RESTARTS")
        .unwrap_or_default()
        .split(',')
        .filter_map(|s| s.parse().ok())
        .collect();
    let cp = std::env::temp_dir().join("exp_cp.map");
    let _ = std::fs::remove_file(&cp);
    let policy = || {
        Some(CheckpointPolicy {
            path: cp.clone(),
            every_keyframes: 1,
        })
    };
    let mut sys = System::new(SlamParams::default(), Camera::tum_fr1());
    sys.set_checkpoint(policy());
    let mut traj = Trajectory {
        stamps: vec![],
        poses: vec![],
    };
    for (i, (t, rgb, d)) in data.iter().enumerate() {
        if restarts.contains(&i) {
            drop(sys);
            let f = MapFile::read(&cp).unwrap();
            sys = System::with_map(SlamParams::default(), Camera::tum_fr1(), f);
            sys.set_checkpoint(policy());
            let n = traj.stamps.len();
            let recent: Vec<_> = (n.saturating_sub(3)..n)
                .map(|k| (traj.stamps[k], traj.poses[k]))
                .collect();
            sys.resume_motion(&recent);
        }
        let r = sys.track_rgbd(rgb.as_raw(), d.as_raw(), None, 640, 480, *t);
        if r.state.is_tracked() {
            traj.stamps.push(*t);
            traj.poses.push(r.pose_wc);
        }
    }
    let est = std::env::temp_dir().join("exp_est.txt");
    std::fs::write(&est, traj.to_tum()).unwrap();
    let s = evaluate_files(&tum().join("groundtruth.txt"), &est, EvalOptions::default()).unwrap();
    eprintln!(
        "restarts {restarts:?}: ATE {:.4} ({} poses)",
        s.ate_rmse_m, s.pairs
    );
}
