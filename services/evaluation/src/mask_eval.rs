//! `dynslam masks-eval`: how good the masks are, against a synthesised
//! sequence's ground truth, with the product's models outside the pipeline.
//!
//! Every `keyframe_every`-th frame is segmented (the segmenter's score),
//! the frames between are propagated from it (the propagator's score, per
//! distance from the keyframe), as the pipeline's routing would do with a
//! fixed keyframe interval; with `routing.early_segment_requests` (the
//! default) the frame after one where the propagator saw something move
//! that it does not follow is segmented too, as in the pipeline. Scores are
//! per ground-truth person, see [`scenes::truth`], also split by why a
//! person may be hard ([`ByCause`]); people who come into view (walk in,
//! or step out from behind something) are followed until they are masked
//! ([`Entries`]).
//!
//! Ignore regions: real people in the source footage are not in the
//! synthesised ground truth, and the segmenter is right to mask them. A
//! sequence folder may hold `ignore.png` (one label image for every frame)
//! and/or `ignore.txt` (per-frame label images, listed like `masks.txt`);
//! their non-zero pixels are left out of every score.

use std::io::Write;
use std::path::Path;

use anyhow::{bail, Context, Result};
use datasets::decode::decode_depth_into;
use datasets::progress::Progress;
use datasets::source::{tum_folder, FrameEntry, MaskList};
use image::{GrayImage, RgbImage};
use onnx_runtime::init_runtime;
use pipeline_config::PipelineConfig;
use propagation::newcomers::NewcomerCheck;
use shared_types::views::DepthImage;

use propagation::propagate::{LkPropagator, PropagatorParams};
use run_folder::ignore::IgnoreRegions;
use scenes::truth::{instance_ious, InstanceIou};
use segmentation::exports::YoloFamily;
use segmentation::onnx::{YoloSeg, YoloSettings};
use serde::Serialize;

/// What `dynslam masks-eval` measured on one sequence.
#[derive(Debug, Clone, Serialize)]
pub struct MaskScores {
    /// Frames evaluated.
    pub frames: usize,
    /// A keyframe (segmented) every this many frames; the rest propagated.
    pub keyframe_every: usize,
    /// People smaller than this (pixels) are not scored.
    pub min_px: usize,
    /// Mean IoU of the segmenter on keyframes (over scored people).
    pub segmenter_iou: f64,
    /// Person-frames behind `segmenter_iou`.
    pub segmenter_samples: usize,
    /// Mean IoU of the propagator on all frames between keyframes.
    pub propagator_iou: f64,
    /// Person-frames behind `propagator_iou`.
    pub propagator_samples: usize,
    /// Mean propagator IoU by distance from the keyframe (index 0: 1 frame after).
    pub propagator_iou_by_offset: Vec<f64>,
    /// Mean propagator IoU over people who were already scored on the
    /// prompting keyframe (a person entering later cannot be propagated).
    pub propagator_iou_prompted: f64,
    /// Mean propagator IoU over people the segmenter found on the
    /// prompting keyframe (IoU >= `FOUND_IOU` there): the propagator's own
    /// quality, without the segmenter's misses.
    pub propagator_iou_found: f64,
    /// The segmenter's and the propagator's scores by cause.
    pub segmenter_by_cause: ByCause,
    /// The propagator's, likewise.
    pub propagator_by_cause: ByCause,
    /// Whether ignore regions (`ignore.png` / `ignore.txt`) were applied.
    pub ignore_regions: bool,
    /// Frames segmented because the propagator asked (early requests).
    pub early_segments: usize,
    /// People coming into view, and how soon they were masked.
    pub entries: Entries,
    /// The segmenter's median time per keyframe, milliseconds.
    pub segmenter_ms_p50: f64,
    /// The propagator's median time per frame, milliseconds.
    pub propagator_ms_p50: f64,
}

/// Mean IoU over a subset of the scored person-frames.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Subset {
    /// Mean IoU.
    pub iou: f64,
    /// Person-frames behind it.
    pub samples: usize,
    #[serde(skip)]
    sum: f64,
}

impl Subset {
    fn add(&mut self, iou: f64) {
        self.sum += iou;
        self.samples += 1;
        self.iou = self.sum / self.samples as f64;
    }
}

