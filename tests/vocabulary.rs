//! The shipped bag-of-words vocabulary is what the README's command makes:
//! `dynslam vocab train` on the shared TUM frames reproduces
//! assets/vocabulary/orb-k10-l4.vocab byte for byte (and its pinned
//! SHA-256); bad training input is a clear error.

mod common;
use common::*;
use std::path::Path;
use std::process::Command;

fn repo() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn the_shipped_vocabulary_is_reproduced_by_the_readme_command() {
    let dir = scratch("vocab-train");
    let out = dir.join("v.vocab");
    let t = std::time::Instant::now();
    let r = Command::new(dynslam())
        .args(["vocab", "train", "--out"])
        .arg(&out)
        .arg(shared_tum().join("rgb"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&r.stderr);
    assert!(r.status.success(), "{stderr}");
    assert!(
        stderr.contains("ORB features of 300/300 images"),
        "progress: {stderr}"
    );
    assert!(stderr.contains("k-means level 4/4"), "progress: {stderr}");
    eprintln!("trained in {:.1} s", t.elapsed().as_secs_f64());
    let shipped = repo().join("assets/vocabulary/orb-k10-l4.vocab");
    assert!(
        std::fs::read(&out).unwrap() == std::fs::read(&shipped).unwrap(),
        "the README's command no longer reproduces {}: retrain it and update its .sha256",
        shipped.display()
    );
    let pinned =
        std::fs::read_to_string(repo().join("assets/vocabulary/orb-k10-l4.vocab.sha256")).unwrap();
    let printed = String::from_utf8_lossy(&r.stdout);
    let hash = |s: &str| s.split_whitespace().next().unwrap_or("").to_string();
    assert_eq!(hash(&printed), hash(&pinned), "stdout: {printed}");
    let info = Command::new(dynslam())
        .args(["vocab", "info"])
        .arg(&shipped)
        .output()
        .unwrap();
    let info = String::from_utf8_lossy(&info.stdout);
    assert!(
        info.contains("9896 words (k 10, L 4)") && info.contains(&hash(&pinned)),
        "{info}"
    );
}

#[test]
fn bad_training_input_is_named() {
    let dir = scratch("vocab-bad");
    let train = |args: &[&str]| {
        let r = Command::new(dynslam())
            .args(["vocab", "train", "--out"])
            .arg(dir.join("v.vocab"))
            .args(args)
            .output()
            .unwrap();
        assert_eq!(r.status.code(), Some(1));
        String::from_utf8_lossy(&r.stderr).to_string()
    };
    let missing = dir.join("nothing-here");
    assert!(train(&[missing.to_str().unwrap()]).contains("no such image file or folder"));
    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    assert!(train(&[empty.to_str().unwrap()]).contains("has no .png files"));
    let not_png = dir.join("notes.png");
    std::fs::write(&not_png, "not an image").unwrap();
    let e = train(&[not_png.to_str().unwrap()]);
    assert!(
        e.contains("cannot read image") && e.contains("notes.png"),
        "{e}"
    );
    let tiny = dir.join("tiny.png");
    image::RgbImage::new(20, 20).save(&tiny).unwrap();
    assert!(train(&[tiny.to_str().unwrap()]).contains("too small for ORB"));
    let broken = dir.join("broken.vocab");
    std::fs::write(&broken, b"DSLAMVOC\x01\0\0\0").unwrap();
    let r = Command::new(dynslam())
        .args(["vocab", "info"])
        .arg(&broken)
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&r.stderr);
    assert!(e.contains("broken.vocab") && e.contains("truncated"), "{e}");
}
