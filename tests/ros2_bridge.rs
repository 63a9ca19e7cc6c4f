//! The ROS 2 bridge against ROS 2 clients we did not write (PyPI:
//! eclipse-zenoh as the router and a raw subscriber, rosbags decoding the CDR
//! and computing the RIHS01 type hashes from its Jazzy store, zenoh-ros2-sdk
//! as a ROS 2 node), over real TCP links on loopback.

mod common;
use common::*;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::time::{Duration, Instant};

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};
use serde_json::Value;

/// The Python of `.cache/ros2-venv` (the ROS 2 test clients).
fn ros2_python() -> PathBuf {
    venv_python("ros2-venv", "ros2py")
}

/// The tests of this file run one at a time: several are real-time runs
/// (tracked frames and latency depend on the two cores being theirs), and
/// every one starts a whole pipeline.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// tests/ros2/client.py in one of its modes, running until `finish`.
struct PyClient {
    child: Child,
    stdin: Option<ChildStdin>,
    out: PathBuf,
}

impl PyClient {
    fn start(mode: &str, endpoint: &str, out: &Path, extra: &[&str]) -> Self {
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/ros2/client.py");
        let mut child = Command::new(ros2_python())
            .arg(script)
            .arg(mode)
            .args(["--endpoint", endpoint, "--out"])
            .arg(out)
            .args(extra)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start the Python client");
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        assert_eq!(line.trim(), "ready", "the {mode} client did not start");
        let stdin = child.stdin.take();
        Self {
            child,
            stdin,
            out: out.to_path_buf(),
        }
    }

    /// Closes its stdin (it writes its record and exits) and reads the record.
    fn finish(mut self) -> Value {
        drop(self.stdin.take());
        let status = self.child.wait().unwrap();
        assert!(status.success(), "the Python client failed: {status}");
        serde_json::from_str(&std::fs::read_to_string(&self.out).unwrap()).unwrap()
    }
}

/// The trajectory file's poses: (timestamp, [tx ty tz qx qy qz qw]).
fn trajectory(run_dir: &Path) -> Vec<(f64, [f64; 7])> {
    std::fs::read_to_string(run_dir.join("trajectory.txt"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            (v[0], [v[1], v[2], v[3], v[4], v[5], v[6], v[7]])
        })
        .collect()
}

/// The SLAM's camera pose as REP-103 puts the base (the default mounting:
/// optical axes, no offset): the optical x right / y down / z forward become
/// the base's -y / -z / x, in the map (the base at the first frame) too.
fn expected_base_pose(camera: &[f64; 7]) -> (Vector3<f64>, UnitQuaternion<f64>) {
    #[rustfmt::skip]
    let m = Matrix3::new(
        0.0, 0.0, 1.0,
        -1.0, 0.0, 0.0,
        0.0, -1.0, 0.0,
    );
    let t = m * Vector3::new(camera[0], camera[1], camera[2]);
    let r = UnitQuaternion::from_quaternion(Quaternion::new(
        camera[6], camera[3], camera[4], camera[5],
    ))
    .to_rotation_matrix();
    let r = m * r.matrix() * m.transpose();
    (t, UnitQuaternion::from_matrix(&r))
}

fn as_pose(v: &Value) -> (Vector3<f64>, UnitQuaternion<f64>) {
    let p: Vec<f64> = v
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    (
        Vector3::new(p[0], p[1], p[2]),
        UnitQuaternion::from_quaternion(Quaternion::new(p[6], p[3], p[4], p[5])),
    )
}

fn stamp(v: &Value) -> f64 {
    v[0].as_f64().unwrap() + v[1].as_f64().unwrap() * 1e-9
}

fn samples<'a>(record: &'a Value, topic: &str) -> &'a [Value] {
    record["samples"][topic]
        .as_array()
        .map(Vec::as_slice)
        .unwrap_or(&[])
}

fn attachment_seqs(samples: &[Value]) -> Vec<i64> {
    samples
        .iter()
        .map(|s| s["attachment"]["seq"].as_i64().unwrap())
        .collect()
}

/// `dynslam run` of the shared sequence's first `limit` frames with the
/// bridge on; `toml` is the run's config (the bridge's connection in it).
fn bridge_run(dir: &Path, toml: &str, name: &str, limit: usize) -> RunResult {
    let config = write_config(dir, toml);
    let run_id = format!("{name}{}", std::process::id());
    let run = run(
        &shared_tum(),
        &config,
        &dir.join("runs"),
        &run_id,
        &["--ros2", "--limit", &limit.to_string()],
    );
    assert!(run.success(), "{}", run.stderr());
    run
}

