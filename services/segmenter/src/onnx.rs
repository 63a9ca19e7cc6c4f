//! The YOLOv8-seg backend: ONNX Runtime (`onnx_runtime`: the provisioned
//! library, execution providers) running a verified model file; decoding in
//! [`crate::yolo`].

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use ort::session::Session;
use ort::value::TensorRef;
use pipeline::config::ServiceConfig;
use pipeline::mask_worker::MaskModel;
use pipeline::runtime::InputError;
use pipeline::views::FrameView;
use shared_types::Instance;

use crate::coco;
use crate::letterbox::Letterbox;
use crate::yolo::{candidates, nms, paint_masks, Prototypes, MASK_COEFFICIENTS};

/// Settings of the backend, resolved from the configuration.
#[derive(Debug, Clone)]
pub struct YoloSettings {
    pub model: PathBuf,
    pub input_size: usize,
    pub score_threshold: f32,
    pub iou_threshold: f32,
    pub dynamic_classes: Vec<usize>,
    pub threads: usize,
}

/// Default model file and its sha256 (../shared/models/README.md).
pub const DEFAULT_MODEL: &str = "yolov8n-seg_f32.onnx";
pub const DEFAULT_MODEL_SHA256: &str =
    "38459a0adc72f8b13be368e641b3c1a9815799b9bddbb86e0140aa18ec059942";

impl YoloSettings {
    /// Resolves and verifies the settings of `[services.segmenter]`: every
    /// problem is an [`InputError`] that names the key or file.
    pub fn from_config(cfg: &ServiceConfig) -> Result<Self> {
        let file = if cfg.model.is_empty() {
            DEFAULT_MODEL
        } else {
            cfg.model.as_str()
        };
        let sha = if cfg.model_sha256.is_empty() {
            if file != DEFAULT_MODEL {
                return Err(InputError(format!(
                    "key `services.segmenter.model_sha256`: required for model '{file}'"
                ))
                .into());
            }
            DEFAULT_MODEL_SHA256
        } else {
            cfg.model_sha256.as_str()
        };
        let model = verified_model(file, sha, cfg.model_path.as_deref())?;
        let dynamic_classes =
            coco::dynamic_classes(&cfg.classes, "segmenter").map_err(InputError)?;
        let score_threshold = cfg.score_threshold.unwrap_or(0.5);
        let iou_threshold = cfg.iou_threshold.unwrap_or(0.7);
        for (key, v) in [
            ("score_threshold", score_threshold),
            ("iou_threshold", iou_threshold),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(InputError(format!(
                    "key `services.segmenter.{key}`: {v} is not in 0..1"
                ))
                .into());
            }
        }
        let input_size = cfg.input_size.unwrap_or(320) as usize;
        if input_size == 0 || !input_size.is_multiple_of(32) {
            return Err(InputError(format!(
                "key `services.segmenter.input_size`: {input_size} must be a positive multiple of 32"
            ))
            .into());
        }
        Ok(Self {
            model,
            input_size,
            score_threshold,
            iou_threshold,
            dynamic_classes,
            threads: cfg.threads.unwrap_or(2).max(1),
        })
    }
}

use onnx_runtime::{open_session, verified_model};

/// YOLOv8-seg instance segmentation.
pub struct YoloSeg {
    _env: ort::environment::Environment,
    session: Session,
    settings: YoloSettings,
    input: Vec<f32>,
}

impl YoloSeg {
    pub fn load(env: ort::environment::Environment, settings: YoloSettings) -> Result<Self> {
        let session = open_session(&env, &settings.model, settings.threads)?;
        onnx_runtime::check_signature(
            &session,
            &settings.model,
            "YOLOv8-seg export",
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
        let n = self.settings.input_size;
        let lb = Letterbox::new(width, height, n);
        lb.fill_input(rgb, width, height, &mut self.input);
        let input = TensorRef::from_array_view(([1usize, 3, n, n], &self.input[..]))?;
        let outputs = self.session.run(ort::inputs!["images" => input])?;
        let (shape0, out0) = outputs["output0"].try_extract_tensor::<f32>()?;
        let (shape1, out1) = outputs["output1"].try_extract_tensor::<f32>()?;
        let (rows, anchors) = (shape0[1] as usize, shape0[2] as usize);
        if rows < 4 + MASK_COEFFICIENTS + 1
            || shape1.len() != 4
            || shape1[1] as usize != MASK_COEFFICIENTS
        {
            bail!("unexpected YOLOv8-seg outputs {shape0:?} / {shape1:?}");
        }
        let num_classes = rows - 4 - MASK_COEFFICIENTS;
        let wanted = |c: usize| self.settings.dynamic_classes.contains(&c);
        let dets = candidates(
            out0,
            num_classes,
            anchors,
            self.settings.score_threshold,
            &wanted,
        );
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
        Ok(paint_masks(&dets, &protos, &lb, width, height, labels))
    }
}

impl MaskModel for YoloSeg {
    fn name(&self) -> &str {
        "yolov8-seg"
    }

    fn infer(&mut self, frame: &FrameView, labels: &mut [u8]) -> Result<Vec<Instance>> {
        self.segment(frame.rgb, frame.width(), frame.height(), labels)
            .context("YOLOv8-seg inference")
    }
}
