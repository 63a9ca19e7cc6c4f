#![deny(missing_docs)]
//! Locating and verifying the files models need: model weights and the ONNX
//! Runtime shared library (and its settings, [`OnnxRuntimeConfig`]). Nothing is ever downloaded here: `just setup`
//! provisions the library from the PyPI wheel; weights come from a path.
//! Every file is checked against the sha256 in the configuration, and every
//! failure says which file, where it was looked for and how to provide it.

use std::io::Read;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

/// Environment variable naming a folder of model files.
pub const MODELS_ENV: &str = "DYNSLAM_MODELS";
/// Environment variable naming the ONNX Runtime library (ort's own name).
pub const ORT_ENV: &str = "ORT_DYLIB_PATH";
/// Where `just setup` puts the ONNX Runtime library, relative to the repo.
pub const ORT_CACHE: &str = ".cache/onnxruntime/libonnxruntime.so.1.31.1";
/// Where `just setup` puts model files it derives from the shared ones
/// (the segmenter at other input sizes), relative to the repo.
pub const DERIVED_MODELS: &str = ".cache/models";

/// Why a file a model needs could not be had.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ProvisionError {
    /// No model file where it was looked for.
    #[error("model file {file} not found; looked in: {looked}. Put it in one of these places, set {MODELS_ENV} to its folder, or set `model_path` in the config")]
    ModelMissing {
        /// The file name.
        file: String,
        /// The places looked in.
        looked: String,
    },
    /// No ONNX Runtime library where it was looked for.
    #[error("ONNX Runtime library not found; looked in: {looked}. Run `just setup` (it extracts it from the PyPI wheel onnxruntime==1.31.1) or set {ORT_ENV}")]
    RuntimeMissing {
        /// The places looked in.
        looked: String,
    },
    /// A file whose sha256 is not the configured one.
    #[error("{path}: sha256 is {found}, the configuration expects {expected}; the file is corrupt or a different version")]
    HashMismatch {
        /// The file.
        path: PathBuf,
        /// The configured sha256.
        expected: String,
        /// The file's.
        found: String,
    },
    /// A file that could not be read.
    #[error("{path}: cannot read: {message}")]
    Unreadable {
        /// The file.
        path: PathBuf,
        /// What the system said.
        message: String,
    },
}

/// An error caused by input a restart cannot fix (a missing or corrupt model
/// or library, a bad setting): a service that fails with it exits with the
/// input exit code (`pipeline::runtime::exit_code::INPUT`), and the
/// supervisor reports it instead of restarting the service.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct InputError(pub String);

/// The ONNX Runtime shared library the model backends load.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct OnnxRuntimeConfig {
    /// Path of `libonnxruntime.so`; default: `$ORT_DYLIB_PATH`, then the
    /// `just setup` cache.
    pub library: Option<PathBuf>,
    /// Expected sha256 of the library (empty: not checked).
    pub sha256: String,
    /// Execution providers in order of preference. One the library lacks is
    /// skipped with a warning when `cpu` is listed, an error otherwise.
    pub providers: Vec<Provider>,
    /// Let the intra-op thread pool spin while waiting for work. Off: on a
    /// loaded robot computer a spinning pool burns the cores the SLAM needs
    /// (measured: the segmenter at 0.57x the CPU and 0.57x the p50 latency
    /// with spinning off on the loaded 2-core machine).
    pub spin: bool,
}

/// An ONNX Runtime execution provider (`[onnxruntime] providers`).
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Provider {
    /// ONNX Runtime's own CPU kernels (every build has them).
    Cpu,
    /// NVIDIA CUDA (a GPU build of ONNX Runtime, e.g. the onnxruntime-gpu wheel or JetPack's).
    Cuda,
    /// NVIDIA TensorRT (a TensorRT-enabled build).
    #[serde(rename = "tensorrt")]
    TensorRt,
}

impl Provider {
    /// Its name in the configuration.
    pub fn as_str(&self) -> &'static str {
        match self {
            Provider::Cpu => "cpu",
            Provider::Cuda => "cuda",
            Provider::TensorRt => "tensorrt",
        }
    }
}

impl Default for OnnxRuntimeConfig {
    fn default() -> Self {
        Self {
            library: None,
            sha256: "fc44112fbe06d7d689c57e11d3862031f64711007e4ee020f8eed5185fd2c1d3".into(),
            providers: vec![Provider::Cpu],
            spin: false,
        }
    }
}

/// The shared TUM sequence the benches play by default, beside the repo.
pub const SHARED_TUM: &str = "../shared/data/tum/rgbd_dataset_freiburg1_rpy_first300";

/// The shared TUM sequence beside the repository of the running binary
/// (so the benches' default works from any directory), else beside the
/// working directory.
pub fn shared_tum() -> PathBuf {
    repo_root_of_exe()
        .map(|root| root.join(SHARED_TUM))
        .filter(|p| p.is_dir())
        .unwrap_or_else(|| PathBuf::from(SHARED_TUM))
}