/// A service's entry in a run's status.json.
fn service_entry<'a>(status: &'a Value, service: &str) -> &'a Value {
    status["children"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["service"] == service)
        .unwrap_or_else(|| panic!("no {service} in {status}"))
}

#[test]
fn ros2_clients_we_did_not_write_get_every_tracked_pose_of_a_real_run() {
    let _serial = one_at_a_time();
    let dir = scratch("ros2-bridge");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    // A hand-held camera: the map frame's z = 0 is the camera's height at
    // the start, so the grid's band takes in the desk below it.
    let router = PyClient::start(
        "listen",
        &endpoint,
        &dir.join("listen.json"),
        &["--grid-band", "-1.0", "1.0", "--late-joiner"],
    );
    let msgs = dir.join("msgs");
    let sdk = PyClient::start(
        "sdk",
        &endpoint,
        &dir.join("sdk.json"),
        &["--msgs", msgs.to_str().unwrap()],
    );
    // The product's defaults (real models, lockstep), the bridge pointed at
    // the test's router.
    let toml = format!(
        "[bridge]\nconnect = [\"{endpoint}\"]\nmask_image = true\ngrid_min_height = -1.0\ngrid_max_height = 1.0\n"
    );
    let run = bridge_run(&dir, &toml, "ros2", 90);
    let sdk = sdk.finish();
    let got = router.finish();
    assert_eq!(
        got["errors"],
        Value::Array(vec![]),
        "rosbags could not read every sample"
    );

    // Every type hash in the keys is the RIHS01 rosbags computes.
    let hashes = got["hashes"].as_object().unwrap();
    for ty in [
        "nav_msgs/msg/Odometry",
        "tf2_msgs/msg/TFMessage",
        "nav_msgs/msg/Path",
        "geometry_msgs/msg/PoseArray",
        "diagnostic_msgs/msg/DiagnosticArray",
        "std_msgs/msg/String",
        "sensor_msgs/msg/Image",
        "sensor_msgs/msg/PointCloud2",
        "nav_msgs/msg/OccupancyGrid",
    ] {
        let h = &hashes[ty];
        assert_eq!(h["key"], h["rosbags"], "{ty}: {h}");
    }

    // Every tracked frame's odometry, exactly once, in order, equal to
    // trajectory.txt in REP-103 axes.
    let traj = trajectory(&run.run_dir);
    assert!(traj.len() >= 85, "only {} of 90 frames tracked", traj.len());
    let odom = samples(&got, "/dynslam/odometry");
    assert_eq!(odom.len(), traj.len(), "one odometry per tracked frame");
    let seqs = attachment_seqs(odom);
    assert_eq!(seqs, (1..=traj.len() as i64).collect::<Vec<_>>());
    for (o, (t, cam)) in odom.iter().zip(&traj) {
        assert!((stamp(&o["stamp"]) - t).abs() < 2e-6, "{o} vs {t}");
        assert_eq!(o["frame_id"], "map");
        assert_eq!(o["child_frame_id"], "base_link");
        assert_eq!(o["attachment"]["len"], 33);
        let (pos, rot) = as_pose(&o["pose"]);
        let (want_pos, want_rot) = expected_base_pose(cam);
        assert!((pos - want_pos).norm() < 1e-6, "{pos} vs {want_pos}");
        assert!(rot.angle_to(&want_rot) < 1e-6);
    }
    // /tf: map -> base_link with the same stamps and poses.
    let tf = samples(&got, "/tf");
    assert_eq!(tf.len(), odom.len());
    for (t, o) in tf.iter().zip(odom) {
        let tr = &t["transforms"][0];
        assert_eq!(tr["frame_id"], "map");
        assert_eq!(tr["child_frame_id"], "base_link");
        assert_eq!(tr["stamp"], o["stamp"]);
        let (a, ra) = as_pose(&tr["pose"]);
        let (b, rb) = as_pose(&o["pose"]);
        assert!((a - b).norm() < 1e-12 && ra.angle_to(&rb) < 1e-9);
    }
    let statics = samples(&got, "/tf_static");
    assert!(!statics.is_empty());
    assert_eq!(
        statics[0]["transforms"][0]["child_frame_id"],
        "camera_optical_frame"
    );
    // The path ends with every tracked frame; the keyframes are there.
    let path = samples(&got, "/dynslam/path");
    assert_eq!(path.last().unwrap()["poses"], traj.len());
    let keyframes = samples(&got, "/dynslam/keyframes");
    assert!(!keyframes.is_empty());
    assert_eq!(samples(&got, "/dynslam/state")[0]["data"], "ok");

    // The map: a cloud after keyframes (x y z rgb, float32, in the map
    // frame), the keyframes again as the map holds them, and the occupancy
    // grid, whose occupied cells are those recomputed here from the cloud of
    // the same map.
    let clouds = samples(&got, "/dynslam/map_points");
    assert!(clouds.len() >= 2, "{} clouds", clouds.len());
    for c in clouds {
        assert_eq!(c["frame_id"], "map");
        assert_eq!(c["height"], 1);
        assert_eq!(c["point_step"], 16);
        assert_eq!(
            c["fields"],
            serde_json::json!([
                ["x", 0, 7, 1],
                ["y", 4, 7, 1],
                ["z", 8, 7, 1],
                ["rgb", 12, 7, 1]
            ])
        );
        assert_eq!(
            c["data_len"].as_u64(),
            Some(16 * c["width"].as_u64().unwrap())
        );
        assert_eq!(c["finite"], true);
    }
    let last_cloud = clouds.last().unwrap()["width"].as_u64().unwrap();
    assert!(last_cloud > 1000, "only {last_cloud} map points");
    let kf_arrays: Vec<u64> = keyframes
        .iter()
        .map(|k| k["poses"].as_u64().unwrap())
        .collect();
    assert!(kf_arrays.iter().any(|&n| n > 3), "{kf_arrays:?}");
    let grids = samples(&got, "/map");
    assert!(!grids.is_empty());
    for g in grids {
        assert_eq!(g["frame_id"], "map");
        assert!((g["resolution"].as_f64().unwrap() - 0.05).abs() < 1e-6);
        assert_eq!(
            g["data_len"].as_u64(),
            Some(g["width"].as_u64().unwrap() * g["height"].as_u64().unwrap())
        );
    }
    let last_grid = grids.last().unwrap();
    assert!(
        last_grid["occupied"].as_u64().unwrap() > 20 && last_grid["free"].as_u64().unwrap() > 20,
        "{last_grid}"
    );
    // The latched topics: a subscriber that joins late gets the last
    // sample from the publisher's cache at once (rmw_zenoh's transient
    // local), more than a plain subscriber joining with it.
    let late = &got["late_joiner"];
    for topic in ["tf_static", "map", "dynslam/map_points"] {
        let (cached, plain) = (
            late[topic]["cached"].as_u64(),
            late[topic]["plain"].as_u64(),
        );
        assert!(
            cached.unwrap_or(0) >= 1 && cached > plain,
            "{topic}: {cached:?} from the cache, {plain:?} plain"
        );
    }
    let checks = got["grid_checks"].as_array().unwrap();
    assert!(!checks.is_empty(), "no grid with its cloud");
    for c in checks {
        let (grid, mine, common) = (
            c["grid"].as_u64().unwrap() as f64,
            c["recomputed"].as_u64().unwrap() as f64,
            c["common"].as_u64().unwrap() as f64,
        );
        // Cells at a boundary may differ by the float rounding of a
        // coordinate; nothing else may.
        assert!(common >= 0.98 * grid.max(mine), "{c}");
    }
    // Diagnostics: the SLAM's figures and each service's state.
    let diag = samples(&got, "/diagnostics");
    assert!(!diag.is_empty());
    let names: Vec<&str> = diag
        .iter()
        .flat_map(|d| d["status"].as_array().unwrap())
        .map(|s| s["name"].as_str().unwrap())
        .collect();
    for want in ["/dynslam: slam", "/dynslam: segmenter", "/dynslam: bridge"] {
        assert!(names.contains(&want), "{want} not in {names:?}");
    }

    // The masks SLAM used: a mono8 label image for every tracked frame that
    // had masks, stamped as its frame.
    let masks = samples(&got, "/dynslam/masks");
    let masked = read_rows(&run.run_dir)
        .iter()
        .filter(|r| r["state"] == "ok" && r["mask_source"] != "none")
        .count();
    assert_eq!(
        masks.len(),
        masked,
        "one mask image per masked tracked frame"
    );
    for m in masks {
        assert_eq!(m["encoding"], "mono8");
        assert_eq!(
            (m["width"].as_u64(), m["height"].as_u64()),
            (Some(640), Some(480))
        );
        assert_eq!(m["data_len"], 640 * 480);
        assert_eq!(m["frame_id"], "camera_optical_frame");
        assert!(odom.iter().any(|o| o["stamp"] == m["stamp"]));
    }
    // The liveliness tokens parse as rmw_zenoh writes them.
    let tokens: Vec<&str> = got["tokens"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|t| t[0] == "SampleKind.PUT")
        .map(|t| t[1].as_str().unwrap())
        .collect();
    let node = tokens
        .iter()
        .find(|t| t.ends_with("/NN/%/%/dynslam"))
        .unwrap_or_else(|| panic!("no node token in {tokens:?}"));
    let zid = node.split('/').nth(2).unwrap();
    let odom_token = tokens
        .iter()
        .find(|t| t.contains("/MP/") && t.contains("%dynslam%odometry"))
        .unwrap();
    let parts: Vec<&str> = odom_token.split('/').collect();
    assert_eq!(parts.len(), 13, "{odom_token}");
    assert_eq!(&parts[..3], &["@ros2_lv", "0", zid]);
    assert_eq!(parts[10], "nav_msgs::msg::dds_::Odometry_");
    assert_eq!(
        parts[11],
        hashes["nav_msgs/msg/Odometry"]["rosbags"].as_str().unwrap()
    );
    assert_eq!(parts[12].split(':').count(), 6, "QoS part {}", parts[12]);

    // zenoh-ros2-sdk found the topic and, subscribing with the hash it
    // computed itself, got every odometry.
    let topics = sdk["topics"].as_array().unwrap();
    assert!(
        topics
            .iter()
            .any(|t| t[0] == "/dynslam/odometry" && t[1][0] == "nav_msgs/msg/Odometry"),
        "{topics:?}"
    );
    assert_eq!(
        sdk["subscriber_hash"],
        hashes["nav_msgs/msg/Odometry"]["rosbags"]
    );
    assert_eq!(sdk["received"].as_array().unwrap().len(), odom.len());
    assert_no_shm_left(&run.run_id);
}

