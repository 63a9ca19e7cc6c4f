//! YOLOv8-seg output decoding.
//!
//! `output0` is `[1, 4 + C + 32, A]`: per anchor the box (centre x, centre y,
//! width, height in input pixels), C class scores and 32 mask coefficients.
//! `output1` is `[1, 32, H, W]` mask prototypes at a quarter of the input
//! size. An instance's mask is `sigmoid(coefficients . prototypes)`, cropped
//! to its box and thresholded at 0.5. Here the mask is sampled bilinearly at
//! every image pixel inside the box (one resampling from prototype to image
//! instead of Ultralytics' two), which is what the NumPy reference does too.

use shared_types::Instance;

use crate::letterbox::Letterbox;

/// Mask coefficients per detection (YOLOv8-seg's prototypes).
pub const MASK_COEFFICIENTS: usize = 32;

/// One detection in input (letterbox) coordinates.
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    /// COCO class id.
    pub class_id: usize,
    /// Class score.
    pub score: f32,
    /// x0, y0, x1, y1 in input pixels.
    pub bbox: [f32; 4],
    /// Weights of the prototype masks.
    pub coefficients: [f32; MASK_COEFFICIENTS],
}

/// Anchors whose best class is wanted and scores at least `min_score`.
pub fn candidates(
    output0: &[f32],
    num_classes: usize,
    anchors: usize,
    min_score: f32,
    wanted: &dyn Fn(usize) -> bool,
) -> Vec<Detection> {
    let at = |row: usize, a: usize| output0[row * anchors + a];
    let mut out = Vec::new();
    for a in 0..anchors {
        let (mut best, mut score) = (0, f32::MIN);
        for c in 0..num_classes {
            let s = at(4 + c, a);
            if s > score {
                best = c;
                score = s;
            }
        }
        if score < min_score || !wanted(best) {
            continue;
        }
        let (cx, cy, w, h) = (at(0, a), at(1, a), at(2, a), at(3, a));
        let mut coefficients = [0.0; MASK_COEFFICIENTS];
        for (k, c) in coefficients.iter_mut().enumerate() {
            *c = at(4 + num_classes + k, a);
        }
        out.push(Detection {
            class_id: best,
            score,
            bbox: [cx - w / 2.0, cy - h / 2.0, cx + w / 2.0, cy + h / 2.0],
            coefficients,
        });
    }
    out
}

/// Intersection over union of two boxes (x0 y0 x1 y1).
pub fn iou(a: &[f32; 4], b: &[f32; 4]) -> f32 {
    let iw = (a[2].min(b[2]) - a[0].max(b[0])).max(0.0);
    let ih = (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
    let inter = iw * ih;
    let area = |r: &[f32; 4]| (r[2] - r[0]).max(0.0) * (r[3] - r[1]).max(0.0);
    let union = area(a) + area(b) - inter;
    if union <= 0.0 {
        0.0
    } else {
        inter / union
    }
}

/// Class-wise non-maximum suppression: highest score first; a box is dropped
/// when it overlaps a kept box of the same class by more than `max_iou`.
pub fn nms(mut dets: Vec<Detection>, max_iou: f32, max_keep: usize) -> Vec<Detection> {
    dets.sort_by(|a, b| b.score.total_cmp(&a.score));
    let mut kept: Vec<Detection> = Vec::new();
    for d in dets {
        if kept.len() >= max_keep {
            break;
        }
        if kept
            .iter()
            .all(|k| k.class_id != d.class_id || iou(&k.bbox, &d.bbox) <= max_iou)
        {
            kept.push(d);
        }
    }
    kept
}

/// Prototype masks `[32, ph, pw]`.
pub struct Prototypes<'a> {
    /// The values, prototype by prototype, row by row.
    pub data: &'a [f32],
    /// Rows of one prototype.
    pub height: usize,
    /// Columns of one prototype.
    pub width: usize,
}

