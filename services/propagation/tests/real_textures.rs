//! Propagation on real textures: an elliptic "object" cut from one real TUM
//! frame moves (and grows) over another real TUM frame, whose background may
//! move too (camera motion). The propagated mask must match the object's
//! true mask.

use std::path::Path;

use propagation::newcomers::DepthImage;
use propagation::propagate::{LkPropagator, PropagatorParams};
use propagation::synthetic;
use shared_types::Instance;

const W: usize = 640;
const H: usize = 480;

fn tum(name: &str) -> image::RgbImage {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/tum/rgbd_dataset_freiburg1_rpy_first300/rgb");
    image::open(dir.join(name)).unwrap().to_rgb8()
}

fn render(
    bg: &image::RgbImage,
    tex: &image::RgbImage,
    shift: (f32, f32),
    c: (f32, f32),
    scale: f32,
) -> (Vec<u8>, Vec<bool>) {
    let r = synthetic::render(bg.as_raw(), tex.as_raw(), W, H, shift, c, scale);
    (r.rgb, r.mask)
}

fn iou(labels: &[u8], truth: &[bool]) -> f64 {
    synthetic::iou(labels, 1, truth)
}

/// The one object of these tests, as the segmenter would report it.
fn person() -> Instance {
    Instance {
        object_id: 7,
        class_id: 0,
        score: 0.9,
        bbox: [0.0; 4],
    }
}

fn prompt(p: &mut LkPropagator, rgb: &[u8], mask: &[bool]) {
    let labels: Vec<u8> = mask.iter().map(|&m| m as u8).collect();
    p.prompt_with(rgb, W, H, &labels, &[person()]);
}

/// Real time: the segmenter's masks for frame 3 come while frame 6 is
/// already propagated; the propagator starts again from frame 3's own image
/// and reaches frame 7 in one step.
#[test]
fn a_late_prompt_is_carried_forward_from_its_own_frame() {
    let (bg, tex) = (tum("1305031229.528748.png"), tum("1305031234.493831.png"));
    let centre = |k: usize| (250.0 + 6.0 * k as f32, 220.0 + 3.0 * k as f32);
    let mut p = LkPropagator::new(PropagatorParams::default());
    let mut labels = vec![0u8; W * H];
    // No prompt yet: the frames are propagated to (nothing to follow) and kept.
    for k in 0..=6 {
        let (rgb, _) = render(&bg, &tex, (0.0, 0.0), centre(k), 1.0);
        labels.fill(0);
        assert!(p
            .propagate_frame(k as u64, &rgb, None, W, H, &mut labels)
            .is_empty());
    }
    let (_, at3) = render(&bg, &tex, (0.0, 0.0), centre(3), 1.0);
    let labels3: Vec<u8> = at3.iter().map(|&m| m as u8).collect();
    let inst = person();
    assert!(
        !p.prompt_behind(99, &labels3, &[inst]),
        "frame 99 was never seen"
    );
    assert!(p.prompt_behind(3, &labels3, &[inst]));
    let (rgb7, truth7) = render(&bg, &tex, (0.0, 0.0), centre(7), 1.0);
    labels.fill(0);
    let found = p.propagate_frame(7, &rgb7, None, W, H, &mut labels);
    assert_eq!(found.len(), 1);
    let v = iou(&labels, &truth7);
    assert!(v >= 0.8, "IoU at frame 7 after a prompt on frame 3: {v}");

    // The run's first keyframe: kept while segmented, nothing propagated
    // before it; its prompt is followed into the next frame.
    let mut fresh = LkPropagator::new(PropagatorParams::default());
    let (rgb0, at0) = render(&bg, &tex, (0.0, 0.0), centre(0), 1.0);
    fresh.keep_image(0, &rgb0, W, H);
    let labels0: Vec<u8> = at0.iter().map(|&m| m as u8).collect();
    assert!(fresh.prompt_behind(0, &labels0, &[inst]));
    let (rgb1, truth1) = render(&bg, &tex, (0.0, 0.0), centre(1), 1.0);
    labels.fill(0);
    assert_eq!(
        fresh
            .propagate_frame(1, &rgb1, None, W, H, &mut labels)
            .len(),
        1
    );
    assert!(iou(&labels, &truth1) >= 0.85);
}

