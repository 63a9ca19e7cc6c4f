//! The pipeline configuration (`configs/pipeline.toml`).
//!
//! One file describes a whole run: the source, the clock mode, routing,
//! restart policy and each service's backend. The supervisor reads it, copies
//! the resolved file into the run folder and hands that copy to every child,
//! so all processes of a run (and a resumed run) see the same settings.
//! Unknown keys are errors that name their path (`services.slam.keyframe_evry`):
//! a typo must never silently fall back to a default on a robot.

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct PipelineConfig {
    #[serde(default)]
    pub run: RunConfig,
    #[serde(default)]
    pub source: SourceConfig,
    #[serde(default)]
    pub routing: RoutingConfig,
    #[serde(default)]
    pub supervisor: SupervisorConfig,
    #[serde(default)]
    pub services: ServicesConfig,
    #[serde(default)]
    pub onnxruntime: OnnxRuntimeConfig,
    #[serde(default)]
    pub camera: CameraConfig,
    #[serde(default)]
    pub bridge: BridgeConfig,
}

/// The ROS 2 bridge (`[bridge]`): the run's poses, TF, path, state and
/// diagnostics as ROS 2 topics in rmw_zenoh's wire format (README "ROS 2").
/// Off the frame path: its death never stops tracking.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct BridgeConfig {
    /// Start the bridge with the run (`dynslam run --ros2`).
    pub enabled: bool,
    /// Replace the bridge's program (as a service's `command`).
    pub command: Vec<String>,
    /// A Zenoh JSON5 configuration file (TLS, mutual TLS, access control,
    /// several endpoints): used as it is, `mode` and `connect` are then
    /// not applied. Empty: rmw_zenoh's session defaults below.
    pub zenoh_config: Option<PathBuf>,
    /// Zenoh session mode: "peer" (rmw_zenoh's nodes) or "client".
    pub mode: String,
    /// Where the Zenoh router is (`ros2 run rmw_zenoh_cpp rmw_zenohd`).
    pub connect: Vec<String>,
    /// ROS_DOMAIN_ID of the topics (0..=232, as ROS 2 allows).
    pub domain_id: u32,
    /// The node's namespace ("" or "/robot1"): several robots on one
    /// network. Relative topic names resolve under it.
    pub namespace: String,
    /// The node's name (`ros2 node list`).
    pub node_name: String,
    /// "ros": poses in REP-103 axes (the map frame is the base frame at the
    /// first tracked frame: x forward, z up); "optical": the SLAM's own
    /// world frame (the first camera's optical axes: z forward, y down).
    pub world_frame: String,
    pub map_frame: String,
    /// The robot's odometry frame when it publishes `odom -> base_frame`
    /// on tf: the SLAM then publishes `map -> odom` (REP-105); empty: the
    /// SLAM publishes `map -> base_frame`.
    pub odom_frame: String,
    pub base_frame: String,
    pub camera_frame: String,
    /// The camera's mounting, base_frame -> camera_frame (metres, and
    /// roll pitch yaw in radians as `static_transform_publisher` takes
    /// them). Default: at the base's origin, optical axes (z forward).
    pub camera_xyz: [f64; 3],
    pub camera_rpy: [f64; 3],
    /// Topic names: relative ones resolve under the namespace.
    pub odometry_topic: String,
    pub path_topic: String,
    pub keyframes_topic: String,
    pub state_topic: String,
    /// The masks SLAM tracked each frame with, as a mono8 label image
    /// (0 background, i + 1 instance i) on `mask_topic`; off by default
    /// (300 KB a frame).
    pub mask_image: bool,
    pub mask_topic: String,
    pub tf_topic: String,
    pub tf_static_topic: String,
    pub diagnostics_topic: String,
    /// Seconds between publications of the path and of the diagnostics.
    pub path_period_s: f64,
    pub diagnostics_period_s: f64,
    /// The map's points as `sensor_msgs/PointCloud2` on `map_cloud_topic`,
    /// and the keyframes as the map holds them (moved by bundle adjustment
    /// and loops), after keyframes, at most once per `map_period_s` (and
    /// after every closed loop).
    pub map_cloud: bool,
    pub map_cloud_topic: String,
    pub map_period_s: f64,
    /// A `nav_msgs/OccupancyGrid` (Nav2) on `grid_topic` with each map:
    /// points between `grid_min_height` and `grid_max_height` above the
    /// map frame's z = 0 are obstacles (`world_frame = "ros"` only).
    pub grid: bool,
    pub grid_topic: String,
    pub grid_resolution: f64,
    pub grid_min_height: f64,
    pub grid_max_height: f64,
    /// Points a cell needs to be occupied.
    pub grid_min_points: u32,
    /// The services `save_map`, `reset` and `set_localization_mode` (off
    /// unless enabled: they change the map from the network).
    pub services: bool,
    /// Where `save_map` writes (a name from the network never leaves it).
    pub maps_dir: PathBuf,
}

impl Default for BridgeConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            command: Vec::new(),
            zenoh_config: None,
            mode: "peer".into(),
            connect: vec!["tcp/localhost:7447".into()],
            domain_id: 0,
            namespace: String::new(),
            node_name: "dynslam".into(),
            world_frame: "ros".into(),
            map_frame: "map".into(),
            odom_frame: String::new(),
            base_frame: "base_link".into(),
            camera_frame: "camera_optical_frame".into(),
            camera_xyz: [0.0; 3],
            camera_rpy: [
                -std::f64::consts::FRAC_PI_2,
                0.0,
                -std::f64::consts::FRAC_PI_2,
            ],
            odometry_topic: "dynslam/odometry".into(),
            path_topic: "dynslam/path".into(),
            keyframes_topic: "dynslam/keyframes".into(),
            state_topic: "dynslam/state".into(),
            mask_image: false,
            mask_topic: "dynslam/masks".into(),
            tf_topic: "tf".into(),
            tf_static_topic: "tf_static".into(),
            diagnostics_topic: "/diagnostics".into(),
            path_period_s: 1.0,
            diagnostics_period_s: 1.0,
            map_cloud: true,
            map_cloud_topic: "dynslam/map_points".into(),
            map_period_s: 1.0,
            grid: true,
            grid_topic: "map".into(),
            grid_resolution: 0.05,
            grid_min_height: 0.1,
            grid_max_height: 1.5,
            grid_min_points: 2,
            services: false,
            maps_dir: PathBuf::from("maps"),
        }
    }
}

