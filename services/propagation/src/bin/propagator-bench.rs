//! Propagator speed: median and p99 milliseconds per 640x480 frame of the
//! `lk` backend following one person-sized object (an ellipse textured from a
//! real TUM frame, moving and growing over another real TUM frame while the
//! camera moves), re-prompted every 10 frames as keyframes would. Also prints
//! the mean IoU against the object's true mask. With `--sam2-encoder` and
//! `--sam2-decoder` the `sam2` backend runs on the same frames in the same
//! run (its ms and the ratio to `lk`; on the tiny test graphs that is our
//! pre-/post-processing and ONNX Runtime's overhead, not SAM 2's speed).
//! The newcomer check (early segmenter requests) is timed on its own over
//! consecutive real frames of the dataset with their depth, with the
//! requests it made (the shared sequence is static: each is a false one).
//!
//! `propagator-bench [--frames N] [--dataset DIR] [--out FILE] [--sam2-encoder F --sam2-decoder F]`

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Parser;
use datasets::decode::decode_depth_into;
use datasets::source::tum_folder;
use pipeline_config::{CameraConfig, OnnxRuntimeConfig, PropagatorConfig, RoutingConfig};
use propagation::newcomers::{DepthImage, NewcomerCheck};
use propagation::propagate::{LkPropagator, PropagatorParams};
use propagation::pyramid::{GrayF32, Pyramid};
use propagation::sam2::{Sam2Propagator, Sam2Settings};
use propagation::synthetic::{iou, render};
use shared_types::stats::percentile;
use shared_types::Instance;

#[derive(Debug, Parser)]
#[command(about = "lk propagator: ms per 640x480 frame")]
struct Args {
    #[arg(
        long,
        default_value_os_t = provision::shared_tum()
    )]
    dataset: PathBuf,
    #[arg(long, default_value_t = 200)]
    frames: usize,
    #[arg(long, default_value = "bench-results/propagator.json")]
    out: PathBuf,
    /// SAM 2 image encoder (ONNX) to time against `lk` on the same frames.
    #[arg(long, requires = "sam2_decoder")]
    sam2_encoder: Option<PathBuf>,
    /// SAM 2 prompt/mask decoder (ONNX).
    #[arg(long, requires = "sam2_encoder")]
    sam2_decoder: Option<PathBuf>,
}

/// The `sam2` backend on the given files (hashes taken from the files: a
/// bench of the user's own export).
fn sam2(encoder: &std::path::Path, decoder: &std::path::Path) -> Result<Sam2Propagator> {
    let sha = |p: &std::path::Path| provision::sha256_of(p).map_err(anyhow::Error::msg);
    let name = |p: &std::path::Path| {
        p.file_name()
            .unwrap_or_default()
            .to_string_lossy()
            .into_owned()
    };
    let cfg = PropagatorConfig {
        model: name(encoder),
        model_path: Some(encoder.to_path_buf()),
        model_sha256: sha(encoder)?,
        decoder_model: name(decoder),
        decoder_model_path: Some(decoder.to_path_buf()),
        decoder_model_sha256: sha(decoder)?,
        threads: Some(2),
        ..Default::default()
    };
    let env = onnx_runtime::init_runtime(&OnnxRuntimeConfig::default())?;
    Sam2Propagator::load(env, Sam2Settings::from_config(&cfg)?)
}

