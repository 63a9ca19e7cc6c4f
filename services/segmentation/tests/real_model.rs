//! The real YOLOv8n-seg and YOLO11n-seg models through the real ONNX
//! Runtime on real frames. Needs `just setup` (the runtime, the derived
//! input sizes) and ../shared/models (the weights).

use std::path::{Path, PathBuf};

use onnx_runtime::init_runtime;
use pipeline_config::{OnnxRuntimeConfig, SegmenterConfig};
use provision::ORT_CACHE;
use segmentation::coco::CLASSES;
use segmentation::exports::YoloFamily;
use segmentation::onnx::{YoloSeg, YoloSettings};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn runtime() -> OnnxRuntimeConfig {
    OnnxRuntimeConfig {
        library: Some(repo().join(ORT_CACHE)),
        ..Default::default()
    }
}

fn model(classes: &[&str], score: f32) -> YoloSeg {
    let cfg = SegmenterConfig {
        model_path: Some(repo().join("../shared/models/yolov8n-seg_f32.onnx")),
        classes: classes.iter().map(|s| s.to_string()).collect(),
        score_threshold: Some(score),
        ..Default::default()
    };
    let settings = YoloSettings::from_config(&cfg).unwrap();
    YoloSeg::load(init_runtime(&runtime()).unwrap(), settings).unwrap()
}

fn tum_frame(name: &str) -> (Vec<u8>, usize, usize) {
    let p = repo()
        .join("../shared/data/tum/rgbd_dataset_freiburg1_rpy_first300/rgb")
        .join(name);
    let img = image::open(p).unwrap().to_rgb8();
    let (w, h) = (img.width() as usize, img.height() as usize);
    (img.into_raw(), w, h)
}

#[test]
fn finds_the_laptop_on_the_desk_with_its_mask_inside_its_box() {
    let mut m = model(&CLASSES, 0.3);
    let (rgb, w, h) = tum_frame("1305031229.528748.png");
    let mut labels = vec![0u8; w * h];
    let inst = m.segment(&rgb, w, h, &mut labels).unwrap();
    for (i, d) in inst.iter().enumerate() {
        let n = labels.iter().filter(|&&l| l as usize == i + 1).count();
        println!(
            "{} {:.2} {:?} {n} px",
            CLASSES[d.class_id as usize], d.score, d.bbox
        );
    }
    let laptop = inst
        .iter()
        .position(|d| CLASSES[d.class_id as usize] == "laptop")
        .expect("the laptop in the middle of frame 0 is found");
    let b = inst[laptop].bbox;
    assert!(
        b[0] > 150.0 && b[2] < 500.0 && b[1] > 30.0 && b[3] < 330.0,
        "{b:?}"
    );
    // Every labelled pixel lies in its instance's box, and masks are not empty.
    for (i, d) in inst.iter().enumerate() {
        let mut n = 0;
        for y in 0..h {
            for x in 0..w {
                if labels[y * w + x] as usize == i + 1 {
                    n += 1;
                    assert!(
                        x as f32 + 0.5 >= d.bbox[0] - 1.0 && (x as f32) < d.bbox[2] + 1.0,
                        "pixel {x},{y} outside {:?}",
                        d.bbox
                    );
                    assert!(y as f32 + 0.5 >= d.bbox[1] - 1.0 && (y as f32) < d.bbox[3] + 1.0);
                }
            }
        }
        let area = (d.bbox[2] - d.bbox[0]) * (d.bbox[3] - d.bbox[1]);
        assert!(
            n as f32 > 0.2 * area,
            "mask of {i} covers {n} of {area} box pixels"
        );
    }
}

/// The model of `family` at `input_size` (its export, no file named: the
/// backend and the size choose it).
fn export(family: YoloFamily, input_size: u32) -> YoloSeg {
    let cfg = SegmenterConfig {
        backend: family.backend().into(),
        model_path: Some(export_path(family, input_size as usize)),
        classes: CLASSES.iter().map(|s| s.to_string()).collect(),
        score_threshold: Some(0.3),
        ..Default::default()
    };
    let settings = YoloSettings::from_config(&cfg).unwrap();
    assert_eq!(
        (settings.family, settings.input_size),
        (family, input_size as usize)
    );
    YoloSeg::load(init_runtime(&runtime()).unwrap(), settings).unwrap()
}

