//! The YOLO-seg backends (YOLOv8n-seg, YOLO11n-seg: [`crate::exports`]):
//! ONNX Runtime (`onnx_runtime`: the provisioned
//! library, execution providers) running a verified model file; decoding in
//! [`crate::yolo`].

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use mask_model::MaskModel;
use ort::session::Session;
use ort::value::TensorRef;
use pipeline_config::{ClockMode, SegmenterConfig};
use provision::InputError;
use raster::RgbView;
use shared_types::views::{DepthImage, FrameView, MasksView};
use shared_types::Instance;

use crate::coco;
use crate::exports::{self, YoloFamily};
use crate::foreground::{continues, stands_out, ForegroundParams};
use crate::letterbox::Letterbox;
use crate::yolo::{candidates, nms, paint_masks, Detection, Prototypes, MASK_COEFFICIENTS};

/// Settings of the backend, resolved from the configuration.
#[derive(Debug, Clone)]
pub struct YoloSettings {
    /// The network generation (the model's, when it names a known export).
    pub family: YoloFamily,
    /// The model file (verified).
    pub model: PathBuf,
    /// The square network input in pixels.
    pub input_size: usize,
    /// Minimum class score of an instance.
    pub score_threshold: f32,
    /// Detections from here up to `score_threshold` are kept where they
    /// continue an object of the masks before or depth shows them standing
    /// in front of their surroundings ([`crate::foreground`]); at or above
    /// `score_threshold`, none is kept that way.
    pub weak_score_threshold: f32,
    /// How a weak detection is shown to stand in front.
    pub foreground: ForegroundParams,
    /// Class-wise NMS overlap.
    pub iou_threshold: f32,
    /// COCO ids that become dynamic masks.
    pub dynamic_classes: Vec<usize>,
    /// ONNX Runtime intra-op threads.
    pub threads: usize,
}

/// The input size that an unset `input_size` (and no model naming an
/// export) means in a run of this clock mode: a per-mode default, so it is
/// the scheduling crate's ([`scheduling::mode::segmenter_input_size`]).
pub fn default_input_size(mode: ClockMode) -> usize {
    scheduling::mode::segmenter_input_size(mode)
}

impl YoloSettings {
    /// Resolves and verifies the settings of `[services.segmenter]`: every
    /// problem is an [`InputError`] that names the key or file. Without
    /// `model`, the export of the backend's family ([`exports::EXPORTS`])
    /// for `input_size` is used; without
    /// either, the lockstep default ([`default_input_size`]).
    pub fn from_config(cfg: &SegmenterConfig) -> Result<Self> {
        Self::for_mode(cfg, ClockMode::Lockstep)
    }

    /// [`Self::from_config`] for a run in `mode`: an unset `input_size`
    /// with no model naming an export means [`default_input_size`].
    pub fn for_mode(cfg: &SegmenterConfig, mode: ClockMode) -> Result<Self> {
        // A known export named by `model` or by the file name of
        // `model_path` brings its own input size, so pointing `model_path`
        // at the shared 320 file works without also setting `input_size`.
        let backend = cfg.backend.as_str();
        let named_export = {
            let file_name = cfg
                .model_path
                .as_deref()
                .and_then(|p| p.file_name())
                .and_then(|n| n.to_str());
            let name = if cfg.model.is_empty() {
                file_name.unwrap_or("")
            } else {
                cfg.model.as_str()
            };
            exports::named(name)
        };
        let family = match named_export {
            Some(e) if e.family.backend() != backend && YoloFamily::from_backend(backend).is_some() => {
                return Err(InputError(format!(
                    "key `services.segmenter.backend`: `{}`, but the model '{}' is a {} export; set backend = \"{}\"",
                    backend,
                    e.file,
                    e.family.network(),
                    e.family.backend()
                ))
                .into())
            }
            Some(e) => e.family,
            None => YoloFamily::from_backend(backend).unwrap_or(YoloFamily::V8),
        };
        let input_size = match (cfg.input_size, named_export) {
            (Some(n), Some(m)) if n as usize != m.input_size => {
                return Err(InputError(format!(
                    "key `services.segmenter.input_size`: {n}, but the model '{}' is the {} export; drop `input_size` or choose the model for {n}",
                    m.file, m.input_size
                ))
                .into())
            }
            (Some(n), _) => n as usize,
            (None, Some(m)) => m.input_size,
            (None, None) => default_input_size(mode),
        };
        if input_size == 0 || !input_size.is_multiple_of(32) {
            return Err(InputError(format!(
                "key `services.segmenter.input_size`: {input_size} must be a positive multiple of 32"
            ))
            .into());
        }
        let (file, known) = if !cfg.model.is_empty() {
            (cfg.model.as_str(), named_export)
        } else if let Some(m) = named_export {
            (m.file, Some(m))
        } else {
            let m = exports::export_for(family, input_size).map_err(InputError)?;
            (m.file, Some(m))
        };
        let sha = match (cfg.model_sha256.is_empty(), known) {
            (false, _) => cfg.model_sha256.as_str(),
            (true, Some(m)) => m.sha256,
            (true, None) => {
                return Err(InputError(format!(
                    "key `services.segmenter.model_sha256`: required for model '{file}'"
                ))
                .into())
            }
        };
        let derived = known.is_some_and(|m| !m.shared);
        let model = verified_model(file, sha, cfg.model_path.as_deref()).map_err(|e| {
            if derived && cfg.model_path.is_none() {
                InputError(format!(
                    "{e}; `just setup` makes it from the shared 320 {} model (tools/yolo_input_size.py)",
                    family.network()
                ))
                .into()
            } else {
                e
            }
        })?;
        let dynamic_classes =
            coco::dynamic_classes(&cfg.classes, "segmenter").map_err(InputError)?;
        let score_threshold = cfg.score_threshold.unwrap_or(0.5);
        let weak_score_threshold = cfg.weak_score_threshold.unwrap_or(score_threshold);
        let iou_threshold = cfg.iou_threshold.unwrap_or(0.7);
        for (key, v) in [
            ("score_threshold", score_threshold),
            ("weak_score_threshold", weak_score_threshold),
            ("iou_threshold", iou_threshold),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(InputError(format!(
                    "key `services.segmenter.{key}`: {v} is not in 0..1"
                ))
                .into());
            }
        }
        Ok(Self {
            family,
            model,
            input_size,
            score_threshold,
            weak_score_threshold,
            foreground: ForegroundParams::default(),
            iou_threshold,
            dynamic_classes,
            threads: cfg.threads.unwrap_or(2).max(1),
        })
    }
}

