//! The `sam2` backend through real ONNX Runtime on tiny graphs with the SAM 2
//! export's signature (tests/reference/make_tiny_sam2.py): the decoder's
//! candidate 1 is the box of the first two prompt points, its predicted IoUs
//! follow the frame's brightness. So the mask that comes back is the
//! prompted box only if pre-processing, point coordinates, mask decoding and
//! upsampling are right, and a black frame must end the object. SAM 2's
//! weights cannot be obtained here.

use std::path::{Path, PathBuf};

use pipeline_config::{OnnxRuntimeConfig, PropagatorConfig};
use propagation::sam2::{Sam2Propagator, Sam2Settings};
use provision::{sha256_of, ORT_CACHE};
use shared_types::Instance;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn fixture(name: &str) -> PathBuf {
    repo().join("tests/fixtures").join(name)
}

fn config(encoder: &str, decoder: &str) -> PropagatorConfig {
    PropagatorConfig {
        backend: "sam2".into(),
        model: encoder.into(),
        model_path: Some(fixture(encoder)),
        model_sha256: sha256_of(&fixture(encoder)).unwrap(),
        decoder_model: decoder.into(),
        decoder_model_path: Some(fixture(decoder)),
        decoder_model_sha256: sha256_of(&fixture(decoder)).unwrap(),
        threads: Some(1),
        ..Default::default()
    }
}

fn env() -> ort::environment::Environment {
    onnx_runtime::init_runtime(&OnnxRuntimeConfig {
        library: Some(repo().join(ORT_CACHE)),
        ..Default::default()
    })
    .unwrap()
}

fn load() -> Sam2Propagator {
    let settings =
        Sam2Settings::from_config(&config("tiny_sam2_encoder.onnx", "tiny_sam2_decoder.onnx"))
            .unwrap();
    Sam2Propagator::load(env(), settings).unwrap()
}

const W: usize = 640;
const H: usize = 480;

fn rect_labels(x0: usize, y0: usize, x1: usize, y1: usize) -> Vec<u8> {
    (0..W * H)
        .map(|i| ((x0..x1).contains(&(i % W)) && (y0..y1).contains(&(i / W))) as u8)
        .collect()
}

fn iou(a: &[u8], b: &[u8]) -> f64 {
    let inter = a
        .iter()
        .zip(b)
        .filter(|(x, y)| **x != 0 && **y != 0)
        .count();
    let union = a
        .iter()
        .zip(b)
        .filter(|(x, y)| **x != 0 || **y != 0)
        .count();
    inter as f64 / union.max(1) as f64
}

#[test]
fn an_object_is_followed_by_its_box_and_ends_on_a_black_frame() {
    let mut sam = load();
    let keyframe = rect_labels(100, 120, 200, 360);
    let person = Instance {
        object_id: 7,
        class_id: 0,
        score: 0.9,
        bbox: [100.0, 120.0, 200.0, 360.0],
    };
    sam.prompt_with(&keyframe, W, H, &[person]);
    assert_eq!(sam.objects(), 1);
    let grey = vec![128u8; W * H * 3];
    for step in 0..3 {
        let mut labels = vec![0u8; W * H];
        let inst = sam.propagate(&grey, W, H, &mut labels).unwrap();
        assert_eq!(inst.len(), 1, "step {step}");
        assert_eq!(inst[0].object_id, 7);
        // Mid grey: s = sigmoid(4 * 0.235) = 0.719; the box candidate's 0.9 s wins.
        assert!(
            (inst[0].score - 0.9 * 0.719).abs() < 0.01,
            "{}",
            inst[0].score
        );
        let overlap = iou(&labels, &keyframe);
        assert!(overlap > 0.98, "step {step}: IoU {overlap}");
        let b = inst[0].bbox;
        for (got, want) in b.iter().zip([100.0, 120.0, 200.0, 360.0]) {
            assert!((got - want).abs() <= 1.0, "bbox {b:?}");
        }
    }
    // Black: every predicted IoU < 0.5, the object ends.
    let black = vec![0u8; W * H * 3];
    let mut labels = vec![0u8; W * H];
    assert!(sam.propagate(&black, W, H, &mut labels).unwrap().is_empty());
    assert!(labels.iter().all(|&l| l == 0));
    assert_eq!(sam.objects(), 0);
}

#[test]
fn a_frame_of_another_size_than_its_prompt_is_an_error() {
    let mut sam = load();
    sam.prompt_with(
        &rect_labels(10, 10, 60, 60),
        W,
        H,
        &[Instance {
            object_id: 1,
            class_id: 0,
            score: 1.0,
            bbox: [10.0, 10.0, 60.0, 60.0],
        }],
    );
    let small = vec![128u8; 320 * 240 * 3];
    let err = sam
        .propagate(&small, 320, 240, &mut vec![0u8; 320 * 240])
        .unwrap_err();
    assert!(format!("{err:#}").contains("320x240"), "{err:#}");
}

#[test]
fn wrong_files_and_missing_keys_are_named() {
    // The encoder given as the decoder: the signature check names what is missing.
    let settings =
        Sam2Settings::from_config(&config("tiny_sam2_encoder.onnx", "tiny_sam2_encoder.onnx"))
            .unwrap();
    let err = Sam2Propagator::load(env(), settings).err().unwrap();
    let msg = format!("{err:#}");
    assert!(msg.contains("not a SAM 2 prompt/mask decoder"), "{msg}");
    assert!(msg.contains("point_coords"), "{msg}");
    // An input size the encoder does not take.
    let mut cfg = config("tiny_sam2_encoder.onnx", "tiny_sam2_decoder.onnx");
    cfg.input_size = Some(512);
    let err = Sam2Propagator::load(env(), Sam2Settings::from_config(&cfg).unwrap())
        .err()
        .unwrap();
    let msg = format!("{err:#}");
    assert!(
        msg.contains("services.propagator.input_size") && msg.contains("1024x1024"),
        "{msg}"
    );
    // No decoder configured.
    let mut cfg = config("tiny_sam2_encoder.onnx", "tiny_sam2_decoder.onnx");
    cfg.decoder_model = String::new();
    let msg = format!("{:#}", Sam2Settings::from_config(&cfg).unwrap_err());
    assert!(msg.contains("services.propagator.decoder_model"), "{msg}");
    // A corrupt (other) file for the sha256.
    let mut cfg = config("tiny_sam2_encoder.onnx", "tiny_sam2_decoder.onnx");
    cfg.decoder_model_sha256 = "0".repeat(64);
    let msg = format!("{:#}", Sam2Settings::from_config(&cfg).unwrap_err());
    assert!(
        msg.contains("sha256") && msg.contains("tiny_sam2_decoder.onnx"),
        "{msg}"
    );
    // Thresholds out of range.
    let mut cfg = config("tiny_sam2_encoder.onnx", "tiny_sam2_decoder.onnx");
    cfg.min_predicted_iou = Some(1.5);
    let msg = format!("{:#}", Sam2Settings::from_config(&cfg).unwrap_err());
    assert!(msg.contains("min_predicted_iou"), "{msg}");
}
