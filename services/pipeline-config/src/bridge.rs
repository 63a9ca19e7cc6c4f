//! `[bridge]`: the ROS 2 bridge's settings.

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

use super::in_range;

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
    /// The map frame's tf name.
    pub map_frame: String,
    /// The robot's odometry frame when it publishes `odom -> base_frame`
    /// on tf: the SLAM then publishes `map -> odom` (REP-105); empty: the
    /// SLAM publishes `map -> base_frame`.
    pub odom_frame: String,
    /// The robot's base frame (tf name).
    pub base_frame: String,
    /// The camera's optical frame (tf name), the frame of the masks.
    pub camera_frame: String,
    /// The camera's mounting, base_frame -> camera_frame (metres, and
    /// roll pitch yaw in radians as `static_transform_publisher` takes
    /// them). Default: at the base's origin, optical axes (z forward).
    pub camera_xyz: [f64; 3],
    /// The mounting's roll, pitch and yaw (radians).
    pub camera_rpy: [f64; 3],
    /// Topic names: relative ones resolve under the namespace.
    pub odometry_topic: String,
    /// `nav_msgs/Path` of the tracked frames.
    pub path_topic: String,
    /// `geometry_msgs/PoseArray` of the keyframes.
    pub keyframes_topic: String,
    /// `std_msgs/String`: the tracking state.
    pub state_topic: String,
    /// The masks SLAM tracked each frame with, as a mono8 label image
    /// (0 background, i + 1 instance i) on `mask_topic`; off by default
    /// (300 KB a frame).
    pub mask_image: bool,
    /// Where the label images go.
    pub mask_topic: String,
    /// The tf topic (relative: under the namespace).
    pub tf_topic: String,
    /// The static tf topic (the camera's mounting).
    pub tf_static_topic: String,
    /// `diagnostic_msgs/DiagnosticArray`.
    pub diagnostics_topic: String,
    /// Seconds between publications of the path and of the diagnostics.
    pub path_period_s: f64,
    /// Seconds between diagnostics.
    pub diagnostics_period_s: f64,
    /// The map's points as `sensor_msgs/PointCloud2` on `map_cloud_topic`,
    /// and the keyframes as the map holds them (moved by bundle adjustment
    /// and loops), after keyframes, at most once per `map_period_s` (and
    /// after every closed loop).
    pub map_cloud: bool,
    /// Where the map's points go.
    pub map_cloud_topic: String,
    /// Shortest time between two maps published, seconds.
    pub map_period_s: f64,
    /// A `nav_msgs/OccupancyGrid` (Nav2) on `grid_topic` with each map:
    /// points between `grid_min_height` and `grid_max_height` above the
    /// map frame's z = 0 are obstacles (`world_frame = "ros"` only).
    pub grid: bool,
    /// Where the grid goes.
    pub grid_topic: String,
    /// Metres per cell.
    pub grid_resolution: f64,
    /// Lowest obstacle point, metres above the map frame's z = 0.
    pub grid_min_height: f64,
    /// Highest obstacle point (ceilings above are left out), metres.
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
pub(super) fn ros_name(key: &str, name: &str, slashes: bool) -> Result<(), String> {
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
