//! `dynslam`'s command line: the subcommands, their flags and help texts
//! (clap). What each command does is in `main.rs`.

use std::path::PathBuf;

use clap::{Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(
    name = "dynslam",
    version,
    about = "Dynamic-scene visual SLAM as a zero-copy multi-process pipeline"
)]
pub(crate) struct Cli {
    #[command(subcommand)]
    pub(crate) command: Command,
}

#[derive(Debug, Subcommand)]
pub(crate) enum Command {
    /// Run the whole pipeline on a dataset and write a run folder.
    ///
    /// Exit codes: 0 done, 1 failed (bad input, a service that could not
    /// run), 2 bad command line, 3 degraded (a mask worker was given up on;
    /// status.json and report.md say why), 130 interrupted.
    Run(Box<RunArgs>),
    /// Make a robot's masks on this machine (a GPU box): `dynslam worker
    /// segmenter --run NAME --connect tcp/ROBOT:7447`. The robot's run has
    /// `services.segmenter.location = "remote"` and `remote.run = NAME`
    /// (README "Workers on another machine"); `dynslam worker --help` lists
    /// the worker's options.
    #[command(disable_help_flag = true)]
    Worker {
        /// The worker's arguments (its role first).
        #[arg(trailing_var_arg = true, allow_hyphen_values = true, num_args = 0..)]
        args: Vec<String>,
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
        /// Depth as a camera measures it: `exact` (the ray cast's), `kinect`
        /// (structured light: noise growing with the square of the depth,
        /// disparity steps, the projector's shadow beside foreground edges,
        /// jagged edges, speckle holes, 0.5-4.5 m) or `realsense` (active
        /// stereo: 0.3-6 m, less noise near, no steps).
        #[arg(long, value_enum, default_value_t = DepthSensorArg::Exact)]
        depth_sensor: DepthSensorArg,
        /// Exposure in ms: the colour is averaged over it (motion blur; 0:
        /// sharp); shorter than a frame. 10-20 ms blurs fast turns as fr1's
        /// camera does.
        #[arg(long, default_value_t = 0.0)]
        exposure_ms: f64,
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
        /// Score every YOLO-seg network (YOLOv8n-seg, YOLO11n-seg) at every
        /// input size (320, 480, 640) instead of the configured one: one
        /// line each with IoU per cause and ms per keyframe.
        #[arg(long, conflicts_with = "save")]
        compare_segmenters: bool,
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
pub(crate) enum VocabAction {
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
pub(crate) enum SensorArg {
    Rgbd,
    Monocular,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub(crate) enum CameraPathArg {
    Glide,
    Circuit,
    Orbit,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub(crate) enum DepthSensorArg {
    Exact,
    Kinect,
    Realsense,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub(crate) enum BehavioursArg {
    Across,
    Mixed,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub(crate) enum OcclusionArg {
    Scene,
    None,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub(crate) enum Align {
    None,
    Se3,
    Sim3,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub(crate) enum Mode {
    Lockstep,
    Realtime,
}

/// `dynslam run`'s arguments.
#[derive(Debug, clap::Args)]
pub(crate) struct RunArgs {
    /// TUM RGB-D folder (rgb.txt, depth.txt); default: `source.path` of
    /// the config, and when that is empty too the embedded default scene
    /// (a rendered room with people walking through it, rendered once
    /// into OUTPUT_DIR/default-scene-v2).
    pub(crate) dataset: Option<PathBuf>,
    /// Pipeline configuration, layered over the built-in defaults (the
    /// shipped configs/pipeline.toml); default: the built-in defaults.
    #[arg(long)]
    pub(crate) config: Option<PathBuf>,
    /// Camera: a preset (tum-fr1, tum-fr2, tum-fr3, bonn,
    /// global-shutter-example), a camera file (the keys of [camera]), or
    /// `config` for the config's [camera]. Default: the preset the
    /// dataset folder's name implies (rgbd_dataset_freiburg2_* -> tum-fr2,
    /// rgbd_bonn_* -> bonn), else the config's [camera].
    #[arg(long)]
    pub(crate) camera: Option<String>,
    /// Fail (exit 1) instead of finishing degraded (exit 3) when a mask
    /// worker is given up on (`run.require_masks`).
    #[arg(long)]
    pub(crate) require_masks: bool,
    /// Start in this saved map: poses come out in its world frame (the
    /// first frames relocalise against its keyframes).
    #[arg(long)]
    pub(crate) load_map: Option<PathBuf>,
    /// Write the SLAM map to this file at the end of the run.
    #[arg(long)]
    pub(crate) save_map: Option<PathBuf>,
    /// ORB-SLAM2's localization mode: track in the loaded map, add no
    /// keyframe or point (needs --load-map).
    #[arg(long)]
    pub(crate) localize_only: bool,
    /// Where the run folder is created (default: `run.output_dir`).
    #[arg(long)]
    pub(crate) output_dir: Option<PathBuf>,
    /// Clock mode (default: `run.mode`).
    #[arg(long, value_enum)]
    pub(crate) mode: Option<Mode>,
    /// Route every frame unmasked (ablation).
    #[arg(long)]
    pub(crate) no_masks: bool,
    /// The SLAM's sensor (default: `services.slam.sensor`): `rgbd` or
    /// `monocular` (colour only; depth ignored).
    #[arg(long, value_enum)]
    pub(crate) sensor: Option<SensorArg>,
    /// Play at most this many frames.
    #[arg(long)]
    pub(crate) limit: Option<u64>,
    /// Run id (letters, digits, '-'); default: a fresh random one.
    #[arg(long)]
    pub(crate) run_id: Option<String>,
    /// Publish the run as ROS 2 topics over rmw_zenoh (`[bridge]
    /// enabled = true`; README "ROS 2").
    #[arg(long)]
    pub(crate) ros2: bool,
}
