#![deny(missing_docs)]
//! The pipeline configuration (`configs/pipeline.toml`).
//!
//! One file describes a whole run: the source, the clock mode, routing,
//! restart policy and each service's backend. The supervisor reads it, copies
//! the resolved file into the run folder and hands that copy to every child,
//! so all processes of a run (and a resumed run) see the same settings.
//! Unknown keys are errors that name their path (`services.slam.keyframe_evry`):
//! a typo must never silently fall back to a default on a robot. Each
//! section has its own type (`services.rs` one per service, `source.rs`,
//! `bridge.rs`, the small ones here) with its own range checks; a key in
//! another service's section is an error that says where it belongs.

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

mod bridge;
mod remote;
mod services;
mod source;

pub use bridge::BridgeConfig;
pub use remote::{check_run_name, RemoteConfig};
pub use services::*;
pub use source::{Ros2SourceConfig, SourceConfig, SourceKind, V4l2Config};

/// A whole run's configuration: one field per section of `pipeline.toml`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct PipelineConfig {
    /// `[run]`: clock mode, output, frame size limits.
    #[serde(default)]
    pub run: RunConfig,
    /// `[source]`: what is played (dataset, camera, ROS 2 topic).
    #[serde(default)]
    pub source: SourceConfig,
    /// `[routing]`: which frames go to the segmenter.
    #[serde(default)]
    pub routing: RoutingConfig,
    /// `[supervisor]`: restarts and the watchdog.
    #[serde(default)]
    pub supervisor: SupervisorConfig,
    /// `[services.*]`: each service's own settings.
    #[serde(default)]
    pub services: ServicesConfig,
    /// `[onnxruntime]`: the library and its execution providers.
    #[serde(default)]
    pub onnxruntime: OnnxRuntimeConfig,
    /// `[camera]`: intrinsics, distortion, rolling shutter.
    #[serde(default)]
    pub camera: CameraConfig,
    /// `[bridge]`: ROS 2.
    #[serde(default)]
    pub bridge: BridgeConfig,
    /// `[remote]`: mask workers on another machine.
    #[serde(default)]
    pub remote: RemoteConfig,
}

/// Pinhole intrinsics and radial-tangential distortion of the RGB camera
/// (the depth image is registered to it). Default: TUM Freiburg 1.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct CameraConfig {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
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

/// The ONNX Runtime settings (`[onnxruntime]`); their type lives with the
/// code that finds and checks the library, so the model crates need no IPC.
pub use provision::{OnnxRuntimeConfig, Provider};

/// How frames are clocked through the pipeline (its timing rules live in
/// the scheduling crate).
pub use scheduling::ClockMode;

/// `[run]`: how the run is clocked and where it writes.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RunConfig {
    /// Lockstep (every frame, in order) or real time (the camera's pace).
    pub mode: ClockMode,
    /// Real-time playback speed factor (2.0 plays twice as fast as recorded).
    pub speed: f64,
    /// Where run folders are created (relative to the working directory).
    pub output_dir: PathBuf,
    /// Largest frame the shared-memory segments are sized for.
    pub max_width: u32,
    /// Tallest frame, likewise.
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
    /// None (the rows of `masks.csv` only).
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

/// `[routing]`: see [`scheduling::RoutingConfig`].
pub use scheduling::RoutingConfig;

/// `[supervisor]`: how services are restarted and when a run counts as stalled.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct SupervisorConfig {
    /// Restart delay of a service that died before it had served for a
    /// second (a start-up crash loop); doubled after each such death. A
    /// service that served is restarted at once.
    pub restart_backoff_initial_ms: u64,
    /// The longest that delay grows to.
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

/// A configuration error that names the file, the key path and the problem.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    // The OS error is part of the message, not a `source`: error chains
    // printed with their causes would say it twice.
    /// The file could not be read.
    #[error("cannot read config file {path}: {error}")]
    Read {
        /// The file.
        path: PathBuf,
        /// What the system said.
        error: std::io::Error,
    },
    /// The file was read but is not a valid configuration.
    #[error("config file {path}: {message}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// The key, its line and what is wrong.
        message: String,
    },
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
        self.remote
            .validate(self.services.segmenter.location == "remote")?;
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
        self.services.validate()?;
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
        self.camera
            .validate()
            .map_err(|e| e.replacen("key `", "key `camera.", 1))?;
        if self.onnxruntime.providers.is_empty() {
            return Err(
                "key `onnxruntime.providers`: empty; list at least one of cpu, cuda, tensorrt"
                    .into(),
            );
        }
        self.source.validate(&self.run, &self.services.slam)?;
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

    /// How to start `kind`'s process, and its niceness.
    pub fn process(&self, kind: shared_types::ServiceKind) -> ProcessSettings<'_> {
        self.services.process(kind, &self.bridge.command)
    }

    /// The configuration as TOML (the run folder's `config.toml`).
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
        if let Some(misplaced) = misplaced_service_key(&path, &msg, &line) {
            return misplaced;
        }
        if path.is_empty() || path == "." {
            format!("{msg}{line}")
        } else {
            format!("key `{path}`{line}: {msg}")
        }
    })
}

