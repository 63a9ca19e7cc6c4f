//! SLAM core on a TUM RGB-D folder without the pipeline: per-step time
//! (extract, track, total: median and p99 ms), peak memory, frames tracked
//! and, with ground truth, ATE. `just bench-slam` runs it on the shared
//! sequence.
//!
//! `slam-bench [DATASET] [--masks] [--skip N] [--limit N] [--threads N] [--local-ba N]
//! [--readout S] [--inline-mapping] [--no-triangulation] [--fusion] [--no-loop-closing] [--no-global-ba]
//! [--no-motion-check] [--features N] [--match-ratio R] [--monocular] [--extractor own|kornia] [--no-image-turn]
//! [--keep-every N [--offset K]] [--drop-share P [--seed S]] [--frames-of trajectory.txt] [--verbose]
//! [--out trajectory.txt]`
//! `--keep-every` and `--drop-share` leave frames out as real time does on a
//! busy machine (the newest frame wins, the ones between are dropped):
//! `just bench-dropped` runs a set of such copies and prints their ATE
//! against every frame's. `--frames-of` keeps the frames a trajectory has
//! (a real-time run's `trajectory.txt`): the core alone on exactly the
//! frames real time tracked, to tell what the frames cost from what the
//! rest of the pipeline does.
//! With more than one extraction thread it also measures extraction alone
//! with 1 and N threads on the same frames and prints the ratio.
//! `--masks` feeds the ground-truth masks of a `dynslam synth` folder.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Parser;
use datasets::source::{tum_folder, FrameEntry, MaskList};
use pipeline::config::{CameraConfig, PipelineConfig};
use pipeline::progress::Progress;
use pipeline::stats::percentile;
use slam_backend::convert;
use slam_core::eval::{evaluate_files, Alignment, EvalOptions};
use slam_core::features::orb::{GrayU8, OrbBackend, OrbExtractor, OrbParams};
use slam_core::io::trajectory::Trajectory;
use slam_core::{MapFile, SlamParams, System};