/// Scores split by why a person may be hard to mask (a person can be in
/// several): `entered` (propagated frames only: not scored on the keyframe
/// that prompted the propagator, so it walked in or grew past `min_px`
/// since), `border_cut` (touches the image border), `small` (under
/// [`scenes::truth::SMALL_SHARE`] of the image), `occluded` (the scene or a
/// nearer person hides more than [`OCCLUDED_SHARE`] of the silhouette the
/// image would show; from `objects.json`, empty for a sequence made before
/// it recorded that), `plain` (none of these).
#[derive(Debug, Clone, Default, Serialize)]
pub struct ByCause {
    /// Not on the prompting keyframe.
    pub entered: Subset,
    /// Touching the image border.
    pub border_cut: Subset,
    /// Small in the image.
    pub small: Subset,
    /// Partly hidden.
    pub occluded: Subset,
    /// None of the above.
    pub plain: Subset,
}

/// A person hidden by more than this share of its in-image silhouette
/// counts as occluded.
pub const OCCLUDED_SHARE: f64 = 0.2;

impl ByCause {
    fn add(&mut self, s: &InstanceIou, entered: bool, occluded: bool, image_px: usize) {
        let small = s.small(image_px);
        if entered {
            self.entered.add(s.iou);
        }
        if s.border_cut {
            self.border_cut.add(s.iou);
        }
        if small {
            self.small.add(s.iou);
        }
        if occluded {
            self.occluded.add(s.iou);
        }
        if !(entered || s.border_cut || small || occluded) {
            self.plain.add(s.iou);
        }
    }
}

/// Per frame and person, how much of the silhouette the synthesised frame
/// shows (`objects.json`: `visible_px` of `unoccluded_px`).
#[derive(Debug, Default)]
struct Occlusion {
    /// Timestamp and the people of each frame.
    frames: Vec<(f64, Vec<PersonPixels>)>,
}

#[derive(Debug, Clone, Copy)]
struct PersonPixels {
    id: u8,
    visible: usize,
    unoccluded: usize,
}

#[derive(serde::Deserialize)]
struct ObjectsFile {
    frames: Vec<ObjectsFrame>,
}

#[derive(serde::Deserialize)]
struct ObjectsFrame {
    timestamp: f64,
    objects: Vec<ObjectVisibility>,
}

#[derive(serde::Deserialize)]
struct ObjectVisibility {
    id: u8,
    visible_px: usize,
    /// Absent in sequences synthesised before it was recorded.
    unoccluded_px: Option<usize>,
}

impl Occlusion {
    /// `objects.json` of a `dynslam synth` folder; empty when there is
    /// none or it predates `unoccluded_px`.
    fn open(dataset: &Path) -> Result<Self> {
        let path = dataset.join("objects.json");
        if !path.exists() {
            return Ok(Self::default());
        }
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("cannot read {}", path.display()))?;
        let file: ObjectsFile = serde_json::from_str(&text)
            .with_context(|| format!("{}: not a `dynslam synth` objects file", path.display()))?;
        let frames = file
            .frames
            .into_iter()
            .map(|f| {
                let people = f
                    .objects
                    .into_iter()
                    .filter_map(|o| {
                        Some(PersonPixels {
                            id: o.id,
                            visible: o.visible_px,
                            unoccluded: o.unoccluded_px?,
                        })
                    })
                    .collect();
                (f.timestamp, people)
            })
            .collect();
        Ok(Self { frames })
    }

    /// Whether person `id` is occluded in the frame at `timestamp`.
    fn occluded(&self, timestamp: f64, id: u8) -> bool {
        let frame = self
            .frames
            .iter()
            .find(|(t, _)| (t - timestamp).abs() < 1e-4);
        frame
            .and_then(|(_, people)| people.iter().find(|p| p.id == id))
            .is_some_and(|p| (p.visible as f64) < (1.0 - OCCLUDED_SHARE) * p.unoccluded as f64)
    }
}

/// A person counts as masked at this IoU (entries).
pub const MASKED_IOU: f64 = 0.5;

/// Frames after coming into view within which a person is to be masked.
pub const ENTRY_FRAMES: usize = 3;

/// People coming into view: scored (>= `min_px`) on a frame after not
/// being scored on the one before (walked in across the border, stepped
/// out from behind furniture or another person, or grew past `min_px`).
#[derive(Debug, Clone, Default, Serialize)]
pub struct Entries {
    /// Appearances after the first frame.
    pub count: usize,
    /// Masked (IoU >= [`MASKED_IOU`]) by the [`ENTRY_FRAMES`]th frame after
    /// coming into view (the frame itself is 0).
    pub masked_in_time: usize,
    /// Masked later while still in view.
    pub masked_later: usize,
    /// Frames from coming into view to being masked, over those masked.
    pub delay_frames_p50: f64,
    #[serde(skip)]
    delays: Vec<f64>,
    /// Person id -> frame it came into view, while not yet masked.
    #[serde(skip)]
    waiting: Vec<(u8, usize)>,
    #[serde(skip)]
    visible: Vec<u8>,
}

