//! The `sam2` propagator backend: SAM 2 through ONNX Runtime, for users who
//! have its weights exported to ONNX (they cannot be obtained here; the code
//! is tested on tiny graphs with the same signature, see
//! tests/reference/make_tiny_sam2.py).
//!
//! It follows SAM 2's video idea with what the common two-file export (an
//! image encoder and a prompt/mask decoder, as samexporter writes them)
//! provides: every keyframe's segmenter instances become objects; on each
//! later frame the encoder runs once, and the decoder once per object,
//! prompted from the object's own previous mask: its box (labels 2, 3), a few
//! points deep inside it (label 1) and its low-resolution logits as
//! `mask_input`. The candidate with the best predicted IoU becomes the new
//! mask; an object ends when that prediction, or its area against its
//! keyframe area, collapses. Exports that also ship SAM 2's memory encoder and
//! memory attention would replace the `mask_input` prompt by the memory bank
//! (encoder features conditioned on past masks) between the two calls; see
//! docs/design.md.
//!
//! Signature (checked at load): encoder `image` float32 [1, 3, S, S] (S =
//! `input_size`, 1024 for SAM 2) -> `high_res_feats_0`, `high_res_feats_1`,
//! `image_embed`; decoder `image_embed`, `high_res_feats_0`,
//! `high_res_feats_1`, `point_coords` [1, N, 2] (pixels of the S x S input),
//! `point_labels` [1, N], `mask_input` [1, 1, S/4, S/4], `has_mask_input` [1]
//! -> `masks` [1, C, S/4, S/4] logits, `iou_predictions` [1, C].

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use mask_model::MaskModel;
use onnx_runtime::{check_input_size, check_signature, open_session, verified_model};
use ort::session::Session;
use ort::value::TensorRef;
use pipeline_config::PropagatorConfig;
use provision::InputError;
use shared_types::views::{FrameView, MasksView};
use shared_types::{Instance, MAX_INSTANCES};

/// The image encoder's input names (checked at load).
pub const ENCODER_INPUTS: &[&str] = &["image"];
/// The image encoder's output names.
pub const ENCODER_OUTPUTS: &[&str] = &["high_res_feats_0", "high_res_feats_1", "image_embed"];
/// The decoder's input names.
pub const DECODER_INPUTS: &[&str] = &[
    "image_embed",
    "high_res_feats_0",
    "high_res_feats_1",
    "point_coords",
    "point_labels",
    "mask_input",
    "has_mask_input",
];
/// The decoder's output names.
pub const DECODER_OUTPUTS: &[&str] = &["masks", "iou_predictions"];

/// ImageNet normalisation of SAM 2's image encoder (RGB, 0..1 before it).
const MEAN: [f32; 3] = [0.485, 0.456, 0.406];
const STD: [f32; 3] = [0.229, 0.224, 0.225];
/// A binary mask as decoder logits, as SAM 2's video predictor turns an
/// added mask into mask inputs: 1 -> +10, 0 -> -10 (x 20 - 10).
const MASK_LOGIT_SCALE: f32 = 20.0;
const MASK_LOGIT_BIAS: f32 = -10.0;
/// Point labels of SAM's prompt encoder.
pub const POSITIVE: f32 = 1.0;
/// A box's top-left corner.
pub const BOX_TOP_LEFT: f32 = 2.0;
/// A box's bottom-right corner.
pub const BOX_BOTTOM_RIGHT: f32 = 3.0;
/// Objects smaller than this (pixels) end.
const MIN_OBJECT_PX: usize = 50;

/// Settings of the backend, resolved from `[services.propagator]`.
#[derive(Debug, Clone)]
pub struct Sam2Settings {
    /// The image encoder (verified).
    pub encoder: PathBuf,
    /// The prompt / mask decoder (verified).
    pub decoder: PathBuf,
    /// The encoder's square input.
    pub input_size: usize,
    /// An object ends below this predicted IoU...
    pub min_predicted_iou: f32,
    /// ...or below this share of its keyframe area.
    pub min_area_ratio: f32,
    /// Positive points inside the previous mask per prompt.
    pub prompt_points: usize,
    /// ONNX Runtime intra-op threads.
    pub threads: usize,
}

