//! Loop closing on the real TUM sequence (../shared): no false loop on the
//! sequence played forward, and what a revisit (played forward, then
//! backward) does.

mod common;
use common::{load, tum};
use slam_core::eval::{evaluate, EvalOptions};
use slam_core::io::trajectory::Trajectory;
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
