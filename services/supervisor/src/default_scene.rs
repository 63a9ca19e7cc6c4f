//! The embedded default input of `dynslam run`: a rendered room with people
//! walking through it ([`scenes::room`]), rendered once per output folder
//! and reused (rendering is deterministic).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use pipeline::config::PipelineConfig;
use scenes::room::{default_scene, RoomOptions};

/// Bump when the renderer or the default walks change, so old renders are
/// not reused.
pub const FOLDER: &str = "default-scene-v2";

/// The default scene under `output_dir`, rendered first when missing or
/// incomplete; returns the dynamic sequence's folder (absolute).
pub fn ensure(output_dir: &Path, cfg: &PipelineConfig) -> Result<PathBuf> {
    let dir = output_dir.join(FOLDER);
    let scene = dir.join("scene");
    // objects.json is the last file synth writes: its presence means the
    // render completed.
    if !scene.join("objects.json").is_file() {
        if dir.exists() {
            std::fs::remove_dir_all(&dir).with_context(|| {
                format!("cannot remove the incomplete render {}", dir.display())
            })?;
        }
        eprintln!(
            "no dataset given: rendering the embedded default scene (a room, a moving camera, two people walking) into {}",
            dir.display()
        );
        let camera = slam_backend::convert::camera(&cfg.camera, cfg.source.depth_scale as f64);
        // 640x480, the frame size the configured intrinsics are for.
        let (_, summary) = default_scene(&dir, &camera, &RoomOptions::default())
            .with_context(|| format!("cannot render the default scene into {}", dir.display()))?;
        eprintln!(
            "default scene: {} frames, people visible in {}, mean coverage {:.1} %, max {:.1} %",
            summary.frames,
            summary.frames_with_people,
            100.0 * summary.mean_coverage,
            100.0 * summary.max_coverage
        );
    }
    scene
        .canonicalize()
        .with_context(|| format!("cannot resolve {}", scene.display()))
}
