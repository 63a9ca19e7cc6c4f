//! Transport benchmark: one-way latency of a 640x480 RGB + u16 depth frame
//! between two processes, through iceoryx2 shared memory (zero copy) and
//! through a Unix domain socket (the copying baseline), measured in the same
//! run. Latency is from "the frame is complete in the sender's memory" to
//! "the receiver can read all of it"; both sides stamp CLOCK_MONOTONIC.
//!
//! iceoryx2 is measured twice: with the receiver woken by an iceoryx2 event
//! through a WaitSet (what every pipeline process does) and with a receiver
//! that polls (the hand-off alone, without the cost of waking a sleeping
//! process). `transport-bench [--frames N] [--out FILE]` prints all three,
//! the ratios, and writes them as JSON; the `iceoryx2_*` keys are the
//! WaitSet figures.

use std::io::{Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use anyhow::{bail, Context, Result};
use clap::Parser;
use pipeline::clock::now_ns;
use pipeline::stats::percentile;
use pipeline::transport::{attach, remove_run_files, wait, waitset, Transport, Wake};
use shared_types::names::{RunNames, Topic};
use shared_types::FrameHeader;

const WIDTH: usize = 640;
const HEIGHT: usize = 480;
const FRAME_BYTES: usize = WIDTH * HEIGHT * 5;
/// Pause between frames so that each one travels through an idle pipe.
const PERIOD: Duration = Duration::from_millis(2);

#[derive(Debug, Parser)]
#[command(about = "iceoryx2 vs Unix-socket one-way latency of a 640x480 RGB-D frame")]
struct Args {
    /// Frames sent per transport.
    #[arg(long, default_value_t = 1000)]
    frames: usize,
    /// Where to write the figures as JSON.
    #[arg(long, default_value = "bench-results/transport.json")]
    out: PathBuf,
    /// Internal: run as the receiving process.
    #[arg(long, hide = true)]
    receive: Option<String>,
    /// Internal: run id or socket path of the receiving process.
    #[arg(long, hide = true)]
    endpoint: Option<String>,
}

/// Frames at the start of each series that warm caches and connections.
const WARMUP: usize = 50;

fn main() -> Result<()> {
    let args = Args::parse();
    let endpoint = || args.endpoint.as_deref().context("--endpoint");
    match args.receive.as_deref() {
        Some("iceoryx2") => receive_iceoryx2(endpoint()?, args.frames, false),
        Some("iceoryx2-poll") => receive_iceoryx2(endpoint()?, args.frames, true),
        Some("uds") => receive_uds(endpoint()?, args.frames),
        Some(other) => bail!("unknown receiver {other}"),
        None => drive(&args),
    }
}

fn drive(args: &Args) -> Result<()> {
    let exe = std::env::current_exe()?;
    let run_id = format!("bench-{}", std::process::id());
    let names = RunNames::new(&run_id).map_err(anyhow::Error::msg)?;

    let iox = measure_iceoryx2(&exe, &names, "iceoryx2", args.frames)?;
    let iox_poll = measure_iceoryx2(&exe, &names, "iceoryx2-poll", args.frames)?;

    // Unix domain socket: the whole frame is copied through the kernel.
    let uds = {
        let path = std::env::temp_dir().join(format!("dynslam-bench-{}.sock", std::process::id()));
        let _ = std::fs::remove_file(&path);
        let listener = UnixListener::bind(&path)?;
        let mut child = Command::new(&exe)
            .args([
                "--receive",
                "uds",
                "--endpoint",
                path.to_str().unwrap(),
                "--frames",
                &args.frames.to_string(),
            ])
            .stdout(Stdio::piped())
            .spawn()?;
        let (mut stream, _) = listener.accept()?;
        let mut out = child.stdout.take().context("receiver stdout")?;
        wait_ready(&mut out)?;
        let mut frame = vec![0u8; 8 + FRAME_BYTES];
        for seq in 0..(args.frames + WARMUP) as u64 {
            frame[8] = seq as u8;
            frame[8 + FRAME_BYTES - 1] = seq as u8;
            frame[..8].copy_from_slice(&now_ns().to_ne_bytes());
            stream.write_all(&frame)?;
            std::thread::sleep(PERIOD);
        }
        let figures = collect(out, &mut child)?;
        let _ = std::fs::remove_file(&path);
        figures
    };

    let speedup_p50 = uds.0 / iox.0.max(1e-9);
    println!("one-way latency of a {WIDTH}x{HEIGHT} RGB + u16 depth frame ({FRAME_BYTES} bytes), {} frames each", args.frames);
    println!("{:<40} {:>9} {:>9}", "transport", "p50 us", "p99 us");
    let line = |name: &str, f: (f64, f64)| println!("{name:<40} {:>9.1} {:>9.1}", f.0, f.1);
    line("iceoryx2 zero copy, WaitSet wake-up", iox);
    line("iceoryx2 zero copy, polling receiver", iox_poll);
    line("unix socket, copy (baseline)", uds);
    println!(
        "speedup vs baseline: WaitSet p50 {speedup_p50:.1}x p99 {:.1}x; polling p50 {:.1}x p99 {:.1}x",
        uds.1 / iox.1.max(1e-9),
        uds.0 / iox_poll.0.max(1e-9),
        uds.1 / iox_poll.1.max(1e-9)
    );
    let json = json_object(&[
        ("iceoryx2_p50_us", iox.0),
        ("iceoryx2_p99_us", iox.1),
        ("baseline_p50_us", uds.0),
        ("baseline_p99_us", uds.1),
        ("speedup_p50", speedup_p50),
        ("iceoryx2_poll_p50_us", iox_poll.0),
        ("iceoryx2_poll_p99_us", iox_poll.1),
        ("speedup_poll_p50", uds.0 / iox_poll.0.max(1e-9)),
        ("frame_bytes", FRAME_BYTES as f64),
        ("frames", args.frames as f64),
    ]);
    if let Some(dir) = args.out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(&args.out, json)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    println!("wrote {}", args.out.display());
    Ok(())
}

/// Sends `frames` frames through iceoryx2 to a receiver process of `kind`.
fn measure_iceoryx2(exe: &Path, names: &RunNames, kind: &str, frames: usize) -> Result<(f64, f64)> {
    let transport = Transport::open(names, "bench-sender")?;
    let sender = transport.slice_sender::<FrameHeader>(Topic::Frames, FRAME_BYTES)?;
    let mut child = Command::new(exe)
        .args([
            "--receive",
            kind,
            "--endpoint",
            names.run_id(),
            "--frames",
            &frames.to_string(),
        ])
        .stdout(Stdio::piped())
        .spawn()?;
    let mut out = child.stdout.take().context("receiver stdout")?;
    wait_ready(&mut out)?;
    for seq in 0..(frames + WARMUP) as u64 {
        let mut sample = sender.loan(FRAME_BYTES)?;
        // The frame is produced into shared memory (not timed).
        let payload = sample.payload_mut();
        payload[0] = seq as u8;
        payload[FRAME_BYTES - 1] = seq as u8;
        let header = sample.user_header_mut();
        header.seq = seq;
        header.width = WIDTH as u32;
        header.height = HEIGHT as u32;
        header.stamps.published_ns = now_ns();
        sender.publish(sample)?;
        std::thread::sleep(PERIOD);
    }
    let figures = collect(out, &mut child)?;
    drop(sender);
    drop(transport);
    remove_run_files(names)?;
    Ok(figures)
}

fn json_object(pairs: &[(&str, f64)]) -> String {
    let body: Vec<String> = pairs
        .iter()
        .map(|(k, v)| format!("  \"{k}\": {v:.3}"))
        .collect();
    format!("{{\n{}\n}}\n", body.join(",\n"))
}

fn wait_ready(out: &mut impl Read) -> Result<()> {
    let mut byte = [0u8; 1];
    out.read_exact(&mut byte)
        .context("receiver did not start")?;
    Ok(())
}

/// Reads the receiver's "p50 p99" line (microseconds).
fn collect(mut out: impl Read, child: &mut std::process::Child) -> Result<(f64, f64)> {
    let mut text = String::new();
    out.read_to_string(&mut text)?;
    let status = child.wait()?;
    if !status.success() {
        bail!("receiver failed: {status}");
    }
    let v: Vec<f64> = text
        .split_whitespace()
        .filter_map(|t| t.parse().ok())
        .collect();
    if v.len() != 2 {
        bail!("receiver printed '{text}'");
    }
    Ok((v[0], v[1]))
}

fn report(lat_us: Vec<f64>) {
    let mut lat_us: Vec<f64> = lat_us.into_iter().skip(WARMUP).collect();
    lat_us.sort_by(f64::total_cmp);
    println!(
        "{} {}",
        percentile(&lat_us, 50.0),
        percentile(&lat_us, 99.0)
    );
}

fn receive_iceoryx2(run_id: &str, frames: usize, poll: bool) -> Result<()> {
    let names = RunNames::new(run_id).map_err(anyhow::Error::msg)?;
    let transport = Transport::open(&names, "bench-receiver")?;
    let rx = transport.slice_receiver::<FrameHeader>(Topic::Frames)?;
    let ws = waitset()?;
    let _a = attach(&ws, &rx)?;
    print!("r");
    std::io::stdout().flush()?;
    let total = frames + WARMUP;
    let mut lat = Vec::with_capacity(total);
    let mut checksum = 0u64;
    let started = std::time::Instant::now();
    while lat.len() < total {
        if poll {
            if !rx.has_samples()? {
                std::hint::spin_loop();
                if started.elapsed() > Duration::from_secs(120) {
                    bail!("sender stopped");
                }
                continue;
            }
        } else if wait(&ws, Duration::from_secs(5))? == Wake::Terminate {
            break;
        }
        rx.clear_wakeups();
        while let Some(sample) = rx.next_sample()? {
            // Read the frame in place: first and last byte.
            let p = sample.payload();
            checksum += p[0] as u64 + p[p.len() - 1] as u64;
            lat.push((now_ns() - sample.user_header().stamps.published_ns) as f64 / 1e3);
        }
    }
    std::hint::black_box(checksum);
    report(lat);
    Ok(())
}

fn receive_uds(path: &str, frames: usize) -> Result<()> {
    let mut stream = UnixStream::connect(path)?;
    print!("r");
    std::io::stdout().flush()?;
    let mut buf = vec![0u8; 8 + FRAME_BYTES];
    let mut lat = Vec::with_capacity(frames + WARMUP);
    let mut checksum = 0u64;
    for _ in 0..frames + WARMUP {
        stream.read_exact(&mut buf)?;
        let sent = u64::from_ne_bytes(buf[..8].try_into().unwrap());
        checksum += buf[8] as u64 + buf[buf.len() - 1] as u64;
        lat.push((now_ns() - sent) as f64 / 1e3);
    }
    std::hint::black_box(checksum);
    report(lat);
    Ok(())
}
