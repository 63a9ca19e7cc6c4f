//! Per-object mask propagation, prompted by the segmenter's keyframe masks.
//!
//! For every object: points on a grid inside its mask and along its border
//! are tracked from the previous frame with pyramidal LK and checked
//! forward-backward; a robust affine motion (RANSAC on 3-point samples, then
//! least squares on the inliers) carries the mask, and the inliers' residual
//! motion, interpolated over the object (inverse-distance weights on a coarse
//! grid), lets parts that move differently (arms, legs) follow. An object
//! whose points are mostly lost, or that leaves the view, ends; the next
//! segmenter result prompts afresh. Like SAM 2's memory, it propagates only
//! the instances it was prompted with.

use std::collections::VecDeque;
use std::sync::Arc;

use anyhow::Result;
use mask_model::MaskModel;
use shared_types::views::{FrameView, MasksView};
use shared_types::Instance;

use crate::lk::LkParams;
use crate::newcomers::{DepthImage, Newcomer, NewcomerCheck};
use crate::pyramid::{GrayF32, Pyramid};
use crate::warp::{follow, object_points, track_points, warp_mask};
pub use crate::warp::{robust_affine, Affine};

/// The LK propagator's parameters.
#[derive(Debug, Clone, Copy)]
pub struct PropagatorParams {
    /// Spacing of the tracked points inside a mask (pixels).
    pub grid_step: usize,
    /// Keep a point when tracking it back lands within this many pixels.
    pub max_forward_backward: f32,
    /// An object ends when fewer than this fraction of its points track.
    pub min_tracked_fraction: f32,
    /// RANSAC inlier distance (pixels).
    pub inlier_px: f32,
    /// A warped mask pixel is kept only when the new frame's smoothed grey
    /// value there is within this of the value where it came from: this is
    /// what lets the scene cover a person (occlusion) and what stops the mask
    /// from smearing onto background the motion model drags along.
    pub max_grey_difference: f32,
    /// Levels of the image pyramids.
    pub pyramid_levels: usize,
    /// Point tracking.
    pub lk: LkParams,
}

impl Default for PropagatorParams {
    fn default() -> Self {
        Self {
            grid_step: 8,
            max_forward_backward: 2.0,
            min_tracked_fraction: 0.15,
            inlier_px: 2.0,
            max_grey_difference: 30.0,
            pyramid_levels: 4,
            lk: LkParams::default(),
        }
    }
}

/// One object being followed.
#[derive(Debug, Clone)]
struct Object {
    instance: Instance,
    /// Full-frame mask.
    mask: Vec<bool>,
    /// The object's image motion in the last frame beyond the image's own
    /// shift ([`Pyramid::shift_to`]; pixels): its walking. With the next
    /// frame's shift, the starting guess for tracking it into that frame.
    own_motion: (f32, f32),
}

/// Frames whose pyramids the propagator keeps after propagating to them: a
/// segmenter result for one of them (real time: it comes several frames
/// late) is carried forward from its own image. 30 frames (~12 MB at
/// 640x480) is a second at 30 fps, more than a loaded segmenter takes.
const RECENT_FRAMES: usize = 30;

/// Frames the segmenter works on whose pyramids are kept
/// ([`LkPropagator::keep_image`]), whatever their age, until their prompt
/// comes. On a loaded machine the niced segmenter
/// answers 30-40 frames after its frame (30 fps with two busy processes),
/// past [`RECENT_FRAMES`]: 6-7 of its 9-10 results in a run were ignored
/// ("image gone") and the people were never masked (synthesised people in
/// front, real time, ATE 0.085 m against 0.012 m in lockstep). It works on
/// one frame at a time; a frame it never answers (replaced before its turn)
/// leaves when newer ones come or a newer frame's prompt does.
const AWAITED_FRAMES: usize = 4;

/// Most LK steps a late prompt takes to catch up with the newest frame
/// ([`LkPropagator::catch_up`]): each costs about as much as propagating a
/// frame, and they come at once.
const CATCH_UP_STEPS: usize = 8;

/// Most points an object is followed by through a catch-up's steps (every
/// k-th of its grid and border points): LK costs per point, and the steps
/// come at once (with ~120 points, 25-100 ms a prompt for 1-3 people at 60
/// fps: no masks were made meanwhile). The mask is warped once at the end,
/// where an affine and a coarser residual field need no more.
const CATCH_UP_POINTS: usize = 48;