impl Entries {
    /// The scores of frame `k`.
    fn observe(&mut self, k: usize, scores: &[InstanceIou]) {
        let now: Vec<u8> = scores.iter().map(|s| s.id).collect();
        for s in scores {
            if k > 0 && !self.visible.contains(&s.id) {
                self.count += 1;
                self.waiting.push((s.id, k));
            }
        }
        // Out of view before being masked: not masked (neither count).
        self.waiting.retain(|(id, _)| now.contains(id));
        let mut masked = Vec::new();
        for &(id, since) in &self.waiting {
            if scores.iter().any(|s| s.id == id && s.iou >= MASKED_IOU) {
                let delay = k - since;
                if delay <= ENTRY_FRAMES {
                    self.masked_in_time += 1;
                } else {
                    self.masked_later += 1;
                }
                self.delays.push(delay as f64);
                masked.push(id);
            }
        }
        self.waiting.retain(|(id, _)| !masked.contains(id));
        self.visible = now;
    }

    /// The counts with the median delay.
    fn finish(mut self) -> Self {
        self.delays.sort_by(f64::total_cmp);
        self.delay_frames_p50 = shared_types::stats::percentile(&self.delays, 50.0);
        self
    }

    /// Share of the entries masked in time.
    pub fn in_time_share(&self) -> f64 {
        self.masked_in_time as f64 / self.count.max(1) as f64
    }
}

/// A person counts as found by the segmenter at this keyframe IoU.
pub const FOUND_IOU: f64 = 0.5;

fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        f64::NAN
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

/// The scores of one network at one input size
/// (`masks-eval --compare-segmenters`).
#[derive(Debug, Clone, Serialize)]
pub struct SegmenterScores {
    /// The model (yolov8n-seg, yolo11n-seg, ...).
    pub network: &'static str,
    /// The execution provider it ran on.
    pub backend: &'static str,
    /// Its square input size, pixels.
    pub input_size: usize,
    /// What it scored.
    pub scores: MaskScores,
}

/// [`evaluate`] for every YOLO-seg network at every input size that all of
/// them have, the rest of `config` unchanged; in one run, so the ms compare.
pub fn compare_segmenters(
    dataset: &Path,
    config: &PipelineConfig,
    keyframe_every: usize,
    min_px: usize,
    limit: Option<usize>,
) -> Result<Vec<SegmenterScores>> {
    let mut rows = Vec::new();
    for family in YoloFamily::ALL {
        for input_size in segmentation::exports::input_sizes() {
            let mut cfg = config.clone();
            let seg = &mut cfg.services.segmenter;
            seg.backend = family.backend().into();
            seg.input_size = Some(input_size as u32);
            seg.model.clear();
            seg.model_sha256.clear();
            seg.model_path = None;
            eprintln!("masks-eval: {} at {input_size}", family.network());
            let scores = evaluate(dataset, &cfg, keyframe_every, min_px, limit, None)
                .with_context(|| format!("{} at {input_size}", family.network()))?;
            rows.push(SegmenterScores {
                network: family.network(),
                backend: family.backend(),
                input_size,
                scores,
            });
        }
    }
    Ok(rows)
}