impl Sam2Settings {
    /// Every problem is an input error naming its key: there are no shipped
    /// SAM 2 weights, so the files and their sha256 must be configured.
    pub fn from_config(cfg: &PropagatorConfig) -> Result<Self> {
        let key = |k: &str| format!("key `services.propagator.{k}`");
        let required = |name: &str, value: &str| -> Result<()> {
            if value.is_empty() {
                return Err(InputError(format!(
                    "{}: required by backend \"sam2\" (no SAM 2 weights ship with dynslam; docs/models.md says how to export them)",
                    key(name)
                ))
                .into());
            }
            Ok(())
        };
        required("model", &cfg.model)?;
        required("model_sha256", &cfg.model_sha256)?;
        required("decoder_model", &cfg.decoder_model)?;
        required("decoder_model_sha256", &cfg.decoder_model_sha256)?;
        let encoder = verified_model(&cfg.model, &cfg.model_sha256, cfg.model_path.as_deref())?;
        let decoder = verified_model(
            &cfg.decoder_model,
            &cfg.decoder_model_sha256,
            cfg.decoder_model_path.as_deref(),
        )?;
        let min_predicted_iou = cfg.min_predicted_iou.unwrap_or(0.5);
        let min_area_ratio = cfg.min_area_ratio.unwrap_or(0.2);
        for (k, v) in [
            ("min_predicted_iou", min_predicted_iou),
            ("min_area_ratio", min_area_ratio),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(InputError(format!("{}: {v} is not in 0..1", key(k))).into());
            }
        }
        let input_size = cfg.input_size.unwrap_or(1024) as usize;
        if input_size < 64 || !input_size.is_multiple_of(64) {
            return Err(InputError(format!(
                "{}: {input_size} must be a multiple of 64 (SAM 2: 1024)",
                key("input_size")
            ))
            .into());
        }
        let prompt_points = cfg.prompt_points.unwrap_or(3) as usize;
        if prompt_points > 16 {
            return Err(InputError(format!(
                "{}: {prompt_points} is more than 16",
                key("prompt_points")
            ))
            .into());
        }
        Ok(Self {
            encoder,
            decoder,
            input_size,
            min_predicted_iou,
            min_area_ratio,
            prompt_points,
            threads: cfg.threads.unwrap_or(2).max(1),
        })
    }
}

/// Bilinear sampling along one axis with pixel centres aligned: output
/// index `d` of `n_out` reads the input of `n_in` cells at cells `i0`, `i1`
/// with weight `t` on `i1` (clamped at both ends).
fn bilinear_source(d: usize, n_in: usize, n_out: usize) -> (usize, usize, f32) {
    let s = ((d as f32 + 0.5) * n_in as f32 / n_out as f32 - 0.5).clamp(0.0, (n_in - 1) as f32);
    let i0 = s as usize;
    (i0, (i0 + 1).min(n_in - 1), s.fract())
}

/// The encoder's input: RGB8 `w x h` resized (bilinear, pixel centres
/// aligned, no letterbox: SAM 2 resizes to a square) to `n x n`, scaled to
/// 0..1 and normalised per channel, planar (CHW).
pub fn preprocess(rgb: &[u8], w: usize, h: usize, n: usize, out: &mut [f32]) {
    let plane = n * n;
    for y in 0..n {
        let (y0, y1, ty) = bilinear_source(y, h, n);
        for x in 0..n {
            let (x0, x1, tx) = bilinear_source(x, w, n);
            for c in 0..3 {
                let p = |xx: usize, yy: usize| rgb[(yy * w + xx) * 3 + c] as f32;
                let top = p(x0, y0) * (1.0 - tx) + p(x1, y0) * tx;
                let bottom = p(x0, y1) * (1.0 - tx) + p(x1, y1) * tx;
                let v = (top * (1.0 - ty) + bottom * ty) / 255.0;
                out[c * plane + y * n + x] = (v - MEAN[c]) / STD[c];
            }
        }
    }
}

