//! Frames left out as real time leaves them on a busy machine, on the real
//! TUM sequence (../shared): tracking starts from the turn the images give
//! where the constant-velocity model misses a reversal of the camera's turn,
//! and a young map lost for good starts again.

mod common;
use common::{load, tum};
use slam_core::eval::{evaluate_files, EvalOptions};
use slam_core::io::trajectory::Trajectory;
use slam_core::rng::SplitMix64;
use slam_core::{Camera, SlamParams, System, TrackingState};

/// Frames tracked and frames relocalised over `frames`.
fn track(frames: &[&(f64, image::RgbImage, common::Depth)], params: SlamParams) -> (usize, usize) {
    let mut sys = System::new(params, Camera::tum_fr1());
    let (mut tracked, mut relocalised) = (0, 0);
    for (t, rgb, depth) in frames {
        let r = sys.track_rgbd(rgb.as_raw(), depth.as_raw(), None, 640, 480, *t);
        tracked += r.state.is_tracked() as usize;
        relocalised += (r.state == TrackingState::Relocalised) as usize;
    }
    (tracked, relocalised)
}

/// The first 5 s of fr1_rpy (turns of up to 2 rad/s that reverse) with 45 %
/// of the frames left out at random (two seeds): with the images' turn every
/// frame is tracked and at most one relocalises; with the motion model alone
/// (measured: 76/79 and 71/80 tracked, 5 and 9 relocalisations) the camera is
/// lost or relocalised again and again.
#[test]
fn with_frames_left_out_the_images_turn_keeps_tracking() {
    let data = load(150);
    for seed in [2, 3] {
        let mut rng = SplitMix64::new(seed);
        let kept: Vec<_> = data
            .iter()
            .enumerate()
            .filter(|(i, _)| *i == 0 || rng.uniform(0.0, 1.0) >= 0.45)
            .map(|(_, f)| f)
            .collect();
        let with = track(&kept, SlamParams::default());
        let without = track(
            &kept,
            SlamParams {
                turn_from_images: false,
                ..SlamParams::default()
            },
        );
        eprintln!(
            "seed {seed}, {} frames: tracked / relocalised with the images' turn {with:?}, without {without:?}",
            kept.len()
        );
        assert_eq!(with.0, kept.len(), "seed {seed}: {with:?}");
        assert!(with.1 <= 1, "seed {seed}: {with:?}");
        assert!(
            without.0 < kept.len() || without.1 >= 3,
            "seed {seed}: the motion model alone kept up: {without:?}"
        );
    }
}

/// Every 5th frame of the shared 300 (6 fps of a camera turning up to 2
/// rad/s): the map is lost in a fast turn while it has 2 keyframes and no
/// lost frame relocalises at them (without the restart: 11 of 60 frames
/// tracked, measured). Lost for 0.5 s, the young map starts again at the
/// last tracked pose and most frames are tracked, near the ground truth.
#[test]
fn a_young_map_lost_for_good_starts_again_at_the_last_pose() {
    let data = load(300);
    let kept: Vec<_> = data.iter().step_by(5).collect();
    let mut sys = System::new(SlamParams::default(), Camera::tum_fr1());
    let mut trajectory = Trajectory {
        stamps: Vec::new(),
        poses: Vec::new(),
    };
    let mut last_tracked = None;
    let mut restarts_seen = 0;
    for (t, rgb, depth) in &kept {
        let r = sys.track_rgbd(rgb.as_raw(), depth.as_raw(), None, 640, 480, *t);
        if sys.map_restarts() > restarts_seen {
            restarts_seen = sys.map_restarts();
            // The world frame goes on: the new start is where the camera
            // was last tracked.
            let before: nalgebra::Isometry3<f64> = last_tracked.expect("tracked before");
            let moved = (r.pose_wc.translation.vector - before.translation.vector).norm();
            let turned = r.pose_wc.rotation.angle_to(&before.rotation);
            assert!(moved < 1e-9 && turned < 1e-9, "{moved} m {turned} rad");
            assert!(sys.map().live_keyframes().count() == 1);
        }
        if r.state.is_tracked() {
            last_tracked = Some(r.pose_wc);
            trajectory.stamps.push(*t);
            trajectory.poses.push(r.pose_wc);
        }
    }
    let tracked = trajectory.stamps.len();
    let est = std::env::temp_dir().join(format!("young_map_{}.txt", std::process::id()));
    std::fs::write(&est, trajectory.to_tum()).unwrap();
    let s = evaluate_files(&tum().join("groundtruth.txt"), &est, EvalOptions::default()).unwrap();
    let _ = std::fs::remove_file(&est);
    eprintln!(
        "tracked {tracked} of {}, {} restarts, ATE {:.4} m",
        kept.len(),
        sys.map_restarts(),
        s.ate_rmse_m
    );
    assert!(sys.map_restarts() >= 1);
    assert!(tracked >= 40, "tracked {tracked} of {}", kept.len());
    assert!(s.ate_rmse_m < 0.06, "ATE {:.4} m", s.ate_rmse_m);
}
