//! `report.md`'s text, section by section, from the figures the report
//! computed (its plots are drawn by then: the text links to them).

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Result;
use pipeline_config::PipelineConfig;
use slam_core::eval::{evaluate, Alignment, EvalOptions, EvalSummary};
use slam_core::io::trajectory::Trajectory;

use super::{MaskFigures, EVAL_FILE, WORLD_FRAME};
use crate::plots::Views;
use run_folder::latency::{self, StageSummary};
use run_folder::mask_record::MIN_PERSON_PX;
use run_folder::outputs::FrameRow;

/// Everything the text says, computed before it is written.
pub(super) struct Figures<'a> {
    pub run_dir: &'a Path,
    pub config: &'a PipelineConfig,
    pub rows: &'a [FrameRow],
    pub problems: &'a [String],
    pub tracked: usize,
    pub monocular: bool,
    pub alignment: Alignment,
    pub eval: Option<&'a EvalSummary>,
    pub views: Option<Views>,
    pub masks: &'a MaskFigures,
    pub latency: &'a [StageSummary],
    /// The stages of `plots/latency.png`, top to bottom.
    pub panels: &'a [&'static str],
    /// What could not be made, and why.
    pub notes: &'a [String],
}

/// The whole of `report.md`.
pub(super) fn report(f: &Figures) -> Result<String> {
    let mut md = String::new();
    header(&mut md, f)?;
    trajectory(&mut md, f)?;
    masks(&mut md, f)?;
    latency_section(&mut md, f)?;
    files(&mut md, f.run_dir)?;
    let notes = f.notes;
    if !notes.is_empty() {
        writeln!(md, "\n## Not in this report\n")?;
        for n in notes {
            writeln!(md, "- {n}")?;
        }
    }
    Ok(md)
}

/// The title, what degraded the run, the dataset, camera, frames and
/// backends, and the restarts, outages and remote masks.
fn header(md: &mut String, f: &Figures) -> Result<()> {
    let (run_dir, config, rows, problems, tracked, monocular) = (
        f.run_dir,
        f.config,
        f.rows,
        f.problems,
        f.tracked,
        f.monocular,
    );
    let dataset = &config.source.path;
    let title = run_dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    writeln!(md, "# dynslam run {title}\n")?;
    if !problems.is_empty() {
        writeln!(md, "> **This run is degraded or failed:**")?;
        for p in problems {
            writeln!(md, "> - {p}")?;
        }
        writeln!(md)?;
    }
    writeln!(md, "Dataset: `{}`  ", dataset.display())?;
    let camera = run_folder::run_dir::read_info(run_dir)
        .map(|info| info.camera)
        .unwrap_or_default();
    let c = &config.camera;
    writeln!(
        md,
        "Camera: {} (fx {} fy {} cx {} cy {}, readout {} s)  ",
        if camera.is_empty() {
            "config"
        } else {
            camera.as_str()
        },
        c.fx,
        c.fy,
        c.cx,
        c.cy,
        c.readout_s
    )?;
    let turning = rows.iter().filter(|r| r.state == "turning").count();
    writeln!(
        md,
        "Frames: {}, tracked {} ({:.1} %{}); backends: SLAM `{}`{}, segmenter `{}`, propagator `{}`{}\n",
        rows.len(),
        tracked,
        100.0 * tracked as f64 / rows.len().max(1) as f64,
        if turning > 0 {
            format!("; {turning} turning: the turn from the images, the position held")
        } else {
            String::new()
        },
        config.services.slam.backend,
        if monocular { " (monocular: colour only)" } else { "" },
        config.services.segmenter.backend,
        config.services.propagator.backend,
        if config.routing.no_masks {
            " (run without masks)"
        } else {
            ""
        }
    )?;
    let outages =
        run_folder::outages::outages_line(&run_folder::outages::slam_outages(run_dir, rows));
    for line in [
        restarts_line(run_dir),
        outages,
        remote_line(run_dir, config),
    ]
    .iter()
    .flatten()
    {
        writeln!(md, "{line}\n")?;
    }
    Ok(())
}

