//! The run report: `report.md` and the PNGs under `plots/`, written at the
//! end of every run (and again by `dynslam report RUN_DIR`) from what the
//! run folder holds: `frames.csv`, `masks.csv` + `masks/`, `map.ply`, and
//! the dataset's ground truth (`groundtruth.txt`, and `masks.txt` for
//! synthesised sequences) where it exists.
//!
//! Each part is optional: what cannot be made (no ground truth, an image
//! folder without depth) is said in the report instead of failing the run.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use datasets::source::{FrameEntry, MaskList};
use image::{imageops, Rgb, RgbImage};
use pipeline_config::PipelineConfig;
use plotters::style::RGBColor;
use serde::Serialize;
use slam_core::eval::{evaluate, Alignment, EvalOptions, EvalSummary};
use slam_core::io::trajectory::Trajectory;

mod markdown;

use crate::plots::{self, Chart, Histogram, Level, Series, Style, Views, BLUE, GREEN, GREY, RED};
use run_folder::latency::{self, StageSummary, STAGES};
use run_folder::mask_record::{mask_file, read_ious, read_rows, MaskRow, MIN_PERSON_PX};
use run_folder::outputs::FrameRow;

/// The report, in the run folder.
pub const REPORT_FILE: &str = "report.md";
/// The report's figures for programs ([`ReportSummary`]).
pub const EVAL_FILE: &str = "eval.json";
/// The report's plots (PNG).
pub const PLOTS_DIR: &str = "plots";

/// The world frame of the trajectories and the map, in words.
pub const WORLD_FRAME: &str = "Poses (`trajectory.txt`, `frames.csv`) and `map.ply` are in the world frame of the SLAM map: the optical frame of the camera at the first tracked frame (x right, y down, z forward, metres), or the loaded map's (`--load-map`); a pose is camera-to-world. The accuracy figures align the estimate to the ground truth first (SE(3); Sim(3) for a monocular map).";

/// Mask quality of a run against ground-truth masks.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct MaskScores {
    /// Mean per-person IoU of the segmenter's masks (keyframes).
    pub segmenter_iou: Option<f64>,
    /// Person-frames behind it.
    pub segmenter_samples: usize,
    /// Mean per-person IoU of the propagator's masks.
    pub propagator_iou: Option<f64>,
    /// Person-frames behind it.
    pub propagator_samples: usize,
    /// Mean per-person IoU over every frame with a person, whatever the
    /// frame was routed to (a frame without masks scores 0).
    pub all_frames_iou: Option<f64>,
    /// Person-frames behind it.
    pub all_frames_samples: usize,
}

/// The figures of a report (also returned to callers such as the ablation).
#[derive(Debug, Clone, Serialize)]
pub struct ReportSummary {
    /// Frames recorded.
    pub frames: usize,
    /// Frames tracked (ok, relocalised or turning).
    pub tracked: usize,
    /// Accuracy against the ground truth, when the input has one.
    pub eval: Option<EvalSummary>,
    /// Mask quality, when the input has ground-truth masks.
    pub masks: Option<MaskScores>,
    /// Per-stage latency.
    pub latency: Vec<StageSummary>,
}

impl ReportSummary {
    /// Tracked frames over recorded frames.
    pub fn tracked_fraction(&self) -> f64 {
        self.tracked as f64 / self.frames.max(1) as f64
    }

    /// A stage's median latency, milliseconds (None when no frame had it).
    pub fn stage_p50(&self, stage: &str) -> Option<f64> {
        self.latency
            .iter()
            .find(|s| s.stage == stage && s.count > 0)
            .map(|s| s.p50_ms)
    }
}

/// Draws `plots/latency.png`: a histogram per stage that ran (end to end,
/// tracking, extraction, the mask workers, decoding); returns their names.
fn latency_histograms(
    rows: &[FrameRow],
    latency: &[latency::StageSummary],
    plots: &Path,
) -> Result<Vec<&'static str>> {
    let per_row: Vec<[Option<f64>; STAGES.len()]> = rows.iter().map(latency::stage_ms).collect();
    let shown = [
        "end_to_end",
        "track",
        "slam_extract",
        "segmenter",
        "propagator",
        "decode",
    ];
    let mut panels = Vec::new();
    for name in shown {
        let i = STAGES
            .iter()
            .position(|s| *s == name)
            .expect("a known stage");
        let v: Vec<f64> = per_row.iter().filter_map(|r| r[i]).collect();
        if v.is_empty() {
            continue;
        }
        let stage = latency.iter().find(|s| s.stage == name);
        panels.push(Histogram {
            stage: name,
            values_ms: v,
            p50_ms: stage.map_or(0.0, |s| s.p50_ms),
            p99_ms: stage.map_or(1.0, |s| s.p99_ms),
        });
    }
    if !panels.is_empty() {
        plots::save(
            &plots::histograms(&panels, "Latency per stage (ms per frame)")?,
            &plots.join("latency.png"),
        )?;
    }
    Ok(panels.iter().map(|p| p.stage).collect())
}

