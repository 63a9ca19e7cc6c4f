//! The Rust YOLOv8-seg decoder gives the same instances as onnxruntime's
//! Python API plus a straightforward NumPy decoding of the same model
//! (tests/reference/yolo_reference.py, output stored in
//! tests/fixtures/bus_yolov8n_seg_f32.json) on a real street photo with
//! people and a bus: same classes, boxes within 1 px, mask IoU >= 0.98.
//! The photo comes from the PyPI wheel ultralytics==8.4.190 (`just fixtures`).

use std::path::{Path, PathBuf};

use onnx_runtime::init_runtime;
use pipeline_config::{OnnxRuntimeConfig, SegmenterConfig};
use provision::ORT_CACHE;
use segmentation::onnx::{YoloSeg, YoloSettings};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

#[test]
fn rust_decoder_matches_the_python_numpy_reference_on_a_street_photo() {
    let photo = repo().join(".cache/fixtures/bus.png");
    assert!(
        photo.is_file(),
        "{} missing: run `just fixtures` (part of `just test`)",
        photo.display()
    );
    let reference: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(repo().join("tests/fixtures/bus_yolov8n_seg_f32.json")).unwrap(),
    )
    .unwrap();

    let cfg = SegmenterConfig {
        model_path: Some(repo().join("../shared/models/yolov8n-seg_f32.onnx")),
        score_threshold: Some(reference["score_threshold"].as_f64().unwrap() as f32),
        iou_threshold: Some(reference["iou_threshold"].as_f64().unwrap() as f32),
        ..Default::default()
    };
    let runtime = OnnxRuntimeConfig {
        library: Some(repo().join(ORT_CACHE)),
        ..Default::default()
    };
    let mut model = YoloSeg::load(
        init_runtime(&runtime).unwrap(),
        YoloSettings::from_config(&cfg).unwrap(),
    )
    .unwrap();
    let img = image::open(&photo).unwrap().to_rgb8();
    let (w, h) = (img.width() as usize, img.height() as usize);
    assert_eq!(
        (w as u64, h as u64),
        (
            reference["width"].as_u64().unwrap(),
            reference["height"].as_u64().unwrap()
        )
    );
    let mut labels = vec![0u8; w * h];
    let ours = model.segment(img.as_raw(), w, h, &mut labels).unwrap();

    let theirs = reference["instances"].as_array().unwrap();
    assert!(theirs.len() >= 3, "the photo has people and a bus");
    assert_eq!(ours.len(), theirs.len(), "ours {ours:?}");
    for (i, (o, t)) in ours.iter().zip(theirs).enumerate() {
        assert_eq!(
            o.class_id as u64,
            t["class_id"].as_u64().unwrap(),
            "instance {i}"
        );
        assert!(
            (o.score as f64 - t["score"].as_f64().unwrap()).abs() < 1e-3,
            "instance {i} score"
        );
        for k in 0..4 {
            let d = (o.bbox[k] as f64 - t["bbox"][k].as_f64().unwrap()).abs();
            assert!(
                d <= 1.0,
                "instance {i} box coordinate {k} differs by {d} px"
            );
        }
        let mut reference_mask = vec![false; w * h];
        for run in t["rle"].as_array().unwrap() {
            let (s, n) = (
                run[0].as_u64().unwrap() as usize,
                run[1].as_u64().unwrap() as usize,
            );
            reference_mask[s..s + n].iter_mut().for_each(|p| *p = true);
        }
        let (mut inter, mut union) = (0usize, 0usize);
        for (p, r) in labels.iter().zip(&reference_mask) {
            let mine = *p as usize == i + 1;
            inter += (mine && *r) as usize;
            union += (mine || *r) as usize;
        }
        let iou = inter as f64 / union.max(1) as f64;
        println!(
            "instance {i}: class {} box {:?} mask IoU {iou:.5}",
            o.class_id, o.bbox
        );
        assert!(iou >= 0.98, "instance {i}: mask IoU {iou}");
    }
}