/// Real time on a loaded machine: the segmenter answers for frame 0 after
/// 40 more frames were propagated to, past the frames kept for any late
/// prompt (30). The frame it worked on is kept until its prompt comes, and
/// the object is carried forward through the kept frames: one LK step over
/// the 160 pixels it moved lost it (no object at frame 41).
#[test]
fn a_prompt_40_frames_late_is_carried_forward_to_the_newest_frame() {
    let (bg, tex) = (tum("1305031229.528748.png"), tum("1305031234.493831.png"));
    let centre = |k: usize| (170.0 + 4.0 * k as f32, 200.0 + 1.0 * k as f32);
    let run = |catch_up: bool| -> (usize, f64) {
        let mut p = LkPropagator::new(PropagatorParams::default());
        let mut labels = vec![0u8; W * H];
        let (rgb0, _) = render(&bg, &tex, (0.0, 0.0), centre(0), 1.0);
        p.keep_image(0, &rgb0, W, H); // routed to the segmenter: kept
        for k in 0..=40 {
            let (rgb, _) = render(&bg, &tex, (0.0, 0.0), centre(k), 1.0);
            labels.fill(0);
            p.propagate_frame(k as u64, &rgb, None, W, H, &mut labels);
        }
        let (_, at0) = render(&bg, &tex, (0.0, 0.0), centre(0), 1.0);
        let labels0: Vec<u8> = at0.iter().map(|&m| m as u8).collect();
        if catch_up {
            assert!(
                p.prompt_behind(0, &labels0, &[person()]),
                "frame 0 was kept"
            );
        } else {
            // What one step from frame 0 does: prompted on its image alone.
            let (rgb0, _) = render(&bg, &tex, (0.0, 0.0), centre(0), 1.0);
            p.prompt_with(&rgb0, W, H, &labels0, &[person()]);
        }
        let (rgb41, truth41) = render(&bg, &tex, (0.0, 0.0), centre(41), 1.0);
        labels.fill(0);
        let found = p.propagate_frame(41, &rgb41, None, W, H, &mut labels).len();
        (found, iou(&labels, &truth41))
    };
    let (found, v) = run(true);
    println!("carried forward: {found} objects, IoU {v:.3}");
    assert_eq!(found, 1);
    assert!(v >= 0.8, "IoU at frame 41 after a prompt on frame 0: {v}");
    let (found, v) = run(false);
    println!("one step: {found} objects, IoU {v:.3}");
    assert!(v < 0.5, "one step over 41 frames should not hold: IoU {v}");
}

/// Frame `k` of a fast camera turn: the background and the object move
/// left 90 px a frame; the object, first at column `x0`, walks right
/// `walk` px a frame on its own.
fn in_a_fast_turn(
    bg: &image::RgbImage,
    tex: &image::RgbImage,
    k: usize,
    x0: f32,
    walk: f32,
) -> (Vec<u8>, Vec<bool>) {
    let turn = -90.0 * k as f32;
    render(
        bg,
        tex,
        (turn, 0.0),
        (x0 + turn + walk * k as f32, 240.0),
        1.0,
    )
}

/// A late prompt while the camera turns fast: every frame kept since the
/// prompted one moved the whole image 90 px (fr1_rpy at 60 fps, the
/// propagator taking every second frame, moved it 40-100 px; LK from no
/// motion reaches about 60 px at 4 levels). Each catch-up step starts from
/// the image's own shift, so the object is kept to the newest frame (from
/// no motion, as before: lost).
#[test]
fn a_late_prompt_is_carried_through_a_fast_camera_turn() {
    let (bg, tex) = (tum("1305031229.528748.png"), tum("1305031234.493831.png"));
    let frame = |k| in_a_fast_turn(&bg, &tex, k, 560.0, 4.0);
    let mut p = LkPropagator::new(PropagatorParams::default());
    let mut labels = vec![0u8; W * H];
    p.keep_image(0, &frame(0).0, W, H);
    for k in 1..=4 {
        labels.fill(0);
        p.propagate_frame(k as u64, &frame(k).0, None, W, H, &mut labels);
    }
    let labels0: Vec<u8> = frame(0).1.iter().map(|&m| m as u8).collect();
    assert!(p.prompt_behind(0, &labels0, &[person()]));
    let (rgb5, truth5) = frame(5);
    labels.fill(0);
    let found = p.propagate_frame(5, &rgb5, None, W, H, &mut labels).len();
    let v = iou(&labels, &truth5);
    println!("after a 450 px turn: {found} objects, IoU {v:.3}");
    assert_eq!(found, 1, "the object was lost on the way");
    assert!(v >= 0.8, "IoU at frame 5 after a prompt on frame 0: {v}");
}

