//! Mask R-CNN backend for the standard torchvision ONNX export, the original
//! work's segmenter, for users who have those weights (they cannot be
//! obtained here; the decoding is tested on tiny generated graphs with the
//! same signature, see tests/reference/make_tiny_maskrcnn.py).
//!
//! Signature: input `image` float32 `[3, H, W]` RGB in 0..1 (the model
//! normalises internally); outputs `boxes [N, 4]` (x0, y0, x1, y1 pixels),
//! `labels [N]` int64 COCO category ids (torchvision's 91-id list), `scores [N]`
//! and `masks [N, 1, h, w]` probabilities, either per box (28x28, pasted into
//! the box bilinearly) or already pasted at full image size.

use anyhow::{bail, Context, Result};
use ort::session::Session;
use ort::value::TensorRef;
use pipeline::config::ServiceConfig;
use pipeline::mask_worker::MaskModel;
use pipeline::runtime::InputError;
use pipeline::views::FrameView;
use shared_types::{Instance, MAX_INSTANCES};

use crate::coco::{self, class_of_category};
use crate::onnx::{open_session, verified_model};

/// The raw outputs of one inference.
pub struct RawDetections<'a> {
    pub boxes: &'a [f32],
    pub labels: &'a [i64],
    pub scores: &'a [f32],
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
        let (bw, bh) = ((b[2] - b[0]).max(1e-3), (b[3] - b[1]).max(1e-3));
        for y in y0.floor() as usize..(y1.ceil() as usize).min(height) {
            for x in x0.floor() as usize..(x1.ceil() as usize).min(width) {
                let (cx, cy) = (x as f32 + 0.5, y as f32 + 0.5);
                if cx < b[0] || cx >= b[2] || cy < b[1] || cy >= b[3] {
                    continue;
                }
                let p = if full {
                    mask[y * mw + x]
                } else {
                    // Box-relative bilinear sample of the small mask.
                    let u = ((cx - b[0]) / bw * mw as f32 - 0.5).clamp(0.0, (mw - 1) as f32);
                    let v = ((cy - b[1]) / bh * mh as f32 - 0.5).clamp(0.0, (mh - 1) as f32);
                    let (u0, v0) = (u as usize, v as usize);
                    let (u1, v1) = ((u0 + 1).min(mw - 1), (v0 + 1).min(mh - 1));
                    let (wu, wv) = (u - u0 as f32, v - v0 as f32);
                    let m = |uu: usize, vv: usize| mask[vv * mw + uu];
                    (m(u0, v0) * (1.0 - wu) + m(u1, v0) * wu) * (1.0 - wv)
                        + (m(u0, v1) * (1.0 - wu) + m(u1, v1) * wu) * wv
                };
                let px = &mut labels[y * width + x];
                if *px == 0 && p >= 0.5 {
                    *px = label;
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
    pub fn from_config(env: ort::environment::Environment, cfg: &ServiceConfig) -> Result<Self> {
        if cfg.model.is_empty() || cfg.model_sha256.is_empty() {
            return Err(InputError(
                "keys `services.segmenter.model` and `model_sha256`: the maskrcnn backend needs your torchvision Mask R-CNN ONNX export and its sha256".into(),
            )
            .into());
        }
        let path = verified_model(&cfg.model, &cfg.model_sha256, cfg.model_path.as_deref())?;
        let dynamic = coco::dynamic_classes(&cfg.classes, "segmenter").map_err(InputError)?;
        let session = open_session(&env, &path, cfg.threads.unwrap_or(2))?;
        Ok(Self {
            _env: env,
            session,
            // The original work's threshold.
            min_score: cfg.score_threshold.unwrap_or(0.9),
            dynamic,
            input: Vec::new(),
        })
    }

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
