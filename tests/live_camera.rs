//! A live V4L2 camera (`source.kind = "v4l2"`): this machine has none, so
//! what runs here is `dynslam run` meeting a camera that is not there or a
//! node that is not a camera. Each ends the run at once, before any service
//! starts, with an error naming the device and what to do; nothing is left
//! in shared memory. The
//! pixel formats are tested on camera byte layouts in the live-camera
//! crate's `convert` tests.

mod common;
use common::*;

fn camera_run(tag: &str, device: &str) -> (RunResult, String) {
    let dir = scratch(tag);
    let run_id = format!("{tag}{}", std::process::id());
    let config = write_config(
        &dir,
        &format!(
            "[run]\nmode = \"realtime\"\n[source]\nkind = \"v4l2\"\n[source.v4l2]\ndevice = \"{device}\"\n\
             [services.slam]\nsensor = \"monocular\"\n{NO_MASK_MODELS}"
        ),
    );
    let output = std::process::Command::new(dynslam())
        .args(["run", "--config"])
        .arg(&config)
        .arg("--output-dir")
        .arg(dir.join("runs"))
        .args(["--run-id", &run_id])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    (
        RunResult {
            output,
            run_dir: dir.join("runs").join(&run_id),
            run_id,
        },
        stderr,
    )
}

#[test]
fn a_missing_camera_fails_the_run_naming_the_device() {
    let (run, stderr) = camera_run("nocam", "/dev/video-dynslam-test");
    assert_eq!(run.output.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("camera /dev/video-dynslam-test: no such device")
            && stderr.contains("source.v4l2.device"),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(
        !stderr.contains("started slam"),
        "checked before the models load: {stderr}"
    );
    assert_no_shm_left(&run.run_id);
}

#[test]
fn a_node_that_is_not_a_camera_fails_the_run_saying_so() {
    let (run, stderr) = camera_run("notcam", "/dev/null");
    assert_eq!(run.output.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("camera /dev/null: not a V4L2 video capture device"),
        "{stderr}"
    );
    assert_no_shm_left(&run.run_id);
}

/// `dynslam cameras` lists the capture nodes, or says there are none (this
/// machine has none; a camera's line is formatted like the ones in the
/// README).
#[test]
fn the_cameras_command_lists_what_is_there() {
    let out = std::process::Command::new(dynslam())
        .arg("cameras")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let video_nodes = std::fs::read_dir("/dev")
        .unwrap()
        .filter_map(|e| e.ok())
        .any(|e| e.file_name().to_string_lossy().starts_with("video"));
    if video_nodes {
        assert!(!text.trim().is_empty());
    } else {
        assert!(text.contains("no V4L2 capture device under /dev"), "{text}");
    }
}
