//! The SLAM map files of a run: a map to start in (`--load-map`), one to
//! write at the end (`--save-map`), and the run's own checkpoint, which a
//! restarted SLAM service (or `dynslam resume`) goes on from.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use pipeline::config::PipelineConfig;
use slam_core::MapFile;

/// The checkpoint's name in the run folder.
pub const CHECKPOINT_FILE: &str = "checkpoint.map";
/// The last poses a SLAM service gave before it died (TUM format), for
/// its successor's motion model.
pub const RESUME_POSES_FILE: &str = "slam-resume-poses.txt";

/// Checks the run's map settings before anything starts, and makes their
/// paths absolute (services run from the run folder's config): a map to
/// load must be a map file for this camera and the SLAM's pyramid, a map to
/// save must have a folder to go to, localization needs a map.
pub fn prepare(cfg: &mut PipelineConfig) -> Result<()> {
    let camera = slam_backend::convert::camera(&cfg.camera, cfg.source.depth_scale as f64);
    let params = slam_backend::convert::params(cfg);
    let slam = &mut cfg.services.slam;
    let wants_map = slam.load_map.is_some() || slam.save_map.is_some() || slam.localize_only;
    if wants_map && slam.backend != "orb-rgbd" {
        bail!(
            "--load-map, --save-map and --localize-only need the orb-rgbd SLAM (services.slam.backend is '{}', which keeps no map)",
            slam.backend
        );
    }
    if slam.localize_only && slam.load_map.is_none() {
        bail!("--localize-only needs a map to localise in: give --load-map FILE");
    }
    if let Some(path) = &slam.load_map {
        let file = MapFile::read_for(path, &camera, &params)?;
        tracing::info!(
            keyframes = file.map.live_keyframes().count(),
            points = file.map.live_point_count(),
            "starting in the map {}",
            path.display()
        );
        slam.load_map = Some(absolute(path)?);
    }
    if let Some(path) = &slam.save_map {
        let path = absolute(path)?;
        match path.parent() {
            Some(dir) if dir.is_dir() => {}
            _ => bail!(
                "--save-map {}: the folder it goes in does not exist",
                path.display()
            ),
        }
        if path.is_dir() {
            bail!(
                "--save-map {}: is a folder, not a file name",
                path.display()
            );
        }
        slam.save_map = Some(path);
    }
    Ok(())
}

fn absolute(path: &Path) -> Result<PathBuf> {
    std::path::absolute(path).with_context(|| format!("cannot resolve {}", path.display()))
}

/// The run's checkpoint, if the SLAM service has written one.
pub fn checkpoint(run_dir: &Path) -> Option<PathBuf> {
    Some(run_dir.join(CHECKPOINT_FILE)).filter(|p| p.is_file())
}
