//! `just bench-remote`, its first part: the keyframe round trip to a remote
//! segmenter worker (a `mask-worker` process on this machine), over
//! loopback and through a relay that delays each byte 20 ms each way, for
//! JPEG, PNG and raw frames: p50 / p99 ms, bytes per keyframe and the
//! robot's CPU to encode one, beside the same model's time in-process. `remote-bench relay` runs the relay alone
//! (the real-time part of the bench, tools/bench-remote.py, uses it).
//!
//! `remote-bench [--dataset DIR] [--frames N] [--sizes 320,480] [--delay-ms 20] [--out FILE]`

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use datasets::decode::decode_depth_into;
use datasets::source::tum_folder;
use pipeline::config::PipelineConfig;
use pipeline::mask_worker::MaskModel;
use pipeline::stats::percentile;
use pipeline::views::{FrameView, MasksView};
use remote::link::RemoteSegmenter;
use remote::relay::Relay;
use remote::wire::{encode_request, ImageEncoding};
use shared_types::{FrameHeader, MaskSource, MasksHeader};

#[derive(Debug, Parser)]
#[command(about = "Remote segmenter: keyframe round trip, loopback and through a delaying relay")]
struct Args {
    #[command(subcommand)]
    relay: Option<RelayCommand>,
    #[arg(long, default_value_os_t = pipeline::provision::shared_tum())]
    dataset: PathBuf,
    /// Keyframes sent per condition.
    #[arg(long, default_value_t = 40)]
    frames: usize,
    /// Segmenter input sizes (one worker each).
    #[arg(long, value_delimiter = ',', default_value = "320,480")]
    sizes: Vec<u32>,
    /// The relay's delay each way (ms).
    #[arg(long, default_value_t = 20)]
    delay_ms: u64,
    /// Pipeline configuration of both ends (default: the product's).
    #[arg(long)]
    config: Option<PathBuf>,
    #[arg(long, default_value = "bench-results/remote.json")]
    out: PathBuf,
}

#[derive(Debug, Subcommand)]
enum RelayCommand {
    /// Run a delaying relay until killed.
    Relay {
        #[arg(long)]
        listen: SocketAddr,
        #[arg(long)]
        to: SocketAddr,
        #[arg(long, default_value_t = 20)]
        delay_ms: u64,
    },
}

/// One frame of the dataset, as the services hold it.
struct Frame {
    header: FrameHeader,
    payload: Vec<u8>,
}

fn main() -> Result<()> {
    pipeline::runtime::init_logging_with(remote::LOG_FILTER);
    let args = Args::parse();
    if let Some(RelayCommand::Relay {
        listen,
        to,
        delay_ms,
    }) = args.relay
    {
        let relay = Relay::start(listen, to, Duration::from_millis(delay_ms))?;
        eprintln!("relay {} -> {to}, {delay_ms} ms each way", relay.addr);
        loop {
            std::thread::park();
        }
    }
    let base = PipelineConfig::load_or_default(args.config.as_deref())?;
    let frames = load_frames(&args.dataset, args.frames, base.source.depth_scale)?;
    let scratch = std::env::temp_dir().join(format!("dynslam-remote-bench-{}", std::process::id()));
    std::fs::create_dir_all(&scratch)?;
    println!(
        "remote segmenter keyframe round trip: {} frames of {} per condition, relay {} ms each way",
        frames.len(),
        args.dataset.display(),
        args.delay_ms
    );
    println!(
        "{:<6} {:<9} {:<8} {:>8} {:>8} {:>10} {:>10} {:>14}",
        "input", "path", "encoding", "p50 ms", "p99 ms", "KB/frame", "encode ms", "local p50 ms"
    );
    let mut json = Vec::new();
    for &size in &args.sizes {
        let mut config = base.clone();
        config.services.segmenter.input_size = Some(size);
        config.services.segmenter.model.clear();
        config.services.segmenter.model_path = None;
        let local_ms = local_p50(&config, &frames)?;
        let port = free_port()?;
        let worker_config = scratch.join(format!("worker-{size}.toml"));
        std::fs::write(&worker_config, config.to_toml()?)?;
        let mut worker = start_worker(port, &worker_config)?;
        let worker_addr: SocketAddr = format!("127.0.0.1:{port}").parse()?;
        let relay = Relay::start(
            "127.0.0.1:0".parse()?,
            worker_addr,
            Duration::from_millis(args.delay_ms),
        )?;
        let paths = [
            ("loopback", format!("tcp/{worker_addr}")),
            ("relay", relay.endpoint()),
        ];
        for (path, endpoint) in &paths {
            for encoding in ["jpeg", "png", "raw"] {
                let (mut trips, kb) = round_trips(&config, endpoint, encoding, &frames)?;
                trips.sort_by(f64::total_cmp);
                let (p50, p99) = (percentile(&trips, 50.0), percentile(&trips, 99.0));
                let encode = encode_p50(&config, encoding, &frames)?;
                println!(
                    "{size:<6} {path:<9} {encoding:<8} {p50:>8.1} {p99:>8.1} {kb:>10.0} {encode:>10.1} {local_ms:>14.1}"
                );
                json.push(format!(
                    "    {{\"input_size\": {size}, \"path\": \"{path}\", \"encoding\": \"{encoding}\", \"p50_ms\": {p50:.2}, \"p99_ms\": {p99:.2}, \"kb_per_keyframe\": {kb:.1}, \"encode_p50_ms\": {encode:.2}, \"local_p50_ms\": {local_ms:.2}}}"
                ));
            }
        }
        let _ = worker.kill();
        let _ = worker.wait();
    }
    if let Some(dir) = args.out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(
        &args.out,
        format!(
            "{{\n  \"delay_ms\": {},\n  \"frames\": {},\n  \"round_trips\": [\n{}\n  ]\n}}\n",
            args.delay_ms,
            frames.len(),
            json.join(",\n")
        ),
    )?;
    println!("(written to {})", args.out.display());
    let _ = std::fs::remove_dir_all(&scratch);
    Ok(())
}

