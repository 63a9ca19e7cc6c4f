//! The Mask R-CNN backend's decoding through real ONNX Runtime, on tiny graphs
//! with the torchvision export's output signature (constants chosen by hand:
//! tests/reference/make_tiny_maskrcnn.py). Real Mask R-CNN weights cannot be
//! obtained here.

use std::path::{Path, PathBuf};

use onnx_runtime::init_runtime;
use pipeline_config::{OnnxRuntimeConfig, SegmenterConfig};
use provision::{sha256_of, ORT_CACHE};
use segmentation::coco::CLASSES;
use segmentation::maskrcnn::MaskRcnn;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn load(file: &str) -> MaskRcnn {
    let path = repo().join("tests/fixtures").join(file);
    let cfg = SegmenterConfig {
        model: file.into(),
        model_sha256: sha256_of(&path).unwrap(),
        model_path: Some(path),
        ..Default::default()
    };
    let env = init_runtime(&OnnxRuntimeConfig {
        library: Some(repo().join(ORT_CACHE)),
        ..Default::default()
    })
    .unwrap();
    MaskRcnn::from_config(env, &cfg).unwrap()
}

fn run(file: &str) -> (Vec<shared_types::Instance>, Vec<u8>) {
    let (w, h) = (64, 48);
    let rgb = vec![128u8; w * h * 3];
    let mut labels = vec![0u8; w * h];
    let inst = load(file).segment(&rgb, w, h, &mut labels).unwrap();
    (inst, labels)
}

fn count(labels: &[u8], l: u8) -> usize {
    labels.iter().filter(|&&x| x == l).count()
}

#[test]
fn small_masks_are_pasted_into_their_boxes() {
    let (inst, labels) = run("tiny_maskrcnn_28.onnx");
    // person 0.97 and car 0.93 kept; the 0.40 person (below 0.9) and the chair (static) dropped.
    let names: Vec<_> = inst.iter().map(|i| CLASSES[i.class_id as usize]).collect();
    assert_eq!(names, vec!["person", "car"]);
    assert_eq!(inst[0].bbox, [8.0, 4.0, 24.0, 36.0]);
    // Pasted as torchvision's paste_masks_in_image does (worked out by hand
    // from roi_heads.py): the 28x28 mask padded to 30x30, the box expanded by
    // 30/28 and truncated, the padded mask resized to the box + 1 pixel.
    // Person, box (8, 4, 24, 36) -> (7, 2, 24, 37), 18x36 pixels: columns
    // 1..=8 of it reach >= 0.5 on the left half (x 8..16), rows 1..=34 (y 3..37):
    // one row more above and below the box than a plain box paste.
    assert_eq!(count(&labels, 1), 8 * 34);
    assert_eq!(labels[3 * 64 + 9], 1);
    assert_eq!(labels[2 * 64 + 9], 0);
    assert_eq!(labels[36 * 64 + 15], 1);
    assert_eq!(labels[10 * 64 + 16], 0);
    // Car, box (30, 10, 60, 30) -> (28, 9, 61, 30), 34x22 pixels, whole mask at
    // 0.8: columns 1..=32 (x 29..61) and rows 1..=20 (y 10..30) reach 0.5.
    assert_eq!(count(&labels, 2), 32 * 20);
    assert_eq!(labels[10 * 64 + 29], 2);
    assert_eq!(labels[10 * 64 + 28], 0);
    assert_eq!(labels[29 * 64 + 60], 2);
    assert_eq!(labels[30 * 64 + 60], 0);
    assert_eq!(labels[3 * 64 + 3], 0, "low-score detection not painted");
}

#[test]
fn full_size_masks_are_thresholded_in_place() {
    let (inst, labels) = run("tiny_maskrcnn_full.onnx");
    assert_eq!(inst.len(), 2);
    assert_eq!(count(&labels, 1), 8 * 32);
    // The car's two rows at probability 0.3 are not part of it.
    assert_eq!(count(&labels, 2), 30 * 18);
    assert_eq!(labels[10 * 64 + 40], 0);
    assert_eq!(labels[12 * 64 + 40], 2);
}

#[test]
fn missing_hash_is_a_configuration_error() {
    let env = init_runtime(&OnnxRuntimeConfig {
        library: Some(repo().join(ORT_CACHE)),
        ..Default::default()
    })
    .unwrap();
    let err = MaskRcnn::from_config(env, &SegmenterConfig::default())
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains("model_sha256"), "{err}");
}
