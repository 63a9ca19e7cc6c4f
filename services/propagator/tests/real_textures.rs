//! Propagation on real textures: an elliptic "object" cut from one real TUM
//! frame moves (and grows) over another real TUM frame, whose background may
//! move too (camera motion). The propagated mask must match the object's
//! true mask.

use std::path::Path;

use propagator::propagate::{LkPropagator, PropagatorParams};
use propagator::synthetic;
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

fn prompt(p: &mut LkPropagator, rgb: &[u8], mask: &[bool]) {
    let labels: Vec<u8> = mask.iter().map(|&m| m as u8).collect();
    let inst = Instance {
        object_id: 7,
        class_id: 0,
        score: 0.9,
        bbox: [0.0; 4],
    };
    p.prompt_with(rgb, W, H, &labels, &[inst]);
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
