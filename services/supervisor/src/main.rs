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
    Run {
        /// TUM RGB-D folder (or image folder with `--source images`);
        /// default: `source.path` of the config.
        dataset: Option<PathBuf>,
        /// Pipeline configuration.
        #[arg(long, default_value = "configs/pipeline.toml")]
        config: PathBuf,
        /// Where the run folder is created (default: `run.output_dir`).
        #[arg(long)]
        output_dir: Option<PathBuf>,
        /// Clock mode (default: `run.mode`).
        #[arg(long, value_enum)]
        mode: Option<Mode>,
        /// Route every frame unmasked (ablation).
        #[arg(long)]
        no_masks: bool,
        /// Play at most this many frames.
        #[arg(long)]
        limit: Option<u64>,
        /// Run id (letters, digits, '-'); default: a fresh random one.
        #[arg(long)]
        run_id: Option<String>,
    },
    /// Continue a run whose supervisor was stopped or killed.
    Resume {
        /// The run folder to continue.
        run_dir: PathBuf,
    },
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum Mode {
    Lockstep,
    Realtime,
}

fn main() -> ExitCode {
    init_logging();
    let cli = Cli::parse();
    match dispatch(cli.command) {
        Ok(summary) => {
            eprintln!("{}", summary.latency_table);
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
            println!("{}", summary.run_dir.display());
            if summary.interrupted {
                ExitCode::from(130)
            } else {
                ExitCode::SUCCESS
            }
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn dispatch(command: Command) -> Result<RunSummary> {
    match command {
        Command::Run {
            dataset,
            config,
            output_dir,
            mode,
            no_masks,
            limit,
            run_id,
        } => {
            let mut cfg = PipelineConfig::load(&config)?;
            if let Some(d) = dataset {
                cfg.source.path = d;
            }
            if cfg.source.path.as_os_str().is_empty() {
                anyhow::bail!(
                    "no dataset given: pass a folder (dynslam run PATH) or set source.path in {}",
                    config.display()
                );
            }
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
            if let Some(m) = mode {
                cfg.run.mode = match m {
                    Mode::Lockstep => ClockMode::Lockstep,
                    Mode::Realtime => ClockMode::Realtime,
                };
            }
            if no_masks {
                cfg.routing.no_masks = true;
            }
            if let Some(l) = limit {
                cfg.source.limit = l;
            }
            let id = match run_id {
                Some(id) => id,
                None => run_dir::new_run_id(),
            };
            shared_types::names::RunNames::new(&id).map_err(anyhow::Error::msg)?;
            let out = output_dir.unwrap_or_else(|| cfg.run.output_dir.clone());
            let dir = run_dir::create(&out, &id, &cfg)?;
            eprintln!("run {id}: {}", dir.display());
            execute(&dir)
        }
        Command::Resume { run_dir } => execute(&run_dir),
    }
}
