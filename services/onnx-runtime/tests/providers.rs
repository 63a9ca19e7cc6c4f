//! Execution providers against the real ONNX Runtime library that `just
//! setup` provisions (the CPU build from PyPI): a GPU provider it lacks is an
//! error naming the key unless "cpu" is listed, then a logged fallback; "cpu"
//! alone runs on the CPU. One test: the process has one ONNX Runtime
//! environment, created by the first successful call.

use std::path::{Path, PathBuf};

use provision::ORT_CACHE;
use provision::{OnnxRuntimeConfig, Provider};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn cfg(providers: Vec<Provider>) -> OnnxRuntimeConfig {
    OnnxRuntimeConfig {
        library: Some(repo().join(ORT_CACHE)),
        providers,
        ..Default::default()
    }
}

#[test]
fn providers_the_library_lacks_fail_or_fall_back_as_configured() {
    for wanted in [
        vec![Provider::Cuda],
        vec![Provider::TensorRt, Provider::Cuda],
    ] {
        let err = onnx_runtime::init_runtime(&cfg(wanted.clone())).unwrap_err();
        let msg = format!("{err:#}");
        assert!(msg.contains("key `onnxruntime.providers`"), "{msg}");
        assert!(msg.contains(wanted[0].as_str()), "{msg}");
        assert!(msg.contains("add \"cpu\""), "{msg}");
    }
    // With "cpu" in the list the missing GPU provider is skipped; the session runs.
    let env = onnx_runtime::init_runtime(&cfg(vec![Provider::Cuda, Provider::Cpu])).unwrap();
    let model = repo().join("tests/fixtures/tiny_sam2_encoder.onnx");
    let mut session = onnx_runtime::open_session(&env, &model, 1).unwrap();
    onnx_runtime::check_signature(&session, &model, "encoder", &["image"], &["image_embed"])
        .unwrap();
    let input = vec![0.5f32; 3 * 1024 * 1024];
    let image =
        ort::value::TensorRef::from_array_view(([1usize, 3, 1024, 1024], &input[..])).unwrap();
    let out = session.run(ort::inputs!["image" => image]).unwrap();
    let (_, embed) = out["image_embed"].try_extract_tensor::<f32>().unwrap();
    assert!(embed.iter().all(|v| (v - 0.5).abs() < 1e-5));
    drop(out);
    // "cpu" alone needs no provider at all.
    let lib = repo().join(ORT_CACHE);
    assert!(onnx_runtime::execution_providers(&[Provider::Cpu], &lib)
        .unwrap()
        .is_empty());
    assert_eq!(
        onnx_runtime::execution_providers(&[Provider::Cuda, Provider::Cpu], &lib)
            .unwrap()
            .len(),
        0,
        "the CPU build has no CUDA: skipped"
    );
    // A signature check names what a model lacks.
    let err = onnx_runtime::check_signature(&session, &model, "decoder", &["point_coords"], &[])
        .unwrap_err();
    assert!(format!("{err:#}").contains("point_coords"), "{err:#}");
}
