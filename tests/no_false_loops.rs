//! People must never close a loop: on the shared sequence with people
//! synthesised over it (passing in front of the scene, and hidden by it:
//! `just synth-people`'s sequences), `slam-bench --loop-closing` accepts no
//! loop, with the ground-truth masks and without any mask (the people's
//! features then reach the map: a person seen at two places matches a
//! consistent rigid transform, which the spread test refuses); monocular
//! too (a similarity, its inliers judged by reprojection).

mod common;
use common::*;
use std::process::Command;

fn loops_closed(dataset: &std::path::Path, masks: bool, monocular: bool) -> (usize, String) {
    let mut cmd = Command::new(bin_dir().join("slam-bench"));
    cmd.arg(dataset).arg("--loop-closing");
    if masks {
        cmd.arg("--masks");
    }
    if monocular {
        cmd.arg("--monocular");
    }
    let out = cmd
        .arg("--out")
        .arg(dataset.join("bench_trajectory.txt"))
        .output()
        .unwrap();
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
    let n = line
        .split_whitespace()
        .nth(2)
        .and_then(|n| n.parse().ok())
        .unwrap();
    (n, line)
}

#[test]
fn people_never_close_a_loop() {
    let dir = scratch("no-false-loops");
    for occlusion in ["none", "scene"] {
        let seq = dir.join(format!("people-{occlusion}"));
        let o = Command::new(dynslam())
            .arg("synth")
            .arg(shared_tum())
            .arg(&seq)
            .args(["--objects", "3", "--seed", "5", "--occlusion", occlusion])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        for (masks, monocular) in [(true, false), (false, false), (true, true), (false, true)] {
            let (n, line) = loops_closed(&seq, masks, monocular);
            eprintln!(
                "people ({occlusion} occlusion), masks {masks}, monocular {monocular}: {line}"
            );
            assert_eq!(n, 0, "a loop closed on people: {line}");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}