/// The people of bus.jpg: their masks (labels == their instance).
fn people_on_the_bus_photo(m: &mut YoloSeg) -> Vec<Vec<bool>> {
    let bus = image::open(repo().join(".cache/fixtures/bus.png"))
        .expect(".cache/fixtures/bus.png: run `just fixtures`")
        .to_rgb8();
    let (w, h) = (bus.width() as usize, bus.height() as usize);
    let mut labels = vec![0u8; w * h];
    let inst = m.segment(bus.as_raw(), w, h, &mut labels).unwrap();
    let masks = instance_masks(&inst, &labels);
    masks
        .into_iter()
        .filter(|(c, m)| {
            CLASSES[*c as usize] == "person" && m.iter().filter(|&&p| p).count() * 50 >= w * h
        })
        .map(|(_, m)| m)
        .collect()
}

#[test]
fn yolo11_finds_the_people_yolov8_finds_at_every_input_size() {
    // Same decoder for both generations: if YOLO11's outputs were read
    // wrongly (or the rewritten 480 file's anchor grid were off) its masks
    // would land elsewhere. The people standing in front of the bus
    // (>= 2 % of the image each) are found by both, mask on mask.
    for size in [320, 480, 640] {
        let v8 = people_on_the_bus_photo(&mut export(YoloFamily::V8, size));
        let v11 = people_on_the_bus_photo(&mut export(YoloFamily::V11, size));
        assert!(
            v8.len() >= 3,
            "{size}: YOLOv8n-seg finds {} people",
            v8.len()
        );
        for (k, person) in v8.iter().enumerate() {
            let best = v11.iter().map(|m| iou(person, m)).fold(0.0, f64::max);
            println!("{size}: person {k} of YOLOv8n-seg, mask IoU {best:.3} with YOLO11n-seg's");
            assert!(best > 0.75, "{size}: person {k}: best mask IoU {best:.3}");
        }
    }
}

#[test]
fn a_backend_and_a_model_of_the_other_generation_are_refused() {
    let cfg = SegmenterConfig {
        backend: "yolov8-seg".into(),
        model: "yolo11n-seg_320_f32.onnx".into(),
        model_path: Some(export_path(YoloFamily::V11, 320)),
        ..Default::default()
    };
    let err = YoloSettings::from_config(&cfg).unwrap_err().to_string();
    assert!(
        err.contains("services.segmenter.backend")
            && err.contains("YOLO11n-seg")
            && err.contains("yolo11-seg"),
        "{err}"
    );
    // The file named alone brings its generation and size.
    let cfg = SegmenterConfig {
        backend: "yolo11-seg".into(),
        model: "yolo11n-seg_640_f32.onnx".into(),
        model_path: Some(export_path(YoloFamily::V11, 640)),
        ..Default::default()
    };
    let s = YoloSettings::from_config(&cfg).unwrap();
    assert_eq!((s.family, s.input_size), (YoloFamily::V11, 640));
}

#[test]
fn only_dynamic_classes_become_masks() {
    // A static desk scene: nothing movable in it.
    let mut m = model(&["person", "car", "bicycle"], 0.5);
    let (rgb, w, h) = tum_frame("1305031229.528748.png");
    let mut labels = vec![0u8; w * h];
    let inst = m.segment(&rgb, w, h, &mut labels).unwrap();
    assert!(inst.is_empty(), "{inst:?}");
    assert!(labels.iter().all(|&l| l == 0));
    // A colour buffer that is not the size given is a named error, not a
    // panic.
    let err = m
        .segment(&rgb[..rgb.len() - 3], w, h, &mut labels)
        .unwrap_err()
        .to_string();
    assert!(err.contains("is not 640x480 RGB8"), "{err}");
}

