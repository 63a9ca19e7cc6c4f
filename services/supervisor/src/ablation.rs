//! `dynslam ablate`: the same dynamic sequence through the whole pipeline
//! under each way of handling dynamic objects, one table of ATE, tracked
//! frames, mask IoU and latency.
//!
//! Rows: (a) no masks, (b) ground-truth masks on every frame, (c) the
//! segmenter on every frame, (d) the product's routing (segmenter on
//! keyframes, propagator otherwise), (e) the product's routing with masked
//! pixels blacked out instead of keypoints filtered, (f, g) the product
//! with the segmenter at 320 and 640 input (the default is 480), (h) the
//! product with the SLAM's motion check, (i) the product without the
//! propagator's early segmenter requests, (j, k, l) the product with
//! YOLO11n-seg at 320, 480 and 640 input; and, when the sequence
//! was made by `dynslam synth` from a folder that still exists, the static
//! original without people as the reference.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use pipeline::config::PipelineConfig;
use serde::Serialize;

use crate::run::execute;
use run_folder::run_dir;

/// One configuration of the ablation.
#[derive(Debug, Clone)]
pub struct Variant {
    /// Short name (the row key, the run folder's name).
    pub key: &'static str,
    /// What the table says for it.
    pub label: &'static str,
    /// A different dataset (the static original), or the ablated sequence.
    pub dataset: Option<PathBuf>,
    /// The configuration change this variant makes.
    pub apply: fn(&mut PipelineConfig),
}

/// The variants in table order.
pub fn variants(static_original: Option<PathBuf>) -> Vec<Variant> {
    let mut v = Vec::new();
    if let Some(original) = static_original {
        v.push(Variant {
            key: "static",
            label: "static original (no people), product routing",
            dataset: Some(original),
            apply: |_| {},
        });
    }
    v.extend([
        Variant {
            key: "a",
            label: "(a) no masks",
            dataset: None,
            apply: |c| c.routing.no_masks = true,
        },
        Variant {
            key: "b",
            label: "(b) ground-truth masks, every frame",
            dataset: None,
            apply: |c| {
                c.routing.segment_every_frame = true;
                c.services.segmenter.backend = "ground-truth".into();
            },
        },
        Variant {
            key: "c",
            label: "(c) segmenter on every frame",
            dataset: None,
            apply: |c| c.routing.segment_every_frame = true,
        },
        Variant {
            key: "d",
            label: "(d) product: segmenter on keyframes, propagator between",
            dataset: None,
            apply: |_| {},
        },
        Variant {
            key: "e",
            label: "(e) product routing, masked pixels blacked out",
            dataset: None,
            apply: |c| c.services.slam.mask_mode = "blackout".into(),
        },
        Variant {
            key: "f",
            label: "(f) product routing, segmenter at 320 input",
            dataset: None,
            apply: |c| c.services.segmenter.input_size = Some(320),
        },
        Variant {
            key: "g",
            label: "(g) product routing, segmenter at 640 input",
            dataset: None,
            apply: |c| c.services.segmenter.input_size = Some(640),
        },
        Variant {
            key: "h",
            label: "(h) product routing, without the SLAM's motion check",
            dataset: None,
            apply: |c| c.services.slam.motion_check = false,
        },
        Variant {
            key: "i",
            label: "(i) product routing without early segmenter requests",
            dataset: None,
            apply: |c| c.routing.early_segment_requests = false,
        },
        Variant {
            key: "j",
            label: "(j) product routing, YOLO11n-seg at 320 input",
            dataset: None,
            apply: |c| yolo11_at(c, 320),
        },
        Variant {
            key: "k",
            label: "(k) product routing, YOLO11n-seg at 480 input",
            dataset: None,
            apply: |c| yolo11_at(c, 480),
        },
        Variant {
            key: "l",
            label: "(l) product routing, YOLO11n-seg at 640 input",
            dataset: None,
            apply: |c| yolo11_at(c, 640),
        },
    ]);
    v
}

/// The segmenter's network YOLO11n-seg at `input_size` (rows j-l).
fn yolo11_at(c: &mut PipelineConfig, input_size: u32) {
    c.services.segmenter.backend = segmentation::exports::YoloFamily::V11.backend().into();
    c.services.segmenter.input_size = Some(input_size);
}

/// One row of the table.
#[derive(Debug, Clone, Serialize)]
pub struct AblationRow {
    /// The variant's key.
    pub key: String,
    /// The variant's label.
    pub label: String,
    /// Its run folder.
    pub run_dir: PathBuf,
    /// Frames recorded.
    pub frames: usize,
    /// Share of the frames tracked (percent).
    pub tracked_pct: f64,
    /// ATE against the ground truth (metres), where there is one.
    pub ate_rmse_m: Option<f64>,
    /// Largest position error (metres).
    pub ate_max_m: Option<f64>,
    /// Mean per-person IoU over every frame with a person.
    pub mask_iou: Option<f64>,
    /// Median ms per frame: end to end, and SLAM's tracking alone.
    pub end_to_end_ms_p50: Option<f64>,
    /// See `end_to_end_ms_p50`.
    pub track_ms_p50: Option<f64>,
}