/// The `lk` propagation backend.
pub struct LkPropagator {
    params: PropagatorParams,
    prev: Option<Arc<Pyramid>>,
    objects: Vec<Object>,
    width: usize,
    height: usize,
    /// The pyramids of the last frames propagated to, by sequence number.
    recent: VecDeque<(u64, Arc<Pyramid>)>,
    /// The pyramids of the frames the segmenter works on
    /// ([`Self::keep_image`]), until their prompts come.
    awaited: VecDeque<(u64, Arc<Pyramid>)>,
    /// Prompts taken from the worker's held frame.
    prompts_held: u64,
    /// Prompts that arrived after newer frames had been propagated.
    prompts_behind: u64,
    /// Prompts whose image was no longer at hand (ignored).
    prompts_lost: u64,
    /// Early segmenter requests for what no followed object covers.
    newcomers: Option<NewcomerCheck>,
    /// What the last propagated frame asked for, until taken.
    newcomer: Option<Newcomer>,
    /// The frame whose newcomer check last asked for a segmenter run: only
    /// a prompt on a later frame answers it.
    asked_on: Option<u64>,
    /// Pixels where the depth camera measured something in some frame of
    /// this run (empty before the first depth): elsewhere it never does
    /// (the registered depth's border bands: fr1 about 36 rows at the top,
    /// 40 columns at the right).
    measurable: Vec<bool>,
}

impl LkPropagator {
    /// A propagator with `params` (no newcomer check).
    pub fn new(params: PropagatorParams) -> Self {
        Self {
            params,
            prev: None,
            objects: Vec::new(),
            width: 0,
            height: 0,
            recent: VecDeque::new(),
            awaited: VecDeque::new(),
            prompts_held: 0,
            prompts_behind: 0,
            prompts_lost: 0,
            newcomers: None,
            newcomer: None,
            asked_on: None,
            measurable: Vec::new(),
        }
    }

    /// Also looks for newcomers on every frame propagated to with depth
    /// ([`Self::take_newcomer`]).
    pub fn with_newcomer_check(mut self, check: NewcomerCheck) -> Self {
        self.newcomers = Some(check);
        self
    }

    /// The newcomer the last propagated frame found (an early segmenter
    /// request), once.
    pub fn take_newcomer(&mut self) -> Option<Newcomer> {
        self.newcomer.take()
    }

    /// [`Self::propagate`] to frame `seq`, whose image is then kept for a
    /// late prompt ([`Self::prompt_behind`]).
    pub fn propagate_frame(
        &mut self,
        seq: u64,
        rgb: &[u8],
        depth: Option<DepthImage>,
        width: usize,
        height: usize,
        labels: &mut [u8],
    ) -> Vec<Instance> {
        // A frame the segmenter works on had its pyramid built when it was
        // kept (`keep_image`): not built again.
        let cur = self
            .kept(seq)
            .filter(|p| p.levels[0].width == width && p.levels[0].height == height)
            .unwrap_or_else(|| self.pyramid(rgb, width, height));
        let instances = self.propagate_pyramid(cur, depth, width, height, labels);
        if self.newcomer.is_some() {
            self.asked_on = Some(seq);
        }
        self.remember(seq);
        instances
    }

    fn pyramid(&self, rgb: &[u8], width: usize, height: usize) -> Arc<Pyramid> {
        Arc::new(Pyramid::new(
            GrayF32::from_rgb(rgb, width, height),
            self.params.pyramid_levels,
        ))
    }

    /// Keeps frame `seq`'s image (one the segmenter is working on) for its
    /// prompt ([`Self::prompt_behind`]), however late it comes
    /// ([`AWAITED_FRAMES`]).
    pub fn keep_image(&mut self, seq: u64, rgb: &[u8], width: usize, height: usize) {
        let pyramid = self.pyramid(rgb, width, height);
        self.awaited.retain(|(s, _)| *s != seq);
        self.awaited.push_back((seq, pyramid));
        while self.awaited.len() > AWAITED_FRAMES {
            self.awaited.pop_front();
        }
    }

    /// Keeps the pyramid of the frame just propagated to as frame `seq`'s.
    fn remember(&mut self, seq: u64) {
        if let Some(prev) = self.prev.clone() {
            self.store(seq, prev);
        }
    }

    /// Frame `seq`'s kept pyramid, if any.
    fn kept(&self, seq: u64) -> Option<Arc<Pyramid>> {
        self.recent
            .iter()
            .chain(&self.awaited)
            .find(|(s, _)| *s == seq)
            .map(|(_, p)| p.clone())
    }

