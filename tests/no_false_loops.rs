//! People must never close a loop: on the shared sequence with people
//! synthesised over it (passing in front of the scene, and hidden by it:
//! `just synth-people`'s sequences), with the ground-truth masks and
//! without any mask (the people's features then reach the map: a person
//! seen at two places matches a consistent rigid transform, which the
//! spread test refuses), and monocular too (a similarity, its inliers
//! judged by reprojection), every loop `slam-bench` accepts (loop closing is on by default)
//! must be a loop on the room: it brings the two keyframes it joins closer
//! to how the ground truth says they stand (a loop on people joins them by
//! where a person was, which has nothing to do with the camera's drift).
//! fr1_rpy turns on the spot, so the camera does see the same static room
//! again, and without masks the people drag the map off: measured after
//! the joint rolling-shutter estimate came in, two such loops were closed
//! (people in front: 110 inliers, the pair 0.337 m / 13.3 deg off the
//! truth before the correction, 0.010 m / 0.6 deg after; people hidden: 34
//! inliers, none of them on a person's pixels, 0.279 m / 7.4 deg before,
//! 0.122 m / 3.2 deg after). Before that build none was accepted here.

mod common;
use common::*;
use std::path::Path;
use std::process::Command;

use nalgebra::Isometry3;
use slam_core::io::trajectory::Trajectory;

/// The loops `slam-bench` (loop closing on by default) closes on `dataset`, as the
/// timestamps of the two keyframes each joins, with the summary line.
/// `slam-bench` on `dataset` writing its trajectory to `out`
/// (and the loop-corrected one beside it): the loops' keyframe stamps, the
/// summary line and, monocular, the Sim(3) scale.
fn loops_closed(
    dataset: &Path,
    masks: bool,
    monocular: bool,
    out: &Path,
) -> (Vec<(f64, f64)>, String, Option<f64>) {
    let mut cmd = Command::new(bin_dir().join("slam-bench"));
    cmd.arg(dataset);
    if masks {
        cmd.arg("--masks");
    }
    if monocular {
        cmd.arg("--monocular");
    }
    let out = cmd.arg("--out").arg(out).output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let line = stdout
        .lines()
        .find(|l| l.starts_with("loop closing:"))
        .unwrap_or_else(|| panic!("no loop line in {stdout}"))
        .to_string();
    // "  loop: keyframe 20 (t 1305031233.662) with 9 (t 1305031231.626), ..."
    let stamps = stdout
        .lines()
        .filter(|l| l.trim_start().starts_with("loop: keyframe"))
        .map(|l| {
            let t: Vec<f64> = l
                .split("(t ")
                .skip(1)
                .map(|s| s.split(')').next().unwrap().parse().unwrap())
                .collect();
            (t[0], t[1])
        })
        .collect();
    // Monocular: the Sim(3) alignment's scale ("..., scale 2.4906)").
    let scale = stdout
        .lines()
        .find(|l| l.starts_with("ATE rmse") && l.contains("scale"))
        .and_then(|l| l.split("scale ").nth(1))
        .and_then(|s| s.trim_end_matches(')').split(')').next())
        .and_then(|s| s.parse().ok());
    (stamps, line, scale)
}

/// How far the corrected trajectory's relative pose between `a` and `b`
/// is from the ground truth's (metres, degrees).
fn relative_error(
    truth: &Trajectory,
    corrected: &Trajectory,
    (a, b): (f64, f64),
    scale: f64,
) -> (f64, f64) {
    let pose = |t: &Trajectory, at: f64| -> Isometry3<f64> {
        t.interpolate(at, 0.02)
            .unwrap_or_else(|| panic!("no pose at {at}"))
    };
    let relative = |t: &Trajectory, s: f64| {
        let r = pose(t, a).inverse() * pose(t, b);
        Isometry3::from_parts((r.translation.vector * s).into(), r.rotation)
    };
    let error = relative(truth, 1.0).inverse() * relative(corrected, scale);
    (
        error.translation.vector.norm(),
        error.rotation.angle().to_degrees(),
    )
}

/// Runs `job` on each item, two at a time (the runs are lockstep, so
/// their results do not depend on the load; one slam-bench leaves the
/// second core mostly idle), and returns the results in the items' order.
fn two_at_a_time<T: Sync, R: Send>(items: &[T], job: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..2 {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                let Some(item) = items.get(i) else { break };
                let r = job(item);
                results.lock().unwrap().push((i, r));
            });
        }
    });
    let mut results = results.into_inner().unwrap();
    results.sort_by_key(|(i, _)| *i);
    results.into_iter().map(|(_, r)| r).collect()
}

#[test]
fn people_never_close_a_loop() {
    let dir = scratch("no-false-loops");
    let truth = Trajectory::load_tum(&shared_tum().join("groundtruth.txt")).unwrap();
    let occlusions = ["none", "scene"];
    two_at_a_time(&occlusions, |occlusion| {
        let seq = dir.join(format!("people-{occlusion}"));
        let o = Command::new(dynslam())
            .arg("synth")
            .arg(shared_tum())
            .arg(&seq)
            .args(["--objects", "3", "--seed", "5", "--occlusion", occlusion])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    });
    let mut runs = Vec::new();
    for occlusion in occlusions {
        for (masks, monocular) in [(true, false), (false, false), (true, true), (false, true)] {
            runs.push((occlusion, masks, monocular));
        }
    }
    let results = two_at_a_time(&runs, |&(occlusion, masks, monocular)| {
        let seq = dir.join(format!("people-{occlusion}"));
        let out = seq.join(format!("bench_masks{masks}_monocular{monocular}.txt"));
        let closed = loops_closed(&seq, masks, monocular, &out);
        (out, closed)
    });
    for (&(occlusion, masks, monocular), (out, (loops, line, scale))) in runs.iter().zip(results) {
        eprintln!("people ({occlusion} occlusion), masks {masks}, monocular {monocular}: {line}");
        if loops.is_empty() {
            continue;
        }
        let live = Trajectory::load_tum(&out).unwrap();
        let corrected = Trajectory::load_tum(&out.with_extension("loop_corrected.txt")).unwrap();
        let scale = scale.unwrap_or(1.0);
        for pair in loops {
            let (m0, deg0) = relative_error(&truth, &live, pair, scale);
            let (m, deg) = relative_error(&truth, &corrected, pair, scale);
            eprintln!(
                "  loop between {:.3} and {:.3}: the pair {m0:.3} m / {deg0:.2} deg off the ground truth before, {m:.3} m / {deg:.2} deg after",
                pair.0, pair.1
            );
            assert!(
                m < m0 && deg < deg0,
                "a false loop ({occlusion} occlusion, masks {masks}, monocular {monocular}): \
                 keyframes at {:.3} and {:.3} moved away from the ground truth \
                 ({m0:.3} m / {deg0:.2} deg -> {m:.3} m / {deg:.2} deg)",
                pair.0,
                pair.1
            );
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}