impl BridgeConfig {
    /// Checks names and numbers as ROS 2 would (rcl's name rules, in short).
    pub fn validate(&self) -> Result<(), String> {
        if !matches!(self.mode.as_str(), "peer" | "client") {
            return Err(format!(
                "key `bridge.mode`: \"{}\" is not a Zenoh session mode for a node (\"peer\" or \"client\")",
                self.mode
            ));
        }
        if self.zenoh_config.is_none() && self.connect.is_empty() {
            return Err("key `bridge.connect`: empty; name the Zenoh router (\"tcp/localhost:7447\") or give bridge.zenoh_config".into());
        }
        if self.domain_id > 232 {
            return Err(format!(
                "key `bridge.domain_id`: {} is not a ROS 2 domain id (0..=232)",
                self.domain_id
            ));
        }
        if !matches!(self.world_frame.as_str(), "ros" | "optical") {
            return Err(format!(
                "key `bridge.world_frame`: \"{}\" is neither \"ros\" (REP-103: x forward, z up) nor \"optical\" (the camera's: z forward)",
                self.world_frame
            ));
        }
        if !self.namespace.is_empty() {
            let inner = self.namespace.strip_prefix('/').ok_or_else(|| {
                format!(
                    "key `bridge.namespace`: \"{}\" must start with '/' (\"/robot1\")",
                    self.namespace
                )
            })?;
            ros_name("bridge.namespace", inner, true)?;
        }
        ros_name("bridge.node_name", &self.node_name, false)?;
        for (key, frame) in [
            ("bridge.map_frame", &self.map_frame),
            ("bridge.base_frame", &self.base_frame),
            ("bridge.camera_frame", &self.camera_frame),
        ] {
            ros_name(key, frame, true)?;
        }
        if !self.odom_frame.is_empty() {
            ros_name("bridge.odom_frame", &self.odom_frame, true)?;
        }
        for (key, topic) in [
            ("bridge.odometry_topic", &self.odometry_topic),
            ("bridge.path_topic", &self.path_topic),
            ("bridge.keyframes_topic", &self.keyframes_topic),
            ("bridge.state_topic", &self.state_topic),
            ("bridge.mask_topic", &self.mask_topic),
            ("bridge.tf_topic", &self.tf_topic),
            ("bridge.tf_static_topic", &self.tf_static_topic),
            ("bridge.diagnostics_topic", &self.diagnostics_topic),
            ("bridge.map_cloud_topic", &self.map_cloud_topic),
            ("bridge.grid_topic", &self.grid_topic),
        ] {
            ros_name(key, topic.strip_prefix('/').unwrap_or(topic), true)?;
        }
        for (key, v) in [
            ("bridge.camera_xyz", self.camera_xyz),
            ("bridge.camera_rpy", self.camera_rpy),
        ] {
            if v.iter().any(|x| !x.is_finite()) {
                return Err(format!(
                    "key `{key}`: {v:?} has a value that is not a number"
                ));
            }
        }
        in_range(
            "bridge.path_period_s",
            self.path_period_s,
            0.05,
            3600.0,
            "a period in seconds",
        )?;
        in_range(
            "bridge.diagnostics_period_s",
            self.diagnostics_period_s,
            0.05,
            3600.0,
            "a period in seconds",
        )?;
        in_range(
            "bridge.map_period_s",
            self.map_period_s,
            0.05,
            3600.0,
            "a period in seconds",
        )?;
        in_range(
            "bridge.grid_resolution",
            self.grid_resolution,
            0.005,
            10.0,
            "metres per cell",
        )?;
        for (key, v) in [
            ("bridge.grid_min_height", self.grid_min_height),
            ("bridge.grid_max_height", self.grid_max_height),
        ] {
            in_range(key, v, -100.0, 100.0, "a height in metres")?;
        }
        if self.grid_min_height >= self.grid_max_height {
            return Err(format!(
                "keys `bridge.grid_min_height` = {} and `bridge.grid_max_height` = {}: the band is empty (min must be below max)",
                self.grid_min_height, self.grid_max_height
            ));
        }
        if self.grid && self.world_frame != "ros" {
            return Err(format!(
                "key `bridge.grid`: the occupancy grid needs a floor, i.e. `bridge.world_frame = \"ros\"` (it is \"{}\"); or set bridge.grid = false",
                self.world_frame
            ));
        }
        if self.maps_dir.as_os_str().is_empty() {
            return Err("key `bridge.maps_dir`: empty; name the folder save_map writes to".into());
        }
        Ok(())
    }
}

/// A ROS 2 name: tokens of letters, digits and '_' (not starting with a
/// digit), separated by '/' where `slashes` allows; no empty token.
fn ros_name(key: &str, name: &str, slashes: bool) -> Result<(), String> {
    let bad = |why: &str| {
        Err(format!(
            "key `{key}`: \"{name}\" is not a ROS 2 name ({why})"
        ))
    };
    if name.is_empty() {
        return bad("empty");
    }
    for token in name.split('/') {
        if !slashes && name.contains('/') {
            return bad("no '/' allowed");
        }
        if token.is_empty() {
            return bad("an empty part between slashes");
        }
        if token.starts_with(|c: char| c.is_ascii_digit()) {
            return bad("a part starts with a digit");
        }
        if let Some(c) = token
            .chars()
            .find(|c| !(c.is_ascii_alphanumeric() || *c == '_'))
        {
            return bad(&format!("'{c}': only letters, digits, '_' and '/'"));
        }
    }
    Ok(())
}

/// Pinhole intrinsics and radial-tangential distortion of the RGB camera
/// (the depth image is registered to it). Default: TUM Freiburg 1.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct CameraConfig {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// OpenCV order: k1, k2, p1, p2, k3.
    pub distortion: [f64; 5],
    /// Rolling shutter: seconds from the first image row's exposure to the
    /// last row's (0: global shutter), within `READOUT_S`. Tracking moves
    /// every keypoint to the middle row's instant with the motion model
    /// (rotation, and translation for keypoints with depth).
    pub readout_s: f64,
}

impl CameraConfig {
    /// Accepted rolling-shutter readout times (seconds).
    pub const READOUT_S: std::ops::Range<f64> = 0.0..0.2;

    /// Checks that the values describe a camera; the error names the key.
    pub fn validate(&self) -> Result<(), String> {
        for (key, f) in [("fx", self.fx), ("fy", self.fy)] {
            if !(f.is_finite() && f > 0.0 && f < 1e5) {
                return Err(format!(
                    "key `{key}`: {} is not a focal length in pixels (0 < f < 100000)",
                    readable(f)
                ));
            }
        }
        for (key, c) in [("cx", self.cx), ("cy", self.cy)] {
            if !(c.is_finite() && (0.0..1e5).contains(&c)) {
                return Err(format!(
                    "key `{key}`: {c} is not a principal point in pixels (0 <= c < 100000)"
                ));
            }
        }
        if !self.distortion.iter().all(|d| d.is_finite()) {
            return Err("key `distortion`: k1 k2 p1 p2 k3 must be finite numbers".into());
        }
        if !Self::READOUT_S.contains(&self.readout_s) {
            return Err(format!(
                "key `readout_s`: {} is not a rolling-shutter readout time in seconds (0 <= s < 0.2; 0 for a global shutter)",
                self.readout_s
            ));
        }
        Ok(())
    }
}

impl Default for CameraConfig {
    fn default() -> Self {
        Self {
            fx: 517.306408,
            fy: 516.469215,
            cx: 318.643040,
            cy: 255.313989,
            distortion: [0.262383, -0.953104, -0.005358, 0.002628, 1.163314],
            readout_s: 0.018,
        }
    }
}

/// The ONNX Runtime shared library the model backends load.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct OnnxRuntimeConfig {
    /// Path of `libonnxruntime.so`; default: `$ORT_DYLIB_PATH`, then the
    /// `just setup` cache.
    pub library: Option<PathBuf>,
    /// Expected sha256 of the library (empty: not checked).
    pub sha256: String,
    /// Execution providers in order of preference. One the library lacks is
    /// skipped with a warning when `cpu` is listed, an error otherwise.
    pub providers: Vec<Provider>,
    /// Let the intra-op thread pool spin while waiting for work. Off: on a
    /// loaded robot computer a spinning pool burns the cores the SLAM needs
    /// (measured: the segmenter at 0.57x the CPU and 0.57x the p50 latency
    /// with spinning off on the loaded 2-core machine).
    pub spin: bool,
}