#[derive(Debug, Parser)]
#[command(about = "SLAM core: ms per frame per step, tracking and accuracy")]
struct Args {
    #[arg(default_value_os_t = pipeline::provision::shared_tum())]
    dataset: PathBuf,
    /// Pipeline configuration (default: the built-in defaults, i.e. the
    /// shipped configs/pipeline.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Use the ground-truth masks (masks.txt) of a synthesised sequence.
    #[arg(long)]
    masks: bool,
    /// Start at this frame (with --limit: a slice of the sequence).
    #[arg(long, default_value_t = 0)]
    skip: usize,
    #[arg(long)]
    limit: Option<usize>,
    /// Track only every Nth frame (after --skip and --limit), as real time
    /// does when the SLAM takes N frame periods a frame.
    #[arg(long, default_value_t = 1)]
    keep_every: usize,
    /// With --keep-every: the first frame kept (0..N).
    #[arg(long, default_value_t = 0)]
    offset: usize,
    /// Leave out this share of the frames at random (0..0.9; the first frame
    /// is always kept), as real time does under uneven load.
    #[arg(long, default_value_t = 0.0)]
    drop_share: f64,
    /// Seed of --drop-share's choice.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Keep only the frames whose timestamps this TUM trajectory has (e.g.
    /// a real-time run's trajectory.txt), after --skip and --limit and
    /// before --keep-every and --drop-share.
    #[arg(long)]
    frames_of: Option<PathBuf>,
    /// Print every frame's state, features, inliers and keyframe flag.
    #[arg(long)]
    verbose: bool,
    #[arg(long, default_value = "bench-results/slam_trajectory.txt")]
    out: PathBuf,
    /// Feature-extraction worker threads (default: `services.slam.threads`
    /// of the config, else 2).
    #[arg(long)]
    threads: Option<usize>,
    /// Local bundle adjustment over this many keyframes after each keyframe
    /// (default: the library's, off).
    #[arg(long)]
    local_ba: Option<usize>,
    /// Nearest-neighbour ratio of tracking's match by projection, in
    /// (0, 1] (default: the library's, 1 = the best match wins).
    #[arg(long)]
    match_ratio: Option<f64>,
    /// Local mapping inline after each keyframe instead of on its thread
    /// (same results; to see what the thread saves).
    #[arg(long)]
    inline_mapping: bool,
    /// No new points triangulated between keyframes (depth only).
    #[arg(long)]
    no_triangulation: bool,
    /// Start from this map file (poses come out in its world frame: the
    /// first frames relocalise against its keyframes).
    #[arg(long)]
    load_map: Option<PathBuf>,
    /// Write the map to this file at the end.
    #[arg(long)]
    save_map: Option<PathBuf>,
    /// Localization mode: track against the loaded map, add no keyframe or
    /// point (needs --load-map).
    #[arg(long)]
    localize_only: bool,
    /// Fuse duplicate points between keyframes (off by default).
    #[arg(long)]
    fusion: bool,
    /// No loop closing (it is on by default, as in the product: it looks for
    /// loops after each keyframe, corrects the map, prints the loops closed
    /// and the detection time per keyframe, and writes the loop-corrected
    /// trajectory beside --out).
    #[arg(long)]
    no_loop_closing: bool,
    /// RGB-D motion check off (it is on by default, as in the product: it
    /// drops features in regions that move unlike the camera and prints how
    /// many it dropped).
    #[arg(long)]
    no_motion_check: bool,
    /// Track from the motion model's turn alone, not the one the small
    /// images give where the two disagree (to compare).
    #[arg(long)]
    no_image_turn: bool,
    /// Track up to N frames in a row between full ORB extractions by
    /// following the last frame's points with optical flow (0: every frame
    /// extracted, the default); prints how many frames were.
    #[arg(long, default_value_t = 0)]
    flow_frames: u32,
    /// No global bundle adjustment after a loop
    /// correction (the essential graph alone).
    #[arg(long)]
    no_global_ba: bool,
    /// ORB features per frame (default: the library's, 1000; fewer drift
    /// more).
    #[arg(long)]
    features: Option<usize>,
    /// Play the frames this many times in a row (later passes' timestamps go
    /// on after the first's): a camera that comes back over its path, to
    /// see whether the map stays bounded. ATE is over the first pass.
    #[arg(long, default_value_t = 1)]
    repeat: u32,
    /// Monocular: colour only (the depth files are ignored); ATE after a
    /// Sim(3) alignment, with the scale found.
    #[arg(long)]
    monocular: bool,
    /// Rolling-shutter readout in seconds (default: `camera.readout_s` of
    /// the config; 0 turns the correction off).
    #[arg(long)]
    readout: Option<f64>,
    /// ORB extractor: `own` (the product's) or `kornia` (kornia-imgproc's,
    /// needs a build with `--features slam/kornia`), to compare them.
    #[arg(long, default_value = "own")]
    extractor: String,
}

/// The frames left after `--keep-every`/`--offset` and `--drop-share`.
fn left_out(frames: Vec<FrameEntry>, args: &Args) -> Result<Vec<FrameEntry>> {
    anyhow::ensure!(
        args.keep_every >= 1,
        "--keep-every {}: must be at least 1",
        args.keep_every
    );
    anyhow::ensure!(
        args.offset < args.keep_every,
        "--offset {}: must be below --keep-every ({})",
        args.offset,
        args.keep_every
    );
    anyhow::ensure!(
        (0.0..0.9).contains(&args.drop_share),
        "--drop-share {}: not a share of the frames in [0, 0.9)",
        args.drop_share
    );
    let stamps = match &args.frames_of {
        Some(path) => {
            let mut stamps = Trajectory::load_tum(path)?.stamps;
            stamps.sort_by(f64::total_cmp);
            Some(stamps)
        }
        None => None,
    };
    // A frame is listed when a stamp lies within 0.1 ms of its timestamp
    // (trajectories are written with 6 decimals).
    let listed = |f: &FrameEntry| {
        stamps.as_ref().is_none_or(|s| {
            let i = s.partition_point(|&t| t < f.timestamp - 1e-4);
            s.get(i).is_some_and(|&t| t <= f.timestamp + 1e-4)
        })
    };
    let mut rng = slam_core::rng::SplitMix64::new(args.seed);
    let kept: Vec<FrameEntry> = frames
        .into_iter()
        .filter(listed)
        .skip(args.offset)
        .step_by(args.keep_every)
        .enumerate()
        .filter(|(i, _)| *i == 0 || rng.uniform(0.0, 1.0) >= args.drop_share)
        .map(|(_, f)| f)
        .collect();
    anyhow::ensure!(
        kept.len() >= 2,
        "only {} frame(s) left after --keep-every/--drop-share/--frames-of",
        kept.len()
    );
    Ok(kept)
}

