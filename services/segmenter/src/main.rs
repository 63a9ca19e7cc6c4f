//! segmenter service: keyframe instance segmentation.
//!
//! A thin shell: the worker loop is `pipeline::mask_worker`; this binary
//! only picks the model backend named in `[services.segmenter]`.

use std::process::ExitCode;

use clap::Parser;
use onnx_runtime::init_runtime;
use pipeline::mask_worker::{self, model_from_config, ModelFactory};
use pipeline::runtime::{run_service, InputError, ServiceArgs};
use segmenter::ground_truth::GroundTruthMasks;
use segmenter::maskrcnn::MaskRcnn;
use segmenter::onnx::{YoloSeg, YoloSettings};
use shared_types::{MaskSource, ServiceKind};

#[derive(Debug, Parser)]
#[command(about = "dynslam segmenter: keyframe instance segmentation")]
struct Args {
    #[command(flatten)]
    service: ServiceArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    run_service(ServiceKind::Segmenter, &args.service, |ctx| {
        let yolo: &ModelFactory = &|ctx| {
            let settings =
                YoloSettings::for_mode(&ctx.config.services.segmenter, ctx.config.run.mode)?;
            // Unset, the size depends on the clock mode: say which it is.
            tracing::info!(
                "YOLOv8-seg input {} px ({:?} mode): {}",
                settings.input_size,
                ctx.config.run.mode,
                settings.model.display()
            );
            let env = init_runtime(&ctx.config.onnxruntime)?;
            Ok(Box::new(YoloSeg::load(env, settings)?))
        };
        let maskrcnn: &ModelFactory = &|ctx| {
            let env = init_runtime(&ctx.config.onnxruntime)?;
            Ok(Box::new(MaskRcnn::from_config(
                env,
                &ctx.config.services.segmenter,
            )?))
        };
        let truth: &ModelFactory = &|ctx| match GroundTruthMasks::open(&ctx.config.source.path) {
            Ok(m) => Ok(Box::new(m)),
            // Not retried: the dataset will not grow masks.
            Err(e) => Err(InputError(format!("{e:#}")).into()),
        };
        let model = model_from_config(
            &ctx,
            &[
                ("yolov8-seg", yolo),
                ("maskrcnn", maskrcnn),
                ("ground-truth", truth),
            ],
        )?;
        mask_worker::run(ctx, MaskSource::Segmenter, model)
    })
}
