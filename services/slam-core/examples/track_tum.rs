//! Tracks a TUM RGB-D folder with the SLAM library alone (no processes, no
//! shared memory) and prints the trajectory in TUM format; optionally saves
//! the map, or starts from a saved one.
//!
//! ```text
//! cargo run --release -p slam-core --example track_tum -- FOLDER [--limit N]
//!     [--save-map FILE] [--load-map FILE]
//! ```
//! The camera is TUM Freiburg 1's (edit `Camera::new` for yours).

use std::path::{Path, PathBuf};

use slam_core::io::trajectory::Trajectory;
use slam_core::{Camera, MapFile, SlamParams, System};

/// `timestamp path` lines of a TUM list (`#` comments).
fn read_list(folder: &Path, name: &str) -> Result<Vec<(f64, PathBuf)>, String> {
    let path = folder.join(name);
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut parts = line.split_whitespace();
        let (Some(t), Some(file)) = (parts.next(), parts.next()) else {
            return Err(format!(
                "{} line {}: expected `timestamp path`",
                path.display(),
                i + 1
            ));
        };
        let t: f64 = t
            .parse()
            .map_err(|_| format!("{} line {}: bad timestamp {t}", path.display(), i + 1))?;
        out.push((t, folder.join(file)));
    }
    Ok(out)
}

fn main() -> Result<(), String> {
    let mut args = std::env::args().skip(1);
    let mut folder = None;
    let (mut limit, mut save, mut load) = (usize::MAX, None, None);
    while let Some(a) = args.next() {
        let mut value = || args.next().ok_or(format!("{a} needs a value"));
        match a.as_str() {
            "--limit" => limit = value()?.parse().map_err(|e| format!("--limit: {e}"))?,
            "--save-map" => save = Some(PathBuf::from(value()?)),
            "--load-map" => load = Some(PathBuf::from(value()?)),
            _ if folder.is_none() => folder = Some(PathBuf::from(a)),
            _ => return Err(format!("unexpected argument {a}")),
        }
    }
    let folder =
        folder.ok_or("usage: track_tum FOLDER [--limit N] [--save-map FILE] [--load-map FILE]")?;
    let (rgb, depth) = (
        read_list(&folder, "rgb.txt")?,
        read_list(&folder, "depth.txt")?,
    );
    let (camera, params) = (Camera::tum_fr1(), SlamParams::default());
    let mut system = match &load {
        Some(path) => {
            let file = MapFile::read_for(path, &camera, &params).map_err(|e| e.to_string())?;
            System::with_map(params, camera, file)
        }
        None => System::new(params, camera),
    };
    let mut trajectory = Trajectory {
        stamps: Vec::new(),
        poses: Vec::new(),
    };
    let mut tracked = 0;
    for &(t, ref rgb_path) in rgb.iter().take(limit) {
        // The depth image nearest in time (TUM's association, within 20 ms).
        let Some((_, depth_path)) = depth
            .iter()
            .filter(|(td, _)| (td - t).abs() < 0.02)
            .min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()))
        else {
            continue;
        };
        let open = |p: &Path| image::open(p).map_err(|e| format!("{}: {e}", p.display()));
        let colour = open(rgb_path)?.to_rgb8();
        let d = open(depth_path)?.into_luma16();
        let (w, h) = (colour.width() as usize, colour.height() as usize);
        let r = system.track_rgbd(colour.as_raw(), d.as_raw(), None, w, h, t);
        tracked += r.state.is_tracked() as usize;
        trajectory.stamps.push(t);
        trajectory.poses.push(r.pose_wc);
    }
    print!("{}", trajectory.to_tum());
    eprintln!(
        "tracked {tracked} of {} frames, {} keyframes in the map",
        trajectory.stamps.len(),
        system.map().live_keyframes().count()
    );
    if let Some(path) = save {
        system.save_map(&path).map_err(|e| e.to_string())?;
        eprintln!("map saved to {}", path.display());
    }
    Ok(())
}