/// An ONNX Runtime execution provider (`[onnxruntime] providers`).
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Provider {
    /// ONNX Runtime's own CPU kernels (every build has them).
    Cpu,
    /// NVIDIA CUDA (a GPU build of ONNX Runtime, e.g. the onnxruntime-gpu wheel or JetPack's).
    Cuda,
    /// NVIDIA TensorRT (a TensorRT-enabled build).
    #[serde(rename = "tensorrt")]
    TensorRt,
}

impl Provider {
    pub fn as_str(&self) -> &'static str {
        match self {
            Provider::Cpu => "cpu",
            Provider::Cuda => "cuda",
            Provider::TensorRt => "tensorrt",
        }
    }
}

impl Default for OnnxRuntimeConfig {
    fn default() -> Self {
        Self {
            library: None,
            sha256: "fc44112fbe06d7d689c57e11d3862031f64711007e4ee020f8eed5185fd2c1d3".into(),
            providers: vec![Provider::Cpu],
            spin: false,
        }
    }
}

/// How frames are clocked through the pipeline.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum ClockMode {
    /// Deterministic: the camera-reader waits for each frame's Track result.
    #[default]
    Lockstep,
    /// Camera rate: the newest frame wins, every dropped frame is counted.
    Realtime,
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RunConfig {
    pub mode: ClockMode,
    /// Real-time playback speed factor (2.0 plays twice as fast as recorded).
    pub speed: f64,
    /// Where run folders are created (relative to the working directory).
    pub output_dir: PathBuf,
    /// Largest frame the shared-memory segments are sized for.
    pub max_width: u32,
    pub max_height: u32,
    /// Fail the run (exit 1) instead of finishing it degraded (exit 3) when
    /// a mask worker is given up on (missing model, crash loop).
    pub require_masks: bool,
    /// The run's folder is the user's alone (0700) and every file the run
    /// writes is created under umask 077 (0600); false: the user's umask.
    pub private: bool,
    /// Which mask images the run folder keeps (`masks/<seq>.png`); every set
    /// of masks gets its `masks.csv` row (and its score against ground-truth
    /// masks) whatever this says.
    pub save_masks: SaveMasks,
}

/// Which label images a run writes to `masks/`.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum SaveMasks {
    /// The segmenter's (the keyframes'): a few per second, the ones the
    /// map keeps.
    #[default]
    Keyframes,
    /// Every frame's (a 10-minute run at 30 fps: about 80 MB).
    All,
    None,
}

impl SaveMasks {
    /// Whether a set of masks from `source` is written as an image.
    pub fn keeps(self, source: shared_types::MaskSource) -> bool {
        match self {
            SaveMasks::All => true,
            SaveMasks::Keyframes => source == shared_types::MaskSource::Segmenter,
            SaveMasks::None => false,
        }
    }
}

impl Default for RunConfig {
    fn default() -> Self {
        Self {
            mode: ClockMode::Lockstep,
            speed: 1.0,
            output_dir: PathBuf::from("runs"),
            max_width: 640,
            max_height: 480,
            require_masks: false,
            private: true,
            save_masks: SaveMasks::Keyframes,
        }
    }
}

/// What the camera-reader plays.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum SourceKind {
    /// A TUM RGB-D folder (rgb.txt, depth.txt, rgb/, depth/).
    #[default]
    Tum,
    /// A folder of PNG images, played in file-name order, no depth.
    Images,
    /// Frames published by a program outside the pipeline (a camera driver,
    /// a ROS 2 bridge) into the run's frame service (README "Frames in"):
    /// no camera-reader runs, `path` is unused, real time only.
    External,
    /// A live V4L2 camera (`[source.v4l2]`), real time only.
    V4l2,
    /// A ROS 2 camera driver's topics (`[source.ros2]`) over rmw_zenoh,
    /// through the bridge's Zenoh settings (`[bridge]`); real time only.
    Ros2,
}

/// A V4L2 camera's settings (`source.kind = "v4l2"`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct V4l2Config {
    /// The colour device node.
    pub device: PathBuf,
    /// Requested size; the driver may pick the nearest it has (logged).
    pub width: u32,
    pub height: u32,
    /// Requested frame rate (frames per second).
    pub fps: u32,
    /// "auto" (YUYV, else MJPEG), "yuyv" or "mjpeg".
    pub pixel_format: String,
    /// A depth node (16-bit `Z16`, registered to the colour image) paired
    /// with each colour frame by arrival time within `source.max_time_diff`;
    /// empty: none (needs services.slam.sensor = "monocular").
    pub depth_device: PathBuf,
}

