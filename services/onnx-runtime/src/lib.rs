//! ONNX Runtime for the model backends (segmenter, propagator): the
//! provisioned shared library loaded once per process, the execution
//! providers the configuration asks for, sessions on verified model files and
//! the check that a file has the inputs and outputs a backend needs. Every
//! failure a user can fix is a [`InputError`] naming the
//! file or key.

#![deny(missing_docs)]

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{anyhow, Result};
use ort::ep::ExecutionProviderDispatch;
use ort::session::Session;
use provision::{
    locate_model, locate_onnxruntime, verify, InputError, OnnxRuntimeConfig, Provider,
};

/// Locates a model file and checks its sha256; failures are input errors.
pub fn verified_model(file: &str, sha256: &str, configured: Option<&Path>) -> Result<PathBuf> {
    let path = locate_model(file, configured).map_err(|e| InputError(e.to_string()))?;
    verify(&path, sha256).map_err(|e| InputError(e.to_string()))?;
    Ok(path)
}

/// Whether sessions' thread pools spin (`[onnxruntime] spin`), set by
/// [`init_runtime`] with the rest of the process-wide runtime settings.
static SPIN: AtomicBool = AtomicBool::new(false);

/// An ONNX Runtime session on a verified model file (on the environment's
/// execution providers), `threads` intra-op threads that spin only when
/// `[onnxruntime] spin` says so; a file ONNX Runtime cannot load is an input
/// error naming it.
pub fn open_session(
    env: &ort::environment::Environment,
    model: &Path,
    threads: usize,
) -> Result<Session> {
    let spin = SPIN.load(Ordering::Relaxed);
    let session = Session::builder(env)
        .and_then(|b| b.with_intra_threads(threads.max(1)).map_err(Into::into))
        .and_then(|b| b.with_intra_op_spinning(spin).map_err(Into::into))
        .and_then(|b| b.with_inter_op_spinning(spin).map_err(Into::into))
        .and_then(|mut b| b.commit_from_file(model));
    session.map_err(|e| {
        InputError(format!(
            "{}: cannot load the ONNX model: {e}",
            model.display()
        ))
        .into()
    })
}

/// Checks that `session` has (at least) the named inputs and outputs; a
/// model with another signature is an input error that lists what it has.
pub fn check_signature(
    session: &Session,
    model: &Path,
    what: &str,
    inputs: &[&str],
    outputs: &[&str],
) -> Result<()> {
    let have_in: Vec<&str> = session.inputs().iter().map(|o| o.name()).collect();
    let have_out: Vec<&str> = session.outputs().iter().map(|o| o.name()).collect();
    let missing_in: Vec<&&str> = inputs.iter().filter(|n| !have_in.contains(n)).collect();
    let missing_out: Vec<&&str> = outputs.iter().filter(|n| !have_out.contains(n)).collect();
    if missing_in.is_empty() && missing_out.is_empty() {
        return Ok(());
    }
    Err(InputError(format!(
        "{}: not a {what}: it lacks inputs {missing_in:?} / outputs {missing_out:?} (it has inputs {have_in:?}, outputs {have_out:?})",
        model.display()
    ))
    .into())
}

/// Checks that a model's square image input `name` ([N, C, S, S]) takes the
/// configured size `size` where the model fixes it; `key` names the setting.
pub fn check_input_size(
    session: &Session,
    model: &Path,
    name: &str,
    size: usize,
    key: &str,
) -> Result<()> {
    let dims = session
        .inputs()
        .iter()
        .find(|o| o.name() == name)
        .and_then(|o| o.dtype().tensor_shape())
        .map(|s| s.iter().copied().collect::<Vec<i64>>());
    if let Some(d) = dims {
        if d.len() == 4 && d[2] > 0 && d[3] > 0 && (d[2] as usize != size || d[3] as usize != size)
        {
            return Err(InputError(format!(
                "key `{key}`: {size}, but {} takes {}x{} images (`{name}` {d:?})",
                model.display(),
                d[3],
                d[2]
            ))
            .into());
        }
    }
    Ok(())
}

/// The process's ONNX Runtime environment: ONNX Runtime allows one per
/// process, so it is created on first use and shared.
static RUNTIME: std::sync::Mutex<Option<ort::environment::Environment>> =
    std::sync::Mutex::new(None);

/// Loads ONNX Runtime from the provisioned library (verified) once per
/// process, with the configured execution providers.
pub fn init_runtime(cfg: &OnnxRuntimeConfig) -> Result<ort::environment::Environment> {
    let lib = locate_onnxruntime(cfg.library.as_deref()).map_err(|e| InputError(e.to_string()))?;
    if !cfg.sha256.is_empty() {
        verify(&lib, &cfg.sha256).map_err(|e| InputError(e.to_string()))?;
    }
    SPIN.store(cfg.spin, Ordering::Relaxed);
    let mut slot = RUNTIME
        .lock()
        .map_err(|_| anyhow!("ONNX Runtime initialisation panicked earlier"))?;
    if let Some(env) = slot.as_ref() {
        return Ok(env.clone());
    }
    let builder = ort::init_from(&lib)
        .map_err(|e| InputError(format!("{}: cannot load ONNX Runtime: {e}", lib.display())))?;
    let providers = execution_providers(&cfg.providers, &lib)?;
    let env = builder
        .with_name("dynslam")
        .with_execution_providers(providers)
        .build()
        .map_err(|e| anyhow!("cannot create the ONNX Runtime environment: {e}"))?;
    *slot = Some(env.clone());
    Ok(env)
}

/// The execution providers of `[onnxruntime] providers`, in order. One the
/// loaded library lacks is skipped with a warning when "cpu" is in the list
/// (the fallback), and is an input error when it is not. ONNX Runtime always
/// keeps its CPU provider for what the others cannot run.
pub fn execution_providers(
    wanted: &[Provider],
    lib: &Path,
) -> Result<Vec<ExecutionProviderDispatch>> {
    use ort::ep::ExecutionProvider;
    let fallback = wanted.contains(&Provider::Cpu);
    let mut out = Vec::new();
    for p in wanted {
        let (available, dispatch) = match p {
            Provider::Cpu => continue,
            Provider::Cuda => (
                ort::ep::CUDA::is_available(),
                ort::ep::CUDA::default().build(),
            ),
            Provider::TensorRt => (
                ort::ep::TensorRT::is_available(),
                ort::ep::TensorRT::default().build(),
            ),
        };
        match available {
            Ok(true) => {
                tracing::info!("ONNX Runtime execution provider {}", p.as_str());
                out.push(if fallback {
                    dispatch.fail_silently()
                } else {
                    dispatch.error_on_failure()
                });
            }
            Ok(false) | Err(_) if fallback => tracing::warn!(
                "{}: this ONNX Runtime build has no {} execution provider; running on the CPU (`onnxruntime.providers` lists \"cpu\")",
                lib.display(),
                p.as_str()
            ),
            _ => {
                return Err(InputError(format!(
                    "key `onnxruntime.providers`: {} is not in this ONNX Runtime build ({}); point `onnxruntime.library` at a GPU build, or add \"cpu\" to the list to fall back",
                    p.as_str(),
                    lib.display()
                ))
                .into())
            }
        }
    }
    Ok(out)
}