/// The repository root of a binary in `<repo>/target/<profile>/`.
pub fn repo_root_of_exe() -> Option<PathBuf> {
    let exe = std::env::current_exe().ok()?;
    Some(exe.parent()?.parent()?.parent()?.to_path_buf())
}

/// Finds a model file: the configured path (and only it, when given), else
/// `$DYNSLAM_MODELS/<file>`, then `../shared/models/<file>` and
/// `.cache/models/<file>` (what `just setup` derives) beside the working
/// directory and beside the repository of the running binary.
pub fn locate_model(file: &str, configured: Option<&Path>) -> Result<PathBuf, ProvisionError> {
    let mut fallbacks = Vec::new();
    if let Some(dir) = std::env::var_os(MODELS_ENV) {
        fallbacks.push(PathBuf::from(dir).join(file));
    }
    fallbacks.push(PathBuf::from("../shared/models").join(file));
    fallbacks.push(PathBuf::from(DERIVED_MODELS).join(file));
    if let Some(root) = repo_root_of_exe() {
        fallbacks.push(root.join("../shared/models").join(file));
        fallbacks.push(root.join(DERIVED_MODELS).join(file));
    }
    search(configured, fallbacks).map_err(|looked| ProvisionError::ModelMissing {
        file: file.to_string(),
        looked,
    })
}

/// Finds the ONNX Runtime library: the configured path (and only it, when
/// given), else `$ORT_DYLIB_PATH`, then the `just setup` cache of the
/// working directory and of the repo.
pub fn locate_onnxruntime(configured: Option<&Path>) -> Result<PathBuf, ProvisionError> {
    let mut fallbacks = Vec::new();
    if let Some(p) = std::env::var_os(ORT_ENV) {
        fallbacks.push(PathBuf::from(p));
    }
    fallbacks.push(PathBuf::from(ORT_CACHE));
    if let Some(root) = repo_root_of_exe() {
        fallbacks.push(root.join(ORT_CACHE));
    }
    search(configured, fallbacks).map_err(|looked| ProvisionError::RuntimeMissing { looked })
}

/// The first existing file: the configured path alone when there is one (an
/// explicit path is a decision, never silently replaced by another file),
/// else the first fallback. On failure, the places looked at, in words.
fn search(configured: Option<&Path>, fallbacks: Vec<PathBuf>) -> Result<PathBuf, String> {
    let candidates = match configured {
        Some(p) => vec![p.to_path_buf()],
        None => fallbacks,
    };
    candidates
        .iter()
        .find(|p| p.is_file())
        .cloned()
        .ok_or_else(|| describe(&candidates))
}

fn describe(candidates: &[PathBuf]) -> String {
    candidates
        .iter()
        .map(|p| p.display().to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

/// Hex sha256 of a file.
pub fn sha256_of(path: &Path) -> Result<String, ProvisionError> {
    let unreadable = |e: std::io::Error| ProvisionError::Unreadable {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let mut file = std::fs::File::open(path).map_err(unreadable)?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = file.read(&mut buf).map_err(unreadable)?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
    }
    Ok(hasher
        .finalize()
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect())
}

/// Checks a file against its expected sha256 (case-insensitive hex).
pub fn verify(path: &Path, expected: &str) -> Result<(), ProvisionError> {
    let found = sha256_of(path)?;
    if !found.eq_ignore_ascii_case(expected.trim()) {
        return Err(ProvisionError::HashMismatch {
            path: path.to_path_buf(),
            expected: expected.trim().to_lowercase(),
            found,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sha256_of_known_content() {
        let dir = std::env::temp_dir().join(format!("dynslam-prov-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("abc.bin");
        std::fs::write(&f, b"abc").unwrap();
        let abc = "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad";
        assert_eq!(sha256_of(&f).unwrap(), abc);
        verify(&f, &abc.to_uppercase()).unwrap();
        let err = verify(&f, "00").unwrap_err();
        assert!(err.to_string().contains("abc.bin: sha256 is ba78"), "{err}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn missing_model_names_file_and_places() {
        let err =
            locate_model("no-such-model.onnx", Some(Path::new("/nowhere/m.onnx"))).unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains("no-such-model.onnx") && msg.contains("/nowhere/m.onnx"),
            "{msg}"
        );
        assert!(msg.contains(MODELS_ENV), "{msg}");
    }

    #[test]
    fn shared_models_are_found_and_verified() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/models");
        let p = locate_model(
            "yolov8n-seg_int8.onnx",
            Some(&root.join("yolov8n-seg_int8.onnx")),
        )
        .unwrap();
        verify(
            &p,
            "a892891617cbadd34d860f66a866393a8d4c487c49f1474e9b6d9e578332e56a",
        )
        .unwrap();
    }
}
