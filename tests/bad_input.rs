//! Bad input: each case gives a clear error naming the thing and the
//! problem, nothing panics, the other processes keep going, and what was
//! written so far stays intact.

mod common;
use common::*;

use std::path::Path;

fn id(tag: &str) -> String {
    format!("{tag}{}", std::process::id())
}

const SCRIPTED: &str = "[services.slam]\nbackend = \"scripted\"\n\
     [services.segmenter]\nbackend = \"none\"\n[services.propagator]\nbackend = \"none\"\n";

/// Runs a 12-frame copy of the shared sequence after `damage`, expecting the
/// run to complete with frame 5 skipped for the reason `expect` names.
fn run_with_damaged_frame(tag: &str, damage: impl FnOnce(&Path), expect: &[&str]) {
    run_with_damaged_frame_at(tag, 5, damage, expect)
}

/// The same with frame `bad` damaged.
fn run_with_damaged_frame_at(tag: &str, bad: usize, damage: impl FnOnce(&Path), expect: &[&str]) {
    let dir = scratch(tag);
    let tum = small_tum(&dir, 12);
    damage(&tum);
    let config = write_config(&dir, SCRIPTED);
    let run = run(&tum, &config, &dir.join("runs"), &id(tag), &[]);
    let stderr = run.stderr();
    assert!(
        run.success(),
        "one bad frame must not stop the run:\n{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    let rows = read_rows(&run.run_dir);
    assert_eq!(rows.len(), 12, "every frame has a row");
    for (i, r) in rows.iter().enumerate() {
        if i == bad {
            assert_eq!(r["state"], "skipped", "{r:?}");
            assert_eq!(r["route"], "skip");
            for e in expect {
                assert!(r["note"].contains(e), "note '{}' lacks '{e}'", r["note"]);
                assert!(stderr.contains(e), "log lacks '{e}':\n{stderr}");
            }
        } else {
            assert_eq!(r["state"], "ok", "frame {i}: {r:?}");
        }
    }
    assert_no_shm_left(&run.run_id);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn corrupt_png_is_skipped_and_named() {
    run_with_damaged_frame(
        "corrupt",
        |tum| std::fs::write(rgb_file(tum, 5), b"\x89PNG\r\n\x1a\nthis is no image data").unwrap(),
        &["corrupt or truncated PNG"],
    );
}

#[test]
fn truncated_png_is_skipped_and_named() {
    let mut name = String::new();
    run_with_damaged_frame(
        "truncated",
        |tum| {
            let f = rgb_file(tum, 5);
            name = f.file_name().unwrap().to_string_lossy().into_owned();
            let bytes = std::fs::read(&f).unwrap();
            std::fs::write(&f, &bytes[..bytes.len() / 3]).unwrap();
        },
        &["corrupt or truncated PNG", "rgb/"],
    );
}

#[test]
fn a_directory_in_place_of_a_frame_is_skipped_and_named() {
    run_with_damaged_frame(
        "dirframe",
        |tum| {
            let f = rgb_file(tum, 5);
            std::fs::remove_file(&f).unwrap();
            std::fs::create_dir(&f).unwrap();
        },
        &["is a directory, not an image file", "rgb/"],
    );
}

#[test]
fn missing_depth_file_is_skipped_and_named() {
    run_with_damaged_frame(
        "nodepth",
        |tum| std::fs::remove_file(depth_file(tum, 5)).unwrap(),
        &["depth/", "cannot open"],
    );
}

#[test]
fn frame_of_the_wrong_size_is_skipped_and_named() {
    run_with_damaged_frame(
        "wrongsize",
        |tum| {
            let small = image::RgbImage::from_pixel(320, 240, image::Rgb([90, 120, 150]));
            small.save(rgb_file(tum, 5)).unwrap();
        },
        &["frame is 320x240", "expected 640x480"],
    );
}

/// An odd first frame does not decide the sequence's size (it used to: all
/// the valid frames after it were skipped and the run "completed").
#[test]
fn an_odd_first_frame_is_skipped_not_the_sequence() {
    run_with_damaged_frame_at(
        "oddfirst",
        0,
        |tum| {
            let small = image::RgbImage::from_pixel(320, 240, image::Rgb([90, 120, 150]));
            small.save(rgb_file(tum, 0)).unwrap();
        },
        &["frame is 320x240", "expected 640x480"],
    );
}

/// Runs and expects a failure whose message contains every `expect`.
fn expect_failure(
    dataset: &Path,
    config: &Path,
    out: &Path,
    tag: &str,
    expect: &[&str],
) -> RunResult {
    let run = run(dataset, config, out, &id(tag), &[]);
    let stderr = run.stderr();
    assert!(!run.success(), "must fail:\n{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    for e in expect {
        assert!(stderr.contains(e), "error lacks '{e}':\n{stderr}");
    }
    run
}

#[test]
fn malformed_rgb_list_names_file_and_line() {
    let dir = scratch("malformed");
    let tum = small_tum(&dir, 6);
    let list = tum.join("rgb.txt");
    let mut text = std::fs::read_to_string(&list).unwrap();
    text.push_str("this-is-not-a-line\n");
    std::fs::write(&list, text).unwrap();
    let config = write_config(&dir, SCRIPTED);
    let run = expect_failure(
        &tum,
        &config,
        &dir.join("runs"),
        "malformed",
        &["rgb.txt line 8", "camera-reader"],
    );
    // The other services were stopped in order and nothing is left over.
    assert_no_shm_left(&run.run_id);
    assert!(processes_mentioning(&run.run_id).is_empty());
    // The run folder records what happened.
    let status: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.run_dir.join("status.json")).unwrap())
            .unwrap();
    assert_eq!(status["state"], "failed");
    assert!(status["error"].as_str().unwrap().contains("rgb.txt line 8"));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn unsorted_rgb_list_names_both_lines() {
    let dir = scratch("unsorted");
    let tum = small_tum(&dir, 6);
    let list = tum.join("rgb.txt");
    let text = std::fs::read_to_string(&list).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    lines.swap(3, 4);
    std::fs::write(&list, lines.join("\n") + "\n").unwrap();
    let config = write_config(&dir, SCRIPTED);
    expect_failure(
        &tum,
        &config,
        &dir.join("runs"),
        "unsorted",
        &["rgb.txt line 5", "line 4", "sorted"],
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn missing_dataset_folder_is_named() {
    let dir = scratch("nodata");
    let config = write_config(&dir, SCRIPTED);
    expect_failure(
        Path::new("/no/such/dataset"),
        &config,
        &dir.join("runs"),
        "nodata",
        &["dataset folder /no/such/dataset does not exist"],
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn malformed_config_names_file_and_key() {
    let dir = scratch("badconfig");
    let config = write_config(
        &dir,
        "[run]\nmode = \"lockstep\"\n[services.slam]\nkeyframe_evry = 3\n",
    );
    expect_failure(
        &shared_tum(),
        &config,
        &dir.join("runs"),
        "badconfig",
        &[
            config.to_str().unwrap(),
            "services.slam",
            "keyframe_evry",
            "line 4",
        ],
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn worker_that_exits_at_start_is_given_up_on_and_the_run_goes_on_unmasked() {
    let dir = scratch("deadworker");
    let tum = small_tum(&dir, 10);
    let config = write_config(
        &dir,
        "[services.slam]\nbackend = \"scripted\"\n\
         [services.segmenter]\ncommand = [\"/bin/sh\", \"-c\", \"echo 'ERROR segmenter: model file missing' >&2; exit 3\", \"sh\"]\n\
         [services.propagator]\nbackend = \"none\"\n\
         [supervisor]\nrestart_backoff_initial_ms = 10\nrestart_backoff_max_ms = 40\nrestart_limit = 3\n",
    );
    let run = run(&tum, &config, &dir.join("runs"), &id("deadworker"), &[]);
    let stderr = run.stderr();
    assert_eq!(
        run.output.status.code(),
        Some(3),
        "a dead segmenter does not stop the run, it degrades it (exit 3):\n{stderr}"
    );
    assert!(stderr.contains("segmenter died 4 times"), "{stderr}");
    assert!(stderr.contains("giving up on it"), "{stderr}");
    assert!(
        stderr.contains("model file missing"),
        "the service's own error is quoted:\n{stderr}"
    );
    let rows = read_rows(&run.run_dir);
    assert_eq!(rows.len(), 10);
    for r in &rows {
        assert_eq!(r["state"], "ok");
        assert_eq!(r["route"], "skip");
        assert!(r["note"].contains("unmasked"), "{r:?}");
    }
    assert_no_shm_left(&run.run_id);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn slam_that_exits_at_start_fails_the_run_with_its_name() {
    let dir = scratch("deadslam");
    let tum = small_tum(&dir, 5);
    let config = write_config(
        &dir,
        "[services.slam]\ncommand = [\"/bin/false\"]\n\
         [services.segmenter]\nbackend = \"none\"\n[services.propagator]\nbackend = \"none\"\n\
         [supervisor]\nrestart_backoff_initial_ms = 10\nrestart_backoff_max_ms = 40\nrestart_limit = 2\n",
    );
    let run = expect_failure(
        &tum,
        &config,
        &dir.join("runs"),
        "deadslam",
        &["slam died 3 times", "exit code 1"],
    );
    assert_no_shm_left(&run.run_id);
    assert!(processes_mentioning(&run.run_id).is_empty());
    std::fs::remove_dir_all(&dir).ok();
}

/// Map files a user can give are checked before any process starts: a
/// file that is no map, a missing one, localization without a map, a map
/// for a SLAM that keeps none, a map made with another camera or sensor. Each error
/// names the file or flag and the problem, and no run folder is made.
#[test]
fn bad_map_files_and_flags_are_refused_before_start() {
    let dir = scratch("badmaps");
    let tum = small_tum(&dir, 3);
    let config = write_config(&dir, "");
    let garbage = dir.join("garbage.map");
    // The current format version (3), then nonsense.
    std::fs::write(
        &garbage,
        b"DSLAMMAP\x03\x00\x00\x00 but then nothing sensible",
    )
    .unwrap();
    let ply = dir.join("points.ply");
    std::fs::write(&ply, b"ply\nformat ascii 1.0\nend_header\n").unwrap();
    // A real map, of the fr1 camera.
    let map = dir.join("fr1.map");
    let saved = run(
        &tum,
        &config,
        &dir.join("runs"),
        "mapok",
        &["--save-map", map.to_str().unwrap()],
    );
    assert!(saved.success(), "{}", saved.stderr());
    let garbage_s = garbage.to_str().unwrap();
    let cases: Vec<(Vec<&str>, &str, Vec<String>)> = vec![
        (
            vec!["--load-map", garbage_s],
            "",
            vec![format!("map file {garbage_s}"), "truncated".into()],
        ),
        (
            vec!["--load-map", ply.to_str().unwrap()],
            "",
            vec!["not a dynslam map file".into()],
        ),
        (
            vec!["--load-map", "/nonexistent/a.map"],
            "",
            vec!["map file /nonexistent/a.map".into()],
        ),
        (
            vec!["--localize-only"],
            "",
            vec!["--localize-only needs a map".into()],
        ),
        (
            vec!["--save-map", "/nonexistent/dir/a.map"],
            "",
            vec![
                "--save-map /nonexistent/dir/a.map".into(),
                "does not exist".into(),
            ],
        ),
        (
            vec!["--load-map", map.to_str().unwrap()],
            "[services.slam]\nbackend = \"scripted\"\n",
            vec!["need the orb-rgbd SLAM".into()],
        ),
        (
            vec!["--load-map", map.to_str().unwrap(), "--camera", "tum-fr2"],
            "",
            vec![
                "made with another camera".into(),
                "fx is 517.306408 in the map".into(),
            ],
        ),
        (
            vec!["--load-map", map.to_str().unwrap(), "--sensor", "monocular"],
            "",
            vec![
                "made with another sensor".into(),
                "rgbd in the map, monocular in this run".into(),
            ],
        ),
    ];
    for (i, (flags, extra, expected)) in cases.into_iter().enumerate() {
        let cfg_dir = dir.join(format!("c{i}"));
        std::fs::create_dir_all(&cfg_dir).unwrap();
        let cfg = write_config(&cfg_dir, extra);
        let id = format!("badmap{i}");
        let r = run(&tum, &cfg, &dir.join("runs"), &id, &flags);
        let err = r.stderr();
        assert_eq!(r.output.status.code(), Some(1), "case {i} {flags:?}: {err}");
        for e in &expected {
            assert!(
                err.contains(e.as_str()),
                "case {i} {flags:?}: no '{e}' in:\n{err}"
            );
        }
        assert!(!err.contains("panicked"), "{err}");
        assert!(!r.run_dir.exists(), "case {i}: a run folder was made");
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// A disk that fills up mid-run (the run folder on a 256 KB tmpfs, mounted
/// in a private user and mount namespace: no root needed): the run fails
/// with exit 1 and an error naming the file and the cause, status.json says
/// `failed` with that error, no temporary file stays behind, the services
/// are gone and nothing of the run is left in /dev/shm.
#[test]
fn a_full_disk_mid_run_fails_the_run_cleanly() {
    let dir = scratch("fulldisk");
    let config = write_config(&dir, SCRIPTED);
    let seen = dir.join("seen");
    std::fs::create_dir_all(&seen).unwrap();
    let small = dir.join("small");
    std::fs::create_dir_all(&small).unwrap();
    let run_id = id("fulldisk");
    // Inside the namespace: mount, run, then copy out what the test checks
    // (the tmpfs goes with the namespace).
    let script = format!(
        "set -u; mount -t tmpfs -o size=256k tmpfs '{small}' || exit 97; \
         '{dynslam}' run '{tum}' --config '{config}' --output-dir '{small}' --run-id {run_id} \
           2> '{seen}/stderr'; echo $? > '{seen}/rc'; \
         cp '{small}/{run_id}/status.json' '{seen}/' ; ls -a '{small}/{run_id}' > '{seen}/listing'; \
         df -k '{small}' > '{seen}/df'",
        small = small.display(),
        dynslam = dynslam().display(),
        tum = shared_tum().display(),
        config = config.display(),
        seen = seen.display(),
    );
    let o = std::process::Command::new("unshare")
        .args(["--user", "--map-root-user", "--mount", "sh", "-c", &script])
        .output()
        .expect("unshare (util-linux) runs");
    assert!(
        o.status.success(),
        "the namespace could not be set up (rc {:?}): {}",
        o.status.code(),
        String::from_utf8_lossy(&o.stderr)
    );
    let read = |f: &str| std::fs::read_to_string(seen.join(f)).unwrap_or_default();
    let stderr = read("stderr");
    assert_eq!(read("rc").trim(), "1", "exit 1 on a full disk:\n{stderr}");
    assert!(
        stderr.contains("No space left on device"),
        "the cause is named:\n{stderr}"
    );
    assert!(stderr.contains(&run_id), "the file is named:\n{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    let status: serde_json::Value = serde_json::from_str(&read("status.json"))
        .unwrap_or_else(|e| panic!("status.json: {e}\n{stderr}"));
    assert_eq!(status["state"], "failed", "{status}");
    assert!(
        status["error"]
            .as_str()
            .is_some_and(|e| e.contains("No space left on device")),
        "{status}"
    );
    let listing = read("listing");
    assert!(
        !listing.lines().any(|f| f.ends_with(".tmp")),
        "temporary files left behind:\n{listing}"
    );
    assert_no_shm_left(&run_id);
    assert!(
        processes_mentioning(&run_id).is_empty(),
        "processes of the run outlived it"
    );
    std::fs::remove_dir_all(&dir).ok();
}