#[test]
fn bad_model_files_and_runtime_give_named_errors() {
    let dir = std::env::temp_dir().join(format!("dynslam-badmodel-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // Wrong hash.
    let cfg = SegmenterConfig {
        model_path: Some(repo().join("../shared/models/yolov8n-seg_int8.onnx")),
        model: "yolov8n-seg_int8.onnx".into(),
        model_sha256: "00".repeat(32),
        ..Default::default()
    };
    let err = YoloSettings::from_config(&cfg).unwrap_err().to_string();
    assert!(
        err.contains("yolov8n-seg_int8.onnx: sha256 is a892"),
        "{err}"
    );
    // Missing model.
    let cfg = SegmenterConfig {
        model_path: Some(dir.join("nothing.onnx")),
        model: "nothing.onnx".into(),
        model_sha256: "00".repeat(32),
        ..Default::default()
    };
    let err = YoloSettings::from_config(&cfg).unwrap_err().to_string();
    assert!(
        err.contains("model file nothing.onnx not found") && err.contains("DYNSLAM_MODELS"),
        "{err}"
    );
    // Corrupt ONNX file with a matching hash: the loader names the file.
    let corrupt = dir.join("corrupt.onnx");
    std::fs::write(&corrupt, b"not a protobuf at all").unwrap();
    let sha = provision::sha256_of(&corrupt).unwrap();
    let cfg = SegmenterConfig {
        model_path: Some(corrupt.clone()),
        model: "corrupt.onnx".into(),
        model_sha256: sha,
        ..Default::default()
    };
    let settings = YoloSettings::from_config(&cfg).unwrap();
    let err = YoloSeg::load(init_runtime(&runtime()).unwrap(), settings)
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("corrupt.onnx: cannot load the ONNX model"),
        "{err}"
    );
    // Unknown class name.
    let cfg = SegmenterConfig {
        model_path: Some(repo().join("../shared/models/yolov8n-seg_f32.onnx")),
        classes: vec!["pedestrian".into()],
        ..Default::default()
    };
    let err = YoloSettings::from_config(&cfg).unwrap_err().to_string();
    assert!(
        err.contains("services.segmenter.classes") && err.contains("'pedestrian'"),
        "{err}"
    );
    // Missing runtime library.
    let err = init_runtime(&OnnxRuntimeConfig {
        library: Some(dir.join("libonnxruntime.so")),
        sha256: String::new(),
        ..Default::default()
    });
    let err = err.err().unwrap().to_string();
    assert!(
        err.contains("ONNX Runtime library not found") && err.contains("just setup"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn an_input_size_the_model_does_not_take_is_a_configuration_error() {
    // A user's own export (a name the product does not know, so only the
    // model's input shape can tell) fixed at 320: 640 would crash every
    // inference. (A known export with the wrong size is refused earlier, by
    // the configuration: see onnx.rs's unit tests.)
    let dir = std::env::temp_dir().join(format!("dynslam-own-export-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let own = dir.join("my-yolo.onnx");
    std::fs::remove_file(&own).ok();
    std::os::unix::fs::symlink(
        std::fs::canonicalize(repo().join("../shared/models/yolov8n-seg_f32.onnx")).unwrap(),
        &own,
    )
    .unwrap();
    let cfg = SegmenterConfig {
        model: "my-yolo.onnx".into(),
        model_sha256: segmentation::exports::export_for(YoloFamily::V8, 320)
            .unwrap()
            .sha256
            .into(),
        model_path: Some(own),
        input_size: Some(640),
        ..Default::default()
    };
    let settings = YoloSettings::from_config(&cfg).unwrap();
    let err = YoloSeg::load(init_runtime(&runtime()).unwrap(), settings)
        .err()
        .unwrap();
    std::fs::remove_dir_all(&dir).ok();
    let msg = format!("{err:#}");
    assert!(
        msg.contains("services.segmenter.input_size") && msg.contains("320x320"),
        "{msg}"
    );
    assert!(
        err.downcast_ref::<provision::InputError>().is_some(),
        "an input error (not retried): {msg}"
    );
}

/// The segmenter of `family` at `size` (the export of that size, from
/// ../shared/models or what `just setup` derives into .cache/models).
fn model_at(family: YoloFamily, size: usize) -> YoloSeg {
    let cfg = SegmenterConfig {
        backend: family.backend().into(),
        model_path: Some(export_path(family, size)),
        input_size: Some(size as u32),
        classes: CLASSES.iter().map(|s| s.to_string()).collect(),
        score_threshold: Some(0.25),
        ..Default::default()
    };
    YoloSeg::load(
        init_runtime(&runtime()).unwrap(),
        YoloSettings::from_config(&cfg).unwrap(),
    )
    .unwrap()
}

/// The export of `size` in ../shared/models or where `just setup` derives
/// it (.cache/models).
fn export_path(family: YoloFamily, size: usize) -> PathBuf {
    let file = segmentation::exports::export_for(family, size)
        .unwrap()
        .file;
    [
        repo().join("../shared/models").join(file),
        repo().join(provision::DERIVED_MODELS).join(file),
    ]
    .into_iter()
    .find(|p| p.is_file())
    .unwrap_or_else(|| panic!("{file}: not in ../shared/models or .cache/models; run `just setup`"))
}

/// COCO's car, bus, truck: one network may call another's bus a truck.
fn is_vehicle(class: u32) -> bool {
    matches!(CLASSES[class as usize], "car" | "bus" | "truck")
}

/// Instances of `labels` (1-based) as pixel sets with their class.
fn instance_masks(inst: &[shared_types::Instance], labels: &[u8]) -> Vec<(u32, Vec<bool>)> {
    (0..inst.len())
        .map(|i| {
            let px = labels.iter().map(|&l| l as usize == i + 1).collect();
            (inst[i].class_id, px)
        })
        .collect()
}

fn iou(a: &[bool], b: &[bool]) -> f64 {
    let both = a.iter().zip(b).filter(|(x, y)| **x && **y).count();
    let any = a.iter().zip(b).filter(|(x, y)| **x || **y).count();
    both as f64 / any.max(1) as f64
}

#[test]
fn the_480_and_640_rewrites_agree_with_the_320_export_on_large_objects() {
    // tools/yolo_input_size.py changes only the head's anchor grid: a
    // wrong grid puts boxes (and so the box-cropped masks) elsewhere. On
    // the people and the bus of bus.jpg and the desk of the TUM room, every
    // large object (>= 2 % of the image) the 320 export finds is found by
    // the larger inputs as the same class with the mask overlapping.
    let bus = image::open(repo().join(".cache/fixtures/bus.png"))
        .expect(".cache/fixtures/bus.png: run `just fixtures`")
        .to_rgb8();
    let (bw, bh) = (bus.width() as usize, bus.height() as usize);
    let images = [("bus.png", bus.into_raw(), bw, bh), {
        let (rgb, w, h) = tum_frame("1305031229.528748.png");
        ("tum frame 0", rgb, w, h)
    }];
    // YOLO11n-seg on the desk frame: its only large detection at 320 is a
    // 'person' at 0.37 that the shared 640 file does not find either (the
    // int8-derived weights guess there); bus.jpg alone checks its grid.
    let images_of = |family| match family {
        YoloFamily::V8 => &images[..],
        YoloFamily::V11 => &images[..1],
    };
    // Both generations: YOLO11n-seg's rewrite also regenerates the cell
    // counts of its attention block.
    for (family, size) in YoloFamily::ALL
        .into_iter()
        .flat_map(|f| [(f, 480), (f, 640)])
    {
        let mut base = model_at(family, 320);
        let mut larger = model_at(family, size);
        for (name, rgb, w, h) in images_of(family) {
            let mut labels = vec![0u8; w * h];
            let small = instance_masks(&base.segment(rgb, *w, *h, &mut labels).unwrap(), &labels);
            labels.fill(0);
            let big = instance_masks(&larger.segment(rgb, *w, *h, &mut labels).unwrap(), &labels);
            let large: Vec<_> = small
                .iter()
                .filter(|(_, m)| m.iter().filter(|&&p| p).count() * 50 >= w * h)
                .collect();
            assert!(!large.is_empty(), "{name}: no large object at 320");
            for (class, mask) in large {
                // The same class, or (YOLO11n-seg: bus.jpg's bus is a
                // truck at 480 and in the shared 640 file alike) another
                // road vehicle: the network's confusion, not the grid's.
                let best = big
                    .iter()
                    .filter(|(c, _)| c == class || (is_vehicle(*c) && is_vehicle(*class)))
                    .map(|(_, m)| iou(mask, m))
                    .fold(0.0, f64::max);
                println!(
                    "{} {name} {size}: {} IoU {best:.3} with 320",
                    family.network(),
                    CLASSES[*class as usize]
                );
                assert!(
                    best >= 0.75,
                    "{} {name}: the {} found at 320 overlaps at most {best:.3} at {size}",
                    family.network(),
                    CLASSES[*class as usize]
                );
            }
        }
    }
}

/// The default export (480) keeping detections from `score` and weaker
/// ones down to `weak` on evidence (`weak_score_threshold`).
fn model_480(score: f32, weak: f32) -> YoloSeg {
    let cfg = SegmenterConfig {
        model_path: Some(export_path(YoloFamily::V8, 480)),
        classes: pipeline_config::DEFAULT_DYNAMIC_CLASSES
            .iter()
            .map(|s| s.to_string())
            .collect(),
        score_threshold: Some(score),
        weak_score_threshold: Some(weak),
        ..Default::default()
    };
    YoloSeg::load(
        init_runtime(&runtime()).unwrap(),
        YoloSettings::from_config(&cfg).unwrap(),
    )
    .unwrap()
}

/// Every 10th frame of the static shared sequence with its depth.
fn static_frames_with_depth() -> Vec<(Vec<u8>, Vec<u8>)> {
    let dir = repo().join("../shared/data/tum/rgbd_dataset_freiburg1_rpy_first300");
    let entries = datasets::source::tum_folder(&dir, 0.02).unwrap();
    entries
        .iter()
        .step_by(10)
        .map(|e| {
            let rgb = image::open(&e.rgb).unwrap().to_rgb8().into_raw();
            let mut depth = vec![0u8; 640 * 480 * 2];
            datasets::decode::decode_depth_into(e.depth.as_ref().unwrap(), (640, 480), &mut depth)
                .unwrap();
            (rgb, depth)
        })
        .collect()
}

#[test]
fn weak_detections_need_depth_or_a_followed_object_to_become_masks() {
    // Below score_threshold the network finds people that are cut by the
    // border or partly hidden, among many detections on the desk clutter
    // of the static shared room. Kept on depth evidence alone, the weak
    // ones add little area there (0.0091 of the pixels against 0.0087
    // without them, when written); kept all, they nearly triple it
    // (0.0251).
    let frames = static_frames_with_depth();
    let (w, h) = (640, 480);
    let mut strict = model_480(0.25, 0.25);
    let mut weak = model_480(0.25, 0.05);
    let mut all = model_480(0.05, 0.05);
    let masked = |labels: &[u8]| labels.iter().filter(|&&l| l > 0).count();
    let (mut area_strict, mut area_weak, mut area_all) = (0, 0, 0);
    let mut labels = vec![0u8; w * h];
    for (rgb, depth) in &frames {
        let depth = shared_types::views::DepthImage::new(depth, w, h, 5000.0).unwrap();
        labels.fill(0);
        strict
            .segment_rgbd(rgb, Some(depth), None, w, h, &mut labels)
            .unwrap();
        area_strict += masked(&labels);
        labels.fill(0);
        weak.segment_rgbd(rgb, Some(depth), None, w, h, &mut labels)
            .unwrap();
        area_weak += masked(&labels);
        labels.fill(0);
        all.segment(rgb, w, h, &mut labels).unwrap();
        area_all += masked(&labels);
    }
    let share = |a: usize| a as f64 / (frames.len() * w * h) as f64;
    println!(
        "masked share of {} static frames: {:.4} at 0.25, {:.4} weak on depth, {:.4} all down to 0.05",
        frames.len(),
        share(area_strict),
        share(area_weak),
        share(area_all)
    );
    assert!(
        share(area_weak) <= 1.25 * share(area_strict),
        "depth evidence kept clutter"
    );
    assert!(
        share(area_all) >= 2.0 * share(area_strict),
        "the weak detections are not there to reject (nothing tested)"
    );

    // A weak detection on clutter is kept where the frame before had an
    // object over it (a person followed there), and nowhere else.
    let (rgb, _) = frames
        .iter()
        .find(|(rgb, _)| {
            let mut l = vec![0u8; w * h];
            let strong = strict.segment(rgb, w, h, &mut l).unwrap().len();
            let mut l = vec![0u8; w * h];
            all.segment(rgb, w, h, &mut l).unwrap().len() > strong
        })
        .expect("a static frame with a weak detection");
    let mut plain = vec![0u8; w * h];
    let plain_n = strict.segment(rgb, w, h, &mut plain).unwrap().len();
    let mut every = vec![0u8; w * h];
    all.segment(rgb, w, h, &mut every).unwrap();
    // The frame before: an object exactly where the weak detections are.
    let previous: Vec<u8> = every
        .iter()
        .zip(&plain)
        .map(|(&e, &p)| u8::from(e > 0 && p == 0))
        .collect();
    labels.fill(0);
    let kept = weak
        .segment_rgbd(rgb, None, Some(&previous), w, h, &mut labels)
        .unwrap();
    assert!(kept.len() > plain_n, "a continued weak detection is kept");
    assert!(weak.weak_counts().continued >= (kept.len() - plain_n) as u64);
    assert!(weak.weak_counts().refused > 0, "{:?}", weak.weak_counts());
    assert!(kept.iter().skip(plain_n).all(|d| d.score < 0.25));
    let empty = vec![0u8; w * h];
    labels.fill(0);
    let alone = weak
        .segment_rgbd(rgb, None, Some(&empty), w, h, &mut labels)
        .unwrap();
    assert_eq!(alone.len(), plain_n, "without the object before, none is");
}
