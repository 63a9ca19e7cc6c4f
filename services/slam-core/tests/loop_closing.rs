//! Loop closing on the real TUM sequence (../shared): no false loop on the
//! sequence played forward, nor with frames left out as real time leaves
//! them, and what a revisit (played forward, then backward) does. Played
//! backwards the motion between frames is reversed but the rows' readout
//! order is not (as with a camera set to flip its image), so the
//! rolling-shutter correction must find out which way the rows run.

mod common;
use common::{load, tum};
use slam_core::eval::{evaluate, EvalOptions};
use slam_core::io::trajectory::Trajectory;
use slam_core::rng::SplitMix64;
use slam_core::{Camera, SlamParams, System};

/// Tracks `order` (indices into the loaded frames, timestamps continued at
/// 30 fps where the order goes back): ATE, loops closed, detection ms.
fn run(loop_closing: bool, order: &[usize]) -> (f64, usize, Vec<f64>) {
    let data = load(300);
    let truth = Trajectory::load_tum(&tum().join("groundtruth.txt")).unwrap();
    let params = SlamParams {
        loop_closing,
        ..Default::default()
    };
    let mut sys = System::new(params, Camera::tum_fr1());
    let mut est = Trajectory {
        stamps: Vec::new(),
        poses: Vec::new(),
    };
    let mut gt = est.clone();
    let mut t = data[order[0]].0;
    for (n, &i) in order.iter().enumerate() {
        if n > 0 {
            let dt = (data[i].0 - data[order[n - 1]].0).abs();
            t += dt.max(1e-3);
        }
        let (t_orig, rgb, depth) = &data[i];
        let r = sys.track_rgbd(rgb.as_raw(), depth.as_raw(), None, 640, 480, t);
        if r.state.is_tracked() {
            if let Some(g) = truth.interpolate(*t_orig, 0.02) {
                est.stamps.push(t);
                est.poses.push(r.pose_wc);
                gt.stamps.push(t);
                gt.poses.push(g);
            }
        }
    }
    let ate = evaluate(&gt, &est, EvalOptions::default())
        .unwrap()
        .ate_rmse_m;
    for l in sys.loops() {
        eprintln!("  loop {l:?}");
    }
    (ate, sys.loops().len(), sys.loop_detection_ms())
}

fn p99(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s.get((s.len() * 99 / 100).min(s.len().saturating_sub(1)))
        .copied()
        .unwrap_or(0.0)
}

/// The shared sequence forward only: nothing is revisited after the local
/// map has moved on, so no loop may be accepted, and ATE is what it is
/// without loop closing.
#[test]
fn no_false_loop_on_the_shared_sequence_forward() {
    let order: Vec<usize> = (0..300).collect();
    let (ate, loops, ms) = run(true, &order);
    let (ate_off, _, _) = run(false, &order);
    eprintln!(
        "forward: {loops} loops, ATE {ate:.4} m (without loop closing {ate_off:.4} m), detection \
         p99 {:.2} ms over {} keyframes",
        p99(&ms),
        ms.len()
    );
    assert_eq!(loops, 0, "a false loop on a sequence without revisits");
    assert!((ate - ate_off).abs() < 1e-9, "{ate} vs {ate_off}");
}

/// 40 % of the frames left out at random (`slam-bench --drop-share 0.4`):
/// after a fast turn keyframe 17 was not covisible with keyframe 15, 0.8 s
/// before it, and closed a "loop" with it that moved it 9 cm / 5.8 deg (ATE
/// 0.0163 -> 0.0252 m). A loop comes back after a path: none may close, and
/// ATE is what it is without loop closing.
#[test]
fn no_loop_between_neighbouring_keyframes_with_frames_left_out() {
    let mut rng = SplitMix64::new(1);
    let order: Vec<usize> = (0..300)
        .filter(|&i| i == 0 || rng.uniform(0.0, 1.0) >= 0.4)
        .collect();
    let (ate, loops, _) = run(true, &order);
    let (ate_off, _, _) = run(false, &order);
    eprintln!("40 % left out: {loops} loops, ATE {ate:.4} m (without loop closing {ate_off:.4} m)");
    assert_eq!(loops, 0, "a loop between neighbouring keyframes");
    assert!((ate - ate_off).abs() < 1e-9, "{ate} vs {ate_off}");
}

/// Forward, then backward: the camera comes back over the whole room.
#[test]
fn the_sequence_played_back_revisits_without_harm() {
    let order: Vec<usize> = (0..300).chain((0..300).rev()).collect();
    let (ate, loops, ms) = run(true, &order);
    let (ate_off, _, _) = run(false, &order);
    eprintln!(
        "forward-backward: {loops} loops, ATE {ate:.4} m (without loop closing {ate_off:.4} m), \
         detection p99 {:.2} ms over {} keyframes",
        p99(&ms),
        ms.len()
    );
    assert!(ate <= ate_off * 1.1 + 0.001, "{ate} vs {ate_off}");
}

/// The same image seen on the way out and on the way back must come out at
/// the same place. Measured: 5.1 mm apart on average (p90 11 mm); with the
/// readout taken top row first throughout 25.8 mm (p90 48 mm), ATE of the
/// whole run 0.0104 against 0.0257 m.
#[test]
fn the_way_back_finds_the_same_poses_as_the_way_out() {
    let data = load(usize::MAX);
    let end = data.last().expect("frames").0;
    let mut sys = System::new(SlamParams::default(), Camera::tum_fr1());
    let mut out = Vec::new();
    for (t, rgb, depth) in &data {
        let r = sys.track_rgbd(rgb.as_raw(), depth.as_raw(), None, 640, 480, *t);
        out.push(r.state.is_tracked().then_some(r.pose_wc));
    }
    let mut apart = Vec::new();
    for (i, (t, rgb, depth)) in data.iter().enumerate().rev().skip(1) {
        let r = sys.track_rgbd(rgb.as_raw(), depth.as_raw(), None, 640, 480, 2.0 * end - t);
        assert!(r.state.is_tracked(), "frame {i} lost on the way back");
        if let Some(there) = out[i] {
            apart.push((r.pose_wc.translation.vector - there.translation.vector).norm());
        }
    }
    apart.sort_by(f64::total_cmp);
    let mean = apart.iter().sum::<f64>() / apart.len() as f64;
    let p90 = apart[apart.len() * 9 / 10];
    eprintln!(
        "same image, way out against way back: mean {:.1} mm, p90 {:.1} mm over {}",
        1e3 * mean,
        1e3 * p90,
        apart.len()
    );
    assert!(apart.len() >= 290, "{} frames compared", apart.len());
    assert!(mean < 0.010, "mean {mean:.4} m apart");
    assert!(p90 < 0.020, "p90 {p90:.4} m apart");
}
