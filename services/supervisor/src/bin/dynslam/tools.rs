//! The offline commands: ablation, cameras, vocabularies, rendering and
//! synthesis, mask and trajectory evaluation, the remote worker.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use pipeline::config::PipelineConfig;

use crate::cli::{Align, CameraPathArg, DepthSensorArg, VocabAction};
use crate::run_command::load_config;

/// `dynslam ablate`: the ablation's rows on `dataset` (`only`: some of
/// them), its table as markdown and JSON beside the run folders.
pub(crate) fn ablate(
    dataset: &std::path::Path,
    config: Option<&std::path::Path>,
    output_dir: Option<PathBuf>,
    limit: Option<u64>,
    only: &[String],
) -> Result<ExitCode> {
    let mut cfg = load_config(config)?;
    if let Some(l) = limit {
        cfg.source.limit = l;
    }
    // The rows the ablation has (the static one included), from its one list.
    let known: Vec<&str> = supervisor::ablation::variants(Some(Default::default()))
        .iter()
        .map(|v| v.key)
        .collect();
    if let Some(bad) = only.iter().find(|o| !known.contains(&o.as_str())) {
        anyhow::bail!("--only: unknown row '{bad}' (known: {})", known.join(", "));
    }
    let out = output_dir.unwrap_or_else(|| cfg.run.output_dir.clone());
    let rows = supervisor::ablation::run(dataset, &cfg, &out, only)?;
    let table = supervisor::ablation::table(&rows);
    let md = out.join("ablation.md");
    let text = format!(
        "# dynslam ablate {}\n\n{table}\nRun folders: {}\n",
        dataset.display(),
        rows.iter()
            .map(|r| format!("`{}`", r.run_dir.display()))
            .collect::<Vec<_>>()
            .join(", ")
    );
    std::fs::write(&md, text).with_context(|| format!("cannot write {}", md.display()))?;
    std::fs::write(
        out.join("ablation.json"),
        serde_json::to_string_pretty(&rows)?,
    )?;
    eprintln!("{table}");
    println!("{}", md.display());
    Ok(ExitCode::SUCCESS)
}