/// A pixel position of the `w x h` frame in the `n x n` encoder input.
pub fn to_input(x: f32, y: f32, w: usize, h: usize, n: usize) -> [f32; 2] {
    [x * n as f32 / w as f32, y * n as f32 / h as f32]
}

/// A decoder prompt: point coordinates (input pixels) and their labels.
#[derive(Debug, Clone, PartialEq)]
pub struct Prompt {
    /// x, y per point.
    pub coords: Vec<[f32; 2]>,
    /// Its label per point ([`POSITIVE`], the box corners).
    pub labels: Vec<f32>,
}

/// The prompt of an object from its mask: its box (corners labelled 2 and 3,
/// box x1/y1 exclusive) and up to `points` positive points deep inside it
/// (the pixels farthest from the background, each at least a third of the
/// deepest distance from the others). None for an empty mask.
pub fn prompt_for(mask: &[bool], w: usize, h: usize, points: usize, n: usize) -> Option<Prompt> {
    let (x0, y0, x1, y1) = bbox(mask, w, h)?;
    let mut coords = vec![
        to_input(x0 as f32, y0 as f32, w, h, n),
        to_input((x1 + 1) as f32, (y1 + 1) as f32, w, h, n),
    ];
    let mut labels = vec![BOX_TOP_LEFT, BOX_BOTTOM_RIGHT];
    for (px, py) in interior_points(mask, w, h, points) {
        coords.push(to_input(px as f32 + 0.5, py as f32 + 0.5, w, h, n));
        labels.push(POSITIVE);
    }
    Some(Prompt { coords, labels })
}

/// Inclusive bounding box of the set pixels.
pub fn bbox(mask: &[bool], w: usize, h: usize) -> Option<(usize, usize, usize, usize)> {
    let (mut x0, mut y0, mut x1, mut y1) = (w, h, 0, 0);
    for y in 0..h {
        for x in 0..w {
            if mask[y * w + x] {
                x0 = x0.min(x);
                y0 = y0.min(y);
                x1 = x1.max(x);
                y1 = y1.max(y);
            }
        }
    }
    (x0 <= x1).then_some((x0, y0, x1, y1))
}

/// Up to `k` pixels deep inside the mask: city-block distance to the nearest
/// background pixel (or the image border), greatest first, spaced apart.
pub fn interior_points(mask: &[bool], w: usize, h: usize, k: usize) -> Vec<(usize, usize)> {
    if k == 0 {
        return Vec::new();
    }
    let big = (w + h) as u32;
    let mut d: Vec<u32> = mask.iter().map(|&m| if m { big } else { 0 }).collect();
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            if d[i] == 0 {
                continue;
            }
            let up = if y > 0 { d[i - w] } else { 0 };
            let left = if x > 0 { d[i - 1] } else { 0 };
            d[i] = d[i].min(up + 1).min(left + 1);
        }
    }
    for y in (0..h).rev() {
        for x in (0..w).rev() {
            let i = y * w + x;
            if d[i] == 0 {
                continue;
            }
            let down = if y + 1 < h { d[i + w] } else { 0 };
            let right = if x + 1 < w { d[i + 1] } else { 0 };
            d[i] = d[i].min(down + 1).min(right + 1);
        }
    }
    // Each pick: the deepest pixel far enough from those picked, ties in
    // raster order (k scans instead of sorting every pixel of the object).
    let mut picked: Vec<(usize, usize)> = Vec::new();
    let mut spacing = 1i64;
    while picked.len() < k {
        let far = |i: usize| {
            let (x, y) = ((i % w) as i64, (i / w) as i64);
            picked
                .iter()
                .all(|&(px, py)| (px as i64 - x).abs() + (py as i64 - y).abs() >= spacing)
        };
        let Some(best) = (0..d.len())
            .filter(|&i| d[i] > 0 && far(i))
            .max_by(|&a, &b| d[a].cmp(&d[b]).then(b.cmp(&a)))
        else {
            break;
        };
        if picked.is_empty() {
            spacing = (d[best] / 3).max(1) as i64;
        }
        picked.push((best % w, best / w));
    }
    picked
}

