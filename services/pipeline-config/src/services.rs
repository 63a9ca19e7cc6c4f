//! `[services.*]`: each service process's own settings, one type per
//! service, so that a key in the wrong section is an error (naming where it
//! belongs) instead of a value nobody reads.

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

use shared_types::ServiceKind;

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

/// `[services.*]`: one section per service process.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct ServicesConfig {
    /// `[services.camera-reader]`.
    #[serde(rename = "camera-reader")]
    pub camera_reader: CameraReaderConfig,
    /// `[services.segmenter]`.
    pub segmenter: SegmenterConfig,
    /// `[services.propagator]`.
    pub propagator: PropagatorConfig,
    /// `[services.slam]`.
    pub slam: SlamConfig,
}

/// The product: the RGB-D SLAM core, YOLOv8-seg on keyframes (niced), LK
/// between them (the same values as the shipped `configs/pipeline.toml`,
/// checked by a test). The test doubles (`scripted`, `none`,
/// `ground-truth`) run only where a config names them.
impl Default for ServicesConfig {
    fn default() -> Self {
        Self {
            camera_reader: CameraReaderConfig::default(),
            segmenter: SegmenterConfig {
                // No model and no input_size: the segmenter takes its
                // default export for the clock mode (480 in lockstep, 320
                // in real time); a model or model_path naming a known
                // export brings that export's size.
                score_threshold: Some(0.25),
                weak_score_threshold: Some(0.05),
                iou_threshold: Some(0.7),
                classes: DEFAULT_DYNAMIC_CLASSES.map(String::from).to_vec(),
                threads: Some(2),
                nice: Some(5),
                ..SegmenterConfig::default()
            },
            propagator: PropagatorConfig::default(),
            slam: SlamConfig::default(),
        }
    }
}

/// What the supervisor needs of any service process: how to start it and
/// at which niceness it runs.
#[derive(Debug, Clone, Copy)]
pub struct ProcessSettings<'a> {
    /// Replaces the service's program when not empty.
    pub command: &'a [String],
    /// The process's niceness once the SLAM has tracked (unset: the
    /// supervisor's own).
    pub nice: Option<i32>,
}

/// `[services.camera-reader]`: it plays `[source]`; no backend to choose.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields, default)]
pub struct CameraReaderConfig {
    /// Replace the service's program: `["/path/to/bin", "arg", ...]`. The
    /// supervisor appends the standard service arguments.
    pub command: Vec<String>,
    /// The process's scheduling niceness (-20..=19); unset: the supervisor's.
    pub nice: Option<i32>,
}

/// `[services.segmenter]`: the keyframe masks' model.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct SegmenterConfig {
    /// Replace the service's program (the standard arguments are appended).
    pub command: Vec<String>,
    /// Where the model runs: "local" (this machine) or "remote" (a worker
    /// on another machine over Zenoh, `[remote]`; this machine runs the
    /// link in the segmenter's place).
    pub location: String,
    /// `location = "remote"`, while no worker answers: "local" (this
    /// machine's model makes the masks) or "none" (real time: the
    /// propagator carries masks; lockstep: the frame goes unmasked).
    pub fallback: String,
    /// `yolov8-seg`, `yolo11-seg`, `maskrcnn`, `ground-truth` or `none`.
    pub backend: String,
    /// `none`: simulated work per frame (milliseconds).
    pub work_ms: u64,
    /// The model's file name (located as described in `pipeline::provision`);
    /// unset: the backend's export (YOLOv8n-seg or YOLO11n-seg) for
    /// `input_size`.
    pub model: String,
    /// An explicit path to the model (then only it is tried).
    pub model_path: Option<PathBuf>,
    /// The model's sha256 (required for a model the code does not know).
    pub model_sha256: String,
    /// Minimum class score of an instance.
    pub score_threshold: Option<f32>,
    /// YOLO-seg: weaker detections, down to this score, are kept where the
    /// frame's depth shows them standing in front of their surroundings
    /// (unset: `score_threshold`, none kept that way).
    pub weak_score_threshold: Option<f32>,
    /// IoU above which the weaker of two same-class boxes is suppressed.
    pub iou_threshold: Option<f32>,
    /// The movable classes that become dynamic masks (names).
    pub classes: Vec<String>,
    /// Square network input size in pixels (unset: the named export's,
    /// else the clock mode's default: `scheduling::mode`).
    pub input_size: Option<u32>,
    /// ONNX Runtime intra-op threads.
    pub threads: Option<usize>,
    /// The process's scheduling niceness (-20..=19, higher yields the CPU):
    /// on a busy robot computer its long keyframe inferences take the
    /// cycles tracking and propagation leave instead of delaying them
    /// (tracking never waits for it: its masks are carried forward). It
    /// applies once the SLAM has tracked its first frame (until then every
    /// stage waits for the first segmenter masks). Unset: the supervisor's.
    pub nice: Option<i32>,
}

