//! `source.kind = "ros2"`: the camera's intrinsics from its CameraInfo
//! topic, asked of the bridge binary (the only one that speaks Zenoh)
//! before any service starts, so that every process of the run reads them
//! from the run's config as for any other source.

use anyhow::{bail, Context, Result};
use pipeline::config::{CameraConfig, PipelineConfig};
use shared_types::ServiceKind;

use crate::children::service_program;

/// Runs `bridge camera-info` with `config` and reads the `[camera]` it prints.
pub fn camera_info(config: &PipelineConfig) -> Result<CameraConfig> {
    let mut program = service_program(config, ServiceKind::Bridge)?;
    // service_program names the publishing role; this is the other.
    if program.last().is_some_and(|r| r == "publish") {
        program.pop();
    }
    let file =
        std::env::temp_dir().join(format!("dynslam-camera-info-{}.toml", std::process::id()));
    std::fs::write(&file, config.to_toml()?)
        .with_context(|| format!("cannot write {}", file.display()))?;
    tracing::info!(
        "waiting up to {:.0} s for the camera's CameraInfo on {}",
        config.source.ros2.camera_info_timeout_s,
        config.source.ros2.camera_info_topic
    );
    let out = std::process::Command::new(&program[0])
        .args(&program[1..])
        .arg("camera-info")
        .arg("--config")
        .arg(&file)
        .stderr(std::process::Stdio::piped())
        .output()
        .with_context(|| format!("cannot run {}", program[0]));
    let _ = std::fs::remove_file(&file);
    let out = out?;
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        let reason = err
            .lines()
            .rev()
            .find(|l| l.contains("error"))
            .unwrap_or("the bridge ended without saying why");
        bail!("the ROS 2 camera's intrinsics: {}", reason.trim());
    }
    let section = String::from_utf8_lossy(&out.stdout);
    let parsed = PipelineConfig::parse(&section)
        .map_err(|e| anyhow::anyhow!("the ROS 2 camera's CameraInfo: {e}"))?;
    Ok(parsed.camera)
}