/// The map services, called by zenoh-ros2-sdk's service client (a ROS 2
/// node we did not write) during a real run: a map saved by name, a name
/// that would leave the maps folder refused, localization mode on (no
/// keyframe while it is) and off, a reset (a new map).
#[test]
fn map_services_answer_a_ros2_client_and_a_name_never_leaves_the_maps_folder() {
    let _serial = one_at_a_time();
    let dir = scratch("ros2-services");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let router = PyClient::start("listen", &endpoint, &dir.join("listen.json"), &[]);
    let srv =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/ros2/dynslam_interfaces/srv/SaveMap.srv");
    let client = PyClient::start(
        "services",
        &endpoint,
        &dir.join("services.json"),
        &["--srv", srv.to_str().unwrap(), "--seconds", "240"],
    );
    let maps = dir.join("maps");
    let toml = format!(
        "[bridge]\nconnect = [\"{endpoint}\"]\nservices = true\nmaps_dir = \"{}\"\n",
        maps.display()
    );
    let run = bridge_run(&dir, &toml, "ros2srv", 160);
    let got = client.finish();
    let router = router.finish();

    // Listed as ROS 2 lists services, with the hashes the SDK computes.
    let listed = got["services"].as_array().unwrap();
    for (name, ty) in [
        ("/dynslam/save_map", "dynslam_interfaces/srv/SaveMap"),
        ("/dynslam/reset", "std_srvs/srv/Trigger"),
        ("/dynslam/set_localization_mode", "std_srvs/srv/SetBool"),
    ] {
        assert!(
            listed.iter().any(|s| s[0] == name && s[1][0] == ty),
            "{name} not in {listed:?}"
        );
        let token = router["tokens"]
            .as_array()
            .unwrap()
            .iter()
            .filter_map(|t| t[1].as_str())
            .find(|t| t.contains("/SS/") && t.contains(&name.replace('/', "%")))
            .unwrap_or_else(|| panic!("no service token for {name}"));
        assert_eq!(
            token.split('/').nth(11),
            got["hashes"][ty].as_str(),
            "{token}"
        );
    }

    let calls = got["calls"].as_array().unwrap();
    assert_eq!(calls.len(), 5, "{calls:?}");
    let (save, evil, on, off, reset) = (&calls[0], &calls[1], &calls[2], &calls[3], &calls[4]);
    for c in calls {
        assert!(c["success"].is_boolean(), "no response: {c}");
    }
    // Saved where it was told, a map file the SLAM reads back.
    assert_eq!(save["success"], true, "{save}");
    assert!(
        save["message"].as_str().unwrap().contains("office.map"),
        "{save}"
    );
    let saved = std::fs::read(maps.join("office.map")).unwrap();
    assert_eq!(&saved[..8], b"DSLAMMAP");
    // Refused, naming why; nothing written outside the maps folder.
    assert_eq!(evil["success"], false, "{evil}");
    assert!(
        evil["message"].as_str().unwrap().contains("map name"),
        "{evil}"
    );
    assert!(!dir.join("evil.map").exists() && !maps.join("evil.map").exists());
    assert_eq!(std::fs::read_dir(&maps).unwrap().count(), 1);

    // Tracked frames in order, as the odometry counted them.
    let rows: Vec<Row> = read_rows(&run.run_dir)
        .into_iter()
        .filter(|r| r["state"] == "ok" || r["state"] == "relocalised")
        .collect();
    let keyframes = |r: &Row| r["keyframes"].parse::<u64>().unwrap();
    let at = |c: &Value, key: &str| c[key].as_u64().unwrap() as usize;
    // Localization mode: no keyframe between its on and off (a frame or
    // two of margin: the odometry trails the SLAM).
    assert_eq!(
        (on["success"].clone(), off["success"].clone()),
        (true.into(), true.into())
    );
    let quiet = &rows[at(on, "at_response") + 2..at(off, "at_request").min(rows.len())];
    assert!(
        quiet.len() >= 30,
        "{} frames in localization mode",
        quiet.len()
    );
    assert!(
        quiet.iter().all(|r| r["keyframe"] == "0"),
        "a keyframe in localization mode"
    );
    assert!(rows[..at(on, "at_request")]
        .iter()
        .any(|r| r["keyframe"] == "1"));
    // Reset: a new map, its keyframe count starting again.
    assert_eq!(reset["success"], true, "{reset}");
    let before = keyframes(&rows[at(reset, "at_request").saturating_sub(1)]);
    let after = rows[at(reset, "at_response") + 2..]
        .iter()
        .map(keyframes)
        .min()
        .expect("frames after the reset");
    assert!(
        before > 5 && after < before,
        "keyframes {before} before the reset, {after} after"
    );
    assert_no_shm_left(&run.run_id);
}