/// No model setting given: each backend takes its own defaults (the
/// product's values are [`ServicesConfig::default`]'s).
impl Default for SegmenterConfig {
    fn default() -> Self {
        Self {
            command: Vec::new(),
            location: "local".into(),
            fallback: "local".into(),
            backend: "yolov8-seg".into(),
            work_ms: 0,
            model: String::new(),
            model_path: None,
            model_sha256: String::new(),
            score_threshold: None,
            weak_score_threshold: None,
            iou_threshold: None,
            classes: Vec::new(),
            input_size: None,
            threads: None,
            nice: None,
        }
    }
}

/// `[services.propagator]`: the masks between keyframes.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct PropagatorConfig {
    /// Replace the service's program (the standard arguments are appended).
    pub command: Vec<String>,
    /// `lk`, `sam2` or `none`.
    pub backend: String,
    /// `none`: simulated work per frame (milliseconds).
    pub work_ms: u64,
    /// SAM 2: the image encoder's file name, explicit path and sha256.
    pub model: String,
    /// SAM 2: an explicit path to the image encoder.
    pub model_path: Option<PathBuf>,
    /// SAM 2: the image encoder's sha256 (required).
    pub model_sha256: String,
    /// SAM 2: the prompt / mask decoder's file name.
    pub decoder_model: String,
    /// SAM 2: an explicit path to the decoder.
    pub decoder_model_path: Option<PathBuf>,
    /// SAM 2: the decoder's sha256 (required).
    pub decoder_model_sha256: String,
    /// SAM 2: the encoder's square input size.
    pub input_size: Option<u32>,
    /// SAM 2: an object ends when its best predicted IoU falls below this,
    /// or its area below `min_area_ratio` of its keyframe area.
    pub min_predicted_iou: Option<f32>,
    /// SAM 2: see `min_predicted_iou`.
    pub min_area_ratio: Option<f32>,
    /// SAM 2: positive points sampled inside an object's mask for each
    /// prompt (besides its box).
    pub prompt_points: Option<u32>,
    /// SAM 2: ONNX Runtime intra-op threads.
    pub threads: Option<usize>,
    /// The process's scheduling niceness (-20..=19); unset: the supervisor's.
    pub nice: Option<i32>,
}

impl Default for PropagatorConfig {
    fn default() -> Self {
        Self {
            command: Vec::new(),
            backend: "lk".into(),
            work_ms: 0,
            model: String::new(),
            model_path: None,
            model_sha256: String::new(),
            decoder_model: String::new(),
            decoder_model_path: None,
            decoder_model_sha256: String::new(),
            input_size: None,
            min_predicted_iou: None,
            min_area_ratio: None,
            prompt_points: None,
            threads: None,
            nice: None,
        }
    }
}

