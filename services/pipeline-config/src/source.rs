//! `[source]`: what the camera-reader plays.

use datasets::source::{image_folder, repeated, tum_folder, FrameEntry, SourceError};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

use super::{bridge::ros_name, in_range, ClockMode, RunConfig, SlamConfig};

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
    /// Requested height, likewise.
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

/// `[source]`: what the camera-reader plays.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct SourceConfig {
    /// A TUM folder, an image folder, frames from outside, a V4L2 camera or ROS 2 topics.
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

impl SourceConfig {
    /// The frames a run with these settings plays, in order: the folder
    /// read as `kind` says, cut to `limit` (0: all), played `repeat` times.
    /// A live source has no list: [`SourceError::Live`].
    pub fn recorded_frames(&self) -> Result<Vec<FrameEntry>, SourceError> {
        let mut frames = match self.kind {
            SourceKind::Tum => tum_folder(&self.path, self.max_time_diff),
            SourceKind::Images => image_folder(&self.path, self.image_period),
            SourceKind::External => Err(SourceError::Live("external")),
            SourceKind::V4l2 => Err(SourceError::Live("v4l2")),
            SourceKind::Ros2 => Err(SourceError::Live("ros2")),
        }?;
        if self.limit > 0 {
            frames.truncate(self.limit as usize);
        }
        Ok(repeated(frames, self.repeat))
    }

    /// Checks what the source needs of the run and the SLAM (depth, the
    /// clock mode) and a live source's own settings.
    pub fn validate(&self, run: &RunConfig, slam: &SlamConfig) -> Result<(), String> {
        if self.kind == SourceKind::Images && slam.backend == "orb-rgbd" && !slam.is_monocular() {
            return Err(
                    "key `services.slam.sensor`: \"rgbd\" needs depth, and `source.kind = \"images\"` \
                     plays frames without it: set services.slam.sensor = \"monocular\" (or play a TUM \
                     RGB-D folder, kind = \"tum\")"
                        .into(),
                );
        }
        if self.kind == SourceKind::V4l2 {
            let v = &self.v4l2;
            if run.mode != ClockMode::Realtime {
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
            if v.width == 0 || v.height == 0 || v.width > run.max_width || v.height > run.max_height
            {
                return Err(format!(
                        "key `source.v4l2.width`: {}x{} must be within run.max_width x run.max_height = {}x{}",
                        v.width, v.height, run.max_width, run.max_height
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
                && slam.backend == "orb-rgbd"
                && !slam.is_monocular()
            {
                return Err(
                        "key `services.slam.sensor`: \"rgbd\" needs depth, and `source.v4l2.depth_device` \
                         is empty: set services.slam.sensor = \"monocular\" for a colour camera, or name \
                         the camera's depth node"
                            .into(),
                    );
            }
        }
        if self.kind == SourceKind::Ros2 {
            let r = &self.ros2;
            if run.mode != ClockMode::Realtime {
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
                if !slam.is_monocular() {
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
        if self.kind == SourceKind::External && run.mode != ClockMode::Realtime {
            return Err(
                    "key `run.mode`: `source.kind = \"external\"` needs run.mode = \"realtime\" \
                     (an outside publisher sends at its own rate; lockstep needs the camera-reader to \
                     wait for each Track and to replay a frame after a restart)"
                        .into(),
                );
        }
        Ok(())
    }
}