use onnx_runtime::{open_session, verified_model};

/// YOLO-seg instance segmentation (either family: one interface).
pub struct YoloSeg {
    _env: ort::environment::Environment,
    session: Session,
    settings: YoloSettings,
    input: Vec<f32>,
    weak: WeakCounts,
}

/// Weak detections (below `score_threshold`) over a run, for the exit log.
#[derive(Debug, Default, Clone, Copy)]
pub struct WeakCounts {
    /// Kept: they continue an object of the masks before.
    pub continued: u64,
    /// Kept: depth shows them in front of their surroundings.
    pub in_front: u64,
    /// Left out: no evidence.
    pub refused: u64,
}

impl YoloSeg {
    /// The model loaded in ONNX Runtime with `settings`.
    pub fn load(env: ort::environment::Environment, settings: YoloSettings) -> Result<Self> {
        let session = open_session(&env, &settings.model, settings.threads)?;
        onnx_runtime::check_signature(
            &session,
            &settings.model,
            "YOLO-seg export",
            &["images"],
            &["output0", "output1"],
        )?;
        onnx_runtime::check_input_size(
            &session,
            &settings.model,
            "images",
            settings.input_size,
            "services.segmenter.input_size",
        )?;
        let n = settings.input_size;
        let mut me = Self {
            _env: env,
            session,
            input: vec![0.0; 3 * n * n],
            settings,
            weak: WeakCounts::default(),
        };
        // Warm-up: the first run allocates and plans; do it before frames come.
        let blank = vec![114u8; 64 * 48 * 3];
        me.segment(&blank, 64, 48, &mut vec![0u8; 64 * 48])?;
        Ok(me)
    }

    /// Segments an RGB8 image: labels (`w*h`, zeroed by the caller) and instances.
    pub fn segment(
        &mut self,
        rgb: &[u8],
        width: usize,
        height: usize,
        labels: &mut [u8],
    ) -> Result<Vec<Instance>> {
        self.segment_rgbd(rgb, None, None, width, height, labels)
    }

    /// Weak detections kept and left out so far.
    pub fn weak_counts(&self) -> WeakCounts {
        self.weak
    }