/// `[services.slam]`: the SLAM process.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct SlamConfig {
    /// Replace the service's program (the standard arguments are appended).
    pub command: Vec<String>,
    /// `orb-rgbd` (the SLAM core) or `scripted` (a test double).
    pub backend: String,
    /// Scripted: request a keyframe every this many frames.
    pub keyframe_every: u64,
    /// Scripted: simulated work per frame (milliseconds).
    pub work_ms: u64,
    /// How masks are applied: "filter" (keypoints under the dilated mask
    /// are dropped at detection) or "blackout" (masked pixels are painted
    /// black before extraction; the ablation's row e).
    pub mask_mode: String,
    /// Scripted: append every tracked seq to this file (delivery tests).
    pub seen_log: Option<PathBuf>,
    /// Feature extraction threads (pyramid levels in parallel).
    pub threads: Option<usize>,
    /// The process's scheduling niceness (-20..=19); unset: the supervisor's.
    pub nice: Option<i32>,
    /// Write the map as a checkpoint into the run folder every this many
    /// keyframes (and at stop; 0: only at stop). A restarted SLAM service
    /// goes on from it in the same world frame.
    pub checkpoint_every_keyframes: Option<u64>,
    /// A warm standby SLAM process beside the active one: it holds the
    /// newest frames, masks and routes without tracking them, and when the
    /// active SLAM dies the supervisor promotes it at once (it reads the
    /// checkpoint and tracks the frames it holds); a new standby is started
    /// behind it. Unset: on in real time (about 1 % of a core and 11 MB),
    /// off in lockstep (where a restart replays the frame and loses none).
    pub standby: Option<bool>,
    /// Start from this map file (poses in its world frame).
    pub load_map: Option<PathBuf>,
    /// Write the map to this file at the end of the run.
    pub save_map: Option<PathBuf>,
    /// ORB-SLAM2's localization mode: track against the loaded map, add no
    /// keyframe or point (needs `load_map`).
    pub localize_only: bool,
    /// Look for loops after each keyframe and correct the map when one
    /// closes (`loops.csv` in the run folder; on by default).
    pub loop_closing: bool,
    /// RGB-D: drop features in image regions that move unlike the camera
    /// (movers no class list names; `features_moving` in frames.csv; on by
    /// default).
    pub motion_check: bool,
    /// RGB-D, real time: while the pipeline is behind the camera (over 10 %
    /// of the recent frames untracked), frames between keyframes are
    /// tracked by following the last frame's points with optical flow, up
    /// to this many in a row, instead of ORB extraction (default 3; 0: every
    /// frame extracted; lockstep always extracts).
    pub flow_frames: u32,
    /// `rgbd` (colour and depth) or `monocular` (colour only: depth
    /// ignored; the map's scale is its own, evaluated with a Sim(3)
    /// alignment).
    pub sensor: String,
}

/// The product: the RGB-D SLAM core (the shipped `configs/pipeline.toml`).
impl Default for SlamConfig {
    fn default() -> Self {
        Self {
            command: Vec::new(),
            backend: "orb-rgbd".into(),
            keyframe_every: 5,
            work_ms: 0,
            mask_mode: "filter".into(),
            seen_log: None,
            threads: Some(2),
            nice: None,
            checkpoint_every_keyframes: Some(1),
            standby: None,
            load_map: None,
            save_map: None,
            localize_only: false,
            loop_closing: true,
            motion_check: true,
            flow_frames: 3,
            sensor: "rgbd".into(),
        }
    }
}

impl SlamConfig {
    /// The sensor is a colour camera alone.
    pub fn is_monocular(&self) -> bool {
        self.sensor == "monocular"
    }

    /// A warm standby SLAM runs beside the active one (`standby`; unset:
    /// in real time).
    pub fn has_standby(&self, mode: crate::ClockMode) -> bool {
        self.standby.unwrap_or(mode.is_realtime())
    }
}

/// The `[services.*]` sections that take `key` (a misplaced key's error
/// says where it belongs).
pub(super) fn sections_taking(key: &str) -> Vec<&'static str> {
    fn takes<T: serde::de::DeserializeOwned>(key: &str) -> bool {
        let mut table = toml::Table::new();
        table.insert(key.to_string(), toml::Value::Boolean(false));
        match toml::Value::Table(table).try_into::<T>() {
            Ok(_) => true,
            // A wrong type still means the key exists.
            Err(e) => !e.to_string().contains("unknown field"),
        }
    }
    [
        ("camera-reader", takes::<CameraReaderConfig>(key)),
        ("segmenter", takes::<SegmenterConfig>(key)),
        ("propagator", takes::<PropagatorConfig>(key)),
        ("slam", takes::<SlamConfig>(key)),
    ]
    .into_iter()
    .filter_map(|(name, takes)| takes.then_some(name))
    .collect()
}