/// The world frame, the SLAM's restarts, and the accuracy table and plots.
fn trajectory(md: &mut String, f: &Figures) -> Result<()> {
    let (run_dir, config, monocular, alignment) = (f.run_dir, f.config, f.monocular, f.alignment);
    let dataset = &config.source.path;
    writeln!(md, "## Trajectory\n")?;
    writeln!(md, "{WORLD_FRAME}\n")?;
    if monocular {
        writeln!(md, "Monocular: the map's unit is its own (the first keyframe's median scene depth is 1), so the accuracy figures align with a Sim(3) (rotation, translation and scale) and give the scale found.\n")?;
    }
    let starts = run_folder::run_dir::slam_starts(run_dir);
    if config.services.slam.backend == "orb-rgbd" {
        let list = |from_checkpoint: bool| {
            starts
                .iter()
                .filter(|s| s.from_checkpoint == from_checkpoint)
                .map(|s| s.next_seq.to_string())
                .collect::<Vec<_>>()
        };
        let (resumed, empty) = (list(true), list(false));
        if !resumed.is_empty() {
            writeln!(
                md,
                "The SLAM service started again at frame{} {} and went on from its map checkpoint, in the same world frame.\n",
                if resumed.len() > 1 { "s" } else { "" },
                resumed.join(", "),
            )?;
        }
        if !empty.is_empty() {
            writeln!(
                md,
                "**Several world frames:** the SLAM service started again with an empty map (no checkpoint yet) at frame{} {}. Each such start begins a new world frame at that frame's camera, so the poses before and after are not in one frame and the ATE below mixes them.\n",
                if empty.len() > 1 { "s" } else { "" },
                empty.join(", ")
            )?;
        }
    }
    match f.eval {
        Some(e) => {
            writeln!(md, "| | value |\n|---|---|")?;
            writeln!(md, "| poses compared | {} |", e.pairs)?;
            writeln!(
                md,
                "| ATE RMSE ({} aligned) | {:.4} m |\n| ATE mean / median / max | {:.4} / {:.4} / {:.4} m |",
                if monocular { "Sim(3)" } else { "SE(3)" },
                e.ate_rmse_m, e.ate_mean_m, e.ate_median_m, e.ate_max_m
            )?;
            if monocular {
                writeln!(md, "| scale (metres per map unit) | {:.4} |", e.scale)?;
            }
            writeln!(
                md,
                "| RPE per frame | {:.4} m, {:.3} deg |\n| RPE per {:.0} s | {:.4} m, {:.3} deg |\n",
                e.rpe_trans_rmse_m,
                e.rpe_rot_rmse_deg,
                e.rpe_interval_s,
                e.rpe_interval_trans_rmse_m,
                e.rpe_interval_rot_rmse_deg
            )?;
            if let Some(line) = corrected_trajectory_line(run_dir, dataset, alignment) {
                writeln!(md, "{line}\n")?;
            }
            writeln!(md, "![trajectory](plots/trajectory.png)\n")?;
            writeln!(
                md,
                "Ground truth (grey) and the {}-aligned estimate (coloured by its position error, scale on the right), in the ground truth's frame; views {}, same scale on both axes; the red square is the start, magenta rings mark loop closures. Full figures in `{EVAL_FILE}`.\n",
                if monocular { "Sim(3)" } else { "SE(3)" },
                f.views.as_ref().map(|v| v.describe()).unwrap_or_default()
            )?;
            writeln!(md, "![ATE over time](plots/ate_over_time.png)\n")?;
            writeln!(
                md,
                "Position error of each frame after the alignment, with its RMSE and median.\n"
            )?;
        }
        None => writeln!(md, "No ground truth: no accuracy figures.\n")?,
    }
    Ok(())
}