/// Two robots on one router, namespaced: nothing of one shows under the other.
#[test]
fn two_namespaced_runs_on_one_router_do_not_mix() {
    let _serial = one_at_a_time();
    let dir = scratch("ros2-namespaces");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let router = PyClient::start("listen", &endpoint, &dir.join("listen.json"), &[]);
    let mut runs = Vec::new();
    for (robot, limit) in [("robot1", "30"), ("robot2", "45")] {
        let sub = dir.join(robot);
        std::fs::create_dir_all(&sub).unwrap();
        let config = write_config(
            &sub,
            &format!(
                "[bridge]\nconnect = [\"{endpoint}\"]\nnamespace = \"/{robot}\"\n[services.slam]\nbackend = \"scripted\"\nwork_ms = 10\n{NO_MASK_MODELS}"
            ),
        );
        let run_id = format!("{robot}-{}", std::process::id());
        let child = Command::new(dynslam())
            .arg("run")
            .arg(shared_tum())
            .arg("--config")
            .arg(&config)
            .arg("--output-dir")
            .arg(sub.join("runs"))
            .args(["--run-id", &run_id, "--ros2", "--limit", limit])
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        runs.push((robot, sub.join("runs").join(&run_id), child));
    }
    for (robot, _, child) in &mut runs {
        let (status, err) = child.wait_with_output_ref();
        assert!(status.success(), "{robot}: {err}");
    }
    let got = router.finish();
    let topics: Vec<&String> = got["samples"].as_object().unwrap().keys().collect();
    for (robot, run_dir, _) in &runs {
        let traj = trajectory(run_dir);
        let odom = samples(&got, &format!("/{robot}/dynslam/odometry"));
        assert_eq!(odom.len(), traj.len(), "{robot}: {topics:?}");
        assert_eq!(
            attachment_seqs(odom),
            (1..=traj.len() as i64).collect::<Vec<_>>()
        );
        for (o, (t, _)) in odom.iter().zip(&traj) {
            assert!((stamp(&o["stamp"]) - t).abs() < 2e-6);
        }
        assert_eq!(
            samples(&got, &format!("/{robot}/tf")).len(),
            traj.len(),
            "{robot}'s TF under its namespace"
        );
    }
    assert!(samples(&got, "/dynslam/odometry").is_empty());
    assert!(samples(&got, "/tf").is_empty());
    let tokens = got["tokens"].to_string();
    assert!(tokens.contains("/NN/%/%robot1/dynslam") && tokens.contains("/NN/%/%robot2/dynslam"));
}

