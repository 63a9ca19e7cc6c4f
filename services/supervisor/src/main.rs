//! `dynslam`: the command a person types.
//!
//! `dynslam run [DATASET]` starts a run; `dynslam resume RUN_DIR` continues
//! a run whose supervisor was killed. The run folder's path is printed last
//! on stdout.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use pipeline::config::{ClockMode, PipelineConfig};
use pipeline::runtime::init_logging;
use supervisor::run::{execute, RunSummary};
use supervisor::run_dir;

#[derive(Debug, Parser)]
#[command(
    name = "dynslam",
    version,
    about = "Dynamic-scene visual SLAM as a zero-copy multi-process pipeline"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run the whole pipeline on a dataset and write a run folder.
    ///
    /// Exit codes: 0 done, 1 failed (bad input, a service that could not
    /// run), 2 bad command line, 3 degraded (a mask worker was given up on;
    /// status.json and report.md say why), 130 interrupted.
    Run {
        /// TUM RGB-D folder (rgb.txt, depth.txt); default: `source.path` of
        /// the config, and when that is empty too the embedded default scene
        /// (a rendered room with people walking through it, rendered once
        /// into OUTPUT_DIR/default-scene-v2).
        dataset: Option<PathBuf>,
        /// Pipeline configuration, layered over the built-in defaults (the
        /// shipped configs/pipeline.toml); default: the built-in defaults.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Camera: a preset (tum-fr1, tum-fr2, tum-fr3, bonn,
        /// global-shutter-example), a camera file (the keys of [camera]), or
        /// `config` for the config's [camera]. Default: the preset the
        /// dataset folder's name implies (rgbd_dataset_freiburg2_* -> tum-fr2,
        /// rgbd_bonn_* -> bonn), else the config's [camera].
        #[arg(long)]
        camera: Option<String>,
        /// Fail (exit 1) instead of finishing degraded (exit 3) when a mask
        /// worker is given up on (`run.require_masks`).
        #[arg(long)]
        require_masks: bool,
        /// Start in this saved map: poses come out in its world frame (the
        /// first frames relocalise against its keyframes).
        #[arg(long)]
        load_map: Option<PathBuf>,
        /// Write the SLAM map to this file at the end of the run.
        #[arg(long)]
        save_map: Option<PathBuf>,
        /// ORB-SLAM2's localization mode: track in the loaded map, add no
        /// keyframe or point (needs --load-map).
        #[arg(long)]
        localize_only: bool,
        /// Where the run folder is created (default: `run.output_dir`).
        #[arg(long)]
        output_dir: Option<PathBuf>,
        /// Clock mode (default: `run.mode`).
        #[arg(long, value_enum)]
        mode: Option<Mode>,
        /// Route every frame unmasked (ablation).
        #[arg(long)]
        no_masks: bool,
        /// The SLAM's sensor (default: `services.slam.sensor`): `rgbd` or
        /// `monocular` (colour only; depth ignored).
        #[arg(long, value_enum)]
        sensor: Option<SensorArg>,
        /// Play at most this many frames.
        #[arg(long)]
        limit: Option<u64>,
        /// Run id (letters, digits, '-'); default: a fresh random one.
        #[arg(long)]
        run_id: Option<String>,
        /// Publish the run as ROS 2 topics over rmw_zenoh (`[bridge]
        /// enabled = true`; README "ROS 2").
        #[arg(long)]
        ros2: bool,
    },
    /// Continue a run whose supervisor was stopped or killed.
    Resume {
        /// The run folder to continue.
        run_dir: PathBuf,
    },
    /// Ablation on a dynamic sequence: the whole pipeline without masks,
    /// with ground-truth masks, segmenter on every frame, the product's
    /// routing, and blackout; one table of ATE, tracked %, mask IoU, ms/frame.
    Ablate {
        /// A folder written by `dynslam synth` (ground-truth masks needed
        /// for row b and the IoU column).
        dataset: PathBuf,
        /// Pipeline configuration (default: the built-in defaults).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Where the run folders and ablation.md go (default: `run.output_dir`).
        #[arg(long)]
        output_dir: Option<PathBuf>,
        /// Play at most this many frames per run.
        #[arg(long)]
        limit: Option<u64>,
        /// Run only these rows (static, a, b, c, d, e); default all.
        #[arg(long, value_delimiter = ',')]
        only: Vec<String>,
    },
    /// Write a run folder's report again (report.md and plots/), e.g. after
    /// the dataset's ground truth was added.
    Report {
        /// The run folder.
        run_dir: PathBuf,
    },
    /// Trajectory accuracy: ATE and RPE of an estimate against ground truth
    /// (TUM format), as evo computes them.
    Eval {
        /// Ground-truth trajectory (TUM: timestamp tx ty tz qx qy qz qw).
        #[arg(long)]
        gt: PathBuf,
        /// Estimated trajectory (TUM format).
        #[arg(long)]
        est: PathBuf,
        /// Alignment before ATE: se3 (RGB-D), sim3 (monocular) or none.
        #[arg(long, value_enum, default_value = "se3")]
        align: Align,
        /// Association tolerance in seconds.
        #[arg(long, default_value_t = 0.02)]
        max_diff: f64,
        /// Print the summary as JSON on stdout.
        #[arg(long)]
        json: bool,
        /// Also write the summary to this JSON file.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Also draw the aligned estimate (coloured by error) against the
        /// ground truth (grey) in its two main views, to this PNG.
        #[arg(long)]
        plot: Option<PathBuf>,
    },
    /// Render the synthetic room as a TUM RGB-D folder (rgb/, depth/,
    /// groundtruth.txt; TUM fr1 camera): `--path circuit` goes once round the
    /// room looking out at the walls and back to its first pose, a loop for
    /// loop closing; `--path orbit` goes round looking in across the room.
    Render {
        /// New folder to write (must not exist or be empty).
        output: PathBuf,
        /// The camera's path: `glide` (the default scene's), `circuit` or `orbit`.
        #[arg(long, value_enum, default_value_t = CameraPathArg::Glide)]
        path: CameraPathArg,
        /// Frames at 30 fps (the circuit takes them all to close).
        #[arg(long, default_value_t = 150)]
        frames: usize,
    },
    /// Make a dynamic sequence: people (and boxes) walking through a TUM
    /// RGB-D sequence, with ground-truth masks (masks/, movers/, objects.json).
    Synth {
        /// TUM RGB-D folder with groundtruth.txt.
        input: PathBuf,
        /// New folder to write (must not exist or be empty).
        output: PathBuf,
        /// Number of people.
        #[arg(long, default_value_t = 2)]
        objects: usize,
        /// Carried boxes besides the people (0.4 m, textured): movers no
        /// class list names, in movers/ and movers.txt, not in masks/ (the
        /// SLAM's motion check should find them).
        #[arg(long, default_value_t = 0)]
        boxes: usize,
        /// Walking speed (m/s; each person varies it by +-20 %).
        #[arg(long, default_value_t = 1.0)]
        speed: f64,
        /// Nearest walking distance from the first camera (m); smaller
        /// covers more of the frame.
        #[arg(long, default_value_t = 0.7)]
        near: f64,
        /// Farthest walking distance (m).
        #[arg(long, default_value_t = 1.4)]
        far: f64,
        /// Height of a person cut-out in the world (m; the cut-outs show
        /// head to waist).
        #[arg(long, default_value_t = 0.75)]
        height: f64,
        /// Random seed: the same seed gives the same scene.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// What hides people: `scene` (nearer scene depth; walks that cross
        /// furniture show only what sticks out) or `none` (people pass
        /// between the camera and the scene, drawn whole).
        #[arg(long, value_enum, default_value_t = OcclusionArg::Scene)]
        occlusion: OcclusionArg,
        /// How people walk: `across` (back and forth across the view,
        /// entering and leaving at its sides) or `mixed` (in turn: across,
        /// toward and away from the camera, across with stops).
        #[arg(long, value_enum, default_value_t = BehavioursArg::Across)]
        behaviour: BehavioursArg,
        /// Synthesise only the first N frames.
        #[arg(long)]
        limit: Option<usize>,
        /// Camera intrinsics and depth scale are read from this config
        /// (default: the built-in defaults).
        #[arg(long)]
        config: Option<PathBuf>,
    },
    /// Mask quality against ground truth on a `dynslam synth` sequence:
    /// segmenter IoU on keyframes, propagator IoU on the frames between.
    MasksEval {
        /// A folder written by `dynslam synth`.
        dataset: PathBuf,
        /// Segment every Nth frame, propagate the N-1 between.
        #[arg(long, default_value_t = 11)]
        keyframe_every: usize,
        /// Score a person only where it covers at least this many pixels.
        #[arg(long, default_value_t = 2000)]
        min_px: usize,
        /// Evaluate only the first N frames.
        #[arg(long)]
        limit: Option<usize>,
        /// Print the scores as JSON on stdout.
        #[arg(long)]
        json: bool,
        /// Write each frame's predicted labels (NNNN.png) and scores.csv here.
        #[arg(long)]
        save: Option<PathBuf>,
        /// Pipeline configuration (default: the built-in defaults).
        #[arg(long)]
        config: Option<PathBuf>,
    },
    /// The V4L2 cameras of this machine (`/dev/video*`): name, formats, and
    /// which `source.v4l2` key takes each (README "Live camera").
    Cameras,
    /// The bag-of-words vocabulary of place recognition (relocalisation):
    /// train one, or describe a file.
    Vocab {
        #[command(subcommand)]
        action: VocabAction,
    },
}