    fn store(&mut self, seq: u64, pyramid: Arc<Pyramid>) {
        self.recent.retain(|(s, _)| *s != seq);
        self.recent.push_back((seq, pyramid));
        while self.recent.len() > RECENT_FRAMES {
            self.recent.pop_front();
        }
    }

    /// New prompts on a frame propagated to earlier (`seq`), when its
    /// pyramid is still kept: the objects are followed from that image to
    /// the next frame. False when it is not.
    pub fn prompt_behind(&mut self, seq: u64, labels: &[u8], instances: &[Instance]) -> bool {
        let pyramid = self.kept(seq);
        // Older frames' prompts will not come after this one's (the
        // segmenter answers in order), or are not worth following.
        self.awaited.retain(|(s, _)| *s > seq);
        let Some(pyramid) = pyramid else {
            return false;
        };
        self.start_from(pyramid, labels, instances);
        self.answered(labels, self.asked_on.is_none_or(|asked| seq > asked));
        self.catch_up(seq);
        true
    }

    /// Follows the objects from the prompted frame `seq` through the kept
    /// frames propagated to since, up to the newest: a late prompt (real
    /// time) is several frames behind, and one LK step over all of them
    /// lost every object (the synthesised people in front at 60 fps: no
    /// propagated frame of 252 had a mask; forward-backward agreement for
    /// 0-17 of 120 points) where steps of a frame or two keep them. At most
    /// [`CATCH_UP_STEPS`] steps (a stride over the kept frames beyond
    /// that), without depth (not kept). Each step's LK starts from the
    /// image's shift between its frames: starting from the object's last
    /// motion (none on the first step) kept 0-12 of ~100 points through
    /// fast turns (realtime-bench, people across, 60 fps with 2 busy).
    fn catch_up(&mut self, seq: u64) {
        let later: Vec<Arc<Pyramid>> = self
            .recent
            .iter()
            .filter(|(s, _)| *s > seq)
            .map(|(_, p)| p.clone())
            .collect();
        let (Some(start), Some(newest)) = (self.prev.clone(), later.last().cloned()) else {
            return;
        };
        let stride = later.len().div_ceil(CATCH_UP_STEPS).max(1);
        // Every stride-th frame counted back from the newest, which is
        // where the next frame is followed from.
        let steps: Vec<&Arc<Pyramid>> = later.iter().rev().step_by(stride).rev().collect();
        // Each step's image shift, the LK guess for every object: the
        // steps span several frames and unequal gaps, where the camera's
        // turn moves everything more than the object's own motion does
        // ([`Pyramid::shift_to`]).
        let shifts: Vec<(f32, f32)> = std::iter::once(&start)
            .chain(steps.iter().copied())
            .collect::<Vec<_>>()
            .windows(2)
            .map(|w| w[0].shift_to(w[1]))
            .collect();
        // The image's shift from the prompted frame to the newest: an
        // object's motion beyond it is its own.
        let shifted = shifts
            .iter()
            .fold((0.0, 0.0), |a, s| (a.0 + s.0, a.1 + s.1));
        let (width, height, params) = (self.width, self.height, self.params);
        let objects = std::mem::take(&mut self.objects);
        self.objects = objects
            .into_iter()
            .filter_map(|mut obj| {
                // Points chained through the steps; the mask warped once,
                // from the prompted frame to the newest.
                let all = object_points(&obj.mask, width, height, &params)?;
                let every = all.len().div_ceil(CATCH_UP_POINTS).max(1);
                let first: Vec<(f32, f32)> = all.into_iter().step_by(every).collect();
                let (mut src, mut at) = (first.clone(), first);
                let mut from = &start;
                for (&cur, &shift) in steps.iter().zip(&shifts) {
                    let (kept, now) = track_points(from, cur, &at, shift, &params)?;
                    // The starting positions of the points that survived.
                    src = kept.iter().map(|&i| src[i]).collect();
                    at = now;
                    from = cur;
                }
                let (mask, moved) = warp_mask(
                    &start, &newest, None, &obj.mask, &src, &at, width, height, &params,
                )?;
                obj.mask = mask;
                // Per frame: the next frame is one after the newest.
                let frames = later.len() as f32;
                obj.own_motion = (
                    (moved.0 - shifted.0) / frames,
                    (moved.1 - shifted.1) / frames,
                );
                Some(obj)
            })
            .collect();
        self.prev = Some(newest);
    }

