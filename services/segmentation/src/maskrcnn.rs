//! Mask R-CNN backend for the standard torchvision ONNX export, the original
//! work's segmenter, for users who have those weights (they cannot be
//! obtained here; the decoding is tested on tiny generated graphs with the
//! same signature, see tests/reference/make_tiny_maskrcnn.py).
//!
//! Signature: input `image` float32 `[3, H, W]` RGB in 0..1 (the model
//! normalises internally); outputs `boxes [N, 4]` (x0, y0, x1, y1 pixels),
//! `labels [N]` int64 COCO category ids (torchvision's 91-id list), `scores [N]`
//! and `masks [N, 1, h, w]` probabilities, either per box (28x28, pasted as
//! torchvision's own `paste_masks_in_image` does: [`paste_mask`]) or already
//! pasted at full image size (the standard export: torchvision's
//! postprocess is part of the graph). Pixels at probability >= 0.5 belong to
//! the instance.

use anyhow::{bail, Context, Result};
use mask_model::MaskModel;
use ort::session::Session;
use ort::value::TensorRef;
use pipeline_config::SegmenterConfig;
use provision::InputError;
use shared_types::views::FrameView;
use shared_types::{Instance, MAX_INSTANCES};

use crate::coco::{self, class_of_category};
use onnx_runtime::{open_session, verified_model};

/// Mask probability at or above which a pixel belongs to the instance
/// (torchvision's documented threshold for its soft masks).
pub const MASK_THRESHOLD: f32 = 0.5;

/// A mask pasted into the image: rows of probabilities from (x0, y0).
#[derive(Debug, Clone, PartialEq)]
pub struct Pasted {
    /// The first column.
    pub x0: usize,
    /// The first row.
    pub y0: usize,
    /// Probabilities, row by row.
    pub rows: Vec<Vec<f32>>,
}

/// Pastes an `mh x mw` box-relative mask into a `width x height` image as
/// torchvision's `paste_masks_in_image` does (roi_heads.py, padding 1): the
/// mask is padded by one zero cell, the box expanded by (M + 2) / M about
/// its centre and truncated to integers, the padded mask resized bilinearly
/// (align_corners = False) to the box's `x1 - x0 + 1` by `y1 - y0 + 1`
/// pixels, and the part inside the image kept.
pub fn paste_mask(
    mask: &[f32],
    mh: usize,
    mw: usize,
    bbox: [f32; 4],
    width: usize,
    height: usize,
) -> Pasted {
    let (ph, pw) = (mh + 2, mw + 2);
    let padded = |y: usize, x: usize| -> f32 {
        if y == 0 || x == 0 || y == ph - 1 || x == pw - 1 {
            0.0
        } else {
            mask[(y - 1) * mw + (x - 1)]
        }
    };
    // expand_masks: scale from the mask's width (torchvision's M = shape[-1]).
    let scale = (mw + 2) as f32 / mw as f32;
    let (w_half, h_half) = (
        (bbox[2] - bbox[0]) * 0.5 * scale,
        (bbox[3] - bbox[1]) * 0.5 * scale,
    );
    let (xc, yc) = ((bbox[2] + bbox[0]) * 0.5, (bbox[3] + bbox[1]) * 0.5);
    // `.to(torch.int64)` truncates toward zero, as `as i64` does.
    let bx = [
        (xc - w_half) as i64,
        (yc - h_half) as i64,
        (xc + w_half) as i64,
        (yc + h_half) as i64,
    ];
    let w = (bx[2] - bx[0] + 1).max(1) as usize;
    let h = (bx[3] - bx[1] + 1).max(1) as usize;
    // F.interpolate(bilinear, align_corners=False): source = (d + 0.5) * in/out - 0.5,
    // negative sources clamped to 0, the upper neighbour clamped to the last cell.
    let source = |d: usize, n_in: usize, n_out: usize| -> (usize, usize, f32) {
        let s = ((d as f32 + 0.5) * n_in as f32 / n_out as f32 - 0.5).max(0.0);
        let i0 = (s as usize).min(n_in - 1);
        let i1 = (i0 + 1).min(n_in - 1);
        (i0, i1, s - i0 as f32)
    };
    let x_0 = bx[0].max(0);
    let x_1 = (bx[2] + 1).min(width as i64);
    let y_0 = bx[1].max(0);
    let y_1 = (bx[3] + 1).min(height as i64);
    let mut rows = Vec::new();
    for y in y_0..y_1 {
        let (r0, r1, ty) = source((y - bx[1]) as usize, ph, h);
        let row = (x_0..x_1)
            .map(|x| {
                let (c0, c1, tx) = source((x - bx[0]) as usize, pw, w);
                let top = padded(r0, c0) * (1.0 - tx) + padded(r0, c1) * tx;
                let bottom = padded(r1, c0) * (1.0 - tx) + padded(r1, c1) * tx;
                top * (1.0 - ty) + bottom * ty
            })
            .collect();
        rows.push(row);
    }
    Pasted {
        x0: x_0.max(0) as usize,
        y0: y_0.max(0) as usize,
        rows,
    }
}

