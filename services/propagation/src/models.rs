//! The propagator backends by name: what `[services.propagator] backend`
//! selects.

use anyhow::Result;
use mask_model::{model_from_config, MaskModel, ModelFactory};
use onnx_runtime::init_runtime;
use pipeline_config::PipelineConfig;
use shared_types::ServiceKind;

use crate::newcomers::NewcomerCheck;
use crate::propagate::{LkPropagator, PropagatorParams};
use crate::sam2::{Sam2Propagator, Sam2Settings};

/// Loads the backend `[services.propagator]` names (`none` included).
pub fn load(config: &PipelineConfig) -> Result<Box<dyn MaskModel>> {
    let lk: &ModelFactory = &|config| {
        let mut lk = LkPropagator::new(PropagatorParams::default());
        let routing = &config.routing;
        if routing.early_segment_requests {
            let mode = config.run.mode;
            if mode.is_realtime() && routing.unseen_view_share > 0.0 {
                tracing::debug!(
                    "routing.unseen_view_share applies to lockstep runs: in real time the segmenter would be busy on every frame it can take, at the tracking's expense"
                );
            }
            lk = lk.with_newcomer_check(NewcomerCheck::for_pipeline(&config.camera, routing, mode));
        }
        Ok(Box::new(lk))
    };
    let sam2: &ModelFactory = &|config| {
        let settings = Sam2Settings::from_config(&config.services.propagator)?;
        let env = init_runtime(&config.onnxruntime)?;
        Ok(Box::new(Sam2Propagator::load(env, settings)?))
    };
    model_from_config(
        ServiceKind::Propagator,
        config,
        &[("lk", lk), ("sam2", sam2)],
    )
}