/// Frame to frame through a fast camera turn (90 px a frame, as where the
/// propagator takes every second or third frame of fr1_rpy at 60 fps): each
/// frame's LK starts from the image's shift plus the object's own motion.
/// From the object's last image motion alone it is lost on the first frame.
#[test]
fn follows_an_object_frame_to_frame_through_a_fast_camera_turn() {
    let (bg, tex) = (tum("1305031229.528748.png"), tum("1305031234.493831.png"));
    let frame = |k| in_a_fast_turn(&bg, &tex, k, 500.0, 5.0);
    let mut p = LkPropagator::new(PropagatorParams::default());
    let (rgb0, mask0) = frame(0);
    prompt(&mut p, &rgb0, &mask0);
    for k in 1..=4 {
        let (rgb, truth) = frame(k);
        let mut labels = vec![0u8; W * H];
        let found = p.propagate(&rgb, W, H, &mut labels).len();
        let v = iou(&labels, &truth);
        println!("frame {k}: {found} objects, IoU {v:.3}");
        assert_eq!(found, 1, "frame {k}: the object was lost");
        assert!(v >= 0.8, "frame {k}: IoU {v}");
    }
}

#[test]
fn follows_a_moving_object_over_a_static_background() {
    let (bg, tex) = (tum("1305031229.528748.png"), tum("1305031234.493831.png"));
    let mut p = LkPropagator::new(PropagatorParams::default());
    let (rgb, mask) = render(&bg, &tex, (0.0, 0.0), (250.0, 220.0), 1.0);
    prompt(&mut p, &rgb, &mask);
    for k in 1..=10 {
        let c = (250.0 + 7.0 * k as f32, 220.0 + 4.0 * k as f32);
        let (rgb, truth) = render(&bg, &tex, (0.0, 0.0), c, 1.0);
        let mut labels = vec![0u8; W * H];
        let inst = p.propagate(&rgb, W, H, &mut labels);
        assert_eq!(inst.len(), 1, "frame {k}");
        assert_eq!(inst[0].object_id, 7, "identity is kept");
        let v = iou(&labels, &truth);
        println!("frame {k}: IoU {v:.3}");
        assert!(v >= 0.85, "frame {k}: IoU {v}");
    }
}

#[test]
fn follows_an_approaching_object_while_the_camera_moves() {
    let (bg, tex) = (tum("1305031229.528748.png"), tum("1305031234.493831.png"));
    let mut p = LkPropagator::new(PropagatorParams::default());
    let (rgb, mask) = render(&bg, &tex, (0.0, 0.0), (300.0, 240.0), 1.0);
    prompt(&mut p, &rgb, &mask);
    let mut last = 0.0;
    for k in 1..=10 {
        let bgs = (-3.0 * k as f32, 1.5 * k as f32);
        let c = (300.0 + 5.0 * k as f32, 240.0 - 2.0 * k as f32);
        let (rgb, truth) = render(&bg, &tex, bgs, c, 1.0 + 0.03 * k as f32);
        let mut labels = vec![0u8; W * H];
        p.propagate(&rgb, W, H, &mut labels);
        last = iou(&labels, &truth);
        println!("frame {k}: IoU {last:.3}");
        assert!(last >= 0.75, "frame {k}: IoU {last}");
    }
    assert!(last >= 0.75);
}