/// Scores segmenter and propagator on `dataset` (a `dynslam synth` folder).
/// With `save`, every frame's predicted instance labels go there as
/// `NNNN.png` (0: none) with `scores.csv` (one row per scored person), to
/// see where masks fail.
pub fn evaluate(
    dataset: &Path,
    config: &PipelineConfig,
    keyframe_every: usize,
    min_px: usize,
    limit: Option<usize>,
    save: Option<&Path>,
) -> Result<MaskScores> {
    if keyframe_every < 2 {
        bail!("--keyframe-every {keyframe_every}: must be at least 2 (a keyframe and a propagated frame)");
    }
    let truth = MaskList::open(dataset)?.with_context(|| {
        format!(
            "{} has no masks.txt: masks-eval needs a sequence made by `dynslam synth`",
            dataset.display()
        )
    })?;
    let mut frames = tum_folder(dataset, config.source.max_time_diff)?;
    if let Some(n) = limit {
        frames.truncate(n);
    }
    // The export the config's runs would use (its clock mode decides an
    // unset input size).
    let settings = YoloSettings::for_mode(&config.services.segmenter, config.run.mode)?;
    let mut segmenter = YoloSeg::load(init_runtime(&config.onnxruntime)?, settings)?;
    let mut propagator = LkPropagator::new(PropagatorParams::default());
    if config.routing.early_segment_requests {
        propagator = propagator.with_newcomer_check(NewcomerCheck::for_pipeline(
            &config.camera,
            &config.routing,
            pipeline_config::ClockMode::Lockstep,
        ));
    }
    let mut tally = Tally::new(keyframe_every);
    // Frames since the last segmented one, and whether the propagator asked.
    let (mut since_segment, mut requested) = (0usize, false);
    let mut depth_buf = Vec::new();
    let ignore = IgnoreRegions::open(dataset)?;
    let occlusion = Occlusion::open(dataset)?;
    let mut saved = save.map(SavedMasks::create).transpose()?;
    // The frame before's labels: the segmenter keeps a weak detection that
    // continues an object there, as in the pipeline.
    let mut previous_labels: Vec<u8> = Vec::new();
    let mut progress = Progress::new("masks-eval", frames.len() as u64);
    for (k, frame) in frames.iter().enumerate() {
        let (rgb, gt) = frame_and_truth(frame, &truth)?;
        let (w, h) = (rgb.width() as usize, rgb.height() as usize);
        let mut labels = vec![0u8; w * h];
        let scheduled = k == 0 || since_segment + 1 >= keyframe_every;
        if requested && !scheduled {
            tally.early_segments += 1;
        }
        let offset = if scheduled || requested {
            0
        } else {
            since_segment + 1
        };
        since_segment = offset;
        requested = false;
        // The frame's depth, as the pipeline's services get it (weak
        // detections are confirmed by it; what comes into view across a
        // border is checked against it; the newcomer check), decoded
        // before the clock starts.
        let depth = match &frame.depth {
            Some(path) => {
                depth_buf.resize(w * h * 2, 0);
                decode_depth_into(path, (w as u32, h as u32), &mut depth_buf)?;
                Some(
                    DepthImage::new(&depth_buf, w, h, config.source.depth_scale)
                        .context("depth buffer size")?,
                )
            }
            _ => None,
        };
        let t = std::time::Instant::now();
        if offset == 0 {
            let previous = (k > 0).then_some(&previous_labels[..]);
            let instances =
                segmenter.segment_rgbd(rgb.as_raw(), depth, previous, w, h, &mut labels)?;
            tally.seg_ms.push(t.elapsed().as_secs_f64() * 1e3);
            propagator.prompt_with(rgb.as_raw(), w, h, &labels, &instances);
        } else {
            propagator.propagate_rgbd(rgb.as_raw(), depth, w, h, &mut labels);
            tally.prop_ms.push(t.elapsed().as_secs_f64() * 1e3);
            requested = propagator.take_newcomer().is_some();
        }
        let ignored = ignore.at(frame.timestamp, w, h)?;
        let scores = instance_ious(&labels, gt.as_raw(), ignored.as_deref(), w, min_px);
        tally.entries.observe(k, &scores);
        if let Some(saved) = saved.as_mut() {
            saved.write(k, offset, w, h, &labels, &scores)?;
        }
        let occluded = |id| occlusion.occluded(frame.timestamp, id);
        tally.add(offset, scores, occluded, w * h);
        previous_labels = labels;
        progress.inc();
    }
    progress.finish();
    if let Some(saved) = saved.as_mut() {
        saved.finish()?;
    }
    Ok(tally.finish(frames.len(), keyframe_every, min_px, ignore.any()))
}

/// A frame's colour image and its ground-truth labels, of the same size.
fn frame_and_truth(frame: &FrameEntry, truth: &MaskList) -> Result<(RgbImage, GrayImage)> {
    let rgb = image::open(&frame.rgb)
        .with_context(|| frame.rgb.display().to_string())?
        .to_rgb8();
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    let gt = truth.load_at(frame.timestamp).map_err(anyhow::Error::msg)?;
    if (gt.width() as usize, gt.height() as usize) != (w, h) {
        bail!(
            "mask of frame {:.6} is {}x{}, the frame {w}x{h}",
            frame.timestamp,
            gt.width(),
            gt.height()
        );
    }
    Ok((rgb, gt))
}

/// What masks-eval gathers frame by frame.
struct Tally {
    entries: Entries,
    early_segments: usize,
    seg_iou: Vec<f64>,
    prop_iou: Vec<f64>,
    /// Propagated IoU of the people the last segmented frame was prompted
    /// with, and of those it found (IoU >= [`FOUND_IOU`]).
    prompted_iou: Vec<f64>,
    found_iou: Vec<f64>,
    /// Propagated IoU by frames since the segmented one (1, 2, ...).
    by_offset: Vec<Vec<f64>>,
    seg_ms: Vec<f64>,
    prop_ms: Vec<f64>,
    prompted_ids: Vec<u8>,
    found_ids: Vec<u8>,
    seg_cause: ByCause,
    prop_cause: ByCause,
}