trait WaitRef {
    fn wait_with_output_ref(&mut self) -> (std::process::ExitStatus, String);
}

impl WaitRef for Child {
    fn wait_with_output_ref(&mut self) -> (std::process::ExitStatus, String) {
        let mut err = String::new();
        if let Some(mut e) = self.stderr.take() {
            use std::io::Read;
            let _ = e.read_to_string(&mut err);
        }
        (self.wait().unwrap(), err)
    }
}

/// The bridge killed 10 times during a real-time run: every frame recorded
/// once, tracking goes on, and each topic's sequence numbers go on after
/// every restart (no frame published twice).
#[test]
fn killing_the_bridge_ten_times_loses_no_frame_and_its_topics_go_on() {
    let _serial = one_at_a_time();
    let dir = scratch("ros2-kills");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let router = PyClient::start("listen", &endpoint, &dir.join("listen.json"), &[]);
    let config = write_config(
        &dir,
        &format!(
            "[run]\nmode = \"realtime\"\n[supervisor]\nrestart_backoff_max_ms = 200\n[bridge]\nconnect = [\"{endpoint}\"]\ndiagnostics_period_s = 0.2\n[services.slam]\nbackend = \"scripted\"\nwork_ms = 5\n{NO_MASK_MODELS}"
        ),
    );
    let run_id = format!("ros2kill{}", std::process::id());
    let run_dir = dir.join("runs").join(&run_id);
    let mut child = Command::new(dynslam())
        .arg("run")
        .arg(shared_tum())
        .arg("--config")
        .arg(&config)
        .arg("--output-dir")
        .arg(dir.join("runs"))
        .args(["--run-id", &run_id, "--ros2"])
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let bridge_pid = |status: &Value| {
        status["children"]
            .as_array()?
            .iter()
            .find(|c| c["service"] == "bridge" && c["state"] == "ready")?["pid"]
            .as_u64()
    };
    let mut killed = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(60);
    while killed.len() < 10 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(150));
        let Ok(text) = std::fs::read_to_string(run_dir.join("status.json")) else {
            continue;
        };
        let Ok(status) = serde_json::from_str::<Value>(&text) else {
            continue;
        };
        if let Some(pid) = bridge_pid(&status) {
            if !killed.contains(&pid) && status["frames_done"].as_u64().unwrap_or(0) > 5 {
                unsafe { libc::kill(pid as i32, libc::SIGKILL) };
                killed.push(pid);
            }
        }
    }
    let (status, err) = child.wait_with_output_ref();
    assert_eq!(
        killed.len(),
        10,
        "killed only {killed:?} before the run ended"
    );
    assert!(status.success(), "{err}");
    let got = router.finish();

    let rows = read_rows(&run_dir);
    let mut seqs: Vec<u64> = rows.iter().map(|r| r["seq"].parse().unwrap()).collect();
    seqs.sort();
    assert_eq!(
        seqs,
        (0..300).collect::<Vec<_>>(),
        "every frame recorded once"
    );
    let tracked = rows.iter().filter(|r| r["state"] == "ok").count();
    assert!(tracked > 200, "tracking went on: {tracked} of 300 tracked");
    assert_eq!(
        service_entry(&read_status(&run_dir), "bridge")["restarts"],
        10
    );
    // Each topic's numbers only go up, across ten processes.
    for topic in ["/dynslam/odometry", "/tf", "/diagnostics"] {
        let s = attachment_seqs(samples(&got, topic));
        assert!(s.len() > 10, "{topic}: {s:?}");
        assert!(s.windows(2).all(|w| w[1] > w[0]), "{topic}: {s:?}");
    }
    let odom = samples(&got, "/dynslam/odometry");
    let stamps: Vec<f64> = odom.iter().map(|o| stamp(&o["stamp"])).collect();
    assert!(
        stamps.windows(2).all(|w| w[1] > w[0]),
        "no frame published twice"
    );
    // Most frames reached ROS 2 despite the kills (the pose stream keeps
    // its last 16 for a restarted bridge).
    assert!(
        odom.len() * 10 >= tracked * 8,
        "{} of {tracked}",
        odom.len()
    );
}

