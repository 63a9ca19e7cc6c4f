//! `dynslam synth` on the shared TUM sequence: the output is a TUM folder the
//! pipeline plays and `dynslam eval` accepts; ground-truth masks are exactly
//! the changed pixels; depth under a person is the person's depth; the
//! camera's ground truth is byte-identical; a seed reproduces the scene.

mod common;
use common::*;
use std::path::Path;
use std::process::Command;

fn synth(out: &Path, extra: &[&str]) -> std::process::Output {
    Command::new(dynslam())
        .arg("synth")
        .arg(shared_tum())
        .arg(out)
        .args(["--limit", "60", "--objects", "3"])
        .args(if extra.is_empty() {
            &["--seed", "4"]
        } else {
            extra
        })
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap()
}

#[test]
fn synthesised_sequence_has_exact_ground_truth() {
    let dir = scratch("synth");
    let out = dir.join("dyn");
    let o = synth(&out, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        std::fs::read(out.join("groundtruth.txt")).unwrap(),
        std::fs::read(shared_tum().join("groundtruth.txt")).unwrap()
    );
    let record: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("objects.json")).unwrap()).unwrap();
    let frames = record["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 60);
    let (mut person_px, mut frames_with_people) = (0usize, 0usize);
    let mut hidden_px = 0u64;
    for (i, f) in frames.iter().enumerate() {
        // Output files keep the input's names (rgb/<stamp>.png, depth/<stamp>.png).
        let rgb_in = image::open(shared_tum().join(f["rgb"].as_str().unwrap()))
            .unwrap()
            .to_rgb8();
        let rgb_out = image::open(out.join(f["rgb"].as_str().unwrap()))
            .unwrap()
            .to_rgb8();
        let depth_in = image::open(shared_tum().join(f["depth"].as_str().unwrap()))
            .unwrap()
            .into_luma16();
        let depth_out = image::open(out.join(f["depth"].as_str().unwrap()))
            .unwrap()
            .into_luma16();
        let mask = image::open(out.join(f["mask"].as_str().unwrap()))
            .unwrap()
            .to_luma8();
        let depth_of = |id: u8| {
            let o = f["objects"]
                .as_array()
                .unwrap()
                .iter()
                .find(|o| o["id"] == id)
                .unwrap();
            (o["depth_m"].as_f64().unwrap() * 5000.0).round() as u16
        };
        let mut here = 0;
        for (k, &id) in mask.as_raw().iter().enumerate() {
            if id == 0 {
                assert_eq!(
                    depth_out.as_raw()[k],
                    depth_in.as_raw()[k],
                    "frame {i} pixel {k}"
                );
                assert_eq!(
                    rgb_out.as_raw()[3 * k..3 * k + 3],
                    rgb_in.as_raw()[3 * k..3 * k + 3]
                );
            } else {
                here += 1;
                let d = depth_of(id);
                assert_eq!(
                    depth_out.as_raw()[k],
                    d,
                    "frame {i} pixel {k}: person depth"
                );
                // Drawn only where the person is in front of the scene.
                let scene = depth_in.as_raw()[k];
                assert!(
                    scene == 0 || d < scene,
                    "frame {i} pixel {k} drawn behind the scene"
                );
            }
        }
        // Every pixel that changed belongs to a person.
        let changed = (0..mask.as_raw().len())
            .filter(|&k| {
                rgb_out.as_raw()[3 * k..3 * k + 3] != rgb_in.as_raw()[3 * k..3 * k + 3]
                    || depth_out.as_raw()[k] != depth_in.as_raw()[k]
            })
            .count();
        assert!(changed <= here);
        let listed: u64 = f["objects"]
            .as_array()
            .unwrap()
            .iter()
            .map(|o| o["visible_px"].as_u64().unwrap())
            .sum();
        assert_eq!(
            listed as usize, here,
            "frame {i}: objects.json pixel counts"
        );
        // The unhidden silhouette holds at least what is visible of it.
        for o in f["objects"].as_array().unwrap() {
            let full = o["unoccluded_px"].as_u64().unwrap();
            assert!(full >= o["visible_px"].as_u64().unwrap(), "frame {i}: {o}");
        }
        hidden_px += f["objects"]
            .as_array()
            .unwrap()
            .iter()
            .map(|o| o["unoccluded_px"].as_u64().unwrap() - o["visible_px"].as_u64().unwrap())
            .sum::<u64>();
        person_px += here;
        frames_with_people += (here > 0) as usize;
    }
    assert!(
        frames_with_people > 10,
        "people seen in {frames_with_people} of 60 frames"
    );
    assert!(person_px > 100_000);
    // The scene hides parts of people walking through it (scene occlusion).
    assert!(hidden_px > 0, "nothing of the people was hidden");

    // The same seed gives the same scene, another seed another one.
    let again = dir.join("again");
    assert!(synth(&again, &[]).status.success());
    let other = dir.join("other");
    assert!(synth(&other, &["--seed", "5"]).status.success());
    let masks = |d: &Path| {
        frames
            .iter()
            .map(|f| std::fs::read(d.join(f["mask"].as_str().unwrap())).unwrap())
            .collect::<Vec<_>>()
    };
    assert_eq!(masks(&out), masks(&again));
    assert_ne!(masks(&out), masks(&other));

    // An existing non-empty folder is refused, not overwritten.
    let o = synth(&out, &[]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("not empty"));

    // The pipeline plays it; eval accepts its ground truth.
    let config = write_config(&dir, "[services.slam]\nbackend = \"scripted\"\n[services.segmenter]\nbackend = \"none\"\n[services.propagator]\nbackend = \"none\"\n");
    let r = run(
        &out,
        &config,
        &dir.join("runs"),
        &format!("syn{}", std::process::id()),
        &["--limit", "20"],
    );
    assert!(r.success(), "{}", r.stderr());
    assert_eq!(read_rows(&r.run_dir).len(), 20);
    let e = Command::new(dynslam())
        .args(["eval", "--json", "--gt"])
        .arg(out.join("groundtruth.txt"))
        .arg("--est")
        .arg(out.join("groundtruth.txt"))
        .output()
        .unwrap();
    assert!(e.status.success(), "{}", String::from_utf8_lossy(&e.stderr));
}

