//! Real time with a segmenter much slower than the camera: tracking does not
//! wait for it. Every frame is tracked with the propagator's masks, one frame
//! at a time is segmented in the background, and every segmenter result is
//! used (it re-prompts the propagator) instead of being thrown away.

mod common;
use common::*;

/// `name: N` in the pipeline's log (the services' exit summaries).
fn logged_count(log: &str, name: &str) -> Option<u64> {
    let at = log.rfind(name)? + name.len();
    log[at..]
        .trim_start_matches([':', ' '])
        .split(|c: char| !c.is_ascii_digit())
        .next()?
        .parse()
        .ok()
}

#[test]
fn a_segmenter_slower_than_five_frame_periods_does_not_starve_tracking() {
    let dir = scratch("slow-segmenter");
    // 30 fps: a frame period is 33 ms; the segmenter takes 200 ms (6
    // periods). The SLAM double takes 5 ms: it could track every frame.
    let config = write_config(
        &dir,
        "[services.slam]\nbackend = \"scripted\"\nwork_ms = 5\nkeyframe_every = 3\n\
         [services.segmenter]\nbackend = \"none\"\nwork_ms = 200\n\
         [services.propagator]\nbackend = \"lk\"\n",
    );
    let frames = 90;
    let run = run(
        &shared_tum(),
        &config,
        &dir.join("runs"),
        &format!("slowseg{}", std::process::id()),
        &["--mode", "realtime", "--limit", &frames.to_string()],
    );
    assert!(run.success(), "{}", run.stderr());
    let rows = read_rows(&run.run_dir);
    assert_eq!(rows.len(), frames, "every frame has a row");
    let tracked: Vec<_> = rows.iter().filter(|r| r["state"] == "ok").collect();
    assert!(
        tracked.len() * 100 >= frames * 80,
        "tracked {} of {frames} frames: a slow segmenter must not starve tracking",
        tracked.len()
    );
    // Masks on every tracked frame (the propagator's, or the segmenter's on
    // the first one).
    let unmasked = tracked
        .iter()
        .filter(|r| r["mask_source"] == "none")
        .count();
    assert_eq!(unmasked, 0, "tracked frames without masks");
    let behind = rows
        .iter()
        .filter(|r| r["route"] == "segment-behind")
        .count();
    assert!(behind >= 3, "frames segmented in the background: {behind}");
    // No segmenter result is thrown away: each one prompted the propagator
    // (the last may be published while the propagator is being stopped).
    let log = run.stderr();
    let published = logged_count(&log, "segmenter: masks published").expect("segmenter summary");
    let used = logged_count(&log, "segmenter prompts used").expect("propagator summary");
    let ignored = logged_count(&log, "ignored (image gone)").expect("propagator summary");
    assert_eq!(
        ignored, 0,
        "segmenter results ignored by the propagator\n{log}"
    );
    assert!(
        used + 1 >= published && published >= 3,
        "segmenter results: {published} published, {used} used"
    );
    // It started at the supervisor's priority (the first masks are what
    // every stage waits for) and took its niceness once the SLAM tracked.
    assert!(
        log.contains("segmenter now runs at niceness 5"),
        "no niceness applied\n{log}"
    );
    assert_no_shm_left(&run.run_id);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_slam_far_slower_than_the_camera_makes_the_reader_leave_frames_out() {
    let dir = scratch("slow-slam");
    // 30 fps, SLAM 150 ms per frame: decoding every frame would only burn
    // CPU; the reader leaves frames out once 3 decoded ones wait.
    let config = write_config(
        &dir,
        &format!("[services.slam]\nbackend = \"scripted\"\nwork_ms = 150\n{NO_MASK_MODELS}"),
    );
    let frames = 60;
    let run = run(
        &shared_tum(),
        &config,
        &dir.join("runs"),
        &format!("slowslam{}", std::process::id()),
        &["--mode", "realtime", "--limit", &frames.to_string()],
    );
    assert!(run.success(), "{}", run.stderr());
    let rows = read_rows(&run.run_dir);
    let mut seqs: Vec<u64> = rows.iter().map(|r| r["seq"].parse().unwrap()).collect();
    seqs.sort_unstable();
    assert_eq!(
        seqs,
        (0..frames as u64).collect::<Vec<_>>(),
        "one row per frame"
    );
    let left_out = rows
        .iter()
        .filter(|r| r["note"].contains("left out by the camera-reader"))
        .count();
    let tracked = rows.iter().filter(|r| r["state"] == "ok").count();
    assert!(left_out > 10, "frames left out undecoded: {left_out}");
    assert!(tracked >= 8, "tracked {tracked}");
    assert!(rows
        .iter()
        .filter(|r| r["note"].contains("left out"))
        .all(|r| r["state"] == "dropped"));
    assert_no_shm_left(&run.run_id);
    std::fs::remove_dir_all(&dir).ok();
}
