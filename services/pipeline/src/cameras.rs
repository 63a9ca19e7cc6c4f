//! Camera presets (`configs/cameras/*.toml`, embedded in the binaries so
//! that they work from any directory) and the choice of a run's camera:
//! `--camera NAME|FILE`, else the preset a TUM-style folder name implies,
//! else the configuration's `[camera]`.

use std::path::Path;

use crate::config::CameraConfig;

/// `--camera config`: use the configuration's `[camera]` whatever the
/// dataset folder is called.
pub const FROM_CONFIG: &str = "config";

/// The shipped presets: name and TOML text (the keys of `[camera]`).
pub const PRESETS: &[(&str, &str)] = &[
    (
        "tum-fr1",
        include_str!("../../../configs/cameras/tum-fr1.toml"),
    ),
    (
        "tum-fr2",
        include_str!("../../../configs/cameras/tum-fr2.toml"),
    ),
    (
        "tum-fr3",
        include_str!("../../../configs/cameras/tum-fr3.toml"),
    ),
    ("bonn", include_str!("../../../configs/cameras/bonn.toml")),
    (
        "global-shutter-example",
        include_str!("../../../configs/cameras/global-shutter-example.toml"),
    ),
];

/// Which camera a run uses and why (said in the log and the report).
#[derive(Debug, Clone, PartialEq)]
pub struct CameraChoice {
    /// The intrinsics, distortion and rolling shutter chosen.
    pub camera: CameraConfig,
    /// A preset's name, a file's path, or "config".
    pub name: String,
    /// Why this one, in words.
    pub reason: String,
}

/// A preset by name.
pub fn preset(name: &str) -> Option<CameraConfig> {
    PRESETS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(n, text)| parse(text).unwrap_or_else(|e| panic!("shipped preset {n}: {e}")))
}

/// Parses a camera file (the keys of `[camera]`, each optional over the
/// TUM freiburg1 default) and checks its values.
pub fn parse(text: &str) -> Result<CameraConfig, String> {
    let camera: CameraConfig = toml::from_str(text.trim_start_matches('\u{feff}'))
        .map_err(|e: toml::de::Error| e.to_string().trim_end().to_string())?;
    camera.validate()?;
    Ok(camera)
}

/// The preset a dataset folder's name implies: TUM's
/// `rgbd_dataset_freiburgN_*` and the Bonn dataset's `rgbd_bonn_*`.
pub fn preset_for_folder(dataset: &Path) -> Option<&'static str> {
    let name = dataset.file_name()?.to_string_lossy().to_lowercase();
    if name.starts_with("rgbd_bonn_") {
        return Some("bonn");
    }
    let rest = name.strip_prefix("rgbd_dataset_freiburg")?;
    match rest.chars().next()? {
        '1' => Some("tum-fr1"),
        '2' => Some("tum-fr2"),
        '3' => Some("tum-fr3"),
        _ => None,
    }
}

/// Picks the run's camera: `requested` (a preset name, a camera file, or
/// "config") when given, else the folder name's preset, else `configured`.
pub fn choose(
    requested: Option<&str>,
    dataset: &Path,
    configured: &CameraConfig,
) -> Result<CameraChoice, String> {
    let from_config = |reason: String| CameraChoice {
        camera: configured.clone(),
        name: FROM_CONFIG.to_string(),
        reason,
    };
    match requested {
        Some(FROM_CONFIG) => Ok(from_config("--camera config".into())),
        Some(name) => {
            if let Some(camera) = preset(name) {
                return Ok(CameraChoice {
                    camera,
                    name: name.to_string(),
                    reason: "--camera".into(),
                });
            }
            let path = Path::new(name);
            if !path.is_file() {
                return Err(format!(
                    "--camera {name}: neither a preset ({}, {FROM_CONFIG}) nor a camera file",
                    names().join(", ")
                ));
            }
            let text = std::fs::read_to_string(path)
                .map_err(|e| format!("--camera {name}: cannot read: {e}"))?;
            let camera = parse(&text).map_err(|e| format!("camera file {name}: {e}"))?;
            Ok(CameraChoice {
                camera,
                name: name.to_string(),
                reason: "--camera (file)".into(),
            })
        }
        None => match preset_for_folder(dataset) {
            Some(name) => Ok(CameraChoice {
                camera: preset(name).expect("a shipped preset"),
                name: name.to_string(),
                reason: format!(
                    "dataset folder name {}",
                    dataset
                        .file_name()
                        .map(|n| n.to_string_lossy().into_owned())
                        .unwrap_or_default()
                ),
            }),
            None => Ok(from_config(
                "the configuration's [camera] (the folder name names no preset; --camera picks one)"
                    .into(),
            )),
        },
    }
}

/// The preset names.
pub fn names() -> Vec<&'static str> {
    PRESETS.iter().map(|(n, _)| *n).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    #[test]
    fn every_preset_parses_and_fr1_is_the_default_camera() {
        for name in names() {
            assert!(preset(name).is_some(), "{name}");
        }
        assert_eq!(preset("tum-fr1").unwrap(), CameraConfig::default());
        assert_eq!(preset("global-shutter-example").unwrap().readout_s, 0.0);
        let bonn = preset("bonn").unwrap();
        assert_eq!((bonn.fx, bonn.cy), (542.822841, 237.756098));
    }

    #[test]
    fn folder_names_pick_presets() {
        let p = |s: &str| preset_for_folder(&PathBuf::from("/data").join(s));
        assert_eq!(p("rgbd_dataset_freiburg1_rpy_first300"), Some("tum-fr1"));
        assert_eq!(
            p("rgbd_dataset_freiburg2_desk_with_person"),
            Some("tum-fr2")
        );
        assert_eq!(p("rgbd_dataset_freiburg3_walking_xyz"), Some("tum-fr3"));
        assert_eq!(p("rgbd_bonn_crowd"), Some("bonn"));
        assert_eq!(p("my_robot_run"), None);
        assert_eq!(p("rgbd_dataset_freiburg9_x"), None);
    }

    #[test]
    fn requested_camera_wins_and_bad_requests_are_named() {
        let dir = PathBuf::from("/data/rgbd_dataset_freiburg3_walking_xyz");
        let cfg = CameraConfig::default();
        assert_eq!(choose(None, &dir, &cfg).unwrap().name, "tum-fr3");
        assert_eq!(choose(Some("bonn"), &dir, &cfg).unwrap().name, "bonn");
        let c = choose(Some("config"), &dir, &cfg).unwrap();
        assert_eq!(c.camera, cfg);
        let other = choose(None, Path::new("/data/robot"), &cfg).unwrap();
        assert_eq!(other.name, FROM_CONFIG);
        let err = choose(Some("fr7"), &dir, &cfg).unwrap_err();
        assert!(
            err.contains("--camera fr7") && err.contains("tum-fr2"),
            "{err}"
        );
        let file = std::env::temp_dir().join(format!("dynslam-cam-{}.toml", std::process::id()));
        std::fs::write(&file, "fx = -3.0\n").unwrap();
        let err = choose(Some(file.to_str().unwrap()), &dir, &cfg).unwrap_err();
        assert!(err.contains("camera file") && err.contains("fx"), "{err}");
        std::fs::write(&file, "fx = 600.0\nreadout_s = 0.0\n").unwrap();
        let c = choose(Some(file.to_str().unwrap()), &dir, &cfg).unwrap();
        assert_eq!((c.camera.fx, c.camera.fy), (600.0, cfg.fy));
        std::fs::remove_file(&file).ok();
    }
}
