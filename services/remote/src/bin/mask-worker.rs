//! mask-worker: makes a robot's masks on this machine
//! (`dynslam worker segmenter --run NAME --connect tcp/ROBOT:7447`).

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Result;
use clap::{Parser, ValueEnum};
use pipeline::config::{check_run_name, ClockMode, PipelineConfig};
use pipeline::runtime::init_logging_with;
use remote::serve::serve;
use remote::session::{open, Endpoints};

#[derive(Debug, Clone, Copy, ValueEnum)]
enum Role {
    /// Keyframe instance segmentation (`[services.segmenter]`).
    Segmenter,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum Mode {
    Lockstep,
    Realtime,
}

#[derive(Debug, Parser)]
#[command(
    about = "dynslam mask worker: makes a robot's masks on this machine over Zenoh",
    after_help = "On the robot: [services.segmenter] location = \"remote\" and [remote] run = the same NAME (README \"Workers on another machine\")."
)]
struct Args {
    /// Which worker to be.
    role: Role,
    /// The run name the robot's `[remote] run` gives: only its frames are answered.
    #[arg(long)]
    run: String,
    /// Zenoh endpoint to connect to (the robot's `[remote] listen`, or a router); repeatable.
    #[arg(long)]
    connect: Vec<String>,
    /// Zenoh endpoint to listen on (when the robot connects here); repeatable.
    #[arg(long)]
    listen: Vec<String>,
    /// A Zenoh JSON5 configuration (TLS, mutual TLS, access control); replaces --connect/--listen.
    #[arg(long)]
    zenoh_config: Option<PathBuf>,
    /// Zenoh session mode.
    #[arg(long, default_value = "peer")]
    session_mode: String,
    /// Pipeline configuration whose [services.segmenter] and [onnxruntime] pick the model (default: the product's).
    #[arg(long)]
    config: Option<PathBuf>,
    /// The robot's clock mode: an unset input size follows it (480 px lockstep, 320 px real time).
    #[arg(long, value_enum)]
    mode: Option<Mode>,
}

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    STOP.store(true, Ordering::Relaxed);
}

fn main() -> ExitCode {
    init_logging_with(remote::LOG_FILTER);
    let args = Args::parse();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!("{e:#}");
            ExitCode::from(pipeline::runtime::exit_code::INPUT)
        }
    }
}

fn run(args: &Args) -> Result<()> {
    check_run_name(&args.run, "--run").map_err(anyhow::Error::msg)?;
    if args.zenoh_config.is_none() && args.connect.is_empty() && args.listen.is_empty() {
        anyhow::bail!("give --connect ENDPOINT (the robot's [remote] listen, e.g. tcp/robot:7447), --listen ENDPOINT or --zenoh-config FILE");
    }
    let mut config = PipelineConfig::load_or_default(args.config.as_deref())?;
    if let Some(mode) = args.mode {
        config.run.mode = match mode {
            Mode::Lockstep => ClockMode::Lockstep,
            Mode::Realtime => ClockMode::Realtime,
        };
    }
    let Role::Segmenter = args.role;
    let mut model = segmentation::models::load(&config)?;
    // SAFETY: the handler only stores to an atomic (async-signal-safe).
    unsafe {
        libc::signal(libc::SIGTERM, on_signal as *const () as libc::sighandler_t);
        libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
    }
    let session = open(&Endpoints {
        zenoh_config: args.zenoh_config.as_deref(),
        mode: &args.session_mode,
        listen: &args.listen,
        connect: &args.connect,
    })?;
    let stats = serve(&session, &args.run, &mut *model, &STOP)?;
    tracing::info!(
        "stopped: {} frames answered, {} failed, {} requests refused, {} superseded by newer ones",
        stats.answered,
        stats.failed,
        stats.refused,
        stats.superseded
    );
    Ok(())
}
