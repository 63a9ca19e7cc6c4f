//! `dynslam run` and `dynslam resume`: the configuration resolved, the run
//! executed, its summary printed and its exit code chosen.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use pipeline::config::{ClockMode, PipelineConfig};
use run_folder::run_dir;
use supervisor::run::{execute, RunSummary};

use crate::cli::{Mode, RunArgs, SensorArg};

/// `dynslam run`'s configuration: the file, the flags over it, the dataset
/// checked, the camera chosen (still without the map files prepared).
pub(crate) fn run_config(
    args: RunArgs,
) -> Result<(
    PipelineConfig,
    PathBuf,
    pipeline::cameras::CameraChoice,
    Option<String>,
)> {
    let RunArgs {
        dataset,
        config,
        camera,
        require_masks,
        load_map,
        save_map,
        localize_only,
        output_dir,
        mode,
        no_masks,
        sensor,
        limit,
        run_id,
        ros2,
    } = args;
    let mut cfg = load_config(config.as_deref())?;
    cfg.bridge.enabled |= ros2;
    if let Some(s) = sensor {
        cfg.services.slam.sensor = match s {
            SensorArg::Rgbd => "rgbd",
            SensorArg::Monocular => "monocular",
        }
        .into();
        cfg.validate()
            .map_err(|e| anyhow::anyhow!("--sensor with the configuration: {e}"))?;
    }
    let slam = &mut cfg.services.slam;
    slam.load_map = load_map.or(slam.load_map.take());
    slam.save_map = save_map.or(slam.save_map.take());
    slam.localize_only |= localize_only;
    if let Some(d) = dataset {
        cfg.source.path = d;
    }
    if require_masks {
        cfg.run.require_masks = true;
    }
    let out = output_dir.unwrap_or_else(|| cfg.run.output_dir.clone());
    resolve_source(&mut cfg, &out)?;
    if let Some(m) = mode {
        cfg.run.mode = match m {
            Mode::Lockstep => ClockMode::Lockstep,
            Mode::Realtime => ClockMode::Realtime,
        };
        cfg.validate()
            .map_err(|e| anyhow::anyhow!("--mode with the configuration: {e}"))?;
    }
    if no_masks {
        cfg.routing.no_masks = true;
    }
    if let Some(l) = limit {
        cfg.source.limit = l;
    }
    if matches!(
        cfg.services.segmenter.backend.as_str(),
        "yolov8-seg" | "yolo11-seg" | "maskrcnn"
    ) {
        // Caught here, before any process starts, not as a degraded run.
        segmentation::coco::dynamic_classes(&cfg.services.segmenter.classes, "segmenter")
            .map_err(anyhow::Error::msg)?;
    }
    if cfg.source.kind == pipeline::config::SourceKind::Ros2 && camera.is_none() {
        // A ROS 2 camera says its intrinsics on its CameraInfo topic.
        cfg.camera = supervisor::ros2_camera::camera_info(&cfg)?;
    }
    let choice = pipeline::cameras::choose(camera.as_deref(), &cfg.source.path, &cfg.camera)
        .map_err(anyhow::Error::msg)?;
    if choice.name != pipeline::cameras::FROM_CONFIG && choice.camera != cfg.camera {
        tracing::warn!(
            "camera {} ({}) differs from the config's [camera] and replaces it; --camera config keeps the config's",
            choice.name,
            choice.reason
        );
    } else {
        tracing::info!("camera {}: {}", choice.name, choice.reason);
    }
    // Presets and camera files are validated as they are read.
    cfg.camera = choice.camera.clone();
    Ok((cfg, out, choice, run_id))
}

/// The run's source: a live one (no dataset folder allowed with it; a V4L2
/// camera probed), or a dataset folder that exists (the embedded default
/// scene, rendered once into `out`, when none is given).
pub(crate) fn resolve_source(cfg: &mut PipelineConfig, out: &std::path::Path) -> Result<()> {
    // Live sources: frames from a camera or an outside publisher.
    let live = match cfg.source.kind {
        pipeline::config::SourceKind::External => Some("external"),
        pipeline::config::SourceKind::V4l2 => Some("v4l2"),
        pipeline::config::SourceKind::Ros2 => Some("ros2"),
        _ => None,
    };
    if let (Some(kind), false) = (live, cfg.source.path.as_os_str().is_empty()) {
        anyhow::bail!(
            "dataset folder {} given with source.kind = \"{kind}\" (frames come live): drop one of them",
            cfg.source.path.display()
        );
    }
    if cfg.source.kind == pipeline::config::SourceKind::V4l2 {
        live_camera::v4l2::probe(&cfg.source)?;
    }
    if live.is_none() && cfg.source.path.as_os_str().is_empty() {
        // No dataset: the embedded default scene (rendered once).
        cfg.source.kind = pipeline::config::SourceKind::Tum;
        cfg.source.path = supervisor::default_scene::ensure(out, cfg)?;
    }
    if live.is_none() {
        if !cfg.source.path.is_dir() {
            anyhow::bail!(
                "dataset folder {} does not exist or is not a folder",
                cfg.source.path.display()
            );
        }
        cfg.source.path = cfg
            .source
            .path
            .canonicalize()
            .with_context(|| format!("cannot resolve {}", cfg.source.path.display()))?;
    }
    Ok(())
}