fn main() -> Result<()> {
    let args = Args::parse();
    let entries = tum_folder(&args.dataset, 0.02)?;
    let files: Vec<PathBuf> = entries.iter().map(|f| f.rgb.clone()).collect();
    let load = |i: usize| -> Result<image::RgbImage> {
        let f = &files[i % files.len()];
        Ok(image::open(f)
            .with_context(|| f.display().to_string())?
            .to_rgb8())
    };
    let (bg, tex) = (load(0)?, load(150)?);
    let (w, h) = (bg.width() as usize, bg.height() as usize);
    let mut p = LkPropagator::new(PropagatorParams::default());
    let mut sam = match (&args.sam2_encoder, &args.sam2_decoder) {
        (Some(e), Some(d)) => Some(sam2(e, d)?),
        _ => None,
    };
    let mut sam_ms = Vec::new();
    let inst = Instance {
        object_id: 1,
        class_id: 0,
        score: 0.9,
        bbox: [0.0; 4],
    };
    // Each backend over all frames in turn (each frame rendered just before
    // it is used, as a camera delivers it): interleaved, ONNX Runtime's
    // spinning thread pool would slow `lk` down.
    let scene_at = |k: usize| {
        let phase = (k % 10) as f32;
        render(
            bg.as_raw(),
            tex.as_raw(),
            w,
            h,
            (-2.0 * phase, 1.0 * phase),
            (280.0 + 5.0 * phase, 240.0 - 2.0 * phase),
            1.0 + 0.02 * phase,
        )
    };
    let (mut ms, mut ious) = (Vec::new(), Vec::new());
    for k in 0..args.frames {
        let scene = scene_at(k);
        if k % 10 == 0 {
            let labels: Vec<u8> = scene.mask.iter().map(|&m| m as u8).collect();
            p.prompt_with(&scene.rgb, w, h, &labels, &[inst]);
            continue;
        }
        let mut labels = vec![0u8; w * h];
        let t = Instant::now();
        p.propagate(&scene.rgb, w, h, &mut labels);
        ms.push(t.elapsed().as_secs_f64() * 1e3);
        ious.push(iou(&labels, 1, &scene.mask));
    }
    if let Some(s) = sam.as_mut() {
        for k in 0..args.frames {
            let scene = scene_at(k);
            if k % 10 == 0 {
                let labels: Vec<u8> = scene.mask.iter().map(|&m| m as u8).collect();
                s.prompt_with(&labels, w, h, &[inst]);
                continue;
            }
            let mut labels = vec![0u8; w * h];
            let t = Instant::now();
            s.propagate(&scene.rgb, w, h, &mut labels)?;
            sam_ms.push(t.elapsed().as_secs_f64() * 1e3);
        }
    }
    ms.sort_by(f64::total_cmp);
    let (p50, p99) = (percentile(&ms, 50.0), percentile(&ms, 99.0));
    let mean_iou = ious.iter().sum::<f64>() / ious.len().max(1) as f64;
    println!(
        "propagator lk, {w}x{h}, one object, {} propagated frames",
        ms.len()
    );
    println!("{:<12} {:>9} {:>9}", "stage", "p50 ms", "p99 ms");
    println!("{:<12} {:>9.2} {:>9.2}", "propagator", p50, p99);
    println!("mean IoU against the true mask, 1-9 frames after a prompt: {mean_iou:.3}");
    let mut sam_json = String::new();
    if !sam_ms.is_empty() {
        sam_ms.sort_by(f64::total_cmp);
        let (s50, s99) = (percentile(&sam_ms, 50.0), percentile(&sam_ms, 99.0));
        println!(
            "{:<12} {:>9.2} {:>9.2}   ({:.2}x lk at p50; {})",
            "sam2",
            s50,
            s99,
            s50 / p50,
            args.sam2_encoder
                .as_ref()
                .map(|p| p.display().to_string())
                .unwrap_or_default()
        );
        sam_json = format!(",\n  \"sam2_p50_ms\": {s50:.3},\n  \"sam2_p99_ms\": {s99:.3}");
    }
    let (check_ms, requests) = time_newcomer_check(&entries, args.frames)?;
    let (c50, c99) = (percentile(&check_ms, 50.0), percentile(&check_ms, 99.0));
    println!(
        "{:<12} {:>9.2} {:>9.2}   (newcomer check alone, {} real frame pairs, {requests} requests)",
        "newcomers",
        c50,
        c99,
        check_ms.len()
    );
    sam_json.push_str(&format!(
        ",\n  \"newcomer_check_p50_ms\": {c50:.3},\n  \"newcomer_check_p99_ms\": {c99:.3},\n  \"newcomer_requests\": {requests}"
    ));
    if let Some(dir) = args.out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(
        &args.out,
        format!("{{\n  \"propagator_p50_ms\": {p50:.3},\n  \"propagator_p99_ms\": {p99:.3},\n  \"mean_iou\": {mean_iou:.4},\n  \"frames\": {}{sam_json}\n}}\n", ms.len()),
    )?;
    println!("wrote {}", args.out.display());
    Ok(())
}

/// Milliseconds of the newcomer check per pair of consecutive frames (up to
/// `frames` pairs, nothing followed), and the requests it made.
fn time_newcomer_check(
    entries: &[datasets::source::FrameEntry],
    frames: usize,
) -> Result<(Vec<f64>, u64)> {
    let mut check = NewcomerCheck::for_pipeline(
        &CameraConfig::default(),
        &RoutingConfig::default(),
        pipeline_config::ClockMode::Lockstep,
    );
    let lk = PropagatorParams::default();
    let mut prev: Option<Pyramid> = None;
    let mut depth = Vec::new();
    let mut ms = Vec::new();
    for entry in entries.iter().take(frames + 1) {
        let Some(depth_path) = &entry.depth else {
            anyhow::bail!("{}: the newcomer check needs depth", entry.rgb.display());
        };
        let rgb = image::open(&entry.rgb)
            .with_context(|| entry.rgb.display().to_string())?
            .to_rgb8();
        let (w, h) = (rgb.width() as usize, rgb.height() as usize);
        depth.resize(w * h * 2, 0);
        decode_depth_into(depth_path, (w as u32, h as u32), &mut depth)?;
        let cur = Pyramid::new(GrayF32::from_rgb(rgb.as_raw(), w, h), lk.pyramid_levels);
        if let Some(prev) = &prev {
            let depth = DepthImage::new(&depth, w, h, 5000.0).context("depth size")?;
            let t = Instant::now();
            check.check(prev, &cur, &[], depth, lk.lk);
            ms.push(t.elapsed().as_secs_f64() * 1e3);
        }
        prev = Some(cur);
    }
    ms.sort_by(f64::total_cmp);
    Ok((ms, check.requests()))
}