/// A binary mask as `lw x lh` decoder logits: the fraction of each cell's
/// pixels that are set, mapped to SAM 2's mask-input range (-10..+10).
pub fn mask_logits(mask: &[bool], w: usize, h: usize, lw: usize, lh: usize) -> Vec<f32> {
    let mut sum = vec![0u32; lw * lh];
    let mut count = vec![0u32; lw * lh];
    for y in 0..h {
        let cy = (y * lh / h).min(lh - 1);
        for x in 0..w {
            let cx = (x * lw / w).min(lw - 1);
            count[cy * lw + cx] += 1;
            sum[cy * lw + cx] += mask[y * w + x] as u32;
        }
    }
    sum.iter()
        .zip(&count)
        .map(|(&s, &c)| {
            // A cell no pixel falls in (frame smaller than the grid) takes its value
            // from nothing: background.
            let f = if c == 0 { 0.0 } else { s as f32 / c as f32 };
            f * MASK_LOGIT_SCALE + MASK_LOGIT_BIAS
        })
        .collect()
}

/// Low-resolution logits (`lw x lh`, covering the whole frame, as the
/// encoder's square input does) upsampled bilinearly to the `w x h` frame
/// and thresholded at 0 (SAM's mask threshold).
pub fn upsample_mask(logits: &[f32], lw: usize, lh: usize, w: usize, h: usize) -> Vec<bool> {
    let mut out = vec![false; w * h];
    for y in 0..h {
        let (y0, y1, ty) = bilinear_source(y, lh, h);
        for x in 0..w {
            let (x0, x1, tx) = bilinear_source(x, lw, w);
            let l = |xx: usize, yy: usize| logits[yy * lw + xx];
            let top = l(x0, y0) * (1.0 - tx) + l(x1, y0) * tx;
            let bottom = l(x0, y1) * (1.0 - tx) + l(x1, y1) * tx;
            out[y * w + x] = top * (1.0 - ty) + bottom * ty > 0.0;
        }
    }
    out
}

/// The candidate with the highest predicted IoU: (index, IoU).
pub fn best_candidate(ious: &[f32]) -> Option<(usize, f32)> {
    ious.iter()
        .copied()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(&b.1))
}

/// Why an object ends after a decoder step, if it does.
pub fn end_reason(
    predicted_iou: f32,
    area: usize,
    keyframe_area: usize,
    settings: &Sam2Settings,
) -> Option<String> {
    if predicted_iou < settings.min_predicted_iou {
        return Some(format!(
            "predicted IoU {predicted_iou:.2} < {}",
            settings.min_predicted_iou
        ));
    }
    if area < MIN_OBJECT_PX || (area as f32) < settings.min_area_ratio * keyframe_area as f32 {
        return Some(format!(
            "area {area} px against {keyframe_area} px on its keyframe"
        ));
    }
    None
}

/// One followed object.
struct Object {
    instance: Instance,
    mask: Vec<bool>,
    /// Its last mask as decoder logits (the next step's `mask_input`).
    logits: Vec<f32>,
    keyframe_area: usize,
}

/// SAM 2 mask propagation (a [`MaskModel`]).
pub struct Sam2Propagator {
    _env: ort::environment::Environment,
    encoder: Session,
    decoder: Session,
    settings: Sam2Settings,
    input: Vec<f32>,
    /// The decoder's mask resolution (S/4 x S/4 for SAM 2).
    low: (usize, usize),
    objects: Vec<Object>,
    frame_size: (usize, usize),
}

