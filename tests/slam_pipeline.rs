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