impl ServicesConfig {
    /// How to start `kind`'s process and its niceness. The bridge's
    /// settings are its own section (`[bridge]`); as a process it has a
    /// service's defaults besides its `command`.
    pub fn process<'a>(
        &'a self,
        kind: ServiceKind,
        bridge_command: &'a [String],
    ) -> ProcessSettings<'a> {
        let (command, nice) = match kind {
            ServiceKind::CameraReader => (&self.camera_reader.command, self.camera_reader.nice),
            ServiceKind::Segmenter => (&self.segmenter.command, self.segmenter.nice),
            ServiceKind::Propagator => (&self.propagator.command, self.propagator.nice),
            ServiceKind::Slam | ServiceKind::SlamStandby => (&self.slam.command, self.slam.nice),
            ServiceKind::Bridge => {
                return ProcessSettings {
                    command: bridge_command,
                    nice: None,
                }
            }
        };
        ProcessSettings {
            command: command.as_slice(),
            nice,
        }
    }

    /// Checks every service's values for range and sense.
    pub fn validate(&self) -> Result<(), String> {
        if !matches!(self.segmenter.location.as_str(), "local" | "remote") {
            return Err(format!(
                "key `services.segmenter.location`: '{}' is not one of local, remote",
                self.segmenter.location
            ));
        }
        if !matches!(self.segmenter.fallback.as_str(), "local" | "none") {
            return Err(format!(
                "key `services.segmenter.fallback`: '{}' is not one of local, none",
                self.segmenter.fallback
            ));
        }
        let fractions = [
            ("segmenter.score_threshold", self.segmenter.score_threshold),
            (
                "segmenter.weak_score_threshold",
                self.segmenter.weak_score_threshold,
            ),
            ("segmenter.iou_threshold", self.segmenter.iou_threshold),
            (
                "propagator.min_predicted_iou",
                self.propagator.min_predicted_iou,
            ),
            ("propagator.min_area_ratio", self.propagator.min_area_ratio),
        ];
        for (key, v) in fractions {
            if let Some(v) = v {
                super::in_range(&format!("services.{key}"), v as f64, 0.0, 1.0, "a fraction")?;
            }
        }
        for (key, n) in [
            ("segmenter", self.segmenter.input_size),
            ("propagator", self.propagator.input_size),
        ] {
            if let Some(n) = n.filter(|n| !(32..=4096).contains(n) || n % 32 != 0) {
                return Err(format!(
                    "key `services.{key}.input_size`: {n} is not a network input size (a multiple of 32 in 32..=4096)"
                ));
            }
        }
        for (key, t) in [
            ("segmenter", self.segmenter.threads),
            ("propagator", self.propagator.threads),
            ("slam", self.slam.threads),
        ] {
            if let Some(t) = t.filter(|t| !(1..=256).contains(t)) {
                return Err(format!(
                    "key `services.{key}.threads`: {t} is outside 1..=256"
                ));
            }
        }
        for (key, n) in [
            ("camera-reader", self.camera_reader.nice),
            ("segmenter", self.segmenter.nice),
            ("propagator", self.propagator.nice),
            ("slam", self.slam.nice),
        ] {
            if let Some(n) = n.filter(|n| !(-20..=19).contains(n)) {
                return Err(format!(
                    "key `services.{key}.nice`: {n} is not a niceness (-20..=19)"
                ));
            }
        }
        self.slam.validate()
    }
}

impl SlamConfig {
    fn validate(&self) -> Result<(), String> {
        if !matches!(self.mask_mode.as_str(), "" | "filter" | "blackout") {
            return Err(format!(
                "key `services.slam.mask_mode`: '{}' is not one of filter, blackout",
                self.mask_mode
            ));
        }
        if !matches!(self.sensor.as_str(), "" | "rgbd" | "monocular") {
            return Err(format!(
                "key `services.slam.sensor`: '{}' is not one of rgbd, monocular",
                self.sensor
            ));
        }
        if let Some(n) = self.checkpoint_every_keyframes.filter(|&n| n > 100_000) {
            return Err(format!(
                "key `services.slam.checkpoint_every_keyframes`: {n} is not a keyframe count (0 = only at stop ..= 100000)"
            ));
        }
        if self.localize_only && self.load_map.is_none() {
            return Err("key `services.slam.localize_only`: localization needs a map: set services.slam.load_map (or give --load-map)".into());
        }
        Ok(())
    }
}