fn orb_backend(name: &str) -> Result<OrbBackend> {
    match name {
        "own" => Ok(OrbBackend::Own),
        #[cfg(feature = "kornia")]
        "kornia" => Ok(OrbBackend::Kornia),
        #[cfg(not(feature = "kornia"))]
        "kornia" => anyhow::bail!(
            "--extractor kornia: this slam-bench was built without kornia; \
             build it with `cargo build --release -p slam --features kornia`"
        ),
        other => anyhow::bail!("--extractor {other}: expected `own` or `kornia`"),
    }
}

fn main() -> Result<()> {
    let args = Args::parse();
    let cfg = PipelineConfig::load_or_default(args.config.as_deref())?;
    let mut camera = convert::camera(&cfg.camera, cfg.source.depth_scale as f64);
    if let Some(r) = args.readout {
        anyhow::ensure!(
            CameraConfig::READOUT_S.contains(&r),
            "--readout {r}: not a readout time in seconds (0 <= s < 0.2)"
        );
        camera.readout_s = r;
    }
    let mut frames = tum_folder(&args.dataset, cfg.source.max_time_diff)?;
    anyhow::ensure!(
        args.skip < frames.len(),
        "--skip {}: {} has only {} frames",
        args.skip,
        args.dataset.display(),
        frames.len()
    );
    frames.drain(..args.skip);
    if let Some(n) = args.limit {
        frames.truncate(n);
    }
    let frames = left_out(frames, &args)?;
    anyhow::ensure!(
        (1..=1000).contains(&args.repeat),
        "--repeat {}: not a number of passes (1..=1000)",
        args.repeat
    );
    let pass_len = frames.len();
    let first_pass: Vec<f64> = frames.iter().map(|f| f.timestamp).collect();
    let frames = datasets::source::repeated(frames, args.repeat);
    let mut inserted_per_pass = vec![0usize; args.repeat as usize];
    let truth = if args.masks {
        Some(
            MaskList::open(&args.dataset)?
                .with_context(|| format!("--masks: {} has no masks.txt", args.dataset.display()))?,
        )
    } else {
        None
    };
    let threads = args
        .threads
        .or(cfg.services.slam.threads)
        .unwrap_or(SlamParams::default().orb.threads);
    anyhow::ensure!(threads >= 1, "--threads must be at least 1");
    let mut params = if args.monocular {
        SlamParams::monocular()
    } else {
        SlamParams::default()
    };
    params.orb.threads = threads;
    params.orb.backend = orb_backend(&args.extractor)?;
    params.mapping_thread = !args.inline_mapping;
    params.triangulate = !args.no_triangulation;
    params.fuse_points = args.fusion;
    params.loop_closing = !args.no_loop_closing;
    params.motion_check = !args.no_motion_check;
    params.turn_from_images = !args.no_image_turn;
    params.flow_frames = args.flow_frames;
    params.global_bundle_adjustment = !args.no_global_ba;
    if let Some(n) = args.features {
        anyhow::ensure!(n >= 50, "--features {n}: at least 50 are needed to track");
        params.orb.features = n;
    }
    if let Some(r) = args.match_ratio {
        if !(r > 0.0 && r <= 1.0) {
            anyhow::bail!("--match-ratio {r}: not a ratio in (0, 1]");
        }
        params.match_ratio = r;
    }
    if let Some(n) = args.local_ba {
        params.local_ba_keyframes = n;
    }
    anyhow::ensure!(
        !args.localize_only || args.load_map.is_some(),
        "--localize-only needs a map to localise in: give --load-map FILE"
    );
    let mut system = match &args.load_map {
        Some(path) => {
            let file = MapFile::read_for(path, &camera, &params)?;
            println!(
                "map {}: {} keyframes, {} points",
                path.display(),
                file.map.live_keyframes().count(),
                file.map.live_point_count()
            );
            System::with_map(params, camera, file)
        }
        None => System::new(params, camera),
    };
    system.set_localize_only(args.localize_only);
    let (mut extract, mut track, mut total) = (Vec::new(), Vec::new(), Vec::new());
    let mut motion = Vec::new();
    // Local mapping time per keyframe (on its thread unless --inline-mapping).
    let mut mapping = Vec::new();
    let mut trajectory = Trajectory {
        stamps: Vec::new(),
        poses: Vec::new(),
    };
    let mut tracked = 0;
    let mut relocalised = 0;
    let mut turning = 0;
    // The first frame with a pose (monocular: the start's second view).
    let mut started_at: Option<usize> = None;
    let (mut moving, mut features, mut by_flow) = (0u64, 0u64, 0usize);
    let mut progress = Progress::new("slam", frames.len() as u64);
    for (i, f) in frames.iter().enumerate() {
        let rgb = image::open(&f.rgb)
            .with_context(|| f.rgb.display().to_string())?
            .to_rgb8();
        // Monocular: the depth files are not even read.
        let depth: Vec<u16> = if args.monocular {
            Vec::new()
        } else {
            let depth_path = f.depth.as_ref().context("frame without depth")?;
            image::open(depth_path)
                .with_context(|| depth_path.display().to_string())?
                .into_luma16()
                .into_raw()
        };
        let mask = match &truth {
            Some(t) => Some(
                t.load_at(first_pass[i % pass_len])
                    .map_err(anyhow::Error::msg)?
                    .into_raw(),
            ),
            None => None,
        };
        let (w, h) = (rgb.width() as usize, rgb.height() as usize);
        let r = system.track_rgbd(rgb.as_raw(), &depth, mask.as_deref(), w, h, f.timestamp);
        if args.verbose {
            eprintln!(
                "{:.3} {:?} feat {} inl {} kf {} pts {}",
                f.timestamp,
                r.state,
                r.counts.features,
                r.counts.inliers,
                r.keyframe_inserted,
                r.counts.map_points
            );
        }
        if r.counts.mapping_us > 0 {
            mapping.push(r.counts.mapping_us as f64 / 1e3);
        }
        inserted_per_pass[i / pass_len] += r.keyframe_inserted as usize;
        moving += r.counts.features_moving as u64;
        by_flow += r.counts.tracked_by_flow as usize;
        features += (r.counts.features + r.counts.features_moving) as u64;
        extract.push(r.extract_ms);
        track.push(r.track_ms);
        motion.push(r.motion_ms);
        total.push(r.extract_ms + r.track_ms);
        if r.state.is_tracked() {
            tracked += 1;
        }
        relocalised += (r.state == slam_core::TrackingState::Relocalised) as usize;
        turning += (r.state == slam_core::TrackingState::Turning) as usize;
        if r.state != slam_core::TrackingState::NotInitialised {
            started_at.get_or_insert(i);
        }
        // Tracked frames only (as the pipeline's trajectory.txt): an
        // untracked frame's pose is a guess.
        if r.state.is_tracked() && i < pass_len {
            trajectory.stamps.push(f.timestamp);
            trajectory.poses.push(r.pose_wc);
        }
        progress.inc();
    }
    progress.finish();
    if let Some(dir) = args.out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(&args.out, trajectory.to_tum())?;
    for v in [
        &mut extract,
        &mut track,
        &mut motion,
        &mut total,
        &mut mapping,
    ] {
        v.sort_by(f64::total_cmp);
    }
    println!(
        "SLAM core on {} ({} frames, masks: {})",
        args.dataset.display(),
        frames.len(),
        if args.masks { "ground truth" } else { "none" }
    );
    println!("{:<10} {:>9} {:>9}", "step", "p50 ms", "p99 ms");
    // The motion check is part of track; its own row when it is on.
    let motion_row = motion.iter().any(|&ms| ms > 0.0);
    for (name, v) in [
        ("extract", &extract),
        ("track", &track),
        ("motion", &motion),
        ("total", &total),
        ("mapping/kf", &mapping),
    ]
    .into_iter()
    .filter(|(name, _)| *name != "motion" || motion_row)
    {
        println!(
            "{:<10} {:>9.2} {:>9.2}",
            name,
            percentile(v, 50.0),
            percentile(v, 99.0)
        );
    }
    let mapped = system.mapping_counts();
    let inserted = system.keyframes_inserted();
    if let Some(path) = &args.save_map {
        system.save_map(path)?;
        println!("map saved to {}", path.display());
    }
    let map = system.map();
    let live = map.live_keyframes().count();
    println!(
        "tracked {tracked}/{} frames ({:.1} %), {live} keyframes ({inserted} inserted by this run, {} culled), {} map points ({} in use)",
        frames.len(),
        100.0 * tracked as f64 / frames.len().max(1) as f64,
        map.keyframes.len() - live,
        map.points.len(),
        map.live_point_count()
    );
    if args.repeat > 1 {
        println!("keyframes inserted per pass: {inserted_per_pass:?}");
    }
    println!(
        "local mapping: {} points triangulated, {} duplicates fused, {} observations added",
        mapped.triangulated, mapped.fused, mapped.observations_added
    );
    println!(
        "relocalisations (by bag of words): {relocalised}; young maps lost and started again: {}",
        system.map_restarts()
    );
    if params.is_monocular() {
        println!(
            "map started at frame {}; turning (the turn from the images, the position held): {turning} frames",
            started_at.map_or("-".to_string(), |i| i.to_string())
        );
    }
    if params.flow_frames > 0 {
        println!(
            "flow tracking: {by_flow} of {} frames tracked without extraction",
            frames.len()
        );
    }
    if params.motion_check {
        println!(
            "motion check: {moving} of {features} features dropped ({:.2} %)",
            100.0 * moving as f64 / features.max(1) as f64
        );
    }
    if params.loop_closing {
        let mut detect = system.loop_detection_ms();
        detect.sort_by(f64::total_cmp);
        println!(
            "loop closing: {} loops closed; detection per keyframe p50 {:.2} ms, p99 {:.2} ms",
            system.loops().len(),
            percentile(&detect, 50.0),
            percentile(&detect, 99.0)
        );
        for (l, (correct, ba)) in system.loops().iter().zip(system.loop_correction_ms()) {
            let stamp = |k| {
                system
                    .keyframe_timestamp(k)
                    .map_or("?".to_string(), |t| format!("{t:.6}"))
            };
            println!(
                "  loop: keyframe {} (t {}) with {} (t {}), {} inliers, corrected {:.3} m / {:.2} deg, \
                 scale {:.4} (correction {correct:.0} ms, global BA {ba:.0} ms)",
                l.keyframe,
                stamp(l.keyframe),
                l.matched,
                stamp(l.matched),
                l.inliers,
                l.correction_m,
                l.correction_deg,
                l.scale
            );
        }
    }
    // The frames moved with their keyframes by the corrections.
    let corrected_out = args.out.with_extension("loop_corrected.txt");
    if !system.loops().is_empty() {
        std::fs::write(&corrected_out, system.trajectory().to_tum())?;
    }
    println!("peak memory (VmHWM) {:.1} MiB", peak_rss_mib());
    let mut variants = vec![(format!("{threads} threads"), orb(threads, OrbBackend::Own))];
    if threads > 1 {
        variants.insert(0, ("1 thread".to_string(), orb(1, OrbBackend::Own)));
    }
    if params.orb.backend != OrbBackend::Own {
        variants.push(("kornia".to_string(), orb(threads, params.orb.backend)));
    }
    if variants.len() > 1 {
        let medians = extraction_medians(&frames, &variants)?;
        let base = medians[0];
        let figures: Vec<String> = variants
            .iter()
            .zip(&medians)
            .map(|((name, _), m)| format!("{name} p50 {m:.2} ms (x{:.2})", base / m))
            .collect();
        println!(
            "extraction alone, first {} frames, alternating: {}",
            frames.len().min(SPEEDUP_FRAMES),
            figures.join(", ")
        );
    }
    let gt = args.dataset.join("groundtruth.txt");
    if gt.is_file() {
        let options = EvalOptions {
            alignment: if args.monocular {
                Alignment::Sim3
            } else {
                Alignment::Se3
            },
            ..Default::default()
        };
        let s = evaluate_files(&gt, &args.out, options)?;
        println!(
            "ATE rmse {:.4} m ({} pairs{}), RPE/frame {:.4} m {:.3} deg",
            s.ate_rmse_m,
            s.pairs,
            if args.monocular {
                format!(", Sim(3) aligned, scale {:.4}", s.scale)
            } else {
                String::new()
            },
            s.rpe_trans_rmse_m,
            s.rpe_rot_rmse_deg
        );
        if !system.loops().is_empty() {
            let c = evaluate_files(&gt, &corrected_out, options)?;
            println!(
                "ATE rmse with the loop corrections {:.4} m ({} pairs; {})",
                c.ate_rmse_m,
                c.pairs,
                corrected_out.display()
            );
        }
    }
    println!("trajectory: {}", args.out.display());
    Ok(())
}

