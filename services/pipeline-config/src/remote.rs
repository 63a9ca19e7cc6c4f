//! `[remote]`: the link to mask workers on another machine over Zenoh
//! (`services.segmenter.location = "remote"`, README "Workers on another
//! machine").

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

use super::in_range;

/// How the robot reaches its remote workers and what it sends them.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RemoteConfig {
    /// The name both ends agree on (`dynslam worker segmenter --run NAME`):
    /// the Zenoh keys are `dynslam/<run>/...` and a worker answers only
    /// frames of its own run. Letters, digits, `-` and `_`.
    pub run: String,
    /// A Zenoh JSON5 configuration file (TLS, mutual TLS, access control):
    /// used as it is; `mode`, `listen` and `connect` are then not applied.
    pub zenoh_config: Option<PathBuf>,
    /// Zenoh session mode: "peer" or "client" (through a router).
    pub mode: String,
    /// Endpoints this end listens on (the worker connects to one).
    pub listen: Vec<String>,
    /// Endpoints this end connects to (a router, or a listening worker).
    pub connect: Vec<String>,
    /// How a frame's colour travels: "jpeg" (`jpeg_quality`, 1..=100),
    /// "png" (lossless: the worker's masks are the local model's) or "raw"
    /// (no encoding on the robot's CPU; 1.5 MB a 640x480 frame with depth:
    /// a wired link).
    pub encoding: String,
    /// JPEG quality (1..=100) with `encoding = "jpeg"`.
    pub jpeg_quality: u8,
    /// Send the frame's depth too (16-bit PNG, raw with `encoding = "raw"`):
    /// the segmenter keeps weak detections where depth shows them standing out.
    pub depth: bool,
    /// How long a frame waits for its remote masks before the fallback
    /// takes it (milliseconds).
    pub timeout_ms: u64,
    /// `fallback = "none"`: how long the start waits for a worker to appear
    /// (seconds) before failing with what to start.
    pub startup_wait_s: f64,
}

impl Default for RemoteConfig {
    fn default() -> Self {
        Self {
            run: String::new(),
            zenoh_config: None,
            mode: "peer".into(),
            listen: vec!["tcp/0.0.0.0:7447".into()],
            connect: Vec::new(),
            encoding: "jpeg".into(),
            jpeg_quality: 90,
            depth: true,
            timeout_ms: 2000,
            startup_wait_s: 30.0,
        }
    }
}

/// Checks a run name for the Zenoh keys (`what` names where it came from).
pub fn check_run_name(name: &str, what: &str) -> Result<(), String> {
    if name.is_empty() {
        return Err(format!(
            "{what}: empty; name the run both ends agree on (letters, digits, - and _), e.g. \"robot1\""
        ));
    }
    if name.len() > 32
        || !name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
    {
        return Err(format!(
            "{what}: '{name}' is not a run name (at most 32 letters, digits, - and _)"
        ));
    }
    Ok(())
}

impl RemoteConfig {
    /// Checks the section (only when a worker is remote: `needed`).
    pub fn validate(&self, needed: bool) -> Result<(), String> {
        if !needed {
            return Ok(());
        }
        check_run_name(&self.run, "key `remote.run`")?;
        if !matches!(self.mode.as_str(), "peer" | "client") {
            return Err(format!(
                "key `remote.mode`: \"{}\" is not a Zenoh session mode here (\"peer\" or \"client\")",
                self.mode
            ));
        }
        if self.zenoh_config.is_none() && self.listen.is_empty() && self.connect.is_empty() {
            return Err("keys `remote.listen` and `remote.connect`: both empty; listen for the worker (\"tcp/0.0.0.0:7447\"), connect to it or a router, or give remote.zenoh_config".into());
        }
        if !matches!(self.encoding.as_str(), "jpeg" | "png" | "raw") {
            return Err(format!(
                "key `remote.encoding`: '{}' is not one of jpeg, png, raw",
                self.encoding
            ));
        }
        in_range(
            "remote.jpeg_quality",
            self.jpeg_quality as f64,
            1.0,
            100.0,
            "a JPEG quality",
        )?;
        in_range(
            "remote.timeout_ms",
            self.timeout_ms as f64,
            1.0,
            600_000.0,
            "a time in milliseconds",
        )?;
        in_range(
            "remote.startup_wait_s",
            self.startup_wait_s,
            0.0,
            3600.0,
            "a time in seconds",
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn run_names_are_checked_and_the_error_says_what_is_wanted() {
        assert!(check_run_name("robot-1_a", "x").is_ok());
        let e = check_run_name("", "key `remote.run`").unwrap_err();
        assert!(e.contains("key `remote.run`: empty"), "{e}");
        for bad in ["a/b", "a*", "ü", &"x".repeat(33)] {
            let e = check_run_name(bad, "--run").unwrap_err();
            assert!(e.contains("is not a run name"), "{e}");
        }
    }

    #[test]
    fn the_section_is_checked_only_when_a_worker_is_remote() {
        let c = RemoteConfig::default();
        assert!(c.validate(false).is_ok());
        assert!(c.validate(true).unwrap_err().contains("remote.run"));
        let c = RemoteConfig {
            run: "r".into(),
            encoding: "webp".into(),
            ..Default::default()
        };
        assert!(c.validate(true).unwrap_err().contains("remote.encoding"));
        let c = RemoteConfig {
            run: "r".into(),
            jpeg_quality: 0,
            ..Default::default()
        };
        assert!(c
            .validate(true)
            .unwrap_err()
            .contains("remote.jpeg_quality"));
    }
}