/// Writes the report of the run in `run_dir`; `rows` are its frames,
/// `problems` what degraded or failed the run (the report opens with them).
pub fn write(
    run_dir: &Path,
    config: &PipelineConfig,
    rows: &[FrameRow],
    problems: &[String],
) -> Result<ReportSummary> {
    let plots = run_dir.join(PLOTS_DIR);
    std::fs::create_dir_all(&plots)
        .with_context(|| format!("cannot create {}", plots.display()))?;
    let dataset = &config.source.path;
    let mut notes: Vec<String> = Vec::new();
    let tracked = rows.iter().filter(|r| r.is_tracked()).count();
    let latency = latency::summarize(rows);

    // Trajectory accuracy.
    let monocular =
        config.services.slam.backend == "orb-rgbd" && config.services.slam.is_monocular();
    let alignment = if monocular {
        Alignment::Sim3
    } else {
        Alignment::Se3
    };
    let eval = match trajectory_eval(run_dir, dataset, rows, alignment) {
        Ok(e) => e,
        Err(e) => {
            notes.push(format!("trajectory evaluation: {e:#}"));
            None
        }
    };
    let views = match &eval {
        Some(e) => {
            std::fs::write(run_dir.join(EVAL_FILE), serde_json::to_string_pretty(e)?)?;
            Some(trajectory_plots(run_dir, e, &plots)?)
        }
        None => None,
    };
    let masks = mask_figures(run_dir, config, rows, &plots, &mut notes)?;
    let panels = latency_histograms(rows, &latency, &plots)?;

    let md = markdown::report(&markdown::Figures {
        run_dir,
        config,
        rows,
        problems,
        tracked,
        monocular,
        alignment,
        eval: eval.as_ref(),
        views,
        masks: &masks,
        latency: &latency,
        panels: &panels,
        notes: &notes,
    })?;
    let path = run_dir.join(REPORT_FILE);
    std::fs::write(&path, md).with_context(|| format!("cannot write {}", path.display()))?;
    Ok(ReportSummary {
        frames: rows.len(),
        tracked,
        eval,
        masks: masks.scores,
        latency,
    })
}

/// Draws `plots/trajectory.png` and `plots/ate_over_time.png`; returns the
/// views the trajectory plot shows.
fn trajectory_plots(run_dir: &Path, e: &EvalSummary, plots: &Path) -> Result<Views> {
    let (img, v) = plots::trajectory(
        &e.positions,
        &loop_indices(run_dir, e),
        &format!(
            "Trajectory: estimate vs ground truth (ATE RMSE {:.4} m)",
            e.ate_rmse_m
        ),
    )?;
    plots::save(&img, &plots.join("trajectory.png"))?;
    let t0 = e.ate_series.first().map_or(0.0, |p| p.0);
    let spec = Chart {
        title: "Absolute trajectory error over time",
        x_desc: "time since the first frame (s)",
        y_desc: "position error (m)",
        series: vec![Series {
            name: "ATE per frame",
            points: e.ate_series.iter().map(|(t, v)| (t - t0, *v)).collect(),
            colour: RED,
            style: Style::Line,
        }],
        levels: vec![
            Level {
                name: format!("RMSE {:.4} m", e.ate_rmse_m),
                value: e.ate_rmse_m,
                colour: BLUE,
            },
            Level {
                name: format!("median {:.4} m", e.ate_median_m),
                value: e.ate_median_m,
                colour: GREEN,
            },
        ],
        y_max: None,
    };
    plots::save(
        &plots::chart(&spec, 900, 320)?,
        &plots.join("ate_over_time.png"),
    )?;
    Ok(v)
}

/// What the report says of the run's masks.
pub(super) struct MaskFigures {
    /// The sets of masks SLAM got (`masks.csv`).
    pub rows: Vec<MaskRow>,
    /// Their quality, where the dataset has ground-truth masks.
    pub scores: Option<MaskScores>,
    /// `plots/mask_iou.png` was drawn.
    pub iou_plot: bool,
    /// `plots/masks.png` (the strip of frames) was drawn.
    pub strip: bool,
}

