//! Segmenter speed: median and p99 milliseconds per 640x480 frame
//! (letterbox + inference + decoding + mask painting) on real TUM frames,
//! ONNX Runtime with the configured number of threads, for each network
//! (YOLOv8n-seg, YOLO11n-seg) at each input size (320, 480, 640: the
//! exports of `segmentation::exports`), back to back in one run so that the
//! ratios compare like with like; each row's p50 is also given as a ratio
//! to the first row's (by default YOLOv8n-seg at 320, real time's). Each
//! frame is segmented as the service does it: with its depth and the frame
//! before's labels, which weak detections (`weak_score_threshold`) are
//! checked against.
//!
//! `segmenter-bench [--frames N] [--threads T] [--sizes 320,480,640]
//! [--backends yolov8-seg,yolo11-seg] [--config FILE] [--out FILE]`

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Parser;
use datasets::decode::decode_depth_into;
use datasets::source::tum_folder;
use onnx_runtime::init_runtime;
use pipeline_config::PipelineConfig;
use segmentation::exports::YoloFamily;
use segmentation::onnx::{YoloSeg, YoloSettings};
use shared_types::stats::percentile;
use shared_types::views::DepthImage;

#[derive(Debug, Parser)]
#[command(about = "YOLO-seg segmenters: ms per 640x480 frame")]
struct Args {
    /// TUM RGB-D folder whose frames are segmented.
    #[arg(
        long,
        default_value_os_t = provision::shared_tum()
    )]
    dataset: PathBuf,
    #[arg(long, default_value_t = 100)]
    frames: usize,
    /// ONNX Runtime intra-op threads.
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// Network input sizes to measure (each its own export; the configured
    /// `model`, if any, is ignored here).
    #[arg(long, value_delimiter = ',', default_value = "320,480,640")]
    sizes: Vec<u32>,
    /// The networks to measure, by backend name.
    #[arg(long, value_delimiter = ',', default_value = "yolov8-seg,yolo11-seg")]
    backends: Vec<String>,
    /// Pipeline configuration (default: the built-in defaults, i.e. the
    /// shipped configs/pipeline.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    #[arg(long, default_value = "bench-results/models.json")]
    out: PathBuf,
}

fn main() -> Result<()> {
    let args = Args::parse();
    let config = PipelineConfig::load_or_default(args.config.as_deref())?;
    let entries: Vec<_> = tum_folder(&args.dataset, 0.02)?
        .into_iter()
        .take(args.frames)
        .collect();
    let images: Vec<_> = entries
        .iter()
        .map(|f| {
            image::open(&f.rgb)
                .map(|i| i.to_rgb8())
                .with_context(|| format!("{}", f.rgb.display()))
        })
        .collect::<Result<_>>()?;
    let (w, h) = (images[0].width() as usize, images[0].height() as usize);
    // Depth as the camera-reader decodes it (native-endian u16), if any.
    let depths: Vec<Option<Vec<u8>>> = entries
        .iter()
        .map(|f| {
            f.depth
                .as_ref()
                .map(|path| {
                    let mut raw = vec![0u8; w * h * 2];
                    decode_depth_into(path, (w as u32, h as u32), &mut raw)
                        .with_context(|| format!("{}", path.display()))
                        .map(|()| raw)
                })
                .transpose()
        })
        .collect::<Result<_>>()?;
    let depth_of = |k: usize| {
        // Decoded at w x h above: the size matches.
        depths[k]
            .as_deref()
            .and_then(|raw| DepthImage::new(raw, w, h, config.source.depth_scale))
    };
    let families = args
        .backends
        .iter()
        .map(|b| {
            YoloFamily::from_backend(b).with_context(|| {
                let known: Vec<_> = YoloFamily::ALL.iter().map(|f| f.backend()).collect();
                format!("--backends: unknown '{b}' (known: {})", known.join(", "))
            })
        })
        .collect::<Result<Vec<_>>>()?;
    println!(
        "segmenters, {w}x{h} frames, {} threads, {} frames per network and input size",
        args.threads,
        images.len()
    );
    println!(
        "{:<12} {:<11} {:>9} {:>9} {:>10} {:>9}",
        "network", "input size", "p50 ms", "p99 ms", "instances", "x first"
    );
    let mut rows = Vec::new();
    let mut first_p50 = None;
    for (family, &size) in families
        .iter()
        .flat_map(|f| args.sizes.iter().map(move |s| (f, s)))
    {
        let mut cfg = config.services.segmenter.clone();
        cfg.backend = family.backend().into();
        cfg.threads = Some(args.threads);
        cfg.input_size = Some(size);
        cfg.model.clear();
        cfg.model_sha256.clear();
        cfg.model_path = None;
        let settings = YoloSettings::from_config(&cfg)?;
        let mut model = YoloSeg::load(init_runtime(&config.onnxruntime)?, settings)?;
        let (mut labels, mut previous) = (vec![0u8; w * h], vec![0u8; w * h]);
        // Warm-up outside the measurement.
        for img in images.iter().take(5) {
            model.segment(img.as_raw(), w, h, &mut labels)?;
        }
        let mut ms = Vec::with_capacity(images.len());
        let mut found = 0;
        for (k, img) in images.iter().enumerate() {
            labels.fill(0);
            let before = (k > 0).then_some(previous.as_slice());
            let t = Instant::now();
            found += model
                .segment_rgbd(img.as_raw(), depth_of(k), before, w, h, &mut labels)?
                .len();
            ms.push(t.elapsed().as_secs_f64() * 1e3);
            std::mem::swap(&mut labels, &mut previous);
        }
        ms.sort_by(f64::total_cmp);
        let (p50, p99) = (percentile(&ms, 50.0), percentile(&ms, 99.0));
        let ratio = p50 / *first_p50.get_or_insert(p50);
        let network = family.network();
        println!("{network:<12} {size:<11} {p50:>9.2} {p99:>9.2} {found:>10} {ratio:>9.2}");
        rows.push(format!(
            "    {{\"network\": \"{network}\", \"input_size\": {size}, \"p50_ms\": {p50:.3}, \"p99_ms\": {p99:.3}, \"instances\": {found}}}"
        ));
    }
    if let Some(dir) = args.out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(
        &args.out,
        format!(
            "{{\n  \"threads\": {},\n  \"frames\": {},\n  \"segmenter\": [\n{}\n  ]\n}}\n",
            args.threads,
            images.len(),
            rows.join(",\n")
        ),
    )?;
    println!("wrote {}", args.out.display());
    Ok(())
}