impl Tally {
    fn new(keyframe_every: usize) -> Self {
        Self {
            entries: Entries::default(),
            early_segments: 0,
            seg_iou: Vec::new(),
            prop_iou: Vec::new(),
            prompted_iou: Vec::new(),
            found_iou: Vec::new(),
            by_offset: vec![Vec::new(); keyframe_every - 1],
            seg_ms: Vec::new(),
            prop_ms: Vec::new(),
            prompted_ids: Vec::new(),
            found_ids: Vec::new(),
            seg_cause: ByCause::default(),
            prop_cause: ByCause::default(),
        }
    }

    /// The scores of a frame `offset` frames after the last segmented one
    /// (0: segmented itself); `occluded(id)` says whether that person is
    /// occluded there.
    fn add(
        &mut self,
        offset: usize,
        scores: Vec<InstanceIou>,
        occluded: impl Fn(u8) -> bool,
        image_px: usize,
    ) {
        if offset == 0 {
            self.prompted_ids = scores.iter().map(|s| s.id).collect();
            self.found_ids = scores
                .iter()
                .filter(|s| s.iou >= FOUND_IOU)
                .map(|s| s.id)
                .collect();
            self.seg_iou.extend(scores.iter().map(|s| s.iou));
            for s in &scores {
                self.seg_cause.add(s, false, occluded(s.id), image_px);
            }
            return;
        }
        for s in scores {
            let entered = !self.prompted_ids.contains(&s.id);
            self.prop_cause.add(&s, entered, occluded(s.id), image_px);
            self.prop_iou.push(s.iou);
            self.by_offset[offset - 1].push(s.iou);
            if self.prompted_ids.contains(&s.id) {
                self.prompted_iou.push(s.iou);
            }
            if self.found_ids.contains(&s.id) {
                self.found_iou.push(s.iou);
            }
        }
    }

    fn finish(
        mut self,
        frames: usize,
        keyframe_every: usize,
        min_px: usize,
        ignore_regions: bool,
    ) -> MaskScores {
        self.seg_ms.sort_by(f64::total_cmp);
        self.prop_ms.sort_by(f64::total_cmp);
        MaskScores {
            frames,
            keyframe_every,
            min_px,
            segmenter_iou: mean(&self.seg_iou),
            segmenter_samples: self.seg_iou.len(),
            propagator_iou: mean(&self.prop_iou),
            propagator_samples: self.prop_iou.len(),
            propagator_iou_by_offset: self.by_offset.iter().map(|v| mean(v)).collect(),
            propagator_iou_prompted: mean(&self.prompted_iou),
            propagator_iou_found: mean(&self.found_iou),
            segmenter_by_cause: self.seg_cause,
            propagator_by_cause: self.prop_cause,
            ignore_regions,
            early_segments: self.early_segments,
            entries: self.entries.finish(),
            segmenter_ms_p50: shared_types::stats::percentile(&self.seg_ms, 50.0),
            propagator_ms_p50: shared_types::stats::percentile(&self.prop_ms, 50.0),
        }
    }
}

/// `masks-eval --save`: predicted labels per frame and a score table.
struct SavedMasks {
    dir: std::path::PathBuf,
    scores: std::io::BufWriter<std::fs::File>,
}

impl SavedMasks {
    fn create(dir: &Path) -> Result<Self> {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let path = dir.join("scores.csv");
        let file =
            std::fs::File::create(&path).with_context(|| format!("creating {}", path.display()))?;
        let mut scores = std::io::BufWriter::new(file);
        writeln!(scores, "frame,after_keyframe,person,pixels,iou,border_cut")?;
        Ok(Self {
            dir: dir.to_path_buf(),
            scores,
        })
    }

    fn write(
        &mut self,
        frame: usize,
        offset: usize,
        w: usize,
        h: usize,
        labels: &[u8],
        scores: &[InstanceIou],
    ) -> Result<()> {
        let path = self.dir.join(format!("{frame:04}.png"));
        image::save_buffer(
            &path,
            labels,
            w as u32,
            h as u32,
            image::ExtendedColorType::L8,
        )
        .with_context(|| format!("writing {}", path.display()))?;
        for s in scores {
            writeln!(
                self.scores,
                "{frame},{offset},{},{},{:.4},{}",
                s.id, s.pixels, s.iou, s.border_cut as u8
            )?;
        }
        Ok(())
    }

    fn finish(&mut self) -> Result<()> {
        self.scores
            .flush()
            .with_context(|| format!("writing {}", self.dir.join("scores.csv").display()))
    }
}