impl Default for V4l2Config {
    fn default() -> Self {
        Self {
            device: PathBuf::from("/dev/video0"),
            width: 640,
            height: 480,
            fps: 30,
            pixel_format: "auto".into(),
            depth_device: PathBuf::new(),
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct SourceConfig {
    pub kind: SourceKind,
    /// Folder to play; empty means "given on the command line".
    pub path: PathBuf,
    /// TUM association tolerance between rgb and depth timestamps (seconds).
    pub max_time_diff: f64,
    /// Depth value per metre (5000 for TUM).
    pub depth_scale: f32,
    /// Play at most this many frames (0: all).
    pub limit: u64,
    /// Frame period for image folders without timestamps (seconds).
    pub image_period: f64,
    /// Play the sequence this many times in a row (soaks and kill storms):
    /// each pass's timestamps go on one frame period after the last pass's.
    pub repeat: u32,
    /// `kind = "v4l2"`: the camera.
    pub v4l2: V4l2Config,
    /// `kind = "ros2"`: the camera driver's topics.
    pub ros2: Ros2SourceConfig,
}

/// `source.kind = "ros2"`: frames from a ROS 2 camera driver's topics
/// (README "ROS 2"). Relative names resolve under `bridge.namespace`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct Ros2SourceConfig {
    /// sensor_msgs/Image (rgb8, bgr8) or sensor_msgs/CompressedImage (jpeg, png).
    pub colour_topic: String,
    /// sensor_msgs/Image (16UC1 millimetres, 32FC1 metres) registered to
    /// the colour image; empty: none (services.slam.sensor = "monocular").
    pub depth_topic: String,
    /// sensor_msgs/CameraInfo (plumb_bob): the intrinsics, unless --camera
    /// names them.
    pub camera_info_topic: String,
    /// How long the run waits for the first CameraInfo before it fails.
    pub camera_info_timeout_s: f64,
    /// The stream ends when no frame came for this long after the first
    /// (a played bag ended); 0: it never ends by itself (Ctrl-C ends the run).
    pub end_after_idle_s: f64,
}

impl Default for Ros2SourceConfig {
    fn default() -> Self {
        Self {
            colour_topic: "camera/color/image_raw".into(),
            depth_topic: "camera/aligned_depth_to_color/image_raw".into(),
            camera_info_topic: "camera/color/camera_info".into(),
            camera_info_timeout_s: 10.0,
            end_after_idle_s: 0.0,
        }
    }
}

impl Default for SourceConfig {
    fn default() -> Self {
        Self {
            kind: SourceKind::Tum,
            path: PathBuf::new(),
            max_time_diff: 0.02,
            depth_scale: 5000.0,
            limit: 0,
            image_period: 1.0 / 30.0,
            repeat: 1,
            v4l2: V4l2Config::default(),
            ros2: Ros2SourceConfig::default(),
        }
    }
}

/// `[routing]`: see [`scheduling::RoutingConfig`].
pub use scheduling::RoutingConfig;

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct SupervisorConfig {
    /// First restart delay; doubled after every restart of the same service.
    pub restart_backoff_initial_ms: u64,
    pub restart_backoff_max_ms: u64,
    /// A service that stays up this long gets its backoff and its crash
    /// count reset.
    pub restart_backoff_reset_s: u64,
    /// Give up on a service that died this many times in a row without
    /// staying up `restart_backoff_reset_s` (a crash loop).
    pub restart_limit: u32,
    /// How long a (re)started service may take to announce readiness.
    pub ready_timeout_s: u64,
    /// Grace period between SIGTERM and SIGKILL at shutdown.
    pub stop_timeout_ms: u64,
    /// Period of the child-exit and dead-node checks.
    pub watch_period_ms: u64,
    /// Watchdog: with every service up, no frame recorded for this long
    /// names the stage the oldest frame is stuck in and kills that service
    /// (restarted like a crash); 0: off.
    pub stall_timeout_s: u64,
}

impl Default for SupervisorConfig {
    fn default() -> Self {
        Self {
            restart_backoff_initial_ms: 100,
            restart_backoff_max_ms: 5000,
            restart_backoff_reset_s: 10,
            restart_limit: 10,
            ready_timeout_s: 60,
            stop_timeout_ms: 3000,
            watch_period_ms: 20,
            stall_timeout_s: 30,
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct ServicesConfig {
    #[serde(rename = "camera-reader")]
    pub camera_reader: ServiceConfig,
    pub segmenter: ServiceConfig,
    pub propagator: ServiceConfig,
    pub slam: ServiceConfig,
}

/// The movable COCO classes masked by default (DESIGN section 1).
pub const DEFAULT_DYNAMIC_CLASSES: [&str; 8] = [
    "person",
    "bicycle",
    "car",
    "motorcycle",
    "bus",
    "truck",
    "dog",
    "cat",
];

/// The product: the RGB-D SLAM core, YOLOv8-seg on keyframes, LK between
/// them (the same values as the shipped `configs/pipeline.toml`, checked by
/// a test). The test doubles (`scripted`, `none`, `ground-truth`) run only
/// where a config names them.
impl Default for ServicesConfig {
    fn default() -> Self {
        Self {
            camera_reader: ServiceConfig::default(),
            segmenter: ServiceConfig {
                backend: "yolov8-seg".into(),
                // No model and no input_size: the segmenter takes its
                // default export for the clock mode (480 in lockstep, 320
                // in real time); a model or model_path naming a known
                // export brings that export's size.
                classes: DEFAULT_DYNAMIC_CLASSES.map(String::from).to_vec(),
                score_threshold: Some(0.25),
                weak_score_threshold: Some(0.05),
                iou_threshold: Some(0.7),
                threads: Some(2),
                nice: Some(5),
                ..ServiceConfig::default()
            },
            propagator: ServiceConfig {
                backend: "lk".into(),
                ..ServiceConfig::default()
            },
            slam: ServiceConfig {
                backend: "orb-rgbd".into(),
                keyframe_every: 5,
                threads: Some(2),
                mask_mode: "filter".into(),
                checkpoint_every_keyframes: Some(1),
                sensor: "rgbd".into(),
                ..ServiceConfig::default()
            },
        }
    }
}

/// Settings of one service process. `backend` picks the implementation behind
/// the service's trait; the remaining keys are that backend's options.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields, default)]
pub struct ServiceConfig {
    /// Replace the service's program: `["/path/to/bin", "arg", ...]`. The
    /// supervisor appends the standard service arguments.
    pub command: Vec<String>,
    /// Which implementation to run (service specific; see the shipped config).
    pub backend: String,
    /// Scripted SLAM: request a keyframe every this many frames.
    pub keyframe_every: u64,
    /// Scripted backends: simulated work per frame (milliseconds).
    pub work_ms: u64,
    /// SLAM: how masks are applied: "filter" (default: keypoints under the
    /// dilated mask are dropped at detection) or "blackout" (masked pixels
    /// are painted black before extraction; the ablation's row e).
    pub mask_mode: String,
    /// Scripted SLAM: append every tracked seq to this file (delivery tests).
    pub seen_log: Option<PathBuf>,
    /// Model backends: file name of the model (located as described in
    /// `pipeline::provision`), an explicit path, and its sha256.
    pub model: String,
    pub model_path: Option<PathBuf>,
    pub model_sha256: String,
    /// Model backends: minimum class score of an instance.
    pub score_threshold: Option<f32>,
    /// YOLOv8-seg: weaker detections, down to this score, are kept where the
    /// frame's depth shows them standing in front of their surroundings
    /// (unset: `score_threshold`, none kept that way).
    pub weak_score_threshold: Option<f32>,
    /// Model backends: IoU above which the weaker of two same-class boxes is suppressed.
    pub iou_threshold: Option<f32>,
    /// Model backends: the movable classes that become dynamic masks (names).
    pub classes: Vec<String>,
    /// Model backends: square network input size in pixels (YOLOv8-seg
    /// unset: the named export's, else 480 in lockstep and 320 in real time).
    pub input_size: Option<u32>,
    /// Model backends: ONNX Runtime intra-op threads; SLAM: feature
    /// extraction threads (pyramid levels in parallel; default 2).
    pub threads: Option<usize>,
    /// The process's scheduling niceness (-20..=19, higher yields the CPU):
    /// the segmenter runs at 10 by default, so that on a busy robot
    /// computer its long keyframe inferences take the cycles tracking and
    /// propagation leave instead of delaying them (tracking never waits for
    /// it: its masks are carried forward). It applies once the SLAM has
    /// tracked its first frame (until then every stage waits for the
    /// first segmenter masks). Unset: the supervisor's own.
    pub nice: Option<i32>,
    /// Two-part models (SAM 2: `model` is the image encoder): the prompt /
    /// mask decoder's file name, explicit path and sha256.
    pub decoder_model: String,
    pub decoder_model_path: Option<PathBuf>,
    pub decoder_model_sha256: String,
    /// SAM 2 propagator: an object ends when its best predicted IoU falls
    /// below this, or its area below `min_area_ratio` of its keyframe area.
    pub min_predicted_iou: Option<f32>,
    pub min_area_ratio: Option<f32>,
    /// SAM 2 propagator: positive points sampled inside an object's mask
    /// for each prompt (besides its box).
    pub prompt_points: Option<u32>,
    /// SLAM: write the map as a checkpoint into the run folder every this
    /// many keyframes (and at stop; 0: only at stop). A restarted SLAM
    /// service goes on from it in the same world frame.
    pub checkpoint_every_keyframes: Option<u64>,
    /// SLAM: start from this map file (poses in its world frame).
    pub load_map: Option<PathBuf>,
    /// SLAM: write the map to this file at the end of the run.
    pub save_map: Option<PathBuf>,
    /// SLAM: ORB-SLAM2's localization mode: track against the loaded map,
    /// add no keyframe or point (needs `load_map`).
    pub localize_only: bool,
    /// SLAM: look for loops after each keyframe and correct the map when
    /// one closes (`loops.csv` in the run folder; off by default).
    pub loop_closing: bool,
    /// SLAM (`orb-rgbd`, RGB-D): drop features in image regions that move
    /// unlike the camera (movers no class list names; `features_moving`
    /// in frames.csv; off by default).
    pub motion_check: bool,
    /// SLAM (`orb-rgbd`): `rgbd` (colour and depth) or `monocular` (colour
    /// only: depth ignored; the map's scale is its own, evaluated with a
    /// Sim(3) alignment).
    pub sensor: String,
}

impl ServiceConfig {
    /// SLAM: the sensor is a colour camera alone.
    pub fn is_monocular(&self) -> bool {
        self.sensor == "monocular"
    }
}

/// A configuration error that names the file, the key path and the problem.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    // The OS error is part of the message, not a `source`: error chains
    // printed with their causes would say it twice.
    #[error("cannot read config file {path}: {error}")]
    Read {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("config file {path}: {message}")]
    Invalid { path: PathBuf, message: String },
}

impl PipelineConfig {
    /// Reads and validates a configuration file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|error| ConfigError::Read {
            path: path.to_path_buf(),
            error,
        })?;
        // A UTF-8 byte-order mark (Windows editors) is not part of the TOML.
        Self::parse(text.trim_start_matches('\u{feff}')).map_err(|message| ConfigError::Invalid {
            path: path.to_path_buf(),
            message,
        })
    }

    /// `path` layered over the built-in defaults, or the built-in defaults
    /// (the shipped `configs/pipeline.toml`) when there is no file.
    pub fn load_or_default(path: Option<&Path>) -> Result<Self, ConfigError> {
        match path {
            Some(p) => Self::load(p),
            None => Ok(Self::default()),
        }
    }

    /// Parses configuration text layered over the built-in defaults (which
    /// are the shipped `configs/pipeline.toml`): every key the text sets
    /// replaces the default's, tables merge key by key, so a file with only
    /// `[camera]` (or only `services.segmenter.threads`) still runs the
    /// product. Errors name the key path and line.
    pub fn parse(text: &str) -> Result<Self, String> {
        // The text alone first: unknown keys and wrong types, with their lines.
        let _: PipelineConfig = deserialize_named(text)?;
        let user: toml::Table = text.parse().map_err(|e: toml::de::Error| e.to_string())?;
        let mut layered = toml::Table::try_from(PipelineConfig::default())
            .map_err(|e| format!("cannot serialise the built-in defaults: {e}"))?;
        merge_tables(&mut layered, user);
        let config: PipelineConfig = toml::Value::Table(layered)
            .try_into()
            .map_err(|e: toml::de::Error| e.message().to_string())?;
        config.validate().map_err(|e| {
            // Name the line where the text sets the offending key.
            let key = e
                .strip_prefix("key `")
                .and_then(|rest| rest.split('`').next())
                .unwrap_or_default();
            match line_of_key(text, key) {
                Some(line) => format!("{e} (line {line})"),
                None => e,
            }
        })?;
        Ok(config)
    }

    /// Checks every value for range and sense (the file's load does; call it
    /// again after changing values, e.g. from command-line flags).
    pub fn validate(&self) -> Result<(), String> {
        let r = &self.run;
        // 4096x4096 RGB-D frames are 80 MB per shared-memory slot already.
        for (key, v) in [
            ("run.max_width", r.max_width),
            ("run.max_height", r.max_height),
        ] {
            if !(16..=4096).contains(&v) {
                return Err(format!(
                    "key `{key}`: {v} is not a usable frame size in pixels (16..=4096)"
                ));
            }
        }
        in_range("run.speed", r.speed, 0.01, 100.0, "a playback speed factor")?;
        self.bridge.validate()?;
        in_range(
            "source.max_time_diff",
            self.source.max_time_diff,
            1e-4,
            1.0,
            "an association tolerance in seconds",
        )?;
        in_range(
            "source.depth_scale",
            self.source.depth_scale as f64,
            1.0,
            1e5,
            "depth units per metre (TUM 5000, millimetres 1000)",
        )?;
        let sup = &self.supervisor;
        for (key, v, lo, hi) in [
            ("supervisor.ready_timeout_s", sup.ready_timeout_s, 1, 3600),
            (
                "supervisor.stop_timeout_ms",
                sup.stop_timeout_ms,
                1,
                600_000,
            ),
            (
                "supervisor.restart_backoff_reset_s",
                sup.restart_backoff_reset_s,
                1,
                86_400,
            ),
        ] {
            if !(lo..=hi).contains(&v) {
                return Err(format!("key `{key}`: {v} is outside {lo}..={hi}"));
            }
        }
        for (name, svc) in [
            ("segmenter", &self.services.segmenter),
            ("propagator", &self.services.propagator),
            ("slam", &self.services.slam),
        ] {
            for (key, v) in [
                ("score_threshold", svc.score_threshold),
                ("weak_score_threshold", svc.weak_score_threshold),
                ("iou_threshold", svc.iou_threshold),
                ("min_predicted_iou", svc.min_predicted_iou),
                ("min_area_ratio", svc.min_area_ratio),
            ] {
                if let Some(v) = v {
                    in_range(
                        &format!("services.{name}.{key}"),
                        v as f64,
                        0.0,
                        1.0,
                        "a fraction",
                    )?;
                }
            }
            if let Some(n) = svc.input_size {
                if !(32..=4096).contains(&n) || n % 32 != 0 {
                    return Err(format!(
                        "key `services.{name}.input_size`: {n} is not a network input size (a multiple of 32 in 32..=4096)"
                    ));
                }
            }
            if let Some(t) = svc.threads {
                if !(1..=256).contains(&t) {
                    return Err(format!(
                        "key `services.{name}.threads`: {t} is outside 1..=256"
                    ));
                }
            }
            if let Some(n) = svc.nice {
                if !(-20..=19).contains(&n) {
                    return Err(format!(
                        "key `services.{name}.nice`: {n} is not a niceness (-20..=19)"
                    ));
                }
            }
        }
        in_range(
            "routing.unseen_view_share",
            self.routing.unseen_view_share as f64,
            0.0,
            1.0,
            "a share of the image (0: off)",
        )?;
        if !(self.source.image_period.is_finite() && self.source.image_period > 0.0) {
            return Err("key `source.image_period`: must be a positive number of seconds".into());
        }
        if !(1..=100_000).contains(&self.source.repeat) {
            return Err(format!(
                "key `source.repeat`: {} is not a number of passes over the sequence (1..=100000)",
                self.source.repeat
            ));
        }
        if !matches!(
            self.services.slam.mask_mode.as_str(),
            "" | "filter" | "blackout"
        ) {
            return Err(format!(
                "key `services.slam.mask_mode`: '{}' is not one of filter, blackout",
                self.services.slam.mask_mode
            ));
        }
        let slam = &self.services.slam;
        if !matches!(slam.sensor.as_str(), "" | "rgbd" | "monocular") {
            return Err(format!(
                "key `services.slam.sensor`: '{}' is not one of rgbd, monocular",
                slam.sensor
            ));
        }
        if let Some(n) = slam.checkpoint_every_keyframes.filter(|&n| n > 100_000) {
            return Err(format!(
                "key `services.slam.checkpoint_every_keyframes`: {n} is not a keyframe count (0 = only at stop ..= 100000)"
            ));
        }
        if slam.localize_only && slam.load_map.is_none() {
            return Err("key `services.slam.localize_only`: localization needs a map: set services.slam.load_map (or give --load-map)".into());
        }
        self.camera
            .validate()
            .map_err(|e| e.replacen("key `", "key `camera.", 1))?;
        if self.onnxruntime.providers.is_empty() {
            return Err(
                "key `onnxruntime.providers`: empty; list at least one of cpu, cuda, tensorrt"
                    .into(),
            );
        }
        if self.source.kind == SourceKind::Images
            && self.services.slam.backend == "orb-rgbd"
            && !self.services.slam.is_monocular()
        {
            return Err(
                "key `services.slam.sensor`: \"rgbd\" needs depth, and `source.kind = \"images\"` \
                 plays frames without it: set services.slam.sensor = \"monocular\" (or play a TUM \
                 RGB-D folder, kind = \"tum\")"
                    .into(),
            );
        }
        if self.source.kind == SourceKind::V4l2 {
            let v = &self.source.v4l2;
            if self.run.mode != ClockMode::Realtime {
                return Err(
                    "key `run.mode`: `source.kind = \"v4l2\"` needs run.mode = \"realtime\" (a \
                     camera does not wait for the SLAM, nor replay a frame after a restart)"
                        .into(),
                );
            }
            if !["auto", "yuyv", "mjpeg"].contains(&v.pixel_format.as_str()) {
                return Err(format!(
                    "key `source.v4l2.pixel_format`: \"{}\" is not one of \"auto\", \"yuyv\", \"mjpeg\"",
                    v.pixel_format
                ));
            }
            if v.width == 0
                || v.height == 0
                || v.width > self.run.max_width
                || v.height > self.run.max_height
            {
                return Err(format!(
                    "key `source.v4l2.width`: {}x{} must be within run.max_width x run.max_height = {}x{}",
                    v.width, v.height, self.run.max_width, self.run.max_height
                ));
            }
            if v.fps == 0 || v.fps > 240 {
                return Err(format!("key `source.v4l2.fps`: {} must be 1 to 240", v.fps));
            }
            if v.device.as_os_str().is_empty() {
                return Err(
                    "key `source.v4l2.device`: empty (a device node such as /dev/video0)".into(),
                );
            }
            if v.depth_device.as_os_str().is_empty()
                && self.services.slam.backend == "orb-rgbd"
                && !self.services.slam.is_monocular()
            {
                return Err(
                    "key `services.slam.sensor`: \"rgbd\" needs depth, and `source.v4l2.depth_device` \
                     is empty: set services.slam.sensor = \"monocular\" for a colour camera, or name \
                     the camera's depth node"
                        .into(),
                );
            }
        }
        if self.source.kind == SourceKind::Ros2 {
            let r = &self.source.ros2;
            if self.run.mode != ClockMode::Realtime {
                return Err(
                    "key `run.mode`: `source.kind = \"ros2\"` needs run.mode = \"realtime\" (a ROS 2 camera sends at its own rate)"
                        .into(),
                );
            }
            for (key, topic) in [
                ("source.ros2.colour_topic", &r.colour_topic),
                ("source.ros2.camera_info_topic", &r.camera_info_topic),
            ] {
                ros_name(key, topic.strip_prefix('/').unwrap_or(topic), true)?;
            }
            if r.depth_topic.is_empty() {
                if !self.services.slam.is_monocular() {
                    return Err("key `source.ros2.depth_topic`: empty, and services.slam.sensor = \"rgbd\" needs depth: name the depth topic or set services.slam.sensor = \"monocular\"".into());
                }
            } else {
                let t = &r.depth_topic;
                ros_name(
                    "source.ros2.depth_topic",
                    t.strip_prefix('/').unwrap_or(t),
                    true,
                )?;
            }
            in_range(
                "source.ros2.camera_info_timeout_s",
                r.camera_info_timeout_s,
                0.1,
                3600.0,
                "a time in seconds",
            )?;
            if r.end_after_idle_s != 0.0 {
                in_range(
                    "source.ros2.end_after_idle_s",
                    r.end_after_idle_s,
                    0.1,
                    86_400.0,
                    "a time in seconds (0: never)",
                )?;
            }
        }
        if self.source.kind == SourceKind::External && self.run.mode != ClockMode::Realtime {
            return Err(
                "key `run.mode`: `source.kind = \"external\"` needs run.mode = \"realtime\" \
                 (an outside publisher sends at its own rate; lockstep needs the camera-reader to \
                 wait for each Track and to replay a frame after a restart)"
                    .into(),
            );
        }
        let s = &self.supervisor;
        if s.restart_backoff_initial_ms == 0
            || s.restart_backoff_max_ms < s.restart_backoff_initial_ms
        {
            return Err(
                "key `supervisor.restart_backoff_max_ms`: must be >= restart_backoff_initial_ms > 0"
                    .into(),
            );
        }
        if s.watch_period_ms == 0 {
            return Err("key `supervisor.watch_period_ms`: must be > 0".into());
        }
        if s.stall_timeout_s > 3600 {
            return Err(format!(
                "key `supervisor.stall_timeout_s`: {} s is not a stall timeout (0 = off, 1..=3600)",
                s.stall_timeout_s
            ));
        }
        Ok(())
    }

    /// Bytes of the largest frame payload (RGB8 + u16 depth).
    pub fn max_frame_bytes(&self) -> usize {
        self.run.max_width as usize * self.run.max_height as usize * 5
    }

    /// Bytes of the largest mask label image.
    pub fn max_mask_bytes(&self) -> usize {
        self.run.max_width as usize * self.run.max_height as usize
    }

    pub fn service(&self, kind: shared_types::ServiceKind) -> &ServiceConfig {
        use shared_types::ServiceKind as K;
        match kind {
            K::CameraReader => &self.services.camera_reader,
            K::Segmenter => &self.services.segmenter,
            K::Propagator => &self.services.propagator,
            K::Slam => &self.services.slam,
            // The bridge's settings are its own section ([bridge]); as a
            // process it has a service's defaults (no backend, no nice).
            K::Bridge => {
                static BRIDGE: std::sync::OnceLock<ServiceConfig> = std::sync::OnceLock::new();
                BRIDGE.get_or_init(ServiceConfig::default)
            }
        }
    }

    pub fn to_toml(&self) -> Result<String, toml::ser::Error> {
        toml::to_string_pretty(self)
    }
}

/// `value` within `lo..=hi`, else an error naming the key, the value, the range and what it is.
fn in_range(key: &str, value: f64, lo: f64, hi: f64, what: &str) -> Result<(), String> {
    if value.is_finite() && (lo..=hi).contains(&value) {
        return Ok(());
    }
    Err(format!(
        "key `{key}`: {} is not {what} ({lo}..={hi})",
        readable(value)
    ))
}

/// A number as a person reads it (1e300, not three hundred digits).
fn readable(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-4..1e6).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// The line of `key` (a dotted path) in `text`, where the text sets it.
fn line_of_key(text: &str, key: &str) -> Option<usize> {
    let (section, name) = key.rsplit_once('.')?;
    let mut current = String::new();
    for (i, line) in text.lines().enumerate() {
        let l = line.trim();
        if let Some(rest) = l.strip_prefix('[') {
            current = rest.trim_end_matches(']').trim().to_string();
            continue;
        }
        if current == section {
            if let Some((k, _)) = l.split_once('=') {
                if k.trim() == name {
                    return Some(i + 1);
                }
            }
        }
    }
    None
}

/// Deserialises `text` alone, naming the key path and line of an error.
fn deserialize_named(text: &str) -> Result<PipelineConfig, String> {
    let deserializer = toml::Deserializer::new(text);
    serde_path_to_error::deserialize(deserializer).map_err(|e| {
        let path = e.path().to_string();
        let inner = e.into_inner();
        let msg = inner.message().to_string();
        let line = inner
            .span()
            .map(|s| {
                let (line, column) = line_column_of(text, s.start);
                format!(" (line {line}, column {column})")
            })
            .unwrap_or_default();
        if path.is_empty() || path == "." {
            format!("{msg}{line}")
        } else {
            format!("key `{path}`{line}: {msg}")
        }
    })
}

/// Layers `over` onto `base`: tables merge recursively, anything else in
/// `over` replaces the value in `base`.
fn merge_tables(base: &mut toml::Table, over: toml::Table) {
    for (key, value) in over {
        match (base.get_mut(&key), value) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge_tables(b, o),
            (_, value) => {
                base.insert(key, value);
            }
        }
    }
}