#[test]
fn bad_synth_options_and_inputs_are_named() {
    let dir = scratch("synth-bad");
    let o = synth(&dir.join("a"), &["--speed=0"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--speed"));
    let o = Command::new(dynslam())
        .args(["synth", "/nonexistent/tum"])
        .arg(dir.join("b"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("/nonexistent/tum"));
    // A TUM folder without ground truth cannot place people in the world.
    let tum = small_tum(&dir, 5);
    let o = Command::new(dynslam())
        .arg("synth")
        .arg(&tum)
        .arg(dir.join("c"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("groundtruth.txt"), "{err}");
    let o = synth(&dir.join("d"), &["--behaviour", "sideways"]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--behaviour"));
}

/// `--behaviour mixed`: the people take turns at walking across, toward and
/// away, and across with stops, and objects.json says which.
#[test]
fn mixed_behaviours_are_recorded_and_move_as_named() {
    let dir = scratch("synth-mixed");
    let out = dir.join("mixed");
    let o = synth(&out, &["--behaviour", "mixed", "--occlusion", "none"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let record: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("objects.json")).unwrap()).unwrap();
    let behaviours: Vec<&str> = record["walkers"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w["behaviour"].as_str().unwrap())
        .collect();
    assert_eq!(behaviours, ["across", "toward-away", "stop-and-go"]);
    assert_eq!(record["options"]["behaviours"], "mixed");
    // The toward-away walker's image height changes while its place
    // across the image stays about the same.
    let heights: Vec<f64> = record["frames"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|f| f["objects"].as_array().unwrap().clone())
        .filter(|o| o["id"] == 2)
        .map(|o| o["height_px"].as_f64().unwrap())
        .collect();
    assert!(heights.len() > 10, "{heights:?}");
    let (lo, hi) = heights
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &h| (a.min(h), b.max(h)));
    assert!(hi > 1.2 * lo, "toward-away heights {lo:.0}..{hi:.0} px");
    std::fs::remove_dir_all(&dir).ok();
}

/// The mask-quality targets on the shared TUM frames with people
/// passing in front of the scene (`--occlusion none`, what `just
/// eval-masks` reports first): real YOLOv8n-seg on keyframes (IoU >= 0.8),
/// the LK propagator on the 10 frames after each (IoU >= 0.7 over the people
/// present on the keyframe; 0.830 / 0.740 when written). `--save` writes
/// every frame's labels and the per-person scores.
#[test]
fn masks_on_people_passing_in_front_of_the_tum_scene_meet_the_targets() {
    let dir = scratch("synth-front");
    let out = dir.join("front");
    let o = Command::new(dynslam())
        .arg("synth")
        .arg(shared_tum())
        .arg(&out)
        .args(["--objects", "3", "--seed", "5", "--occlusion", "none"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let saved = dir.join("labels");
    let o = Command::new(dynslam())
        .arg("masks-eval")
        .arg(&out)
        .arg("--json")
        .arg("--save")
        .arg(&saved)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let scores: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let score = |key: &str| json_f64(&scores, key);
    assert!(score("segmenter_iou") >= 0.8, "{scores}");
    assert!(score("propagator_iou_prompted") >= 0.7, "{scores}");
    assert!(score("segmenter_samples") >= 20.0, "{scores}");
    let table = std::fs::read_to_string(saved.join("scores.csv")).unwrap();
    let rows = table.lines().count() - 1;
    assert_eq!(
        rows as f64,
        score("segmenter_samples") + score("propagator_samples"),
        "one row per scored person-frame"
    );
    let labels = image::open(saved.join("0000.png")).unwrap().to_luma8();
    assert_eq!(labels.dimensions(), (640, 480));
    assert!(labels.pixels().any(|p| p.0[0] != 0), "frame 0 has a person");

    // By cause: every scored person-frame is in one cause or `plain`; only
    // propagated frames have people who entered since their keyframe.
    let samples = |side: &str, cause: &str| scores[side][cause]["samples"].as_u64().unwrap();
    let seg: u64 = ["border_cut", "small", "occluded", "plain"]
        .iter()
        .map(|c| samples("segmenter_by_cause", c))
        .sum();
    assert!(seg >= score("segmenter_samples") as u64, "{scores}");
    assert!(samples("segmenter_by_cause", "plain") > 0, "{scores}");
    assert_eq!(samples("segmenter_by_cause", "entered"), 0, "{scores}");
    assert_eq!(scores["ignore_regions"], false);

    // Early segmenter requests (on by default) against the same sequence
    // with them off: people who come into view are masked sooner (7 of 12
    // within 3 frames against 2 of 12 when written) and the propagated
    // frames are better for it (0.662 against 0.585).
    let off_config = dir.join("no-early.toml");
    std::fs::write(&off_config, "[routing]\nearly_segment_requests = false\n").unwrap();
    let o = Command::new(dynslam())
        .arg("masks-eval")
        .arg(&out)
        .arg("--json")
        .arg("--config")
        .arg(&off_config)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let off: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let in_time = |s: &serde_json::Value| s["entries"]["masked_in_time"].as_u64().unwrap();
    eprintln!(
        "entries masked within 3 frames: {} of {} with early requests, {} of {} without; propagator IoU {:.3} / {:.3}; early segments {}",
        in_time(&scores),
        scores["entries"]["count"],
        in_time(&off),
        off["entries"]["count"],
        score("propagator_iou"),
        json_f64(&off, "propagator_iou"),
        scores["early_segments"]
    );
    assert_eq!(scores["entries"]["count"], off["entries"]["count"]);
    assert!(
        scores["entries"]["count"].as_u64().unwrap() >= 10,
        "{scores}"
    );
    assert!(scores["early_segments"].as_u64().unwrap() > 0, "{scores}");
    assert_eq!(off["early_segments"], 0, "{off}");
    assert!(in_time(&scores) >= 5, "{scores}");
    assert!(in_time(&scores) > in_time(&off), "{scores}\n{off}");
    assert!(
        score("propagator_iou") > json_f64(&off, "propagator_iou"),
        "{scores}\n{off}"
    );

    // Ignore regions: the whole image ignored leaves nobody to score; an
    // ignore image of another size is an error naming it.
    let eval_limited = || {
        Command::new(dynslam())
            .arg("masks-eval")
            .arg(&out)
            .args(["--json", "--limit", "12"])
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .unwrap()
    };
    image::GrayImage::from_pixel(640, 480, image::Luma([1]))
        .save(out.join("ignore.png"))
        .unwrap();
    let o = eval_limited();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ignored: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(ignored["ignore_regions"], true);
    assert_eq!(ignored["segmenter_samples"], 0, "{ignored}");
    assert_eq!(ignored["propagator_samples"], 0, "{ignored}");
    image::GrayImage::new(320, 240)
        .save(out.join("ignore.png"))
        .unwrap();
    let o = eval_limited();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("ignore.png") && err.contains("320x240"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// Issue 21's segmenter and propagator targets on the mixed behaviours
/// (toward and away, stop and go, crossing, entering; what `just
/// eval-masks` reports last): keyframe IoU >= 0.75 and propagated IoU >=
/// 0.65 with the shipped settings. Weak detections kept
/// on evidence (`weak_score_threshold`) are what brings it there: people
/// leaving at the border, at scores 0.05-0.25, continue an object of the
/// frame before (0.756 against 0.706 without them when written). The
/// pipeline's segmenter gets the frame before's masks over the masks topic.
#[test]
fn weak_detections_and_the_unseen_view_bring_the_mixed_behaviours_to_the_targets() {
    let dir = scratch("synth-mixed");
    let out = dir.join("mixed");
    let o = Command::new(dynslam())
        .arg("synth")
        .arg(shared_tum())
        .arg(&out)
        .args(["--objects", "3", "--seed", "5", "--occlusion", "none"])
        .args(["--behaviour", "mixed"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let eval = |config: Option<&Path>| {
        let mut cmd = Command::new(dynslam());
        cmd.arg("masks-eval").arg(&out).arg("--json");
        if let Some(c) = config {
            cmd.arg("--config").arg(c);
        }
        let o = cmd
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice::<serde_json::Value>(&o.stdout).unwrap()
    };
    let shipped = eval(None);
    let strict_config = dir.join("strict.toml");
    std::fs::write(
        &strict_config,
        "[services.segmenter]\nweak_score_threshold = 0.25\n",
    )
    .unwrap();
    let strict = eval(Some(&strict_config));
    let (with, without) = (
        json_f64(&shipped, "segmenter_iou"),
        json_f64(&strict, "segmenter_iou"),
    );
    eprintln!(
        "mixed behaviours, keyframe IoU {with:.3} with weak detections, {without:.3} without; propagator {:.3} / {:.3}",
        json_f64(&shipped, "propagator_iou"),
        json_f64(&strict, "propagator_iou")
    );
    assert!(with >= 0.75, "{shipped}");
    assert!(with > without + 0.02, "{shipped}\n{strict}");

    // Issue 21's propagated-frame target on the same sequence: >= 0.65.
    // What brings it there is the view the segmenter has not seen
    // (`routing.unseen_view_share`): people the camera's turn brings into
    // view show no motion of their own to ask with (0.693 against 0.648
    // without it when written; entries in time 8 against 6 of 10).
    let unseen_off_config = dir.join("unseen-off.toml");
    std::fs::write(&unseen_off_config, "[routing]\nunseen_view_share = 0.0\n").unwrap();
    let unseen_off = eval(Some(&unseen_off_config));
    let in_time = |s: &serde_json::Value| s["entries"]["masked_in_time"].as_u64().unwrap();
    eprintln!(
        "mixed behaviours, propagator IoU {:.3} / {:.3} with / without the unseen view; entries in time {} / {} of {}",
        json_f64(&shipped, "propagator_iou"),
        json_f64(&unseen_off, "propagator_iou"),
        in_time(&shipped),
        in_time(&unseen_off),
        shipped["entries"]["count"]
    );
    assert!(json_f64(&shipped, "propagator_iou") >= 0.65, "{shipped}");
    assert!(
        json_f64(&shipped, "propagator_iou") > json_f64(&unseen_off, "propagator_iou"),
        "{shipped}\n{unseen_off}"
    );
    assert!(
        in_time(&shipped) > in_time(&unseen_off),
        "{shipped}\n{unseen_off}"
    );

    // In the pipeline (separate processes): the segmenter reads the masks
    // published before each keyframe from the masks topic and keeps weak
    // detections that continue them (its exit log counts them).
    let o = Command::new(dynslam())
        .arg("run")
        .arg(&out)
        .arg("--output-dir")
        .arg(dir.join("runs"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{log}");
    let continued: u64 = log
        .split("weak detections (score 0.05-0.25) kept: ")
        .nth(1)
        .and_then(|rest| rest.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no weak-detection count in the log:\n{log}"));
    assert!(continued > 0, "{log}");
    std::fs::remove_dir_all(&dir).ok();
}
