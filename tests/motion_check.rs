//! The SLAM's motion check on a mover no class list names: a textured box
//! carried through the shared fr1 room (`dynslam synth --boxes`), tracked
//! by the SLAM library alone without any mask. Issue 21's bar: the check
//! finds the box in >= 80 % of the frames where it covers >= 2000 px
//! (85.6 % here; `just eval-motion` runs it alone).
//! (That it removes < 1 % of the features of the static sequence and keeps
//! its ATE is slam-core's `core_tum` test.)

mod common;
use common::*;

use scenes::composite::Pinhole;
use scenes::synth::synthesize;
use scenes::walkers::{Occlusion, WalkOptions};
use slam_core::{Camera, SlamParams, System};

/// Pixels a moving region covers that are the box's, and its own area.
fn overlap(
    region: &slam_core::tracking::motion_check::MovingRegion,
    movers: &[u8],
    w: usize,
) -> (usize, usize) {
    let h = movers.len() / w;
    let x0 = region.min[0].max(0.0) as usize;
    let y0 = region.min[1].max(0.0) as usize;
    let x1 = (region.max[0].max(0.0) as usize).min(w);
    let y1 = (region.max[1].max(0.0) as usize).min(h);
    let mut on_box = 0;
    for y in y0..y1 {
        for x in x0..x1 {
            on_box += (movers[y * w + x] != 0) as usize;
        }
    }
    (on_box, (x1.saturating_sub(x0)) * (y1.saturating_sub(y0)))
}

#[test]
fn a_carried_box_is_found_by_the_motion_check_without_any_mask() {
    let seq = scratch("motion-box").join("seq");
    let options = WalkOptions {
        objects: 0,
        boxes: 1,
        speed_mps: 1.0,
        near_m: 0.9,
        far_m: 1.3,
        seed: 4,
        occlusion: Occlusion::None,
        ..Default::default()
    };
    let fr1 = Pinhole {
        fx: 517.3,
        fy: 516.5,
        cx: 318.6,
        cy: 255.3,
    };
    synthesize(&shared_tum(), &seq, &fr1, 5000.0, &options, None).unwrap();
    let frames = camera_reader::source::tum_folder(&seq, 0.02).unwrap();
    let movers: Vec<std::path::PathBuf> = std::fs::read_to_string(seq.join("movers.txt"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| seq.join(l.split_whitespace().nth(1).unwrap()))
        .collect();
    assert_eq!(movers.len(), frames.len());

    let params = SlamParams {
        motion_check: true,
        ..SlamParams::default()
    };
    let mut sys = System::new(params, Camera::tum_fr1());
    let (mut eligible, mut found, mut dropped, mut features) = (0, 0, 0u64, 0u64);
    let (mut false_regions, mut region_px, mut region_on_box) = (0, 0, 0);
    for (f, movers_png) in frames.iter().zip(&movers) {
        let rgb = image::open(&f.rgb).unwrap().to_rgb8();
        let depth = image::open(f.depth.as_ref().unwrap()).unwrap().to_luma16();
        let r = sys.track_rgbd(rgb.as_raw(), depth.as_raw(), None, 640, 480, f.timestamp);
        let truth = image::open(movers_png).unwrap().to_luma8();
        let box_px = truth.as_raw().iter().filter(|&&l| l != 0).count();
        // Found: the regions cover at least half of the box (its features
        // there are dropped). Precision: how much of the regions is box.
        let mut covered = vec![false; truth.as_raw().len()];
        for region in sys.moving_regions() {
            let (on_box, area) = overlap(region, truth.as_raw(), 640);
            region_px += area;
            region_on_box += on_box;
            false_regions += (on_box == 0) as usize;
            for y in region.min[1].max(0.0) as usize..(region.max[1].max(0.0) as usize).min(480) {
                for x in region.min[0].max(0.0) as usize..(region.max[0].max(0.0) as usize).min(640)
                {
                    covered[y * 640 + x] = true;
                }
            }
        }
        let box_covered = truth
            .as_raw()
            .iter()
            .zip(&covered)
            .filter(|(l, c)| **l != 0 && **c)
            .count();
        let hit = box_covered * 2 >= box_px && box_px > 0;
        dropped += r.counts.features_moving as u64;
        features += (r.counts.features + r.counts.features_moving) as u64;
        if box_px >= 2000 {
            eligible += 1;
            found += hit as usize;
        }
    }
    let share = found as f64 / eligible.max(1) as f64;
    eprintln!(
        "box found (half of it or more in moving regions) in {found} of {eligible} frames where it covers >= 2000 px ({:.1} %); {dropped} of {features} features dropped; {:.1} % of the regions' area is box; {false_regions} regions off the box",
        100.0 * share,
        100.0 * region_on_box as f64 / region_px.max(1) as f64
    );
    assert!(
        eligible >= 30,
        "the box covers >= 2000 px in only {eligible} frames"
    );
    assert!(
        share >= 0.8,
        "found in {:.1} % of the frames",
        100.0 * share
    );
}
