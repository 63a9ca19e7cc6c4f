//! The segmenter backends by name: what `[services.segmenter] backend`
//! selects, for the segmenter service and for a remote worker alike.

use anyhow::Result;
use mask_model::{model_from_config, MaskModel, ModelFactory};
use onnx_runtime::init_runtime;
use pipeline_config::PipelineConfig;
use provision::InputError;
use shared_types::ServiceKind;

use crate::exports::YoloFamily;
use crate::ground_truth::GroundTruthMasks;
use crate::maskrcnn::MaskRcnn;
use crate::onnx::{YoloSeg, YoloSettings};

/// Loads the backend `[services.segmenter]` names (`none` included).
pub fn load(config: &PipelineConfig) -> Result<Box<dyn MaskModel>> {
    let yolo: &ModelFactory = &|config| {
        let settings = YoloSettings::for_mode(&config.services.segmenter, config.run.mode)?;
        // Unset, the size depends on the clock mode: say which it is.
        tracing::info!(
            "{} input {} px ({:?} mode): {}",
            settings.family.network(),
            settings.input_size,
            config.run.mode,
            settings.model.display()
        );
        let env = init_runtime(&config.onnxruntime)?;
        Ok(Box::new(YoloSeg::load(env, settings)?))
    };
    let maskrcnn: &ModelFactory = &|config| {
        let env = init_runtime(&config.onnxruntime)?;
        Ok(Box::new(MaskRcnn::from_config(
            env,
            &config.services.segmenter,
        )?))
    };
    let truth: &ModelFactory = &|config| match GroundTruthMasks::open(&config.source.path) {
        Ok(m) => Ok(Box::new(m)),
        // Not retried: the dataset will not grow masks.
        Err(e) => Err(InputError(format!("{e:#}")).into()),
    };
    model_from_config(
        ServiceKind::Segmenter,
        config,
        &[
            (YoloFamily::V8.backend(), yolo),
            (YoloFamily::V11.backend(), yolo),
            ("maskrcnn", maskrcnn),
            ("ground-truth", truth),
        ],
    )
}