const SPEEDUP_FRAMES: usize = 60;

fn orb(threads: usize, backend: OrbBackend) -> OrbExtractor {
    OrbExtractor::new(OrbParams {
        threads,
        backend,
        ..OrbParams::default()
    })
}

/// Median extraction time of each extractor, measured on the same frames in
/// one run, alternating so all see the same machine.
fn extraction_medians(
    frames: &[FrameEntry],
    variants: &[(String, OrbExtractor)],
) -> Result<Vec<f64>> {
    let mut times = vec![Vec::new(); variants.len()];
    for f in frames.iter().take(SPEEDUP_FRAMES) {
        let rgb = image::open(&f.rgb)
            .with_context(|| f.rgb.display().to_string())?
            .to_rgb8();
        let grey = GrayU8::from_rgb(rgb.as_raw(), rgb.width() as usize, rgb.height() as usize);
        for ((_, extractor), times) in variants.iter().zip(&mut times) {
            let t0 = std::time::Instant::now();
            let (kps, _, _) = extractor.extract(&grey, &|_, _| true);
            times.push(t0.elapsed().as_secs_f64() * 1e3);
            std::hint::black_box(kps);
        }
    }
    Ok(times
        .iter_mut()
        .map(|t| {
            t.sort_by(f64::total_cmp);
            percentile(t, 50.0)
        })
        .collect())
}