/// How each frame got its masks, and their quality against ground truth.
fn masks(md: &mut String, figures: &Figures) -> Result<()> {
    let (rows, mask_rows) = (figures.rows, &figures.masks.rows);
    writeln!(md, "## Dynamic masks\n")?;
    let segmented = mask_rows.iter().filter(|m| m.source == "segmenter").count();
    let propagated = mask_rows
        .iter()
        .filter(|m| m.source == "propagator")
        .count();
    writeln!(
        md,
        "Frames segmented {segmented}, propagated {propagated}, without masks {}; features removed by masks: {} in total.\n",
        rows.len().saturating_sub(segmented + propagated),
        rows.iter().map(|r| r.features_masked as u64).sum::<u64>()
    )?;
    if let Some(s) = &figures.masks.scores {
        let f = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.3}"));
        writeln!(
            md,
            "Mean IoU per ground-truth person (people covering >= {MIN_PERSON_PX} px):\n"
        )?;
        writeln!(
            md,
            "| masks from | mean IoU | person-frames |\n|---|---|---|"
        )?;
        writeln!(
            md,
            "| segmenter (keyframes) | {} | {} |",
            f(s.segmenter_iou),
            s.segmenter_samples
        )?;
        writeln!(
            md,
            "| propagator | {} | {} |",
            f(s.propagator_iou),
            s.propagator_samples
        )?;
        writeln!(
            md,
            "| every frame with a person | {} | {} |\n",
            f(s.all_frames_iou),
            s.all_frames_samples
        )?;
        if figures.masks.iou_plot {
            writeln!(md, "![mask IoU](plots/mask_iou.png)\n")?;
        }
    }
    if figures.masks.strip {
        writeln!(md, "![masks](plots/masks.png)\n")?;
    }
    Ok(())
}

/// The latency table and histograms.
fn latency_section(md: &mut String, f: &Figures) -> Result<()> {
    writeln!(md, "## Latency\n")?;
    writeln!(md, "```\n{}```\n", latency::format_table(f.latency))?;
    if !f.panels.is_empty() {
        writeln!(md, "![latency](plots/latency.png)\n")?;
        writeln!(
            md,
            "Stages, top to bottom: {}. Full trace: `trace.json` (chrome://tracing, Perfetto).\n",
            f.panels.join(", ")
        )?;
    }
    Ok(())
}

/// The files of the run folder and what each holds.
fn files(md: &mut String, run_dir: &Path) -> Result<()> {
    writeln!(md, "## Files\n")?;
    writeln!(md, "- `trajectory.txt`, `keyframes.txt`: TUM format (timestamp tx ty tz qx qy qz qw), world from camera (camera-to-world), the poses as published live")?;
    if run_dir
        .join(run_folder::run_dir::CORRECTED_TRAJECTORY_FILE)
        .is_file()
    {
        writeln!(md, "- `{}`: the same frames as the final map stands, loop corrections applied (TUM format)", run_folder::run_dir::CORRECTED_TRAJECTORY_FILE)?;
    }
    writeln!(md, "- `frames.csv`: one row per frame (state, route, pose, features, features removed by masks, inliers, stage timestamps)")?;
    writeln!(md, "- `masks.csv`: one row per set of masks SLAM got (source, instances, masked pixels); `masks/`: their label images (0 background, i+1 instance i) as `run.save_masks` keeps them (default: the segmenter's); `mask_iou.csv`: each set's per-person IoU where the dataset has ground-truth masks")?;
    let map = run_dir.join(run_folder::run_dir::MAP_FILE);
    match slam_core::io::ply::read_ply(&map) {
        Ok(points) => writeln!(
            md,
            "- `map.ply`: {} map points with colour (world frame)",
            points.len()
        )?,
        Err(_) => writeln!(
            md,
            "- no `map.ply` (the SLAM backend keeps no map, or it was not stopped cleanly)"
        )?,
    }
    let loops = run_dir.join(run_folder::run_dir::LOOPS_FILE);
    match run_folder::loops_csv::count_rows(&loops) {
        Ok(0) if !loops.exists() => writeln!(
            md,
            "- no `loops.csv`: no loop closed (`services.slam.loop_closing`, on by default, looks for them)"
        )?,
        Ok(n) => writeln!(
            md,
            "- `loops.csv`: {n} loop closures (timestamp, keyframe, matched keyframe, inliers, correction in m and deg)"
        )?,
        Err(e) => writeln!(md, "- `loops.csv` cannot be read: {e}")?,
    }
    writeln!(
        md,
        "- `latency_summary.json`, `trace.json`, `status.json`, `config.toml`"
    )?;
    Ok(())
}

