//! Propagator speed: median and p99 milliseconds per 640x480 frame of the
//! `lk` backend following one person-sized object (an ellipse textured from a
//! real TUM frame, moving and growing over another real TUM frame while the
//! camera moves), re-prompted every 10 frames as keyframes would. Also prints
//! the mean IoU against the object's true mask.
//!
//! `propagator-bench [--frames N] [--dataset DIR] [--out FILE]`

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use camera_reader::source::tum_folder;
use clap::Parser;
use pipeline::stats::percentile;
use propagator::propagate::{LkPropagator, PropagatorParams};
use propagator::synthetic::{iou, render};
use shared_types::Instance;

#[derive(Debug, Parser)]
#[command(about = "lk propagator: ms per 640x480 frame")]
struct Args {
    #[arg(
        long,
        default_value_os_t = pipeline::provision::shared_tum()
    )]
    dataset: PathBuf,
    #[arg(long, default_value_t = 200)]
    frames: usize,
    #[arg(long, default_value = "bench-results/propagator.json")]
    out: PathBuf,
}

fn main() -> Result<()> {
    let args = Args::parse();
    let files: Vec<PathBuf> = tum_folder(&args.dataset, 0.02)?
        .into_iter()
        .map(|f| f.rgb)
        .collect();
    let load = |i: usize| -> Result<image::RgbImage> {
        let f = &files[i % files.len()];
        Ok(image::open(f)
            .with_context(|| f.display().to_string())?
            .to_rgb8())
    };
    let (bg, tex) = (load(0)?, load(150)?);
    let (w, h) = (bg.width() as usize, bg.height() as usize);
    let mut p = LkPropagator::new(PropagatorParams::default());
    let inst = Instance {
        object_id: 1,
        class_id: 0,
        score: 0.9,
        bbox: [0.0; 4],
    };
    let (mut ms, mut ious) = (Vec::new(), Vec::new());
    for k in 0..args.frames {
        let phase = (k % 10) as f32;
        let scene = render(
            bg.as_raw(),
            tex.as_raw(),
            w,
            h,
            (-2.0 * phase, 1.0 * phase),
            (280.0 + 5.0 * phase, 240.0 - 2.0 * phase),
            1.0 + 0.02 * phase,
        );
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
    if let Some(dir) = args.out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(
        &args.out,
        format!("{{\n  \"propagator_p50_ms\": {p50:.3},\n  \"propagator_p99_ms\": {p99:.3},\n  \"mean_iou\": {mean_iou:.4},\n  \"frames\": {}\n}}\n", ms.len()),
    )?;
    println!("wrote {}", args.out.display());
    Ok(())
}