/// Zenoh is linked by the bridge and the remote workers' crate alone: the
/// other services' dependency trees stay as they were.
#[test]
fn zenoh_is_in_the_bridges_and_remote_workers_dependency_trees_only() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let tree = |package: &str| {
        let out = Command::new(env!("CARGO"))
            .current_dir(root)
            .args([
                "tree",
                "--offline",
                "--edges",
                "normal",
                "--prefix",
                "none",
                "-p",
                package,
            ])
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout).unwrap()
    };
    for package in [
        "camera-reader",
        "segmenter",
        "propagator",
        "slam",
        "supervisor",
        "pipeline",
        "shared-types",
    ] {
        let t = tree(package);
        assert!(
            !t.lines().any(|l| l.starts_with("zenoh")),
            "{package} depends on zenoh"
        );
    }
    for package in ["bridge", "remote"] {
        assert!(tree(package).lines().any(|l| l.starts_with("zenoh ")));
    }
}

/// REP-105 with the robot's own odometry: a robot (rosbags serialising)
/// publishes odom -> base_link on /tf, with hostile samples among them; the
/// SLAM publishes map -> odom such that map -> odom -> base_link is its
/// pose, and drops the hostile samples with a counted warning.
#[test]
fn with_the_robots_odometry_the_slam_owns_map_to_odom_and_drops_hostile_samples() {
    let _serial = one_at_a_time();
    let dir = scratch("ros2-odom");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let rgb_txt = shared_tum().join("rgb.txt");
    let router = PyClient::start(
        "listen",
        &endpoint,
        &dir.join("listen.json"),
        &["--publish-odom", rgb_txt.to_str().unwrap()],
    );
    let toml = format!(
        "[bridge]\nconnect = [\"{endpoint}\"]\nodom_frame = \"odom\"\ndiagnostics_period_s = 0.3\n[services.slam]\nbackend = \"scripted\"\nwork_ms = 20\n{NO_MASK_MODELS}"
    );
    let run = bridge_run(&dir, &toml, "ros2odom", 60);
    let got = router.finish();
    let status = read_status(&run.run_dir);
    assert_eq!(
        service_entry(&status, "bridge")["restarts"],
        0,
        "hostile samples never kill the bridge"
    );
    assert!(
        run.stderr().contains("samples on /tf dropped so far"),
        "no counted warning"
    );

    // The robot's odometry as the publisher made it (tests/ros2/client.py).
    let first = std::fs::read_to_string(&rgb_txt)
        .unwrap()
        .lines()
        .find(|l| !l.starts_with('#') && !l.trim().is_empty())
        .and_then(|l| l.split_whitespace().next()?.parse::<f64>().ok())
        .unwrap();
    let odom_t_base = |t: f64| {
        nalgebra::Isometry3::from_parts(
            nalgebra::Translation3::new(0.2 * (t - first), 0.05, 0.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3),
        )
    };
    let iso = |v: &Value| {
        let (t, r) = as_pose(v);
        nalgebra::Isometry3::from_parts(t.into(), r)
    };
    let odom = samples(&got, "/dynslam/odometry");
    assert_eq!(odom.len(), 60);
    let ours: Vec<&Value> = samples(&got, "/tf")
        .iter()
        .filter_map(|s| s["transforms"].as_array())
        .flatten()
        .filter(|t| t["frame_id"] == "map")
        .collect();
    assert!(ours.iter().all(|t| t["child_frame_id"] == "odom"));
    assert!(
        ours.len() >= 54,
        "map -> odom for {} of 60 frames",
        ours.len()
    );
    for t in &ours {
        let o = odom
            .iter()
            .find(|o| o["stamp"] == t["stamp"])
            .expect("an odometry at the transform's stamp");
        let map_t_base = iso(&t["pose"]) * odom_t_base(stamp(&t["stamp"]));
        let want = iso(&o["pose"]);
        assert!(
            (map_t_base.translation.vector - want.translation.vector).norm() < 1e-6
                && map_t_base.rotation.angle_to(&want.rotation) < 1e-6,
            "map -> odom -> base_link is not the odometry at {}",
            t["stamp"]
        );
    }
    // The diagnostics count what was dropped, by reason.
    let last = samples(&got, "/diagnostics").last().unwrap().clone();
    let slam = last["status"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["name"] == "/dynslam: slam")
        .unwrap()
        .clone();
    let refused = slam["values"]["refused_messages"].as_str().unwrap();
    assert!(
        refused.contains("wrong type") && refused.contains("unreadable CDR"),
        "{refused}"
    );
}