    /// Objects of `labels` follow from the image of `pyramid` on.
    fn start_from(&mut self, pyramid: Arc<Pyramid>, labels: &[u8], instances: &[Instance]) {
        self.set_objects(labels, instances);
        // The size propagation checks the next frame against.
        if let Some(base) = pyramid.levels.first() {
            self.width = base.width;
            self.height = base.height;
        }
        self.prev = Some(pyramid);
    }

    fn set_objects(&mut self, labels: &[u8], instances: &[Instance]) {
        self.objects = instances
            .iter()
            .enumerate()
            .map(|(i, inst)| Object {
                instance: *inst,
                mask: labels.iter().map(|&l| l as usize == i + 1).collect(),
                own_motion: (0.0, 0.0),
            })
            .filter(|o| o.mask.iter().any(|&m| m))
            .collect();
    }

    /// New prompts: the keyframe image and its instance label image
    /// (`i + 1` for `instances[i]`). Replaces every object.
    pub fn prompt_with(
        &mut self,
        rgb: &[u8],
        width: usize,
        height: usize,
        labels: &[u8],
        instances: &[Instance],
    ) {
        let pyramid = self.pyramid(rgb, width, height);
        self.start_from(pyramid, labels, instances);
        self.answered(labels, true);
    }

    /// The newcomer check learns what the segmenter found
    /// ([`NewcomerCheck::answered`]).
    fn answered(&mut self, labels: &[u8], after_request: bool) {
        if let Some(check) = self.newcomers.as_mut() {
            check.answered(labels, self.width, after_request);
        }
    }

    /// Marks the pixels `depth` measured (`pixels` of them) as measurable.
    fn note_measured(&mut self, depth: &DepthImage, pixels: usize) {
        if self.measurable.len() != pixels {
            self.measurable = vec![false; pixels];
        }
        for (m, raw) in self.measurable.iter_mut().zip(depth.image.data) {
            *m |= *raw != [0, 0];
        }
    }

    /// Number of objects still followed.
    pub fn objects(&self) -> usize {
        self.objects.len()
    }

    /// Follows every object into the new frame; writes its labels.
    pub fn propagate(
        &mut self,
        rgb: &[u8],
        width: usize,
        height: usize,
        labels: &mut [u8],
    ) -> Vec<Instance> {
        self.propagate_rgbd(rgb, None, width, height, labels)
    }

    /// [`Self::propagate`]; with the frame's depth, the newcomer check (when
    /// configured) runs too.
    pub fn propagate_rgbd(
        &mut self,
        rgb: &[u8],
        depth: Option<DepthImage>,
        width: usize,
        height: usize,
        labels: &mut [u8],
    ) -> Vec<Instance> {
        let cur = self.pyramid(rgb, width, height);
        self.propagate_pyramid(cur, depth, width, height, labels)
    }