fn peak_rss_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frames(n: usize) -> Vec<FrameEntry> {
        (0..n)
            .map(|i| FrameEntry {
                timestamp: i as f64 / 30.0,
                rgb: PathBuf::from(format!("rgb/{i}.png")),
                depth: None,
            })
            .collect()
    }

    fn kept(args: &[&str]) -> Result<Vec<usize>> {
        let args = Args::try_parse_from(["slam-bench"].iter().chain(args))?;
        Ok(left_out(frames(30), &args)?
            .iter()
            .map(|f| (f.timestamp * 30.0).round() as usize)
            .collect())
    }

    #[test]
    fn frames_are_left_out_as_asked_and_bad_requests_named() {
        assert_eq!(kept(&[]).unwrap(), (0..30).collect::<Vec<_>>());
        assert_eq!(
            kept(&["--keep-every", "3", "--offset", "1"]).unwrap(),
            (1..30).step_by(3).collect::<Vec<_>>()
        );
        // A seeded random share: the same frames every time, the first kept.
        let a = kept(&["--drop-share", "0.45", "--seed", "2"]).unwrap();
        assert_eq!(a, kept(&["--drop-share", "0.45", "--seed", "2"]).unwrap());
        assert_ne!(a, kept(&["--drop-share", "0.45", "--seed", "3"]).unwrap());
        assert_eq!(a[0], 0);
        assert!((8..=24).contains(&a.len()), "{} of 30 kept", a.len());
        for (bad, named) in [
            (&["--keep-every", "0"][..], "--keep-every 0"),
            (&["--keep-every", "2", "--offset", "2"][..], "--offset 2"),
            (&["--drop-share", "0.95"][..], "--drop-share 0.95"),
            (
                &["--keep-every", "29", "--offset", "28"][..],
                "only 1 frame",
            ),
        ] {
            let e = kept(bad).unwrap_err().to_string();
            assert!(e.contains(named), "{bad:?}: {e}");
        }
    }

    #[test]
    fn frames_of_a_trajectory_are_the_ones_it_lists() {
        let dir = std::env::temp_dir().join(format!("slam-bench-frames-of-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let listed = dir.join("trajectory.txt");
        // Frames 2, 3 and 7 (timestamps as a run writes them, 6 decimals).
        let line = |i: usize| format!("{:.6} 0 0 0 0 0 0 1\n", i as f64 / 30.0);
        let text = format!(
            "# timestamp tx ty tz qx qy qz qw\n{}{}{}",
            line(2),
            line(3),
            line(7)
        );
        std::fs::write(&listed, text).unwrap();
        let path = listed.to_str().unwrap();
        assert_eq!(kept(&["--frames-of", path]).unwrap(), vec![2, 3, 7]);
        // --keep-every on top takes every Nth of the listed frames.
        assert_eq!(
            kept(&["--frames-of", path, "--keep-every", "2"]).unwrap(),
            vec![2, 7]
        );
        let missing = dir.join("none.txt");
        let e = kept(&["--frames-of", missing.to_str().unwrap()])
            .unwrap_err()
            .to_string();
        assert!(e.contains("none.txt"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