/// Scores the run's masks against the ground truth where there is one and
/// draws `plots/mask_iou.png` and the strip of frames `plots/masks.png`.
fn mask_figures(
    run_dir: &Path,
    config: &PipelineConfig,
    rows: &[FrameRow],
    plots: &Path,
    notes: &mut Vec<String>,
) -> Result<MaskFigures> {
    let dataset = &config.source.path;
    let mask_rows = read_rows(run_dir)?;
    let frames = config.source.recorded_frames().ok();
    let truth = MaskList::open(dataset).ok().flatten();
    let (scores, ious) = match &truth {
        Some(t) => {
            let ignore = run_folder::ignore::IgnoreRegions::open(dataset)?;
            let (s, i) = mask_scores(run_dir, rows, &mask_rows, t, &ignore)?;
            (Some(s), i)
        }
        None => (None, Vec::new()),
    };
    if !ious.is_empty() {
        let by = |name, src: &str, colour| Series {
            name,
            points: ious
                .iter()
                .filter(|(_, s, _)| s == src)
                .map(|(seq, _, v)| (*seq as f64, *v))
                .collect(),
            colour,
            style: Style::Dots,
        };
        let spec = Chart {
            title: "Mask IoU against ground truth, per person and frame",
            x_desc: "frame number",
            y_desc: "IoU (0-1)",
            series: vec![
                by("segmenter masks", "segmenter", RED),
                by("propagated masks", "propagator", BLUE),
                by("no masks", "none", GREY),
            ],
            levels: Vec::new(),
            y_max: Some(1.05),
        };
        plots::save(&plots::chart(&spec, 900, 320)?, &plots.join("mask_iou.png"))?;
    }
    let strip = match &frames {
        Some(f) => match mask_strip(run_dir, f, rows, &mask_rows, truth.as_ref()) {
            Ok(img) => {
                plots::save(&img, &plots.join("masks.png"))?;
                true
            }
            Err(e) => {
                notes.push(format!("mask strip: {e:#}"));
                false
            }
        },
        None => false,
    };

    Ok(MaskFigures {
        rows: mask_rows,
        scores,
        iou_plot: !ious.is_empty(),
        strip,
    })
}

/// Where in `e`'s associated poses each loop of `loops.csv` closed (the
/// pose nearest its timestamp).
fn loop_indices(run_dir: &Path, e: &EvalSummary) -> Vec<usize> {
    let stamps = run_folder::loops_csv::timestamps(&run_dir.join(run_folder::run_dir::LOOPS_FILE));
    stamps
        .unwrap_or_default()
        .into_iter()
        .filter(|t| t.is_finite())
        .filter_map(|t| {
            let i = e.ate_series.partition_point(|p| p.0 < t);
            [i.checked_sub(1), Some(i)]
                .into_iter()
                .flatten()
                .filter(|&j| j < e.ate_series.len())
                .min_by(|&a, &b| {
                    (e.ate_series[a].0 - t)
                        .abs()
                        .total_cmp(&(e.ate_series[b].0 - t).abs())
                })
        })
        .collect()
}

/// ATE/RPE of `trajectory.txt` when the dataset has ground truth.
fn trajectory_eval(
    run_dir: &Path,
    dataset: &Path,
    rows: &[FrameRow],
    alignment: Alignment,
) -> Result<Option<EvalSummary>> {
    let gt_path = dataset.join("groundtruth.txt");
    if !gt_path.is_file() {
        return Ok(None);
    }
    let gt = Trajectory::load_tum(&gt_path)?;
    let est = Trajectory::load_tum(&run_dir.join("trajectory.txt"));
    let est = match est {
        Ok(t) => t,
        Err(_) if rows.iter().all(|r| !r.is_tracked()) => {
            anyhow::bail!("no frame was tracked")
        }
        Err(e) => return Err(e.into()),
    };
    let options = EvalOptions {
        alignment,
        ..Default::default()
    };
    Ok(Some(evaluate(&gt, &est, options)?))
}

type FrameIou = (u64, String, f64);