impl Sam2Propagator {
    /// Both models loaded in ONNX Runtime with `settings`.
    pub fn load(env: ort::environment::Environment, settings: Sam2Settings) -> Result<Self> {
        let encoder = open_session(&env, &settings.encoder, settings.threads)?;
        check_signature(
            &encoder,
            &settings.encoder,
            "SAM 2 image encoder",
            ENCODER_INPUTS,
            ENCODER_OUTPUTS,
        )?;
        check_input_size(
            &encoder,
            &settings.encoder,
            "image",
            settings.input_size,
            "services.propagator.input_size",
        )?;
        let decoder = open_session(&env, &settings.decoder, settings.threads)?;
        check_signature(
            &decoder,
            &settings.decoder,
            "SAM 2 prompt/mask decoder",
            DECODER_INPUTS,
            DECODER_OUTPUTS,
        )?;
        let n = settings.input_size;
        Ok(Self {
            _env: env,
            encoder,
            decoder,
            input: vec![0.0; 3 * n * n],
            low: (n / 4, n / 4),
            settings,
            objects: Vec::new(),
            frame_size: (0, 0),
        })
    }

    /// Objects followed now.
    pub fn objects(&self) -> usize {
        self.objects.len()
    }

    /// New objects from a keyframe's labels (`i + 1` = `instances[i]`).
    pub fn prompt_with(&mut self, labels: &[u8], w: usize, h: usize, instances: &[Instance]) {
        let (lw, lh) = self.low;
        self.frame_size = (w, h);
        self.objects = instances
            .iter()
            .enumerate()
            .filter_map(|(i, inst)| {
                let mask: Vec<bool> = labels.iter().map(|&l| l as usize == i + 1).collect();
                let area = mask.iter().filter(|&&m| m).count();
                (area >= MIN_OBJECT_PX).then(|| Object {
                    instance: *inst,
                    logits: mask_logits(&mask, w, h, lw, lh),
                    mask,
                    keyframe_area: area,
                })
            })
            .collect();
    }

    /// Follows every object into the frame `rgb` (`w x h`): writes their
    /// labels into the zeroed `labels` and returns the instances that go on.
    pub fn propagate(
        &mut self,
        rgb: &[u8],
        w: usize,
        h: usize,
        labels: &mut [u8],
    ) -> Result<Vec<Instance>> {
        if self.objects.is_empty() {
            return Ok(Vec::new());
        }
        if (w, h) != self.frame_size {
            bail!(
                "frame is {w}x{h}, its prompts were {}x{}",
                self.frame_size.0,
                self.frame_size.1
            );
        }
        let n = self.settings.input_size;
        preprocess(rgb, w, h, n, &mut self.input);
        let image = TensorRef::from_array_view(([1usize, 3, n, n], &self.input[..]))?;
        let Self {
            encoder,
            decoder,
            settings,
            objects,
            low,
            ..
        } = self;
        let features = encoder.run(ort::inputs!["image" => image])?;
        let feature = |name: &str| -> Result<([usize; 4], &[f32])> {
            let (shape, data) = features[name]
                .try_extract_tensor::<f32>()
                .with_context(|| format!("SAM 2 encoder output {name}"))?;
            if shape.len() != 4 {
                bail!("SAM 2 encoder output {name} has shape {shape:?}, expected 4 dimensions");
            }
            Ok(([0, 1, 2, 3].map(|k| shape[k] as usize), data))
        };
        let embed = feature("image_embed")?;
        let hrf0 = feature("high_res_feats_0")?;
        let hrf1 = feature("high_res_feats_1")?;
        let (lw, lh) = *low;
        let mut kept = Vec::new();
        for mut obj in std::mem::take(objects) {
            let Some(prompt) = prompt_for(&obj.mask, w, h, settings.prompt_points, n) else {
                continue;
            };
            let np = prompt.coords.len();
            let coords: Vec<f32> = prompt.coords.iter().flatten().copied().collect();
            let outputs = decoder.run(ort::inputs![
                "image_embed" => TensorRef::from_array_view((embed.0, embed.1))?,
                "high_res_feats_0" => TensorRef::from_array_view((hrf0.0, hrf0.1))?,
                "high_res_feats_1" => TensorRef::from_array_view((hrf1.0, hrf1.1))?,
                "point_coords" => TensorRef::from_array_view(([1usize, np, 2], &coords[..]))?,
                "point_labels" => TensorRef::from_array_view(([1usize, np], &prompt.labels[..]))?,
                "mask_input" => TensorRef::from_array_view(([1usize, 1, lh, lw], &obj.logits[..]))?,
                "has_mask_input" => TensorRef::from_array_view(([1usize], &[1.0f32][..]))?,
            ])?;
            let (mshape, masks) = outputs["masks"].try_extract_tensor::<f32>()?;
            let (_, ious) = outputs["iou_predictions"].try_extract_tensor::<f32>()?;
            if mshape.len() != 4 || mshape[2] as usize != lh || mshape[3] as usize != lw {
                bail!("SAM 2 decoder masks have shape {mshape:?}, expected [1, C, {lh}, {lw}]");
            }
            let candidates = mshape[1] as usize;
            let Some((best, iou)) = best_candidate(&ious[..candidates.min(ious.len())]) else {
                continue;
            };
            let logits = masks[best * lw * lh..(best + 1) * lw * lh].to_vec();
            let mask = upsample_mask(&logits, lw, lh, w, h);
            let area = mask.iter().filter(|&&m| m).count();
            if let Some(why) = end_reason(iou, area, obj.keyframe_area, settings) {
                tracing::debug!(object = obj.instance.object_id, "object ends: {why}");
                continue;
            }
            obj.logits = logits;
            obj.mask = mask;
            obj.instance.score = iou;
            kept.push(obj);
        }
        kept.truncate(MAX_INSTANCES);
        let mut instances = Vec::with_capacity(kept.len());
        for (k, obj) in kept.iter_mut().enumerate() {
            // Earlier objects keep contested pixels.
            for (l, &m) in labels.iter_mut().zip(&obj.mask) {
                if m && *l == 0 {
                    *l = (k + 1) as u8;
                }
            }
            if let Some((x0, y0, x1, y1)) = bbox(&obj.mask, w, h) {
                obj.instance.bbox = [x0 as f32, y0 as f32, (x1 + 1) as f32, (y1 + 1) as f32];
            }
            instances.push(obj.instance);
        }
        *objects = kept;
        Ok(instances)
    }
}

