//! Place recognition on the real TUM sequence (../shared): relocalisation by
//! bag of words after a kidnapping, and in a saved map against all of its
//! keyframes.

mod common;
use common::{load, tum};
use slam_core::eval::{evaluate, EvalOptions};
use slam_core::io::trajectory::Trajectory;
use slam_core::{Camera, MapFile, SlamParams, System, TrackingState};

fn system() -> System {
    System::new(SlamParams::default(), Camera::tum_fr1())
}

/// Frames played to build the map before the kidnapping.
const BEFORE: usize = 200;
/// Blank frames (a covered lens) during which the camera is carried away.
const BLANK: usize = 3;
/// Where the camera is put back: a view from early in the sequence, seen
/// by the map's oldest keyframes.
const BACK_AT: std::ops::Range<usize> = 20..80;

/// A "kidnapped" sequence: frames 0..200, three blank frames, then frames
/// 20..80 again (timestamps continued, the ground truth following the
/// frames). Tracking must resume within 3 frames of the scene being visible
/// again, at the right place (ATE over all tracked frames <= 0.03 m), found
/// by the keyframe database at a keyframe that saw that place.
#[test]
fn a_kidnapped_camera_relocalises_by_bag_of_words() {
    let data = load(BEFORE);
    let truth = Trajectory::load_tum(&tum().join("groundtruth.txt")).unwrap();
    let mut sys = system();
    let mut est = Trajectory {
        stamps: Vec::new(),
        poses: Vec::new(),
    };
    let mut gt = est.clone();
    let mut record = |t_new: f64, t_orig: f64, r: &slam_core::FrameResult| {
        if r.state.is_tracked() {
            if let Some(g) = truth.interpolate(t_orig, 0.02) {
                est.stamps.push(t_new);
                est.poses.push(r.pose_wc);
                gt.stamps.push(t_new);
                gt.poses.push(g);
            }
        }
    };
    for (t, rgb, depth) in &data {
        let r = sys.track_rgbd(rgb.as_raw(), depth.as_raw(), None, 640, 480, *t);
        record(*t, *t, &r);
    }
    let keyframes = sys.map().live_keyframes().count();
    let mut t_next = data[BEFORE - 1].0;
    let blank = vec![0u8; 640 * 480 * 3];
    let no_depth = vec![0u16; 640 * 480];
    for _ in 0..BLANK {
        t_next += 1.0 / 30.0;
        let r = sys.track_rgbd(&blank, &no_depth, None, 640, 480, t_next);
        assert_eq!(
            r.state,
            TrackingState::Lost,
            "a blank frame cannot be tracked"
        );
    }
    let t0 = data[BACK_AT.start].0;
    let t_back = t_next + 1.0 / 30.0;
    let mut first_tracked = None;
    let mut first_pose = None;
    let mut tracked_after = 0;
    for (i, (t, rgb, depth)) in data[BACK_AT].iter().enumerate() {
        let t_new = t_back + (t - t0);
        let r = sys.track_rgbd(rgb.as_raw(), depth.as_raw(), None, 640, 480, t_new);
        if r.state.is_tracked() {
            tracked_after += 1;
            if first_tracked.is_none() {
                first_tracked = Some(i);
                first_pose = Some(r.pose_wc);
                assert_eq!(r.state, TrackingState::Relocalised);
            }
        }
        record(t_new, *t, &r);
    }
    let from = sys.last_relocalisation_keyframe();
    let ate = evaluate(&gt, &est, EvalOptions::default())
        .unwrap()
        .ate_rmse_m;
    eprintln!(
        "kidnapped: {keyframes} keyframes before; tracked again at frame {first_tracked:?} after the \
         jump, from keyframe {from:?}; {tracked_after}/{} tracked after it; ATE over {} tracked \
         frames {ate:.4} m",
        BACK_AT.len(),
        est.stamps.len()
    );
    let first = first_tracked.expect("never relocalised after the jump");
    assert!(
        first < 3,
        "relocalised only at frame {first} after the jump"
    );
    assert!(
        tracked_after >= BACK_AT.len() * 9 / 10,
        "{tracked_after} tracked after the jump"
    );
    assert!(ate <= 0.03, "ATE {ate:.4} m");
    assert_saw_the_place(&mut sys, from.unwrap(), first_pose.unwrap());
}

/// Keyframe `kf` looks where the relocalised pose `pose_wc` looks: camera
/// centres within 0.3 m, viewing directions within 30 deg.
fn assert_saw_the_place(sys: &mut System, kf: usize, pose_wc: nalgebra::Isometry3<f64>) {
    let k = sys.map().keyframes[kf].pose_cw.inverse();
    let apart = (k.translation.vector - pose_wc.translation.vector).norm();
    let axis = |p: &nalgebra::Isometry3<f64>| p.rotation * nalgebra::Vector3::z();
    let angle = axis(&k).angle(&axis(&pose_wc)).to_degrees();
    eprintln!("relocalised at keyframe {kf}: {apart:.3} m, {angle:.1} deg from it");
    assert!(
        apart < 0.3 && angle < 30.0,
        "keyframe {kf} saw another place"
    );
}

/// A run started from a saved map finds the camera among all the map's
/// keyframes: frame 10 of a map made from all 300 frames relocalises near
/// where the run that made the map tracked it, at a keyframe that saw that
/// place, and the frames after it are tracked where that run tracked them.
#[test]
fn a_saved_map_relocalises_against_all_of_its_keyframes() {
    let data = load(300);
    let mut maker = system();
    let mut poses = Vec::new();
    for (t, rgb, depth) in &data {
        poses.push(
            maker
                .track_rgbd(rgb.as_raw(), depth.as_raw(), None, 640, 480, *t)
                .pose_wc,
        );
    }
    let file = MapFile::decode(&maker.map_file().encode().unwrap()).unwrap();
    let keyframes = file.map.live_keyframes().count();
    assert_eq!(
        file.map.database.len(),
        keyframes,
        "the map file carries the keyframe database"
    );
    let mut sys = System::with_map(SlamParams::default(), Camera::tum_fr1(), file);
    let at = 10;
    let (t, rgb, depth) = &data[at];
    let r = sys.track_rgbd(rgb.as_raw(), depth.as_raw(), None, 640, 480, *t);
    assert_eq!(r.state, TrackingState::Relocalised);
    let from = sys.last_relocalisation_keyframe().unwrap();
    let d = poses[at].inverse() * r.pose_wc;
    eprintln!(
        "saved map of {keyframes} keyframes: frame {at} relocalised at keyframe {from}, \
         {:.4} m / {:.3} deg from the pose the map's run tracked",
        d.translation.vector.norm(),
        d.rotation.angle().to_degrees()
    );
    assert_saw_the_place(&mut sys, from, r.pose_wc);
    // A relocalised frame has no motion estimate for the rolling-shutter
    // correction, and fr1_rpy turns fast here: a few cm (as for PnP in
    // core_tum.rs); the motion model is back with the next frames.
    assert!(d.translation.vector.norm() < 0.05, "{d:?}");
    assert!(d.rotation.angle() < 0.05, "{d:?}");
    let mut last = r.pose_wc;
    for (t, rgb, depth) in &data[at + 1..=40] {
        let r = sys.track_rgbd(rgb.as_raw(), depth.as_raw(), None, 640, 480, *t);
        assert!(r.state.is_tracked(), "lost again at {t}");
        last = r.pose_wc;
    }
    let d = poses[40].inverse() * last;
    eprintln!(
        "frame 40: {:.4} m from the map's run",
        d.translation.vector.norm()
    );
    assert!(d.translation.vector.norm() < 0.02, "{d:?}");
}
