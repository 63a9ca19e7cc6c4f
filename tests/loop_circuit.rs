//! Loop closing on a rendered circuit (scenes::room, `CameraPath::Circuit`):
//! the camera goes once round the room looking out at the walls and comes
//! back to where it started, long after the start left the local map. And
//! monocular on the rendered orbit (`CameraPath::Orbit`, round the room
//! looking in), where the loop is a similarity (Sim(3)).

mod common;
use common::*;
use scenes::room::{render_room, CameraPath, RoomOptions};
use slam_core::eval::{evaluate, Alignment, EvalOptions};
use slam_core::io::trajectory::Trajectory;
use slam_core::{Camera, SlamParams, System};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// 15 s at 30 fps: 0.8 deg of turn per frame.
const FRAMES: usize = 450;

/// `path`, rendered once (per path) for the tests of this file.
fn rendered(path: CameraPath) -> &'static Path {
    static CIRCUIT: OnceLock<PathBuf> = OnceLock::new();
    static ORBIT: OnceLock<PathBuf> = OnceLock::new();
    let (cell, name) = match path {
        CameraPath::Orbit => (&ORBIT, "orbit"),
        _ => (&CIRCUIT, "circuit"),
    };
    cell.get_or_init(|| {
        // A scratch folder per path: scratch() empties its folder, and the
        // two renders run in parallel tests.
        let seq = scratch(&format!("loop-{name}")).join(name);
        let t = std::time::Instant::now();
        let opts = RoomOptions {
            frames: FRAMES,
            path,
            ..Default::default()
        };
        render_room(&seq, &Camera::tum_fr1(), &opts).unwrap();
        eprintln!(
            "rendered {FRAMES} frames of the {name} in {:.1} s",
            t.elapsed().as_secs_f64()
        );
        seq
    })
}

fn circuit() -> &'static Path {
    rendered(CameraPath::Circuit)
}

/// Tracks the circuit with `features` ORB features per frame (fewer:
/// more drift): ATE of the final trajectory (frames follow their keyframes
/// through a correction), and the loops closed.
fn track(
    dir: &Path,
    loop_closing: bool,
    features: usize,
) -> (f64, Vec<slam_core::loop_closing::LoopClosure>) {
    let truth = Trajectory::load_tum(&dir.join("groundtruth.txt")).unwrap();
    let mut params = SlamParams {
        loop_closing,
        ..Default::default()
    };
    params.orb.features = features;
    let mut sys = System::new(params, Camera::tum_fr1());
    for t in &truth.stamps {
        let name = format!("{t:.6}.png");
        let rgb = image::open(dir.join("rgb").join(&name)).unwrap().to_rgb8();
        let depth = image::open(dir.join("depth").join(&name))
            .unwrap()
            .into_luma16();
        sys.track_rgbd(rgb.as_raw(), depth.as_raw(), None, 640, 480, *t);
    }
    let trajectory = sys.trajectory();
    assert_eq!(trajectory.len(), FRAMES, "every frame tracked");
    let ate = evaluate(&truth, &trajectory, EvalOptions::default())
        .unwrap()
        .ate_rmse_m;
    eprintln!(
        "{}, {features} features, loop closing {loop_closing}: ATE {ate:.4} m, {} keyframes, \
         loops {:?}",
        dir.display(),
        sys.map().live_keyframes().count(),
        sys.loops()
    );
    (ate, sys.loops().to_vec())
}

/// The loop is found where the path closes (the last keyframes with the
/// first ones) and corrected (essential graph, then global bundle
/// adjustment on the loop-closing thread, merged). With 1000 features there
/// is little drift and the correction does no harm (ATE within 10 %;
/// measured 0.0087 -> 0.0074 m); with 250 features the circuit drifts and
/// the corrected trajectory must be at most 0.7x (measured 0.0307 -> 0.0096
/// m, 0.31x; with the essential graph alone it was 0.76x of an earlier
/// build's 0.0130 m).
#[test]
fn a_closed_circuit_is_detected_and_corrected() {
    let seq = circuit();
    for (features, bound) in [(1000, 1.1), (250, 0.7)] {
        let (off, none) = track(seq, false, features);
        let (on, loops) = track(seq, true, features);
        eprintln!(
            "{features} features: ATE {off:.4} -> {on:.4} m ({:.2}x)",
            on / off
        );
        assert!(none.is_empty());
        assert_eq!(loops.len(), 1, "one loop, where the path closes: {loops:?}");
        assert!(
            loops[0].matched <= 2 && loops[0].keyframe + 5 >= 45,
            "{loops:?}"
        );
        assert!(
            on <= bound * off,
            "{features} features: {on:.4} vs {off:.4} m"
        );
    }
}