/// The raw outputs of one inference.
pub struct RawDetections<'a> {
    /// x0 y0 x1 y1 per detection (image pixels).
    pub boxes: &'a [f32],
    /// COCO label per detection (torchvision's 1-based ids).
    pub labels: &'a [i64],
    /// Score per detection.
    pub scores: &'a [f32],
    /// Soft masks per detection.
    pub masks: &'a [f32],
    /// Height and width of each mask.
    pub mask_size: (usize, usize),
}

/// Decodes detections into a label image (instance `i` as `i + 1`, higher
/// scores first keep contested pixels) and instances (80-class ids).
pub fn decode(
    raw: &RawDetections,
    width: usize,
    height: usize,
    min_score: f32,
    dynamic: &[usize],
    labels: &mut [u8],
) -> Vec<Instance> {
    let n = raw.scores.len();
    let (mh, mw) = raw.mask_size;
    let full = (mh, mw) == (height, width);
    let mut order: Vec<usize> = (0..n)
        .filter(|&i| raw.scores[i] >= min_score)
        .filter(|&i| class_of_category(raw.labels[i]).is_some_and(|c| dynamic.contains(&c)))
        .collect();
    order.sort_by(|&a, &b| raw.scores[b].total_cmp(&raw.scores[a]));
    order.truncate(MAX_INSTANCES);
    let mut instances = Vec::new();
    for (k, &i) in order.iter().enumerate() {
        let b = &raw.boxes[i * 4..i * 4 + 4];
        let (x0, y0) = (
            b[0].clamp(0.0, width as f32),
            b[1].clamp(0.0, height as f32),
        );
        let (x1, y1) = (
            b[2].clamp(0.0, width as f32),
            b[3].clamp(0.0, height as f32),
        );
        let mask = &raw.masks[i * mh * mw..(i + 1) * mh * mw];
        let label = (k + 1) as u8;
        if full {
            for (px, &p) in labels.iter_mut().zip(mask) {
                if *px == 0 && p >= MASK_THRESHOLD {
                    *px = label;
                }
            }
        } else {
            let pasted = paste_mask(mask, mh, mw, [b[0], b[1], b[2], b[3]], width, height);
            for (y, row) in pasted.rows.iter().enumerate() {
                for (dx, &p) in row.iter().enumerate() {
                    let px = &mut labels[(pasted.y0 + y) * width + pasted.x0 + dx];
                    if *px == 0 && p >= MASK_THRESHOLD {
                        *px = label;
                    }
                }
            }
        }
        instances.push(Instance {
            object_id: k as u32,
            class_id: class_of_category(raw.labels[i]).unwrap_or(0) as u32,
            score: raw.scores[i],
            bbox: [x0, y0, x1, y1],
        });
    }
    instances
}

/// Mask R-CNN on ONNX Runtime.
pub struct MaskRcnn {
    _env: ort::environment::Environment,
    session: Session,
    min_score: f32,
    dynamic: Vec<usize>,
    input: Vec<f32>,
}

impl MaskRcnn {
    /// Loads the model named by `[services.segmenter]` (`model`/`model_path`
    /// and `model_sha256` are required: no Mask R-CNN weights ship here).
    pub fn from_config(env: ort::environment::Environment, cfg: &SegmenterConfig) -> Result<Self> {
        if cfg.model.is_empty() || cfg.model_sha256.is_empty() {
            return Err(InputError(
                "keys `services.segmenter.model` and `model_sha256`: the maskrcnn backend needs your torchvision Mask R-CNN ONNX export and its sha256".into(),
            )
            .into());
        }
        let path = verified_model(&cfg.model, &cfg.model_sha256, cfg.model_path.as_deref())?;
        let dynamic = coco::dynamic_classes(&cfg.classes, "segmenter").map_err(InputError)?;
        let session = open_session(&env, &path, cfg.threads.unwrap_or(2))?;
        onnx_runtime::check_signature(
            &session,
            &path,
            "torchvision Mask R-CNN export",
            &["image"],
            &["boxes", "labels", "scores", "masks"],
        )?;
        Ok(Self {
            _env: env,
            session,
            // The original work's threshold.
            min_score: cfg.score_threshold.unwrap_or(0.9),
            dynamic,
            input: Vec::new(),
        })
    }