/// Paints the mask of each detection that `keep` accepts (given the
/// detection and its mask's pixels not yet taken, as indices into the
/// image) into `labels` (`width*height`, the `i`-th kept instance as
/// `i + 1`; a pixel keeps the first, highest-scoring, instance) and returns
/// the kept instances in image coordinates.
pub fn paint_masks(
    dets: &[Detection],
    protos: &Prototypes,
    lb: &Letterbox,
    width: usize,
    height: usize,
    labels: &mut [u8],
    mut keep: impl FnMut(&Detection, &[u32]) -> bool,
) -> Vec<Instance> {
    let (pw, ph) = (protos.width, protos.height);
    let plane = pw * ph;
    let stride = lb.size as f32 / pw as f32; // input pixels per prototype pixel
    let mut instances = Vec::new();
    let mut logits = vec![0.0f32; plane];
    let mut pixels = Vec::new();
    for d in dets {
        if instances.len() >= 254 {
            break;
        }
        // Mask logits on the prototype grid, only inside the (padded) box.
        let gx0 = ((d.bbox[0] / stride).floor().max(0.0) as usize).min(pw);
        let gy0 = ((d.bbox[1] / stride).floor().max(0.0) as usize).min(ph);
        let gx1 = ((d.bbox[2] / stride).ceil() as usize + 1).min(pw);
        let gy1 = ((d.bbox[3] / stride).ceil() as usize + 1).min(ph);
        for gy in gy0..gy1 {
            for gx in gx0..gx1 {
                let o = gy * pw + gx;
                let mut v = 0.0;
                for (k, c) in d.coefficients.iter().enumerate() {
                    v += c * protos.data[k * plane + o];
                }
                logits[o] = v;
            }
        }
        let sample = |x: f32, y: f32| -> f32 {
            // Prototype pixel centres sit at (g + 0.5) * stride.
            let fx = (x / stride - 0.5).clamp(gx0 as f32, (gx1.max(gx0 + 1) - 1) as f32);
            let fy = (y / stride - 0.5).clamp(gy0 as f32, (gy1.max(gy0 + 1) - 1) as f32);
            let (x0, y0) = (fx as usize, fy as usize);
            let (x1, y1) = ((x0 + 1).min(gx1 - 1), (y0 + 1).min(gy1 - 1));
            let (wx, wy) = (fx - x0 as f32, fy - y0 as f32);
            let l = |xx: usize, yy: usize| logits[yy * pw + xx];
            let top = l(x0, y0) * (1.0 - wx) + l(x1, y0) * wx;
            let bottom = l(x0, y1) * (1.0 - wx) + l(x1, y1) * wx;
            top * (1.0 - wy) + bottom * wy
        };
        // The box in image pixels.
        let (ix0, iy0) = lb.to_image(d.bbox[0], d.bbox[1]);
        let (ix1, iy1) = lb.to_image(d.bbox[2], d.bbox[3]);
        let (ix0, iy0) = (ix0.clamp(0.0, width as f32), iy0.clamp(0.0, height as f32));
        let (ix1, iy1) = (ix1.clamp(0.0, width as f32), iy1.clamp(0.0, height as f32));
        pixels.clear();
        for y in iy0.floor() as usize..(iy1.ceil() as usize).min(height) {
            for x in ix0.floor() as usize..(ix1.ceil() as usize).min(width) {
                let (lx, ly) = lb.to_input(x as f32 + 0.5, y as f32 + 0.5);
                if lx < d.bbox[0] || lx >= d.bbox[2] || ly < d.bbox[1] || ly >= d.bbox[3] {
                    continue;
                }
                // sigmoid(v) > 0.5  <=>  v > 0
                if labels[y * width + x] == 0 && sample(lx, ly) > 0.0 {
                    pixels.push((y * width + x) as u32);
                }
            }
        }
        if !keep(d, &pixels) {
            continue;
        }
        let label = (instances.len() + 1) as u8;
        for &i in &pixels {
            labels[i as usize] = label;
        }
        instances.push(Instance {
            object_id: instances.len() as u32,
            class_id: d.class_id as u32,
            score: d.score,
            bbox: [ix0, iy0, ix1, iy1],
        });
    }
    instances
}

#[cfg(test)]
mod tests {
    use super::*;

    fn det(class_id: usize, score: f32, bbox: [f32; 4]) -> Detection {
        Detection {
            class_id,
            score,
            bbox,
            coefficients: [0.0; MASK_COEFFICIENTS],
        }
    }

    #[test]
    fn nms_is_per_class() {
        let a = det(0, 0.9, [0.0, 0.0, 10.0, 10.0]);
        let b = det(0, 0.8, [1.0, 1.0, 11.0, 11.0]); // same class, overlaps a
        let c = det(2, 0.7, [1.0, 1.0, 11.0, 11.0]); // other class: kept
        let kept = nms(vec![b, c.clone(), a.clone()], 0.5, 100);
        assert_eq!(kept, vec![a, c]);
    }