    /// [`Self::propagate_rgbd`] to the frame whose pyramid is `cur`.
    fn propagate_pyramid(
        &mut self,
        cur: Arc<Pyramid>,
        depth: Option<DepthImage>,
        width: usize,
        height: usize,
        labels: &mut [u8],
    ) -> Vec<Instance> {
        self.newcomer = None;
        let Some(prev) = self
            .prev
            .take()
            .filter(|_| width == self.width && height == self.height)
        else {
            // No prompt yet (or the frame size changed): nothing to follow.
            self.objects.clear();
            self.prev = Some(cur);
            self.width = width;
            self.height = height;
            return Vec::new();
        };
        if let Some(d) = depth {
            self.note_measured(&d, width * height);
        }
        let params = self.params;
        let (prev_ref, cur_ref) = (&*prev, &*cur);
        let measurable = &self.measurable;
        let objects = std::mem::take(&mut self.objects);
        // The newcomer check looks outside what the followed objects cover
        // in the previous frame (their masks, read in place). It runs
        // beside the objects' propagation, on another core when one is
        // free: the masks wait only for the longer of the two.
        let followed: Vec<&[bool]> = objects.iter().map(|o| o.mask.as_slice()).collect();
        // Where the propagator skips frames (real time under load) the
        // camera's turn between the frames it takes reached 40-100 px on
        // fr1_rpy, past LK's reach from the last frame's motion: each
        // object's guess is the image's shift plus its own motion.
        let shift = if objects.is_empty() {
            (0.0, 0.0)
        } else {
            prev_ref.shift_to(cur_ref)
        };
        let (moved, newcomer) = std::thread::scope(|scope| {
            let check = match (self.newcomers.as_mut(), depth) {
                (Some(check), Some(depth)) => Some({
                    let followed = &followed;
                    scope.spawn(move || check.check(prev_ref, cur_ref, followed, depth, params.lk))
                }),
                _ => None,
            };
            let moved: Vec<_> = objects
                .iter()
                .map(|obj| {
                    let depth = depth.map(|d| (d, measurable.as_slice()));
                    let guess = (shift.0 + obj.own_motion.0, shift.1 + obj.own_motion.1);
                    follow(
                        prev_ref, cur_ref, depth, &obj.mask, guess, width, height, &params,
                    )
                })
                .collect();
            let newcomer = check.and_then(|h| {
                h.join()
                    .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
            });
            (moved, newcomer)
        });
        let kept = objects
            .into_iter()
            .zip(moved)
            .filter_map(|(mut obj, moved)| {
                let (mask, motion) = moved?;
                obj.mask = mask;
                obj.own_motion = (motion.0 - shift.0, motion.1 - shift.1);
                Some(obj)
            })
            .collect();
        self.newcomer = newcomer;
        self.objects = kept;
        self.prev = Some(cur);
        let mut out = Vec::new();
        for (i, obj) in self.objects.iter_mut().enumerate().take(254) {
            let (mut x0, mut y0, mut x1, mut y1) = (width, height, 0, 0);
            for (p, &m) in obj.mask.iter().enumerate() {
                if m {
                    let (x, y) = (p % width, p / width);
                    x0 = x0.min(x);
                    y0 = y0.min(y);
                    x1 = x1.max(x + 1);
                    y1 = y1.max(y + 1);
                    if labels[p] == 0 {
                        labels[p] = (i + 1) as u8;
                    }
                }
            }
            obj.instance.bbox = [x0 as f32, y0 as f32, x1 as f32, y1 as f32];
            out.push(obj.instance);
        }
        out
    }
}

impl MaskModel for LkPropagator {
    fn name(&self) -> &str {
        "lk"
    }

    fn infer(&mut self, frame: &FrameView, labels: &mut [u8]) -> Result<Vec<Instance>> {
        let (w, h) = (frame.width(), frame.height());
        let depth = frame.depth_image();
        let instances = self.propagate_frame(frame.header.seq, frame.rgb, depth, w, h, labels);
        if let Some(n) = self.newcomer {
            tracing::debug!(
                seq = frame.header.seq,
                cells = n.cells,
                bbox = ?n.bbox,
                why = ?n.why,
                "segmenter run wanted (something moves outside the followed objects, again where it found nothing, or a view it has not seen)"
            );
        }
        Ok(instances)
    }

    fn wants_segment(&mut self) -> bool {
        self.take_newcomer().is_some()
    }

    fn prompt(&mut self, frame: Option<&FrameView>, masks: &MasksView) {
        let seq = masks.header.seq;
        let (labels, instances) = (masks.labels, masks.header.instances());
        // A prompt on a kept frame (one propagated to, or kept while the
        // segmenter worked on it; real time: the segmenter runs behind)
        // starts from that frame's own image; the next frame is then
        // reached in one step.
        if self.prompt_behind(seq, labels, instances) {
            self.prompts_behind += 1;
            return;
        }
        match frame {
            Some(f) => {
                self.prompts_held += 1;
                self.prompt_with(f.rgb, f.width(), f.height(), labels, instances)
            }
            None => {
                self.prompts_lost += 1;
                tracing::warn!(seq, "keyframe image no longer held; prompt ignored");
            }
        }
    }

    fn keep(&mut self, frame: &FrameView) {
        self.keep_image(frame.header.seq, frame.rgb, frame.width(), frame.height());
    }

    fn summary(&self) -> Option<String> {
        let requests = match &self.newcomers {
            Some(check) => format!(
                "; early segmenter requests: {} (something moving outside the followed objects; {} of them again where the segmenter found nothing, {} for a view it had not seen)",
                check.requests(),
                check.retries(),
                check.unseen_views()
            ),
            None => String::new(),
        };
        Some(format!(
            "segmenter prompts used: {} ({} on their own frame, {} carried forward from a kept frame), ignored (image gone): {}{requests}",
            self.prompts_held + self.prompts_behind,
            self.prompts_held,
            self.prompts_behind,
            self.prompts_lost
        ))
    }
}