    /// The dynamic objects in an RGB image (`width` x `height`): their
    /// instances, and their labels painted into `labels`.
    pub fn segment(
        &mut self,
        rgb: &[u8],
        width: usize,
        height: usize,
        labels: &mut [u8],
    ) -> Result<Vec<Instance>> {
        let plane = width * height;
        self.input.resize(3 * plane, 0.0);
        for (i, px) in rgb.chunks_exact(3).enumerate() {
            for (c, &v) in px.iter().enumerate() {
                self.input[c * plane + i] = v as f32 / 255.0;
            }
        }
        let input = TensorRef::from_array_view(([3usize, height, width], &self.input[..]))?;
        let outputs = self.session.run(ort::inputs!["image" => input])?;
        let (_, boxes) = outputs["boxes"].try_extract_tensor::<f32>()?;
        let (_, classes) = outputs["labels"].try_extract_tensor::<i64>()?;
        let (_, scores) = outputs["scores"].try_extract_tensor::<f32>()?;
        let (mshape, masks) = outputs["masks"].try_extract_tensor::<f32>()?;
        let n = scores.len();
        if boxes.len() != 4 * n
            || classes.len() != n
            || mshape.len() != 4
            || mshape[0] as usize != n
        {
            bail!(
                "unexpected Mask R-CNN outputs: {n} scores, {} box values, masks {mshape:?}",
                boxes.len()
            );
        }
        let raw = RawDetections {
            boxes,
            labels: classes,
            scores,
            masks,
            mask_size: (mshape[2] as usize, mshape[3] as usize),
        };
        Ok(decode(
            &raw,
            width,
            height,
            self.min_score,
            &self.dynamic,
            labels,
        ))
    }
}

impl MaskModel for MaskRcnn {
    fn name(&self) -> &str {
        "maskrcnn"
    }

    fn infer(&mut self, frame: &FrameView, labels: &mut [u8]) -> Result<Vec<Instance>> {
        self.segment(frame.rgb, frame.width(), frame.height(), labels)
            .context("Mask R-CNN inference")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Values worked out by hand from torchvision's roi_heads.py
    /// (expand_masks, expand_boxes, paste_mask_in_image, padding 1).
    #[test]
    fn small_masks_are_pasted_as_torchvision_pastes_them() {
        // 2x2 mask [[1, 0], [0, 1]], box (0, 0, 4, 4) in an 8x8 image.
        // Padded 4x4, scale 4/2 = 2: the box becomes (-2, -2, 6, 6), 9x9
        // pixels; image pixels 0..7 of it (x_1 = min(6 + 1, 8)), from offset 2.
        let p = paste_mask(&[1.0, 0.0, 0.0, 1.0], 2, 2, [0.0, 0.0, 4.0, 4.0], 8, 8);
        assert_eq!((p.x0, p.y0, p.rows.len(), p.rows[0].len()), (0, 0, 7, 7));
        // Pixel (0, 0) = resized (2, 2): source (2.5 * 4/9 - 0.5) = 0.6111 in
        // both axes, between padded cells 0 (zero) and 1 (the mask's 1):
        // 0.6111 * 0.6111 = 0.3735.
        let s = 2.5f32 * 4.0 / 9.0 - 0.5;
        assert!((p.rows[0][0] - s * s).abs() < 1e-6, "{}", p.rows[0][0]);
        // Pixel (1, 1) = resized (3, 3): source 3.5 * 4/9 - 0.5 = 1.0556:
        // cells 1 and 2 with weight 0.0556 on 2: the mask's (0,0) = 1 weighs
        // 0.9444^2, its (1,1) = 1 weighs 0.0556^2, the zeros the rest.
        let t = 3.5f32 * 4.0 / 9.0 - 0.5 - 1.0;
        let want = (1.0 - t) * (1.0 - t) + t * t;
        assert!((p.rows[1][1] - want).abs() < 1e-6, "{}", p.rows[1][1]);
        // Pixel (4, 1) = resized (6, 3): source x = 6.5 * 4/9 - 0.5 = 2.3889
        // (cells 2 and 3: the mask's 0 at (0,1) and padding), y as above:
        // the mask's (1, 1) = 1 at weight 0.6111 (x) * 0.0556 (y).
        let sx = 6.5f32 * 4.0 / 9.0 - 0.5 - 2.0;
        let want = (1.0 - sx) * t;
        assert!((p.rows[1][4] - want).abs() < 1e-6, "{}", p.rows[1][4]);
        // A box partly outside the image is cut at the image border.
        let p = paste_mask(&[1.0; 4], 2, 2, [5.0, 5.0, 9.0, 9.0], 8, 8);
        assert_eq!((p.x0, p.y0), (3, 3));
        assert_eq!(p.rows.len(), 5);
        assert_eq!(p.rows[0].len(), 5);
    }

    #[test]
    fn torchvision_ids_map_to_coco80() {
        assert_eq!(class_of_category(1), Some(0)); // person
        assert_eq!(class_of_category(3), Some(2)); // car
        assert_eq!(class_of_category(8), Some(7)); // truck
        assert_eq!(
            class_of_category(62),
            coco::CLASSES.iter().position(|c| *c == "chair")
        );
        assert_eq!(class_of_category(12), None); // N/A
        assert_eq!(class_of_category(0), None);
        assert_eq!(class_of_category(500), None);
    }
}