/// "Restarts: 3 (segmenter 2, slam 1; restarts.log)" for a run whose
/// services were restarted; None for one without restarts.
fn restarts_line(run_dir: &Path) -> Option<String> {
    let log = std::fs::read_to_string(run_dir.join(run_folder::run_dir::RESTARTS_FILE)).ok()?;
    let mut by_service: Vec<(String, usize)> = Vec::new();
    for service in log.lines().filter_map(|l| l.split_whitespace().next()) {
        match by_service.iter_mut().find(|(s, _)| s == service) {
            Some((_, n)) => *n += 1,
            None => by_service.push((service.to_string(), 1)),
        }
    }
    let total: usize = by_service.iter().map(|(_, n)| n).sum();
    let each: Vec<String> = by_service.iter().map(|(s, n)| format!("{s} {n}")).collect();
    (total > 0).then(|| {
        format!(
            "Restarts: {total} ({}; `{}` says when and how each died)",
            each.join(", "),
            run_folder::run_dir::RESTARTS_FILE
        )
    })
}

/// With a remote segmenter: where its masks were made, and how many of its
/// frames went without fresh segmenter masks; None for a local one.
fn remote_line(run_dir: &Path, config: &PipelineConfig) -> Option<String> {
    if config.services.segmenter.location != "remote" {
        return None;
    }
    let counts = run_folder::mask_record::origin_counts(run_dir, "segmenter");
    let n = |origin: &str| counts.get(origin).copied().unwrap_or(0);
    Some(format!(
        "Remote segmenter (run `{}`, fallback {}): {} sets of masks made remotely, {} by the local fallback; {} segmenter frames went without fresh segmenter masks (no worker answered){}",
        config.remote.run,
        config.services.segmenter.fallback,
        n("remote"),
        n("fallback"),
        n("unavailable"),
        match (n("unavailable"), config.run.mode.is_realtime()) {
            (0, _) => "",
            (_, true) => ": the propagator carried the masks",
            (_, false) => ": tracked unmasked",
        }
    ))
}

/// The accuracy of the loop-corrected trajectory the SLAM wrote at stop,
/// as a sentence (None without one or without ground truth), aligned as the
/// live trajectory is (Sim(3) for a monocular map).
fn corrected_trajectory_line(
    run_dir: &Path,
    dataset: &Path,
    alignment: Alignment,
) -> Option<String> {
    let path = run_dir.join(run_folder::run_dir::CORRECTED_TRAJECTORY_FILE);
    if !path.is_file() {
        return None;
    }
    let gt = Trajectory::load_tum(&dataset.join("groundtruth.txt")).ok()?;
    let name = run_folder::run_dir::CORRECTED_TRAJECTORY_FILE;
    Some(
        match Trajectory::load_tum(&path)
            .map_err(anyhow::Error::from)
            .and_then(|est| {
                let options = EvalOptions {
                    alignment,
                    ..Default::default()
                };
                Ok(evaluate(&gt, &est, options)?)
            })
        {
            Ok(c) => format!(
                "With the loop corrections applied to every frame (`{name}`, {} poses): ATE RMSE {:.4} m. The table is of `trajectory.txt`, the poses as they were published live.",
                c.pairs, c.ate_rmse_m
            ),
            Err(err) => format!("`{name}` cannot be evaluated: {err:#}"),
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_report_counts_restarts_per_service_from_the_restarts_log() {
        let dir = std::env::temp_dir().join(format!("dynslam-restarts-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        assert_eq!(restarts_line(&dir), None, "no log: no line");
        for line in [
            "segmenter pid 10 killed by SIGKILL next_seq 30",
            "slam pid 11 killed by SIGKILL next_seq 41",
            "segmenter pid 12 killed by SIGKILL next_seq 77",
        ] {
            run_folder::run_dir::log_restart(&dir, line).unwrap();
        }
        let line = restarts_line(&dir).unwrap();
        assert!(
            line.starts_with("Restarts: 3 (segmenter 2, slam 1;"),
            "{line}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