fn load_frames(dataset: &Path, n: usize, depth_scale: f32) -> Result<Vec<Frame>> {
    let mut frames = Vec::new();
    for (seq, f) in tum_folder(dataset, 0.02)?.into_iter().take(n).enumerate() {
        let rgb = image::open(&f.rgb)
            .with_context(|| f.rgb.display().to_string())?
            .to_rgb8();
        let (w, h) = rgb.dimensions();
        let mut payload = rgb.into_raw();
        let has_depth = if let Some(path) = &f.depth {
            let mut raw = vec![0u8; w as usize * h as usize * 2];
            decode_depth_into(path, (w, h), &mut raw)
                .with_context(|| path.display().to_string())?;
            payload.extend(raw);
            1
        } else {
            0
        };
        let header = FrameHeader {
            seq: seq as u64,
            width: w,
            height: h,
            has_depth,
            depth_scale,
            ..Default::default()
        };
        frames.push(Frame { header, payload });
    }
    if frames.is_empty() {
        bail!("{}: no frames", dataset.display());
    }
    Ok(frames)
}

/// The model's own time per frame, in this process (p50 ms).
fn local_p50(config: &PipelineConfig, frames: &[Frame]) -> Result<f64> {
    let mut model = segmentation::models::load(config)?;
    let mut ms = Vec::new();
    run_frames(&mut *model, frames, |t| ms.push(t))?;
    ms.sort_by(f64::total_cmp);
    Ok(percentile(&ms, 50.0))
}

/// Every frame through `model`, each given the masks before it, as the
/// segmenter's loop does; `each` gets the ms of each after a warm-up of 3.
fn run_frames(
    model: &mut dyn MaskModel,
    frames: &[Frame],
    mut each: impl FnMut(f64),
) -> Result<()> {
    let first = &frames[0].header;
    let size = first.width as usize * first.height as usize;
    let (mut labels, mut previous) = (vec![0u8; size], vec![0u8; size]);
    let mut previous_header: Option<MasksHeader> = None;
    for (k, f) in frames.iter().enumerate() {
        let frame = FrameView::new(&f.header, &f.payload)?;
        labels.fill(0);
        let before = previous_header
            .as_ref()
            .and_then(|h| MasksView::new(h, &previous).ok());
        let t = Instant::now();
        let instances = model.infer_after(&frame, before.as_ref(), &mut labels)?;
        if k >= 3 {
            each(t.elapsed().as_secs_f64() * 1e3);
        }
        let mut h = MasksHeader {
            seq: f.header.seq,
            source: MaskSource::Segmenter as u32,
            width: f.header.width,
            height: f.header.height,
            ..Default::default()
        };
        h.set_instances(&instances);
        previous_header = Some(h);
        std::mem::swap(&mut labels, &mut previous);
    }
    Ok(())
}

/// The robot's CPU per keyframe: encoding a request (p50 ms, one thread).
fn encode_p50(config: &PipelineConfig, encoding: &str, frames: &[Frame]) -> Result<f64> {
    let encoding = ImageEncoding::from_config(encoding, config.remote.jpeg_quality);
    let mut ms = Vec::new();
    for f in frames {
        let frame = FrameView::new(&f.header, &f.payload)?;
        let t = Instant::now();
        encode_request("bench", &frame, None, encoding, config.remote.depth)?;
        ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    ms.sort_by(f64::total_cmp);
    Ok(percentile(&ms, 50.0))
}

/// Round trips (ms, after a warm-up) and KB per keyframe sent.
fn round_trips(
    base: &PipelineConfig,
    endpoint: &str,
    encoding: &str,
    frames: &[Frame],
) -> Result<(Vec<f64>, f64)> {
    let mut config = base.clone();
    config.services.segmenter.location = "remote".into();
    config.remote.run = "bench".into();
    config.remote.listen.clear();
    config.remote.connect = vec![endpoint.to_string()];
    config.remote.encoding = encoding.into();
    config.remote.timeout_ms = 10_000;
    let mut link = RemoteSegmenter::with_fallback(&config, None)?;
    if !link.wait_for_worker(Instant::now() + Duration::from_secs(60)) {
        bail!("the worker did not appear at {endpoint}");
    }
    let mut trips = Vec::new();
    run_frames(&mut link, frames, |t| trips.push(t))?;
    let s = link.stats();
    Ok((trips, s.bytes_sent as f64 / 1024.0 / s.sent.max(1) as f64))
}

fn start_worker(port: u16, config: &Path) -> Result<Child> {
    let exe = std::env::current_exe()?;
    let bin = exe.with_file_name("mask-worker");
    Command::new(&bin)
        .args(["segmenter", "--run", "bench", "--listen"])
        .arg(format!("tcp/127.0.0.1:{port}"))
        .arg("--config")
        .arg(config)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .with_context(|| format!("cannot start {}", bin.display()))
}

fn free_port() -> Result<u16> {
    Ok(std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port())
}