fn line_column_of(text: &str, byte: usize) -> (usize, usize) {
    let before = &text[..byte.min(text.len())];
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    (
        before.matches('\n').count() + 1,
        before[line_start..].chars().count() + 1,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shipped_path() -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/pipeline.toml")
    }

    #[test]
    fn built_in_defaults_are_the_shipped_configuration() {
        let shipped = PipelineConfig::load(&shipped_path()).unwrap();
        assert_eq!(PipelineConfig::default(), shipped);
        assert_eq!(PipelineConfig::parse("").unwrap(), shipped);
        assert_eq!(shipped.services.slam.backend, "orb-rgbd");
        assert_eq!(shipped.services.segmenter.backend, "yolov8-seg");
        assert_eq!(shipped.services.propagator.backend, "lk");
    }

    #[test]
    fn a_partial_config_is_layered_over_the_defaults() {
        // Only [camera]: the product's backends, the given camera values.
        let c = PipelineConfig::parse("[camera]\nfx = 520.9\nreadout_s = 0.0\n").unwrap();
        assert_eq!(c.services.slam.backend, "orb-rgbd");
        assert_eq!(c.services.segmenter.backend, "yolov8-seg");
        assert_eq!(c.services.propagator.backend, "lk");
        assert_eq!((c.camera.fx, c.camera.readout_s), (520.9, 0.0));
        assert_eq!(c.camera.fy, CameraConfig::default().fy);
        let err = PipelineConfig::parse("[services.segmenter]\nnice = 25\n").unwrap_err();
        assert!(err.to_string().contains("services.segmenter.nice"), "{err}");
        // One key of a service section keeps the section's other defaults.
        let c = PipelineConfig::parse("[services.segmenter]\nthreads = 1\n").unwrap();
        assert_eq!(c.services.segmenter.threads, Some(1));
        assert_eq!(c.services.segmenter.backend, "yolov8-seg");
        assert_eq!(c.services.segmenter.classes.len(), 8);
        // A test double runs only when named.
        let c = PipelineConfig::parse("[services.slam]\nbackend = \"scripted\"\n").unwrap();
        assert_eq!(c.services.slam.backend, "scripted");
        assert_eq!(c.services.segmenter.backend, "yolov8-seg");
    }

    #[test]
    fn a_v4l2_camera_is_checked_key_by_key() {
        let cam = |extra: &str| {
            PipelineConfig::parse(&format!(
                "[run]\nmode = \"realtime\"\n[source]\nkind = \"v4l2\"\n[source.v4l2]\ndepth_device = \"/dev/video2\"\n{extra}"
            ))
        };
        let c = cam("").unwrap();
        assert_eq!(c.source.v4l2.device, Path::new("/dev/video0"));
        assert_eq!((c.source.v4l2.width, c.source.v4l2.fps), (640, 30));
        let err = |extra: &str| cam(extra).unwrap_err();
        assert!(err("pixel_format = \"nv12\"").contains("source.v4l2.pixel_format"));
        assert!(err("width = 1920\nheight = 1080").contains("run.max_width"));
        assert!(err("fps = 0").contains("source.v4l2.fps"));
        assert!(err("device = \"\"").contains("source.v4l2.device"));
        // No depth node: the RGB-D SLAM says what to set.
        let e = PipelineConfig::parse("[run]\nmode = \"realtime\"\n[source]\nkind = \"v4l2\"\n")
            .unwrap_err();
        assert!(
            e.contains("services.slam.sensor") && e.contains("monocular"),
            "{e}"
        );
        PipelineConfig::parse(
            "[run]\nmode = \"realtime\"\n[source]\nkind = \"v4l2\"\n[services.slam]\nsensor = \"monocular\"\n",
        )
        .unwrap();
        let e = PipelineConfig::parse(
            "[source]\nkind = \"v4l2\"\n[source.v4l2]\ndepth_device = \"/dev/video2\"\n",
        )
        .unwrap_err();
        assert!(e.contains("run.mode"), "{e}");
    }

    #[test]
    fn an_external_source_runs_in_real_time_only() {
        let err = PipelineConfig::parse("[source]\nkind = \"external\"\n").unwrap_err();
        assert!(
            err.contains("run.mode") && err.contains("realtime"),
            "{err}"
        );
        PipelineConfig::parse("[source]\nkind = \"external\"\n[run]\nmode = \"realtime\"\n")
            .unwrap();
        // The shipped examples (README "Frames in", "Live camera").
        let camera = PipelineConfig::load(&shipped_path().with_file_name("v4l2.toml")).unwrap();
        assert_eq!(camera.source.kind, SourceKind::V4l2);
        assert!(camera.services.slam.is_monocular());
        let example =
            PipelineConfig::load(&shipped_path().with_file_name("external.toml")).unwrap();
        assert_eq!(example.source.kind, SourceKind::External);
        assert_eq!(example.run.mode, ClockMode::Realtime);
    }

    #[test]
    fn an_image_folder_with_the_rgbd_slam_is_an_error_naming_the_keys() {
        let err = PipelineConfig::parse("[source]\nkind = \"images\"\n").unwrap_err();
        assert!(err.contains("source.kind"), "{err}");
        assert!(err.contains("services.slam.sensor"), "{err}");
        PipelineConfig::parse(
            "[source]\nkind = \"images\"\n[services.slam]\nbackend = \"scripted\"\n",
        )
        .unwrap();
        let mono = PipelineConfig::parse(
            "[source]\nkind = \"images\"\n[services.slam]\nsensor = \"monocular\"\n",
        )
        .unwrap();
        assert!(mono.services.slam.is_monocular());
    }

    #[test]
    fn a_missing_config_file_is_named_with_its_os_error_once() {
        let e = PipelineConfig::load(Path::new("/nonexistent/pipeline.toml")).unwrap_err();
        let text = format!("{e}");
        assert!(
            text.starts_with("cannot read config file /nonexistent/pipeline.toml: "),
            "{text}"
        );
        assert_eq!(text.matches("os error").count(), 1, "{text}");
        assert!(std::error::Error::source(&e).is_none());
    }

    #[test]
    fn a_bad_sensor_is_an_error_naming_the_key_and_monocular_closes_loops() {
        let err = PipelineConfig::parse("[services.slam]\nsensor = \"stereo\"\n").unwrap_err();
        assert!(
            err.contains("services.slam.sensor")
                && err.contains("stereo")
                && err.contains("line 2"),
            "{err}"
        );
        // Monocular loop closing corrects a similarity (Sim(3)).
        let c =
            PipelineConfig::parse("[services.slam]\nsensor = \"monocular\"\nloop_closing = true\n")
                .unwrap();
        assert!(c.services.slam.is_monocular() && c.services.slam.loop_closing);
    }

    #[test]
    fn a_byte_order_mark_is_tolerated() {
        let path = std::env::temp_dir().join(format!("dynslam-bom-{}.toml", std::process::id()));
        std::fs::write(&path, "\u{feff}[run]\nspeed = 2.0\n").unwrap();
        assert_eq!(PipelineConfig::load(&path).unwrap().run.speed, 2.0);
        std::fs::remove_file(&path).ok();
    }

    /// Key paths of a TOML table's leaves: `section.key` (`services.slam.threads`).
    fn leaf_keys(table: &toml::Table, prefix: &str, out: &mut Vec<String>) {
        for (k, v) in table {
            let path = if prefix.is_empty() {
                k.clone()
            } else {
                format!("{prefix}.{k}")
            };
            match v {
                toml::Value::Table(t) => leaf_keys(t, &path, out),
                _ => out.push(path),
            }
        }
    }

    #[test]
    fn the_shipped_file_documents_every_key() {
        // Every field set, so that optional keys serialise too.
        let mut full = PipelineConfig::default();
        full.onnxruntime.library = Some("/x".into());
        for svc in [
            &mut full.services.camera_reader,
            &mut full.services.segmenter,
            &mut full.services.propagator,
            &mut full.services.slam,
        ] {
            svc.command = vec!["x".into()];
            svc.seen_log = Some("/x".into());
            svc.model_path = Some("/x".into());
            svc.score_threshold = Some(0.5);
            svc.iou_threshold = Some(0.5);
            svc.input_size = Some(320);
            svc.threads = Some(1);
            svc.classes = vec!["person".into()];
            svc.decoder_model_path = Some("/x".into());
            svc.min_predicted_iou = Some(0.5);
            svc.min_area_ratio = Some(0.2);
            svc.prompt_points = Some(3);
            svc.checkpoint_every_keyframes = Some(5);
            svc.load_map = Some("/x".into());
            svc.save_map = Some("/x".into());
        }
        let mut keys = Vec::new();
        leaf_keys(&toml::Table::try_from(&full).unwrap(), "", &mut keys);
        // Documented keys: `key =` and `# key =` lines under `[section]` or
        // `# [section]` headers; service keys count for every service.
        let text = std::fs::read_to_string(shipped_path()).unwrap();
        let mut documented = std::collections::BTreeSet::new();
        let mut section = String::new();
        for line in text.lines() {
            let l = line.trim_start_matches('#').trim();
            if let Some(rest) = l.strip_prefix('[') {
                if let Some(end) = rest.find(']') {
                    section = rest[..end].trim().to_string();
                    continue;
                }
            }
            if let Some((key, _)) = l.split_once('=') {
                let key = key.trim();
                if !key.is_empty()
                    && key
                        .chars()
                        .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
                {
                    let section = if section.starts_with("services.") {
                        "services.*"
                    } else {
                        section.as_str()
                    };
                    documented.insert(format!("{section}.{key}"));
                }
            }
        }
        let mut missing = Vec::new();
        for key in &keys {
            let general = match key.strip_prefix("services.") {
                Some(rest) => format!("services.*.{}", rest.split_once('.').unwrap().1),
                None => key.clone(),
            };
            if !documented.contains(&general) {
                missing.push(general);
            }
        }
        missing.dedup();
        assert!(
            missing.is_empty(),
            "configs/pipeline.toml does not document: {missing:?}"
        );
        for svc in ["slam", "segmenter", "propagator", "camera-reader"] {
            assert!(
                text.contains(&format!("[services.{svc}]")),
                "no [services.{svc}] section"
            );
        }
    }

    #[test]
    fn unknown_key_is_rejected_with_its_path_and_line() {
        let err = PipelineConfig::parse(
            "[run]\nmode = \"realtime\"\n\n[services.slam]\nkeyframe_evry = 3\n",
        )
        .unwrap_err();
        assert!(err.contains("services.slam"), "{err}");
        assert!(err.contains("keyframe_evry"), "{err}");
        assert!(err.contains("line 5"), "{err}");
    }

    #[test]
    fn wrong_type_and_bad_values_are_rejected() {
        let err = PipelineConfig::parse("[run]\nmode = 3\n").unwrap_err();
        assert!(err.contains("run.mode"), "{err}");
        let err = PipelineConfig::parse("[run]\nspeed = -1.0\n").unwrap_err();
        assert!(err.contains("run.speed"), "{err}");
        let err = PipelineConfig::parse("[camera]\nreadout_s = 0.5\n").unwrap_err();
        assert!(
            err.contains("camera.readout_s") && err.contains("line 2"),
            "{err}"
        );
        assert!(PipelineConfig::parse("[run\n").is_err());
    }

    #[test]
    fn implausible_values_are_errors_naming_key_value_range_and_line() {
        for (text, key) in [
            ("[run]\nspeed = 1e-300\n", "run.speed"),
            ("[run]\nmax_width = 8192\n", "run.max_width"),
            ("[source]\ndepth_scale = 1e-30\n", "source.depth_scale"),
            (
                "[supervisor]\nready_timeout_s = 0\n",
                "supervisor.ready_timeout_s",
            ),
            (
                "[services.segmenter]\nscore_threshold = 2.0\n",
                "services.segmenter.score_threshold",
            ),
            (
                "[services.segmenter]\nweak_score_threshold = -0.1\n",
                "services.segmenter.weak_score_threshold",
            ),
            (
                "[services.segmenter]\niou_threshold = 5.0\n",
                "services.segmenter.iou_threshold",
            ),
            (
                "[services.segmenter]\ninput_size = 100\n",
                "services.segmenter.input_size",
            ),
            (
                "[services.propagator]\nmin_area_ratio = -1.0\n",
                "services.propagator.min_area_ratio",
            ),
            ("[camera]\nfx = 1e300\n", "camera.fx"),
            (
                "[routing]\nunseen_view_share = 1.5\n",
                "routing.unseen_view_share",
            ),
        ] {
            let err = PipelineConfig::parse(&format!("# a comment\n{text}")).unwrap_err();
            assert!(err.contains(&format!("key `{key}`")), "{text}: {err}");
            assert!(err.contains("line 3"), "{text}: {err}");
        }
        // The value and the range are named.
        let err = PipelineConfig::parse("[run]\nspeed = 500.0\n").unwrap_err();
        assert!(err.contains("500") && err.contains("0.01..=100"), "{err}");
    }

    #[test]
    fn execution_providers_are_checked_by_name() {
        let c = PipelineConfig::parse("[onnxruntime]\nproviders = [\"cuda\", \"cpu\"]\n").unwrap();
        assert_eq!(c.onnxruntime.providers, vec![Provider::Cuda, Provider::Cpu]);
        assert_eq!(
            PipelineConfig::default().onnxruntime.providers,
            vec![Provider::Cpu]
        );
        let err = PipelineConfig::parse("[onnxruntime]\nproviders = [\"gpu\"]\n").unwrap_err();
        assert!(
            err.contains("onnxruntime.providers") && err.contains("line 2"),
            "{err}"
        );
        assert!(err.contains("cuda") && err.contains("tensorrt"), "{err}");
        let err = PipelineConfig::parse("[onnxruntime]\nproviders = []\n").unwrap_err();
        assert!(err.contains("onnxruntime.providers"), "{err}");
    }

    #[test]
    fn round_trips_through_toml() {
        let c =
            PipelineConfig::parse("[services.slam]\nbackend = \"scripted\"\nkeyframe_every = 4\n")
                .unwrap();
        let back = PipelineConfig::parse(&c.to_toml().unwrap()).unwrap();
        assert_eq!(c, back);
    }

    #[test]
    fn random_configs_are_errors_or_values_never_panics() {
        for text in crate::fuzz::texts(7, 3000) {
            let _ = PipelineConfig::parse(&text);
        }
    }

    #[test]
    fn shipped_configs_parse() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") {
                PipelineConfig::load(&path).unwrap_or_else(|e| panic!("{e}"));
            }
        }
    }
}