impl MaskModel for Sam2Propagator {
    fn name(&self) -> &str {
        "sam2"
    }

    fn infer(&mut self, frame: &FrameView, labels: &mut [u8]) -> Result<Vec<Instance>> {
        self.propagate(frame.rgb, frame.width(), frame.height(), labels)
            .context("SAM 2 propagation")
    }

    /// SAM 2 is prompted by the keyframe's masks alone: the keyframe image
    /// itself is not needed.
    fn prompt(&mut self, _frame: Option<&FrameView>, masks: &MasksView) {
        let (w, h) = (masks.header.width as usize, masks.header.height as usize);
        self.prompt_with(masks.labels, w, h, masks.header.instances());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings() -> Sam2Settings {
        Sam2Settings {
            encoder: PathBuf::new(),
            decoder: PathBuf::new(),
            input_size: 1024,
            min_predicted_iou: 0.5,
            min_area_ratio: 0.2,
            prompt_points: 3,
            threads: 1,
        }
    }

    fn rect(w: usize, h: usize, x0: usize, y0: usize, x1: usize, y1: usize) -> Vec<bool> {
        (0..w * h)
            .map(|i| (x0..x1).contains(&(i % w)) && (y0..y1).contains(&(i / w)))
            .collect()
    }

    #[test]
    fn preprocessing_normalises_each_channel_and_resizes_bilinearly() {
        // A uniform colour: every input value is its channel's normalised value.
        let rgb = [255u8, 128, 0].repeat(4 * 2);
        let mut out = vec![0.0; 3 * 8 * 8];
        preprocess(&rgb, 4, 2, 8, &mut out);
        let expect = [
            (1.0 - 0.485) / 0.229,
            (128.0 / 255.0 - 0.456) / 0.224,
            (0.0 - 0.406) / 0.225,
        ];
        for c in 0..3 {
            for v in &out[c * 64..(c + 1) * 64] {
                assert!((v - expect[c]).abs() < 1e-5, "channel {c}: {v}");
            }
        }
        // A horizontal ramp 0, 100 (2x1) to 4x1: pixel centres 0.125..0.875 of
        // the width sample the ramp at -0.25 (clamped: 0), 0.25, 0.75, 1.25 (1).
        let rgb = [0u8, 0, 0, 100, 100, 100];
        let mut out = vec![0.0; 3 * 4 * 4];
        preprocess(&rgb, 2, 1, 4, &mut out);
        let red = |x: usize| out[x] * 0.229 + 0.485;
        for (x, want) in [(0, 0.0), (1, 25.0), (2, 75.0), (3, 100.0)] {
            assert!(
                (red(x) * 255.0 - want).abs() < 1e-3,
                "x {x}: {}",
                red(x) * 255.0
            );
        }
    }

    #[test]
    fn a_prompt_is_the_box_and_points_deep_inside_in_input_pixels() {
        // 640x480 frame, object columns 100..200, rows 120..360.
        let mask = rect(640, 480, 100, 120, 200, 360);
        let p = prompt_for(&mask, 640, 480, 3, 1024).unwrap();
        assert_eq!(p.labels, vec![2.0, 3.0, 1.0, 1.0, 1.0]);
        assert_eq!(p.coords[0], [160.0, 256.0]); // 100 * 1024/640, 120 * 1024/480
        assert_eq!(p.coords[1], [320.0, 768.0]); // 200 * 1.6, 360 * 2.1333
                                                 // The deepest pixels lie on the vertical centre line of the 100-wide
                                                 // object: x = 149 or 150 (distance 50), between rows 170 and 310.
        for c in &p.coords[2..] {
            let (x, y) = (c[0] / 1.6 - 0.5, c[1] * 480.0 / 1024.0 - 0.5);
            assert!((149.0..=150.0).contains(&x), "x {x}");
            assert!((169.0..=310.0).contains(&y), "y {y}");
        }
        // Spaced apart: at least a third of the depth (50 / 3 = 16 px, city block).
        let px: Vec<(f32, f32)> = p.coords[2..]
            .iter()
            .map(|c| (c[0] / 1.6, c[1] * 480.0 / 1024.0))
            .collect();
        for (i, a) in px.iter().enumerate() {
            for b in &px[i + 1..] {
                let d = (a.0 - b.0).abs() + (a.1 - b.1).abs();
                assert!(d >= 15.99, "{px:?}");
            }
        }
        assert!(prompt_for(&vec![false; 640 * 480], 640, 480, 3, 1024).is_none());
    }

    #[test]
    fn masks_go_to_logits_and_back() {
        // 8x4 frame onto a 4x2 grid: each cell 2x2 pixels.
        let mask = rect(8, 4, 2, 0, 6, 2); // cells (1,0) and (2,0) full
        let l = mask_logits(&mask, 8, 4, 4, 2);
        assert_eq!(
            l,
            vec![-10.0, 10.0, 10.0, -10.0, -10.0, -10.0, -10.0, -10.0]
        );
        let half = rect(8, 4, 3, 0, 4, 2); // one column of cell (1,0): a half
        assert_eq!(mask_logits(&half, 8, 4, 4, 2)[1], 0.0);
        // Back up: the cells' centres are at pixels 1, 3, 5, 7 (x) and 1, 3 (y);
        // between +10 and -10 the boundary falls halfway, so the mask returns exactly.
        let back = upsample_mask(&l, 4, 2, 8, 4);
        assert_eq!(back, mask);
    }

    #[test]
    fn the_best_candidate_wins_and_objects_end_on_collapse() {
        assert_eq!(best_candidate(&[0.2, 0.9, 0.5]), Some((1, 0.9)));
        assert_eq!(best_candidate(&[]), None);
        let s = settings();
        assert_eq!(end_reason(0.8, 1000, 1000, &s), None);
        assert!(end_reason(0.4, 1000, 1000, &s)
            .unwrap()
            .contains("predicted IoU"));
        assert!(end_reason(0.9, 150, 1000, &s).unwrap().contains("area 150"));
        assert!(
            end_reason(0.9, 40, 60, &s).is_some(),
            "below the minimum size"
        );
    }
}