/// RGB-D on the orbit (round the room looking in across it) with 250
/// features: the loop closes where the path does and the corrected
/// trajectory is no worse than without loop closing. Its keyframes see few
/// close points; the global bundle adjustment once left out the far ones and
/// moved such keyframes by 4-42 cm (measured 0.0211 -> 0.0817 m); with
/// them, as parallax-only measurements, 0.0211 -> 0.0146 m.
#[test]
fn an_orbit_with_few_close_points_is_corrected_without_harm() {
    let seq = rendered(CameraPath::Orbit);
    let (off, none) = track(seq, false, 250);
    let (on, loops) = track(seq, true, 250);
    eprintln!(
        "orbit, 250 features: ATE {off:.4} -> {on:.4} m ({:.2}x)",
        on / off
    );
    assert!(none.is_empty());
    assert_eq!(loops.len(), 1, "one loop, where the path closes: {loops:?}");
    assert!(on <= off, "{on:.4} vs {off:.4} m");
}

/// Monocular on the orbit at the default 1000 features (before tracking
/// searched the last frame's points first the map's scale collapsed while
/// it turned and this took 2000, docs/design.md): the loop closes where
/// the path does, as a similarity, and the trajectory corrected by it (the
/// Sim(3) essential graph, then global bundle adjustment) is at most 0.7x
/// the one without loop closing (slam-bench: 0.0169 -> 0.0056 m, the
/// loop's scale 0.98; Sim(3)-aligned, as a monocular trajectory has no
/// metric scale).
#[test]
fn a_monocular_orbit_closes_its_loop_with_a_similarity() {
    let dir = rendered(CameraPath::Orbit);
    let truth = Trajectory::load_tum(&dir.join("groundtruth.txt")).unwrap();
    let mut ates = Vec::new();
    for loop_closing in [false, true] {
        let mut params = SlamParams::monocular();
        params.loop_closing = loop_closing;
        // Inline: the same figures on every machine (the loop thread's
        // timing moves where a correction lands).
        params.mapping_thread = false;
        let mut sys = System::new(params, Camera::tum_fr1());
        let mut tracked = 0;
        for t in &truth.stamps {
            let name = format!("{t:.6}.png");
            let rgb = image::open(dir.join("rgb").join(&name)).unwrap().to_rgb8();
            let r = sys.track_monocular(rgb.as_raw(), None, 640, 480, *t);
            tracked += r.state.is_tracked() as usize;
        }
        let options = EvalOptions {
            alignment: Alignment::Sim3,
            ..Default::default()
        };
        let ate = evaluate(&truth, &sys.trajectory(), options)
            .unwrap()
            .ate_rmse_m;
        let loops = sys.loops().to_vec();
        eprintln!(
            "orbit, monocular, loop closing {loop_closing}: {tracked}/{FRAMES} tracked, ATE \
             {ate:.4} m, loops {loops:?}"
        );
        assert!(tracked >= FRAMES * 95 / 100, "{tracked} of {FRAMES}");
        if loop_closing {
            assert_eq!(loops.len(), 1, "one loop, where the path closes: {loops:?}");
            let keyframes = sys.map().live_keyframes().count();
            assert!(
                loops[0].matched <= 3 && loops[0].keyframe + 5 >= keyframes,
                "{loops:?} of {keyframes} keyframes"
            );
        } else {
            assert!(loops.is_empty());
        }
        ates.push(ate);
    }
    eprintln!(
        "orbit, monocular: ATE {:.4} -> {:.4} m ({:.2}x)",
        ates[0],
        ates[1],
        ates[1] / ates[0]
    );
    assert!(ates[1] <= 0.7 * ates[0], "{ates:?}");
}

/// The whole pipeline with the default configuration, loop closing on (mask
/// workers off: nothing moves in the room): the loop closure lands in the
/// run folder's `loops.csv`, report.md counts it and evaluates the
/// loop-corrected trajectory the SLAM wrote at stop.
#[test]
fn the_pipeline_records_the_loop_in_loops_csv() {
    let seq = circuit();
    let dir = scratch("loop-pipeline");
    let config = write_config(&dir, NO_MASK_MODELS);
    let r = run(
        seq,
        &config,
        &dir.join("runs"),
        &format!("loops{}", std::process::id()),
        &["--camera", "tum-fr1"],
    );
    assert!(r.success(), "{}", r.stderr());
    let csv = std::fs::read_to_string(r.run_dir.join("loops.csv")).unwrap();
    eprintln!("{csv}");
    let rows: Vec<&str> = csv.lines().skip(1).collect();
    assert_eq!(rows.len(), 1, "{csv}");
    let matched: usize = rows[0].split(',').nth(2).unwrap().parse().unwrap();
    assert!(matched <= 2, "{csv}");
    let report = std::fs::read_to_string(r.run_dir.join("report.md")).unwrap();
    assert!(report.contains("`loops.csv`: 1 loop closures"), "{report}");
    // The SLAM wrote the trajectory with the correction applied, and the
    // report evaluates it next to the live one.
    let corrected = Trajectory::load_tum(&r.run_dir.join("trajectory_loop_corrected.txt")).unwrap();
    assert!(corrected.len() >= FRAMES * 9 / 10, "{}", corrected.len());
    assert!(
        report.contains("With the loop corrections applied to every frame"),
        "{report}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