#[test]
fn an_object_that_leaves_the_view_ends() {
    let (bg, tex) = (tum("1305031229.528748.png"), tum("1305031234.493831.png"));
    let mut p = LkPropagator::new(PropagatorParams::default());
    let (rgb, mask) = render(&bg, &tex, (0.0, 0.0), (560.0, 240.0), 1.0);
    prompt(&mut p, &rgb, &mask);
    let mut ended_at = None;
    for k in 1..=12 {
        let (rgb, _) = render(&bg, &tex, (0.0, 0.0), (560.0 + 12.0 * k as f32, 240.0), 1.0);
        let mut labels = vec![0u8; W * H];
        if p.propagate(&rgb, W, H, &mut labels).is_empty() {
            ended_at = Some(k);
            break;
        }
    }
    let k = ended_at.expect("the object must end once it is out of view");
    assert!(k >= 2, "ended too early at {k}");
    assert_eq!(p.objects(), 0);
}

/// An object walking in across the right border: the part that comes into
/// view continues the mask's outermost column, so the mask grows with the
/// object (without that it keeps the sliver first seen: IoU 0.60 after one
/// frame).
#[test]
fn an_object_walking_in_across_the_border_grows_into_view() {
    let (bg, tex) = (tum("1305031229.528748.png"), tum("1305031234.493831.png"));
    let mut p = LkPropagator::new(PropagatorParams::default());
    let (rgb, mask) = render(&bg, &tex, (0.0, 0.0), (675.0, 240.0), 1.0);
    let first = mask.iter().filter(|&&m| m).count();
    prompt(&mut p, &rgb, &mask);
    let mut area = first;
    for k in 1..=10 {
        let c = (675.0 - 8.0 * k as f32, 240.0);
        let (rgb, truth) = render(&bg, &tex, (0.0, 0.0), c, 1.0);
        let mut labels = vec![0u8; W * H];
        assert_eq!(p.propagate(&rgb, W, H, &mut labels).len(), 1, "frame {k}");
        let v = iou(&labels, &truth);
        area = labels.iter().filter(|&&l| l == 1).count();
        println!("frame {k}: IoU {v:.3}, {area} px");
        assert!(v >= 0.8, "frame {k}: IoU {v}");
    }
    assert!(area > 3 * first, "{first} px -> {area} px");
}

/// With depth, what comes into view across a border is taken as the
/// object's only at the object's depth: once it is wholly in view and walks
/// on, no band of background stays between it and the border (without
/// depth one does: the mask still touches the border, so it is still "cut"
/// and keeps growing from there).
#[test]
fn with_depth_an_object_that_walked_in_leaves_no_band_behind() {
    let (bg, tex) = (tum("1305031229.528748.png"), tum("1305031234.493831.png"));
    let run = |with_depth: bool| -> f64 {
        let mut p = LkPropagator::new(PropagatorParams::default());
        let (rgb, mask) = render(&bg, &tex, (0.0, 0.0), (675.0, 240.0), 1.0);
        prompt(&mut p, &rgb, &mask);
        let mut last = 0.0;
        for k in 1..=16 {
            let c = (675.0 - 16.0 * k as f32, 240.0);
            let (rgb, truth) = render(&bg, &tex, (0.0, 0.0), c, 1.0);
            // The object 1 m away, the background 2 m (5000 units a metre).
            let depth: Vec<u8> = truth
                .iter()
                .flat_map(|&m| if m { 5000u16 } else { 10000 }.to_ne_bytes())
                .collect();
            let depth = with_depth.then(|| DepthImage::new(&depth, W, H, 5000.0).unwrap());
            let mut labels = vec![0u8; W * H];
            assert_eq!(p.propagate_rgbd(&rgb, depth, W, H, &mut labels).len(), 1);
            last = iou(&labels, &truth);
        }
        last
    };
    let (with, without) = (run(true), run(false));
    println!("IoU after 16 frames: {with:.3} with depth, {without:.3} without");
    assert!(with >= 0.8, "with depth: IoU {with}");
    assert!(with > without + 0.05, "with {with}, without {without}");
}