/// `dynslam cameras`: the V4L2 capture devices and how each would be used.
pub(crate) fn cameras() -> Result<ExitCode> {
    let cameras = live_camera::v4l2::list_cameras().context("cannot list /dev for V4L2 cameras")?;
    if cameras.is_empty() {
        println!("no V4L2 capture device under /dev (is a camera plugged in? is /dev/video* visible here, e.g. inside a container?)");
    }
    for c in cameras {
        println!(
            "{}  {}  formats {}  -> {}",
            c.path.display(),
            c.card,
            if c.formats.is_empty() {
                "none".to_string()
            } else {
                c.formats.join(" ")
            },
            c.use_as
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// `dynslam vocab`: train a vocabulary, or describe one.
pub(crate) fn vocab(action: VocabAction) -> Result<ExitCode> {
    match action {
        VocabAction::Train {
            out,
            branching,
            levels,
            seed,
            images,
        } => {
            let opts = slam_core::place_recognition::vocabulary::TrainOptions {
                branching,
                levels,
                seed,
            };
            let t = evaluation::vocab::train(&images, &out, opts)?;
            eprintln!(
                "vocab: {} words from {} features of {} images in {:.1} s",
                t.words, t.features, t.images, t.seconds
            );
            println!("{}  {}", t.sha256, out.display());
        }
        VocabAction::Info { file } => println!("{}", evaluation::vocab::info(&file)?),
    }
    Ok(ExitCode::SUCCESS)
}

/// `dynslam render`: the rendered room (`frames` frames along `path`) as
/// a TUM RGB-D folder in `output`, its depth as `sensor` measures it and
/// its colour exposed for the given ms.
pub(crate) fn render(
    output: &std::path::Path,
    path: CameraPathArg,
    frames: usize,
    (sensor, exposure_ms): (DepthSensorArg, f64),
) -> Result<ExitCode> {
    let options = scenes::room::RoomOptions {
        frames,
        path: match path {
            CameraPathArg::Glide => scenes::room::CameraPath::Glide,
            CameraPathArg::Circuit => scenes::room::CameraPath::Circuit,
            CameraPathArg::Orbit => scenes::room::CameraPath::Orbit,
        },
        sensor: scenes::sensor::SensorModel {
            depth: match sensor {
                DepthSensorArg::Exact => scenes::sensor::DepthSensor::Exact,
                DepthSensorArg::Kinect => scenes::sensor::DepthSensor::Kinect,
                DepthSensorArg::Realsense => scenes::sensor::DepthSensor::RealSense,
            },
            exposure_s: exposure_ms / 1e3,
        },
        ..Default::default()
    };
    let t = std::time::Instant::now();
    scenes::room::render_room(output, &slam_core::Camera::tum_fr1(), &options)
        .map(|n| {
            eprintln!(
                "{n} frames rendered to {} in {:.1} s",
                output.display(),
                t.elapsed().as_secs_f64()
            );
            ExitCode::SUCCESS
        })
        .map_err(anyhow::Error::from)
}

pub(crate) fn synth(
    input: &std::path::Path,
    output: &std::path::Path,
    options: &scenes::walkers::WalkOptions,
    limit: Option<usize>,
    config: Option<&std::path::Path>,
) -> Result<()> {
    let cfg = load_config(config)?;
    let camera = scenes::composite::Pinhole {
        fx: cfg.camera.fx,
        fy: cfg.camera.fy,
        cx: cfg.camera.cx,
        cy: cfg.camera.cy,
    };
    let s = scenes::synth::synthesize(
        input,
        output,
        &camera,
        cfg.source.depth_scale as f64,
        options,
        limit,
    )?;
    eprintln!(
        "{} frames, people visible in {}, mean coverage {:.1} %, max {:.1} %",
        s.frames,
        s.frames_with_people,
        100.0 * s.mean_coverage,
        100.0 * s.max_coverage
    );
    println!("{}", output.display());
    Ok(())
}

/// `masks-eval --compare-segmenters`: one line per network and input size.
pub(crate) fn compare_segmenters_on(
    dataset: &std::path::Path,
    cfg: &PipelineConfig,
    keyframe_every: usize,
    min_px: usize,
    limit: Option<usize>,
    json: bool,
) -> Result<()> {
    use evaluation::mask_eval::Subset;
    let rows =
        evaluation::mask_eval::compare_segmenters(dataset, cfg, keyframe_every, min_px, limit)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    let part = |x: &Subset| {
        if x.samples == 0 {
            "-".to_string()
        } else {
            format!("{:.3}", x.iou)
        }
    };
    println!(
        "{}: keyframe every {keyframe_every}, people scored where they cover >= {min_px} px; IoU of the segmenter on keyframes (all, then by cause; a keyframe has no 'entered since') and of the propagator after them; ms per keyframe",
        dataset.display()
    );
    println!(
        "{:<12} {:>5} {:>9} {:>10} {:>7} {:>9} {:>7} {:>10} {:>8}",
        "network",
        "input",
        "keyframes",
        "border-cut",
        "small",
        "occluded",
        "plain",
        "propagator",
        "ms p50"
    );
    for r in &rows {
        let (s, c) = (&r.scores, &r.scores.segmenter_by_cause);
        println!(
            "{:<12} {:>5} {:>9.3} {:>10} {:>7} {:>9} {:>7} {:>10.3} {:>8.1}",
            r.network,
            r.input_size,
            s.segmenter_iou,
            part(&c.border_cut),
            part(&c.small),
            part(&c.occluded),
            part(&c.plain),
            s.propagator_iou,
            s.segmenter_ms_p50
        );
    }
    Ok(())
}

pub(crate) fn masks_eval(
    dataset: &std::path::Path,
    cfg: &PipelineConfig,
    keyframe_every: usize,
    min_px: usize,
    limit: Option<usize>,
    json: bool,
    save: Option<&std::path::Path>,
) -> Result<()> {
    let s = evaluation::mask_eval::evaluate(dataset, cfg, keyframe_every, min_px, limit, save)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&s)?);
        return Ok(());
    }
    println!(
        "{} frames, keyframe every {}, people scored where they cover >= {} px",
        s.frames, s.keyframe_every, s.min_px
    );
    println!(
        "segmenter  (keyframes)        mean IoU {:.3}  ({} person-frames, p50 {:.1} ms)",
        s.segmenter_iou, s.segmenter_samples, s.segmenter_ms_p50
    );
    println!(
        "propagator (1..{} after)       mean IoU {:.3}  ({} person-frames, p50 {:.1} ms)",
        s.keyframe_every - 1,
        s.propagator_iou,
        s.propagator_samples,
        s.propagator_ms_p50
    );
    println!(
        "propagator, people seen on their keyframe  mean IoU {:.3}",
        s.propagator_iou_prompted
    );
    println!(
        "propagator, people the segmenter found (keyframe IoU >= {})  mean IoU {:.3}",
        evaluation::mask_eval::FOUND_IOU,
        s.propagator_iou_found
    );
    let cause = |name: &str, c: &evaluation::mask_eval::ByCause| {
        let part = |label: &str, x: &evaluation::mask_eval::Subset| {
            if x.samples == 0 {
                format!("{label} -")
            } else {
                format!("{label} {:.3} ({})", x.iou, x.samples)
            }
        };
        println!(
            "{name} by cause: {}  {}  {}  {}  {}",
            part("entered since keyframe", &c.entered),
            part("border-cut", &c.border_cut),
            part("small", &c.small),
            part("occluded", &c.occluded),
            part("none of these", &c.plain)
        );
    };
    cause("segmenter ", &s.segmenter_by_cause);
    cause("propagator", &s.propagator_by_cause);
    if s.ignore_regions {
        println!("ignore regions (ignore.png / ignore.txt) left out of every score");
    }
    println!(
        "early segments (the propagator saw something move that it does not follow): {}",
        s.early_segments
    );
    let e = &s.entries;
    println!(
        "people coming into view: {}, masked (IoU >= {}) within {} frames: {} ({:.0} %), later: {}, median delay {:.0} frames",
        e.count,
        evaluation::mask_eval::MASKED_IOU,
        evaluation::mask_eval::ENTRY_FRAMES,
        e.masked_in_time,
        100.0 * e.in_time_share(),
        e.masked_later,
        e.delay_frames_p50
    );
    let offsets: Vec<String> = s
        .propagator_iou_by_offset
        .iter()
        .enumerate()
        .map(|(i, v)| format!("+{}: {v:.3}", i + 1))
        .collect();
    println!(
        "propagator by frames after the keyframe: {}",
        offsets.join("  ")
    );
    Ok(())
}