/// The static sequence a `dynslam synth` folder was made from, if it still
/// exists.
pub fn static_original(dataset: &Path) -> Option<PathBuf> {
    let text = std::fs::read_to_string(dataset.join("objects.json")).ok()?;
    let v: serde_json::Value = serde_json::from_str(&text).ok()?;
    let input = PathBuf::from(v.get("input")?.as_str()?);
    input.is_dir().then_some(input)
}

/// Runs every variant on `dataset`; run folders go to `output_dir`.
pub fn run(
    dataset: &Path,
    base: &PipelineConfig,
    output_dir: &Path,
    only: &[String],
) -> Result<Vec<AblationRow>> {
    let dataset = dataset
        .canonicalize()
        .with_context(|| format!("dataset folder {} does not exist", dataset.display()))?;
    let batch = run_dir::new_run_id();
    let mut rows = Vec::new();
    let all = variants(static_original(&dataset));
    for v in all
        .iter()
        .filter(|v| only.is_empty() || only.iter().any(|o| o == v.key))
    {
        let mut cfg = base.clone();
        cfg.source.path = v.dataset.clone().unwrap_or_else(|| dataset.clone());
        (v.apply)(&mut cfg);
        let id = format!("ablate-{batch}-{}", v.key);
        let dir = run_dir::create(output_dir, &id, &cfg, "config (ablation)")?;
        eprintln!("ablation {}: {} -> {}", v.key, v.label, dir.display());
        let summary = execute(&dir).with_context(|| format!("ablation run {}", v.label))?;
        let report = summary
            .report
            .with_context(|| format!("ablation run {}: no report", v.label))?;
        rows.push(AblationRow {
            key: v.key.into(),
            label: v.label.into(),
            run_dir: dir,
            frames: report.frames,
            tracked_pct: 100.0 * report.tracked_fraction(),
            ate_rmse_m: report.eval.as_ref().map(|e| e.ate_rmse_m),
            ate_max_m: report.eval.as_ref().map(|e| e.ate_max_m),
            mask_iou: report.masks.as_ref().and_then(|m| m.all_frames_iou),
            end_to_end_ms_p50: report.stage_p50("end_to_end"),
            track_ms_p50: report.stage_p50("track"),
        });
    }
    Ok(rows)
}

/// The table as Markdown.
pub fn table(rows: &[AblationRow]) -> String {
    let f = |v: Option<f64>, d: usize| v.map_or("-".to_string(), |v| format!("{v:.d$}"));
    let mut t = String::from(
        "| variant | ATE RMSE (m) | ATE max (m) | tracked | mask IoU | ms/frame (end to end, p50) | SLAM track (p50 ms) |\n|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let _ = writeln!(
            t,
            "| {} | {} | {} | {:.1} % | {} | {} | {} |",
            r.label,
            f(r.ate_rmse_m, 4),
            f(r.ate_max_m, 3),
            r.tracked_pct,
            if r.key == "a" || r.key == "static" {
                "-".to_string()
            } else {
                f(r.mask_iou, 3)
            },
            f(r.end_to_end_ms_p50, 1),
            f(r.track_ms_p50, 1)
        );
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn variants_change_what_their_label_says() {
        let base = PipelineConfig::parse("").unwrap();
        let vs = variants(None);
        assert_eq!(
            vs.iter().map(|v| v.key).collect::<Vec<_>>(),
            ["a", "b", "c", "d", "e", "f", "g", "h", "i", "j", "k", "l"]
        );
        let applied = |k: &str| {
            let mut c = base.clone();
            (vs.iter().find(|v| v.key == k).unwrap().apply)(&mut c);
            c
        };
        assert!(applied("a").routing.no_masks);
        assert_eq!(applied("b").services.segmenter.backend, "ground-truth");
        assert!(applied("b").routing.segment_every_frame);
        assert!(applied("c").routing.segment_every_frame);
        assert_eq!(applied("d"), base);
        assert_eq!(applied("e").services.slam.mask_mode, "blackout");
        assert_eq!(applied("f").services.segmenter.input_size, Some(320));
        assert_eq!(applied("g").services.segmenter.input_size, Some(640));
        assert_ne!(base.services.segmenter.input_size, Some(320));
        assert!(!applied("h").services.slam.motion_check && base.services.slam.motion_check);
        assert!(
            !applied("i").routing.early_segment_requests && base.routing.early_segment_requests
        );
        for (k, n) in [("j", 320), ("k", 480), ("l", 640)] {
            let c = applied(k);
            assert_eq!(c.services.segmenter.backend, "yolo11-seg");
            assert_eq!(c.services.segmenter.input_size, Some(n));
        }
        assert_eq!(variants(Some(PathBuf::from("/x")))[0].key, "static");
    }

    #[test]
    fn table_has_a_row_per_run() {
        let row = AblationRow {
            key: "d".into(),
            label: "(d) product".into(),
            run_dir: PathBuf::from("/r"),
            frames: 10,
            tracked_pct: 100.0,
            ate_rmse_m: Some(0.0123),
            ate_max_m: Some(0.05),
            mask_iou: Some(0.5),
            end_to_end_ms_p50: Some(60.0),
            track_ms_p50: None,
        };
        let t = table(&[row]);
        assert!(
            t.contains("| (d) product | 0.0123 | 0.050 | 100.0 % | 0.500 | 60.0 | - |"),
            "{t}"
        );
    }
}