/// A key that another `[services.*]` section takes (`[services.propagator]
/// loop_closing = true`): the error names the section, the key, its line
/// and where it belongs.
fn misplaced_service_key(path: &str, msg: &str, line: &str) -> Option<String> {
    let key = msg.strip_prefix("unknown field `")?.split('`').next()?;
    let section = path.strip_suffix(&format!(".{key}")).unwrap_or(path);
    let service = section.strip_prefix("services.")?;
    let belongs: Vec<String> = services::sections_taking(key)
        .into_iter()
        .filter(|s| *s != service)
        .map(|s| format!("[services.{s}]"))
        .collect();
    if belongs.is_empty() {
        return None;
    }
    Some(format!(
        "key `{section}.{key}`{line}: [{section}] has no key `{key}`; it belongs in {}",
        belongs.join(" or ")
    ))
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

    /// Every key of `config` (with all its optional keys set).
    fn every_key() -> Vec<String> {
        let mut full = PipelineConfig::default();
        full.onnxruntime.library = Some("/x".into());
        let x = || Some(PathBuf::from("/x"));
        let s = &mut full.services;
        s.camera_reader.nice = Some(0);
        s.segmenter.model_path = x();
        s.segmenter.input_size = Some(320);
        let p = &mut s.propagator;
        (p.model_path, p.decoder_model_path) = (x(), x());
        (p.input_size, p.threads, p.nice) = (Some(1024), Some(1), Some(0));
        (p.min_predicted_iou, p.min_area_ratio) = (Some(0.5), Some(0.2));
        p.prompt_points = Some(3);
        (s.slam.seen_log, s.slam.load_map, s.slam.save_map) = (x(), x(), x());
        (s.slam.nice, s.slam.standby) = (Some(0), Some(true));
        let mut keys = Vec::new();
        leaf_keys(&toml::Table::try_from(&full).unwrap(), "", &mut keys);
        keys
    }

    #[test]
    fn the_shipped_file_documents_every_key_in_its_own_section_and_no_other() {
        let keys: std::collections::BTreeSet<String> = every_key().into_iter().collect();
        // Documented keys: `key =` and `# key =` lines under `[section]` or
        // `# [section]` headers.
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
                    documented.insert(format!("{section}.{key}"));
                }
            }
        }
        let missing: Vec<&String> = keys.difference(&documented).collect();
        assert!(
            missing.is_empty(),
            "configs/pipeline.toml does not document: {missing:?}"
        );
        let unknown: Vec<&String> = documented
            .iter()
            .filter(|k| k.starts_with("services."))
            .filter(|k| !keys.contains(*k))
            .collect();
        assert!(
            unknown.is_empty(),
            "configs/pipeline.toml documents keys no service takes: {unknown:?}"
        );
        for svc in ["slam", "segmenter", "propagator", "camera-reader"] {
            assert!(
                text.contains(&format!("[services.{svc}]")),
                "no [services.{svc}] section"
            );
        }
    }

    #[test]
    fn a_key_in_the_wrong_service_section_names_section_key_line_and_where_it_belongs() {
        let err = PipelineConfig::parse(
            "[services.slam]\nbackend = \"orb-rgbd\"\n\n[services.propagator]\nloop_closing = true\n",
        )
        .unwrap_err();
        assert!(err.contains("services.propagator.loop_closing"), "{err}");
        assert!(err.contains("line 5"), "{err}");
        assert!(err.contains("belongs in [services.slam]"), "{err}");
        let err = PipelineConfig::parse("[services.slam]\nclasses = [\"person\"]\n").unwrap_err();
        assert!(err.contains("belongs in [services.segmenter]"), "{err}");
        // A key several sections take names them all.
        let err = PipelineConfig::parse("[services.camera-reader]\nthreads = 2\n").unwrap_err();
        assert!(
            err.contains("[services.segmenter] or [services.propagator] or [services.slam]"),
            "{err}"
        );
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
        for text in datasets::fuzz::texts(7, 3000) {
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