pub(crate) fn eval(
    gt: &std::path::Path,
    est: &std::path::Path,
    align: Align,
    max_diff: f64,
    json: bool,
    out: Option<&std::path::Path>,
    plot: Option<&std::path::Path>,
) -> Result<()> {
    use slam_core::eval::{evaluate_files, Alignment, EvalOptions};
    if !(max_diff.is_finite() && max_diff > 0.0) {
        anyhow::bail!("--max-diff {max_diff} must be a positive number of seconds");
    }
    let opts = EvalOptions {
        alignment: match align {
            Align::None => Alignment::None,
            Align::Se3 => Alignment::Se3,
            Align::Sim3 => Alignment::Sim3,
        },
        max_diff,
        ..Default::default()
    };
    let s = evaluate_files(gt, est, opts)?;
    let text = serde_json::to_string_pretty(&s)?;
    if let Some(path) = out {
        std::fs::write(path, &text).with_context(|| format!("cannot write {}", path.display()))?;
    }
    if let Some(path) = plot {
        let (img, _) = evaluation::plots::trajectory(
            &s.positions,
            &[],
            &format!(
                "{} vs {} (ATE RMSE {:.4} m)",
                est.display(),
                gt.display(),
                s.ate_rmse_m
            ),
        )?;
        evaluation::plots::save(&img, path)?;
    }
    if json {
        println!("{text}");
    } else {
        println!(
            "pairs           {} (of {} estimated, {} ground-truth poses)",
            s.pairs, s.est_poses, s.gt_poses
        );
        println!("alignment       {:?}, scale {:.4}", s.alignment, s.scale);
        println!(
            "ATE  rmse {:.4} m  mean {:.4}  median {:.4}  max {:.4}",
            s.ate_rmse_m, s.ate_mean_m, s.ate_median_m, s.ate_max_m
        );
        println!(
            "RPE/frame  trans rmse {:.4} m  rot rmse {:.3} deg",
            s.rpe_trans_rmse_m, s.rpe_rot_rmse_deg
        );
        println!(
            "RPE/{:.0}s     trans rmse {:.4} m  rot rmse {:.3} deg ({} pairs)",
            s.rpe_interval_s,
            s.rpe_interval_trans_rmse_m,
            s.rpe_interval_rot_rmse_deg,
            s.rpe_interval_pairs
        );
    }
    Ok(())
}

/// `dynslam worker ...`: becomes the mask-worker binary next to this one
/// (zenoh and the models stay out of the supervisor's own dependencies).
pub(crate) fn worker(args: &[String]) -> Result<ExitCode> {
    use std::os::unix::process::CommandExt;
    let exe = std::env::current_exe().context("cannot locate the running dynslam executable")?;
    let bin = exe.with_file_name("mask-worker");
    if !bin.is_file() {
        anyhow::bail!(
            "{} not found (build all services: cargo build --release --workspace)",
            bin.display()
        );
    }
    let err = std::process::Command::new(&bin).args(args).exec();
    Err(anyhow::Error::new(err).context(format!("cannot start {}", bin.display())))
}