    /// [`Self::segment`] with what can confirm a weak detection
    /// (`weak_score_threshold`): the label image of the frame before
    /// (`previous`, `width*height`; a weak detection that continues an
    /// object there is kept, as a tracker keeps a low-score detection that
    /// extends a track) and the frame's depth (one that stands in front of
    /// its surroundings is kept).
    pub fn segment_rgbd(
        &mut self,
        rgb: &[u8],
        depth: Option<DepthImage>,
        previous: Option<&[u8]>,
        width: usize,
        height: usize,
        labels: &mut [u8],
    ) -> Result<Vec<Instance>> {
        let n = self.settings.input_size;
        let colour = RgbView::from_bytes(rgb, width, height).with_context(|| {
            format!(
                "colour image of {} bytes is not {width}x{height} RGB8",
                rgb.len()
            )
        })?;
        let lb = Letterbox::new(width, height, n);
        lb.fill_input(colour, &mut self.input);
        let input = TensorRef::from_array_view(([1usize, 3, n, n], &self.input[..]))?;
        let outputs = self.session.run(ort::inputs!["images" => input])?;
        let (shape0, out0) = outputs["output0"].try_extract_tensor::<f32>()?;
        let (shape1, out1) = outputs["output1"].try_extract_tensor::<f32>()?;
        let (rows, anchors) = (shape0[1] as usize, shape0[2] as usize);
        if rows < 4 + MASK_COEFFICIENTS + 1
            || shape1.len() != 4
            || shape1[1] as usize != MASK_COEFFICIENTS
        {
            bail!("unexpected YOLO-seg outputs {shape0:?} / {shape1:?}");
        }
        let num_classes = rows - 4 - MASK_COEFFICIENTS;
        let wanted = |c: usize| self.settings.dynamic_classes.contains(&c);
        let strong = self.settings.score_threshold;
        let previous = previous.filter(|p| p.len() == width * height);
        let lowest = if depth.is_some() || previous.is_some() {
            self.settings.weak_score_threshold.min(strong)
        } else {
            strong
        };
        let dets = candidates(out0, num_classes, anchors, lowest, &wanted);
        let dets = nms(
            dets,
            self.settings.iou_threshold,
            shared_types::MAX_INSTANCES,
        );
        let protos = Prototypes {
            data: out1,
            height: shape1[2] as usize,
            width: shape1[3] as usize,
        };
        let foreground = self.settings.foreground;
        let weak = &mut self.weak;
        let keep = |d: &Detection, pixels: &[u32]| {
            if d.score >= strong {
                return true;
            }
            let (kept, counter) = if previous.is_some_and(|p| continues(pixels, p)) {
                (true, &mut weak.continued)
            } else if depth
                .is_some_and(|depth| stands_out(pixels, &depth, width, height, &foreground))
            {
                (true, &mut weak.in_front)
            } else {
                (false, &mut weak.refused)
            };
            *counter += 1;
            kept
        };
        Ok(paint_masks(
            &dets, &protos, &lb, width, height, labels, keep,
        ))
    }
}

impl MaskModel for YoloSeg {
    fn name(&self) -> &str {
        self.settings.family.backend()
    }

    fn summary(&self) -> Option<String> {
        let w = self.weak;
        Some(format!(
            "weak detections (score {:.2}-{:.2}) kept: {} continuing an object of the masks before, {} in front of their surroundings in depth; left out: {}",
            self.settings.weak_score_threshold,
            self.settings.score_threshold,
            w.continued,
            w.in_front,
            w.refused
        ))
    }

    fn infer(&mut self, frame: &FrameView, labels: &mut [u8]) -> Result<Vec<Instance>> {
        self.infer_after(frame, None, labels)
    }

    fn infer_after(
        &mut self,
        frame: &FrameView,
        previous: Option<&MasksView>,
        labels: &mut [u8],
    ) -> Result<Vec<Instance>> {
        let (width, height) = (frame.width(), frame.height());
        let previous = previous.map(|m| m.labels);
        self.segment_rgbd(
            frame.rgb,
            frame.depth_image(),
            previous,
            width,
            height,
            labels,
        )
        .with_context(|| format!("{} inference", self.settings.family.network()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_unset_input_size_is_480_in_lockstep_and_320_in_real_time() {
        assert_eq!(default_input_size(ClockMode::Lockstep), 480);
        assert_eq!(default_input_size(ClockMode::Realtime), 320);
        // (The run with the model found beside the repo:
        // tests/models_pipeline.rs.) A set size wins over the mode.
        let err = YoloSettings::for_mode(
            &SegmenterConfig {
                input_size: Some(416),
                ..Default::default()
            },
            ClockMode::Realtime,
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("416"), "{err}");
        // A model naming an export wins too.
        let shared = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../../shared/models/yolov8n-seg_f32.onnx");
        let named = SegmenterConfig {
            model_path: Some(shared),
            ..Default::default()
        };
        let lockstep = YoloSettings::for_mode(&named, ClockMode::Lockstep).unwrap();
        assert_eq!(lockstep.input_size, 320);
    }

    #[test]
    fn a_model_path_to_a_known_export_brings_its_input_size() {
        let shared = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../../shared/models/yolov8n-seg_f32.onnx");
        let cfg = SegmenterConfig {
            model_path: Some(shared),
            ..Default::default()
        };
        assert_eq!(YoloSettings::from_config(&cfg).unwrap().input_size, 320);
        let mismatched = SegmenterConfig {
            input_size: Some(640),
            ..cfg
        };
        let err = YoloSettings::from_config(&mismatched)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("input_size") && err.contains("640") && err.contains("320 export"),
            "{err}"
        );
    }
}