/// Per-person IoU of the masks the run used against the ground truth, per
/// frame with a person (a frame without masks scores 0 for each person).
/// The masks were scored as they were recorded (`mask_iou.csv`): the run
/// folder need not keep their images.
fn mask_scores(
    run_dir: &Path,
    rows: &[FrameRow],
    mask_rows: &[MaskRow],
    truth: &MaskList,
    ignore: &run_folder::ignore::IgnoreRegions,
) -> Result<(MaskScores, Vec<FrameIou>)> {
    let masked: std::collections::HashSet<u64> = mask_rows.iter().map(|m| m.seq).collect();
    let scored = read_ious(run_dir)?;
    let mut ious: Vec<FrameIou> = Vec::new();
    for r in rows {
        if masked.contains(&r.seq) {
            // A set of masks the recorder skipped (it fell behind) has no scores.
            for p in scored.get(&r.seq).into_iter().flatten() {
                ious.push((r.seq, p.source.clone(), p.iou));
            }
            continue;
        }
        let Ok(gt) = truth.load_at(r.timestamp) else {
            continue;
        };
        let none = vec![0u8; gt.as_raw().len()];
        let ignored = ignore.at(r.timestamp, gt.width() as usize, gt.height() as usize)?;
        for s in scenes::truth::instance_ious(
            &none,
            gt.as_raw(),
            ignored.as_deref(),
            gt.width() as usize,
            MIN_PERSON_PX,
        ) {
            ious.push((r.seq, "none".to_string(), s.iou));
        }
    }
    let mean = |src: Option<&str>| {
        let v: Vec<f64> = ious
            .iter()
            .filter(|(_, s, _)| src.is_none_or(|want| s == want))
            .map(|(_, _, v)| *v)
            .collect();
        let m = (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
        (m, v.len())
    };
    let (segmenter_iou, segmenter_samples) = mean(Some("segmenter"));
    let (propagator_iou, propagator_samples) = mean(Some("propagator"));
    let (all_frames_iou, all_frames_samples) = mean(None);
    Ok((
        MaskScores {
            segmenter_iou,
            segmenter_samples,
            propagator_iou,
            propagator_samples,
            all_frames_iou,
            all_frames_samples,
        },
        ious,
    ))
}

/// Six frames in a 3x2 grid at half size, masks tinted by source, ground
/// truth outlined. Frames with masks (or people) are preferred.
fn mask_strip(
    run_dir: &Path,
    frames: &[FrameEntry],
    rows: &[FrameRow],
    mask_rows: &[MaskRow],
    truth: Option<&MaskList>,
) -> Result<RgbImage> {
    // Frames whose mask image the run kept (`run.save_masks`).
    let with_masks: Vec<u64> = mask_rows
        .iter()
        .filter(|m| m.masked_px > 0 && m.saved)
        .map(|m| m.seq)
        .collect();
    let pool: Vec<u64> = if with_masks.len() >= 6 {
        with_masks
    } else {
        rows.iter().map(|r| r.seq).collect()
    };
    anyhow::ensure!(!pool.is_empty(), "no frames");
    let picks: Vec<u64> = (0..6).map(|i| pool[i * (pool.len() - 1) / 5]).collect();
    let source_of: std::collections::HashMap<u64, &str> = mask_rows
        .iter()
        .map(|m| (m.seq, m.source.as_str()))
        .collect();
    let (tw, th) = (320u32, 240u32);
    let mut out = RgbImage::from_pixel(3 * tw, 2 * th, Rgb([255, 255, 255]));
    let mut labels = Vec::new();
    for (k, &seq) in picks.iter().enumerate() {
        let entry = frames
            .get(seq as usize)
            .with_context(|| format!("frame {seq} is not in the dataset"))?;
        let mut rgb = image::open(&entry.rgb)
            .with_context(|| format!("cannot read {}", entry.rgb.display()))?
            .into_rgb8();
        let (w, h) = rgb.dimensions();
        if let Some(&src) = source_of.get(&seq) {
            if let Ok(m) = image::open(mask_file(run_dir, seq)) {
                let m = m.into_luma8();
                if m.dimensions() == (w, h) {
                    let tint = rgb_of(if src == "segmenter" { RED } else { BLUE });
                    for (p, l) in rgb.pixels_mut().zip(m.pixels()) {
                        if l[0] != 0 {
                            for c in 0..3 {
                                p[c] = ((p[c] as u16 + tint[c] as u16) / 2) as u8;
                            }
                        }
                    }
                }
            }
        }
        if let Some(Ok(gt)) = truth.map(|t| t.load_at(entry.timestamp)) {
            if gt.dimensions() == (w, h) {
                for y in 1..h - 1 {
                    for x in 1..w - 1 {
                        let l = gt.get_pixel(x, y)[0];
                        let edge = [(x - 1, y), (x + 1, y), (x, y - 1), (x, y + 1)]
                            .iter()
                            .any(|&(a, b)| gt.get_pixel(a, b)[0] != l);
                        if edge {
                            rgb.put_pixel(x, y, rgb_of(GREEN));
                        }
                    }
                }
            }
        }
        let small = imageops::resize(&rgb, tw, th, imageops::FilterType::Triangle);
        let (x, y) = ((k as u32 % 3) * tw, (k as u32 / 3) * th);
        imageops::replace(&mut out, &small, x as i64, y as i64);
        labels.push((format!("frame {seq}"), (x as i32 + 6, y as i32 + 4)));
    }
    let mut legend = vec![("segmenter mask", RED), ("propagated mask", BLUE)];
    if truth.is_some() {
        legend.push(("ground-truth outline", GREEN));
    }
    plots::titled_picture(
        &out,
        "Masks SLAM used on six frames of the run",
        &legend,
        &labels,
    )
}

fn rgb_of(c: RGBColor) -> Rgb<u8> {
    Rgb([c.0, c.1, c.2])
}

/// Path of the report of a run folder.
pub fn report_path(run_dir: &Path) -> PathBuf {
    run_dir.join(REPORT_FILE)
}