/// Makes a CA and two certificates it signs (the router's for "localhost",
/// the bridge's with common name "dynslam-bridge"), with openssl.
fn test_certificates(dir: &Path) {
    common::test_certificates(
        dir,
        &[
            ("router", "localhost", "DNS:localhost,IP:127.0.0.1"),
            ("bridge", "dynslam-bridge", "DNS:dynslam-bridge"),
        ],
    );
}

/// The bridge over mutual TLS with the router's access control, on
/// loopback, with the shipped example configurations.
#[test]
fn the_bridge_publishes_over_mutual_tls_with_the_shipped_examples() {
    let _serial = one_at_a_time();
    let dir = scratch("ros2-tls");
    test_certificates(&dir);
    let port = free_port();
    let router_config = shipped_zenoh_config("router-mtls.json5", &dir, port);
    let bridge_config = shipped_zenoh_config("bridge-mtls.json5", &dir, port);
    let router = PyClient::start(
        "listen",
        "unused",
        &dir.join("listen.json"),
        &["--config", router_config.to_str().unwrap()],
    );
    let toml = format!(
        "[bridge]\nzenoh_config = \"{}\"\n[services.slam]\nbackend = \"scripted\"\nwork_ms = 10\n{NO_MASK_MODELS}",
        bridge_config.display()
    );
    let run = bridge_run(&dir, &toml, "ros2tls", 30);
    let got = router.finish();
    let odom = samples(&got, "/dynslam/odometry");
    assert_eq!(odom.len(), 30, "{}", run.stderr());
    assert_eq!(attachment_seqs(odom), (1..=30).collect::<Vec<_>>());
}