#[derive(Debug, Subcommand)]
enum VocabAction {
    /// Train a vocabulary (hierarchical k-means over the SLAM's ORB
    /// features) on PNG images; deterministic for a seed. The shipped one:
    /// `dynslam vocab train --out assets/vocabulary/orb-k10-l4.vocab
    /// ../shared/data/tum/rgbd_dataset_freiburg1_rpy_first300/rgb`.
    Train {
        /// The vocabulary file to write.
        #[arg(long)]
        out: PathBuf,
        /// Children per tree node (k).
        #[arg(long, default_value_t = 10)]
        branching: usize,
        /// Tree depth (L): up to k^L words.
        #[arg(long, default_value_t = 4)]
        levels: usize,
        /// Seed of k-means++ (same seed and images: same file).
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// PNG files, or folders whose *.png files are all used (name order).
        #[arg(required = true)]
        images: Vec<PathBuf>,
    },
    /// Words, tree shape, SHA-256, load time and training summary of a vocabulary file.
    Info { file: PathBuf },
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum SensorArg {
    Rgbd,
    Monocular,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum CameraPathArg {
    Glide,
    Circuit,
    Orbit,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum BehavioursArg {
    Across,
    Mixed,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum OcclusionArg {
    Scene,
    None,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum Align {
    None,
    Se3,
    Sim3,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum Mode {
    Lockstep,
    Realtime,
}

fn main() -> ExitCode {
    init_logging();
    match dispatch(Cli::parse().command) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn dispatch(command: Command) -> Result<ExitCode> {
    match command {
        Command::Run {
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
        } => {
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
                camera_reader::v4l2::probe(&cfg.source)?;
            }
            if live.is_none() && cfg.source.path.as_os_str().is_empty() {
                // No dataset: the embedded default scene (rendered once).
                cfg.source.kind = pipeline::config::SourceKind::Tum;
                cfg.source.path = supervisor::default_scene::ensure(&out, &cfg)?;
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
                "yolov8-seg" | "maskrcnn"
            ) {
                // Caught here, before any process starts, not as a degraded run.
                segmenter::coco::dynamic_classes(&cfg.services.segmenter.classes, "segmenter")
                    .map_err(anyhow::Error::msg)?;
            }
            if cfg.source.kind == pipeline::config::SourceKind::Ros2 && camera.is_none() {
                // A ROS 2 camera says its intrinsics on its CameraInfo topic.
                cfg.camera = supervisor::ros2_camera::camera_info(&cfg)?;
            }
            let choice =
                pipeline::cameras::choose(camera.as_deref(), &cfg.source.path, &cfg.camera)
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
        Command::Resume { run_dir } => Ok(report_run(&execute(&run_dir)?)),
        Command::Ablate {
            dataset,
            config,
            output_dir,
            limit,
            only,
        } => {
            let mut cfg = load_config(config.as_deref())?;
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
            let rows = supervisor::ablation::run(&dataset, &cfg, &out, &only)?;
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
        Command::Report { run_dir } => {
            let (_, cfg) = run_dir::open(&run_dir)?;
            let (_, rows) = supervisor::outputs::FrameLog::open(&run_dir)?;
            let problems: Vec<String> = run_dir::read_status(&run_dir)
                .and_then(|s| s.error)
                .into_iter()
                .collect();
            supervisor::report::write(&run_dir, &cfg, &rows, &problems)?;
            println!("{}", supervisor::report::report_path(&run_dir).display());
            Ok(ExitCode::SUCCESS)
        }
        Command::Eval {
            gt,
            est,
            align,
            max_diff,
            json,
            out,
            plot,
        } => eval(
            &gt,
            &est,
            align,
            max_diff,
            json,
            out.as_deref(),
            plot.as_deref(),
        )
        .map(|()| ExitCode::SUCCESS),
        Command::Render {
            output,
            path,
            frames,
        } => {
            let options = scenes::room::RoomOptions {
                frames,
                path: match path {
                    CameraPathArg::Glide => scenes::room::CameraPath::Glide,
                    CameraPathArg::Circuit => scenes::room::CameraPath::Circuit,
                    CameraPathArg::Orbit => scenes::room::CameraPath::Orbit,
                },
                ..Default::default()
            };
            let t = std::time::Instant::now();
            scenes::room::render_room(&output, &slam_core::Camera::tum_fr1(), &options)
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
        Command::Synth {
            input,
            output,
            objects,
            boxes,
            speed,
            near,
            far,
            height,
            seed,
            occlusion,
            behaviour,
            limit,
            config,
        } => {
            let options = scenes::walkers::WalkOptions {
                objects,
                boxes,
                speed_mps: speed,
                near_m: near,
                far_m: far,
                height_m: height,
                seed,
                occlusion: match occlusion {
                    OcclusionArg::Scene => scenes::walkers::Occlusion::Scene,
                    OcclusionArg::None => scenes::walkers::Occlusion::None,
                },
                behaviours: match behaviour {
                    BehavioursArg::Across => scenes::walkers::Behaviours::Across,
                    BehavioursArg::Mixed => scenes::walkers::Behaviours::Mixed,
                },
            };
            synth(&input, &output, &options, limit, config.as_deref()).map(|()| ExitCode::SUCCESS)
        }
        Command::Cameras => {
            let cameras =
                camera_reader::v4l2::list_cameras().context("cannot list /dev for V4L2 cameras")?;
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
        Command::Vocab { action } => {
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
                    let t = supervisor::vocab::train(&images, &out, opts)?;
                    eprintln!(
                        "vocab: {} words from {} features of {} images in {:.1} s",
                        t.words, t.features, t.images, t.seconds
                    );
                    println!("{}  {}", t.sha256, out.display());
                }
                VocabAction::Info { file } => println!("{}", supervisor::vocab::info(&file)?),
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::MasksEval {
            dataset,
            keyframe_every,
            min_px,
            limit,
            json,
            save,
            config,
        } => masks_eval(
            &dataset,
            keyframe_every,
            min_px,
            limit,
            json,
            save.as_deref(),
            config.as_deref(),
        )
        .map(|()| ExitCode::SUCCESS),
    }
}

/// Exit code of a run that finished degraded (a mask worker given up on).
const EXIT_DEGRADED: u8 = 3;
/// Exit code of an interrupted run (SIGINT/SIGTERM), as shells report it.
const EXIT_INTERRUPTED: u8 = 130;

fn load_config(path: Option<&std::path::Path>) -> Result<PipelineConfig> {
    Ok(PipelineConfig::load_or_default(path)?)
}

/// Prints a finished run's summary (the run folder last, on stdout) and
/// picks the exit code: 130 interrupted, 3 degraded, 0 otherwise.
fn report_run(summary: &RunSummary) -> ExitCode {
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
            supervisor::report::report_path(&summary.run_dir).display()
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

fn synth(
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

fn masks_eval(
    dataset: &std::path::Path,
    keyframe_every: usize,
    min_px: usize,
    limit: Option<usize>,
    json: bool,
    save: Option<&std::path::Path>,
    config: Option<&std::path::Path>,
) -> Result<()> {
    let cfg = load_config(config)?;
    let s = supervisor::mask_eval::evaluate(dataset, &cfg, keyframe_every, min_px, limit, save)?;
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
        supervisor::mask_eval::FOUND_IOU,
        s.propagator_iou_found
    );
    let cause = |name: &str, c: &supervisor::mask_eval::ByCause| {
        let part = |label: &str, x: &supervisor::mask_eval::Subset| {
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
        supervisor::mask_eval::MASKED_IOU,
        supervisor::mask_eval::ENTRY_FRAMES,
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

fn eval(
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
        let (img, _) = supervisor::plots::trajectory(
            &s.positions,
            &[],
            &format!(
                "{} vs {} (ATE RMSE {:.4} m)",
                est.display(),
                gt.display(),
                s.ate_rmse_m
            ),
        )?;
        supervisor::plots::save(&img, path)?;
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
