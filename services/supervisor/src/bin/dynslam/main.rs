//! `dynslam`: the command a person types.
//!
//! `dynslam run [DATASET]` starts a run; `dynslam resume RUN_DIR` continues
//! a run whose supervisor was killed. The run folder's path is printed last
//! on stdout.
//!
//! `main.rs` parses the command line and dispatches; `run_command` holds
//! `dynslam run` / `resume`, `tools` the offline commands, `cli` the flags.

use std::process::ExitCode;

use anyhow::Result;
use clap::Parser;
use pipeline::runtime::init_logging;
use run_folder::run_dir;
use supervisor::run::execute;

mod cli;
mod run_command;
mod tools;

use cli::{BehavioursArg, Cli, Command, OcclusionArg};
use run_command::{load_config, report_run, run};
use tools::{
    ablate, cameras, compare_segmenters_on, eval, masks_eval, render, synth, vocab, worker,
};

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
        Command::Run(args) => run(*args),
        Command::Resume { run_dir } => Ok(report_run(&execute(&run_dir)?)),
        Command::Ablate {
            dataset,
            config,
            output_dir,
            limit,
            only,
        } => ablate(&dataset, config.as_deref(), output_dir, limit, &only),
        Command::Report { run_dir } => {
            let (_, cfg) = run_dir::open(&run_dir)?;
            let (_, rows) = run_folder::outputs::FrameLog::open(&run_dir)?;
            let problems: Vec<String> = run_dir::read_status(&run_dir)
                .and_then(|s| s.error)
                .into_iter()
                .collect();
            evaluation::report::write(&run_dir, &cfg, &rows, &problems)?;
            println!("{}", evaluation::report::report_path(&run_dir).display());
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
            depth_sensor,
            exposure_ms,
        } => render(&output, path, frames, (depth_sensor, exposure_ms)),
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
        Command::Worker { args } => worker(&args),
        Command::Cameras => cameras(),
        Command::Vocab { action } => vocab(action),
        Command::MasksEval {
            dataset,
            keyframe_every,
            min_px,
            limit,
            json,
            save,
            config,
            compare_segmenters,
        } => {
            let (cfg, dataset) = (load_config(config.as_deref())?, dataset.as_path());
            if compare_segmenters {
                compare_segmenters_on(dataset, &cfg, keyframe_every, min_px, limit, json)
            } else {
                masks_eval(
                    dataset,
                    &cfg,
                    keyframe_every,
                    min_px,
                    limit,
                    json,
                    save.as_deref(),
                )
            }
            .map(|()| ExitCode::SUCCESS)
        }
    }
}