/// ROS 2 cameras in: a Python driver (rosbags serialising) plays the shared
/// TUM frames as rgb8 Image + 32FC1 depth + CameraInfo; a `source.kind =
/// "ros2"` run takes its intrinsics from the CameraInfo, tracks >= 98 % of
/// the frames, and its ATE is within 10 % of the file source's at the same
/// rate (both real time, the product's models).
#[test]
fn a_ros2_camera_in_tracks_like_the_file_source() {
    let _serial = one_at_a_time();
    let dir = scratch("ros2-in");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let frames = 150;
    let player = PyClient::start(
        "play",
        &endpoint,
        &dir.join("played.json"),
        &[
            "--tum",
            shared_tum().to_str().unwrap(),
            "--limit",
            &frames.to_string(),
            "--fps",
            "10",
        ],
    );
    let ros2_dir = dir.join("ros2");
    std::fs::create_dir_all(&ros2_dir).unwrap();
    let config = write_config(
        &ros2_dir,
        &format!(
            "[run]\nmode = \"realtime\"\n[source]\nkind = \"ros2\"\n[source.ros2]\nend_after_idle_s = 3.0\n[bridge]\nconnect = [\"{endpoint}\"]\n"
        ),
    );
    let run_id = format!("ros2in{}", std::process::id());
    let out = Command::new(dynslam())
        .arg("run")
        .arg("--config")
        .arg(&config)
        .arg("--output-dir")
        .arg(ros2_dir.join("runs"))
        .args(["--run-id", &run_id])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let played = player.finish();
    assert_eq!(played["published"].as_array().unwrap().len(), frames);
    let run_dir = ros2_dir.join("runs").join(&run_id);
    // The intrinsics came from the CameraInfo.
    let cfg = pipeline::config::PipelineConfig::load(&run_dir.join("config.toml")).unwrap();
    assert_eq!(cfg.camera.fx, 517.306408);
    assert_eq!(cfg.camera.distortion[4], 1.163314);
    let rows = read_rows(&run_dir);
    let tracked = rows.iter().filter(|r| r["state"] == "ok").count();
    assert!(
        tracked * 100 >= frames * 98,
        "{tracked} of {frames} tracked; {} rows",
        rows.len()
    );
    let gt = shared_tum().join("groundtruth.txt");
    let ros2_ate = json_f64(
        &eval_json(&gt, &run_dir.join("trajectory.txt"), &[]),
        "ate_rmse_m",
    );
    // The file source at the same rate (10 fps: a third of the recorded 30).
    let file_dir = dir.join("file");
    std::fs::create_dir_all(&file_dir).unwrap();
    let file_config = write_config(
        &file_dir,
        "[run]\nmode = \"realtime\"\nspeed = 0.3333333333333333\n",
    );
    let file = run(
        &shared_tum(),
        &file_config,
        &file_dir.join("runs"),
        &format!("ros2file{}", std::process::id()),
        &["--limit", &frames.to_string()],
    );
    assert!(file.success(), "{}", file.stderr());
    let file_ate = json_f64(
        &eval_json(&gt, &file.run_dir.join("trajectory.txt"), &[]),
        "ate_rmse_m",
    );
    eprintln!(
        "ROS 2 in: {tracked}/{frames} tracked, ATE {ros2_ate:.4} m; file source {file_ate:.4} m"
    );
    assert!(
        ros2_ate <= file_ate * 1.1,
        "ATE {ros2_ate:.4} m from ROS 2 against {file_ate:.4} m from the files"
    );
}

/// No CameraInfo on the configured topic: the run fails at once with an
/// error naming the topic (no service started, no crash loop).
#[test]
fn a_ros2_camera_without_camera_info_fails_naming_the_topic() {
    let _serial = one_at_a_time();
    let dir = scratch("ros2-no-info");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let router = PyClient::start("listen", &endpoint, &dir.join("listen.json"), &[]);
    let config = write_config(
        &dir,
        &format!(
            "[run]\nmode = \"realtime\"\n[source]\nkind = \"ros2\"\n[source.ros2]\ncamera_info_topic = \"front/camera_info\"\ncamera_info_timeout_s = 1.0\n[bridge]\nconnect = [\"{endpoint}\"]\nnamespace = \"/robot7\"\n"
        ),
    );
    let started = Instant::now();
    let out = Command::new(dynslam())
        .arg("run")
        .arg("--config")
        .arg(&config)
        .arg("--output-dir")
        .arg(dir.join("runs"))
        .output()
        .unwrap();
    router.finish();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("no sensor_msgs/CameraInfo on /robot7/front/camera_info within 1 s"),
        "{stderr}"
    );
    assert!(started.elapsed() < Duration::from_secs(20));
}