/// `dynslam run`: the configuration resolved from the file and the flags
/// ([`run_config`]), the run folder made, the run executed.
pub(crate) fn run(args: RunArgs) -> Result<ExitCode> {
    let (mut cfg, out, choice, run_id) = run_config(args)?;
    supervisor::map_files::prepare(&mut cfg)?;
    let id = match run_id {
        Some(id) => id,
        None => run_dir::new_run_id(),
    };
    shared_types::names::RunNames::new(&id).map_err(anyhow::Error::msg)?;
    tracing::info!(
        "backends: slam {}, segmenter {}, propagator {}{}",
        cfg.services.slam.backend,
        cfg.services.segmenter.backend,
        cfg.services.propagator.backend,
        if cfg.routing.no_masks {
            " (routing.no_masks: no frame is masked)"
        } else {
            ""
        }
    );
    // Refused before anything is written when a live run holds the id.
    drop(run_dir::RunLock::acquire(&id)?);
    let dir = run_dir::create(
        &out,
        &id,
        &cfg,
        &format!("{}: {}", choice.name, choice.reason),
    )?;
    eprintln!("run {id}: {}", dir.display());
    Ok(report_run(&execute(&dir)?))
}

/// Exit code of a run that finished degraded (a mask worker given up on).
pub(crate) const EXIT_DEGRADED: u8 = 3;
/// Exit code of an interrupted run (SIGINT/SIGTERM), as shells report it.
pub(crate) const EXIT_INTERRUPTED: u8 = 130;

pub(crate) fn load_config(path: Option<&std::path::Path>) -> Result<PipelineConfig> {
    Ok(PipelineConfig::load_or_default(path)?)
}

/// Prints a finished run's summary (the run folder last, on stdout) and
/// picks the exit code: 130 interrupted, 3 degraded, 0 otherwise.
pub(crate) fn report_run(summary: &RunSummary) -> ExitCode {
    for d in &summary.degraded {
        eprintln!("DEGRADED: {d}");
    }
    eprintln!("{}", summary.latency_table);
    if summary.dropped > 0 {
        eprintln!(
            "real time: {} of {} frames dropped (a newer frame was tracked first; frames.csv notes each)",
            summary.dropped, summary.frames
        );
    }
    eprintln!(
        "{} frames, {} tracked, {} service restarts{}",
        summary.frames,
        summary.tracked,
        summary.restarts,
        if summary.interrupted {
            " (interrupted)"
        } else {
            ""
        }
    );
    if let Some(r) = &summary.report {
        if let Some(e) = &r.eval {
            let aligned = match e.alignment {
                slam_core::eval::Alignment::Sim3 => format!("Sim(3) aligned, scale {:.3}", e.scale),
                slam_core::eval::Alignment::Se3 => "SE(3) aligned".into(),
                slam_core::eval::Alignment::None => "not aligned".into(),
            };
            eprintln!(
                "ATE {:.4} m (RMSE, {aligned}, {} poses), RPE/frame {:.4} m {:.3} deg",
                e.ate_rmse_m, e.pairs, e.rpe_trans_rmse_m, e.rpe_rot_rmse_deg
            );
        }
        if let Some(iou) = r.masks.as_ref().and_then(|m| m.all_frames_iou) {
            eprintln!("mask IoU against ground truth, every frame with a person: {iou:.3}");
        }
        eprintln!(
            "report: {}",
            evaluation::report::report_path(&summary.run_dir).display()
        );
    }
    println!("{}", summary.run_dir.display());
    if summary.interrupted {
        ExitCode::from(EXIT_INTERRUPTED)
    } else if !summary.degraded.is_empty() {
        ExitCode::from(EXIT_DEGRADED)
    } else {
        ExitCode::SUCCESS
    }
}