    #[test]
    fn candidates_take_the_best_class_and_threshold() {
        // 2 anchors, 3 classes, rows: 4 box + 3 scores + 32 coefficients.
        let anchors = 2;
        let mut out = vec![0.0f32; (4 + 3 + MASK_COEFFICIENTS) * anchors];
        let set = |o: &mut Vec<f32>, row: usize, a: usize, v: f32| o[row * anchors + a] = v;
        set(&mut out, 0, 0, 50.0);
        set(&mut out, 1, 0, 60.0);
        set(&mut out, 2, 0, 20.0);
        set(&mut out, 3, 0, 10.0);
        set(&mut out, 5, 0, 0.9); // class 1
        set(&mut out, 4, 1, 0.3); // anchor 1: below threshold
        let got = candidates(&out, 3, anchors, 0.5, &|_| true);
        assert_eq!(got.len(), 1);
        assert_eq!(got[0].class_id, 1);
        assert_eq!(got[0].bbox, [40.0, 55.0, 60.0, 65.0]);
        assert!(candidates(&out, 3, anchors, 0.5, &|c| c != 1).is_empty());
    }

    #[test]
    fn masks_follow_prototypes_inside_the_box_only() {
        // One prototype channel that is positive on the left half.
        let (pw, ph) = (8, 8);
        let mut data = vec![0.0f32; MASK_COEFFICIENTS * pw * ph];
        for y in 0..ph {
            for x in 0..pw {
                data[y * pw + x] = if x < 4 { 1.0 } else { -1.0 };
            }
        }
        let protos = Prototypes {
            data: &data,
            height: ph,
            width: pw,
        };
        let lb = Letterbox::new(32, 32, 32); // identity letterbox, stride 4
        let mut d = det(0, 0.9, [0.0, 0.0, 24.0, 32.0]);
        d.coefficients[0] = 1.0;
        let mut labels = vec![0u8; 32 * 32];
        let inst = paint_masks(&[d], &protos, &lb, 32, 32, &mut labels, |_, _| true);
        assert_eq!(inst.len(), 1);
        assert_eq!(inst[0].bbox, [0.0, 0.0, 24.0, 32.0]);
        // Left half labelled, right half and outside the box not.
        assert_eq!(labels[5 * 32 + 3], 1);
        assert_eq!(labels[5 * 32 + 14], 1);
        assert_eq!(labels[5 * 32 + 17], 0);
        assert_eq!(labels[5 * 32 + 28], 0);
        let count = labels.iter().filter(|&&l| l == 1).count();
        assert!((15 * 32..=17 * 32).contains(&count), "{count}");
    }

    #[test]
    fn a_detection_left_out_leaves_no_gap_in_the_labels() {
        // Three boxes on a mask that is everywhere positive; the middle
        // one is refused: the third becomes instance 2, labelled 2.
        let data = vec![1.0f32; MASK_COEFFICIENTS * 8 * 8];
        let protos = Prototypes {
            data: &data,
            height: 8,
            width: 8,
        };
        let lb = Letterbox::new(32, 32, 32);
        let mut dets = vec![
            det(0, 0.9, [0.0, 0.0, 8.0, 8.0]),
            det(0, 0.1, [10.0, 10.0, 18.0, 18.0]),
            det(0, 0.8, [20.0, 20.0, 28.0, 28.0]),
        ];
        for d in &mut dets {
            d.coefficients[0] = 1.0;
        }
        let mut labels = vec![0u8; 32 * 32];
        let mut seen = Vec::new();
        let inst = paint_masks(&dets, &protos, &lb, 32, 32, &mut labels, |d, px| {
            seen.push(px.len());
            d.score > 0.5
        });
        assert_eq!(
            seen,
            vec![64, 64, 64],
            "each mask's free pixels are offered"
        );
        assert_eq!(inst.len(), 2);
        assert_eq!((inst[1].object_id, inst[1].score), (1, 0.8));
        assert_eq!(labels[4 * 32 + 4], 1);
        assert_eq!(labels[14 * 32 + 14], 0);
        assert_eq!(labels[24 * 32 + 24], 2);
    }
}
