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
use nalgebra::{Matrix3, Vector3};
use pipeline::mask_worker::MaskModel;
use pipeline::views::{FrameView, MasksView};
use shared_types::Instance;

use crate::lk::{track, LkParams};
use crate::newcomers::{DepthImage, Newcomer, NewcomerCheck};
use crate::pyramid::{Gray, Pyramid};

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

/// A 2x3 affine map `[a b c; d e f]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Affine(pub [f32; 6]);

impl Affine {
    /// The point `(x, y)` moved by the transform.
    pub fn apply(&self, (x, y): (f32, f32)) -> (f32, f32) {
        let m = &self.0;
        (m[0] * x + m[1] * y + m[2], m[3] * x + m[4] * y + m[5])
    }

    /// The inverse transform (None: singular).
    pub fn inverse(&self) -> Option<Self> {
        let m = &self.0;
        let det = m[0] * m[4] - m[1] * m[3];
        if det.abs() < 1e-6 {
            return None;
        }
        let (a, b, d, e) = (m[4] / det, -m[1] / det, -m[3] / det, m[0] / det);
        Some(Self([
            a,
            b,
            -(a * m[2] + b * m[5]),
            d,
            e,
            -(d * m[2] + e * m[5]),
        ]))
    }

    /// Least-squares affine from point pairs (at least 3, not collinear).
    pub fn fit(src: &[(f32, f32)], dst: &[(f32, f32)]) -> Option<Self> {
        let mut ata = Matrix3::<f64>::zeros();
        let (mut bx, mut by) = (Vector3::<f64>::zeros(), Vector3::<f64>::zeros());
        for (s, d) in src.iter().zip(dst) {
            let v = Vector3::new(s.0 as f64, s.1 as f64, 1.0);
            ata += v * v.transpose();
            bx += v * d.0 as f64;
            by += v * d.1 as f64;
        }
        let inv = ata.try_inverse()?;
        let (px, py) = (inv * bx, inv * by);
        Some(Self([
            px[0] as f32,
            px[1] as f32,
            px[2] as f32,
            py[0] as f32,
            py[1] as f32,
            py[2] as f32,
        ]))
    }
}

/// Robust affine: RANSAC on 3-point samples (deterministic sampling), then
/// least squares on the inliers. Returns the map and the inlier flags.
pub fn robust_affine(
    src: &[(f32, f32)],
    dst: &[(f32, f32)],
    inlier_px: f32,
) -> Option<(Affine, Vec<bool>)> {
    let n = src.len();
    if n < 3 {
        return None;
    }
    let count = |a: &Affine| -> Vec<bool> {
        src.iter()
            .zip(dst)
            .map(|(s, d)| {
                let p = a.apply(*s);
                (p.0 - d.0).powi(2) + (p.1 - d.1).powi(2) <= inlier_px * inlier_px
            })
            .collect()
    };
    let mut best: Option<(Affine, Vec<bool>, usize)> = None;
    let mut state = 0x2545_F491_4F6C_DD1Du64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state % n as u64) as usize
    };
    for _ in 0..64 {
        let (i, j, k) = (next(), next(), next());
        if i == j || j == k || i == k {
            continue;
        }
        let Some(a) = Affine::fit(&[src[i], src[j], src[k]], &[dst[i], dst[j], dst[k]]) else {
            continue;
        };
        let inl = count(&a);
        let c = inl.iter().filter(|&&b| b).count();
        if best.as_ref().is_none_or(|b| c > b.2) {
            best = Some((a, inl, c));
        }
    }
    let (mut a, mut inl, _) =
        best.or_else(|| Affine::fit(src, dst).map(|a| (a, vec![true; n], n)))?;
    for _ in 0..2 {
        let (s, d): (Vec<_>, Vec<_>) = src
            .iter()
            .zip(dst)
            .zip(&inl)
            .filter(|(_, &k)| k)
            .map(|((s, d), _)| (*s, *d))
            .unzip();
        if s.len() < 3 {
            break;
        }
        a = Affine::fit(&s, &d).unwrap_or(a);
        inl = count(&a);
    }
    Some((a, inl))
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
            Gray::from_rgb(rgb, width, height),
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
        for (m, raw) in self.measurable.iter_mut().zip(depth.raw.chunks_exact(2)) {
            *m |= raw != [0, 0];
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

/// Most grid points tracked per object: large objects get a coarser grid,
/// so that the cost per object stays bounded (about 100 + 40 points).
const MAX_GRID_POINTS: usize = 100;
const MAX_BORDER_POINTS: usize = 40;

/// Points to track: a grid inside the mask plus its border pixels (thinned),
/// each at least `inset` pixels inside the mask so that the tracking window
/// sees the object, not the background that moves differently.
fn sample_points(
    mask: &[bool],
    width: usize,
    height: usize,
    min_step: usize,
    inset: usize,
) -> Vec<(f32, f32)> {
    let mut pts = Vec::new();
    let at = |x: usize, y: usize| mask[y * width + x];
    let deep = |x: usize, y: usize| {
        x >= inset
            && y >= inset
            && x + inset < width
            && y + inset < height
            && at(x - inset, y)
            && at(x + inset, y)
            && at(x, y - inset)
            && at(x, y + inset)
    };
    let area = mask.iter().filter(|&&m| m).count();
    let step = min_step.max(((area / MAX_GRID_POINTS) as f32).sqrt().ceil() as usize);
    for y in (step / 2..height).step_by(step) {
        for x in (step / 2..width).step_by(step) {
            if at(x, y) && deep(x, y) {
                pts.push((x as f32, y as f32));
            }
        }
    }
    let mut border = Vec::new();
    for y in 1..height.saturating_sub(1) {
        for x in 1..width.saturating_sub(1) {
            let edge =
                at(x, y) && (!at(x - 1, y) || !at(x + 1, y) || !at(x, y - 1) || !at(x, y + 1));
            // The border point moved inwards along the mask (towards the
            // inside neighbour), where its window covers the object.
            if edge {
                let inward = [(1isize, 0isize), (-1, 0), (0, 1), (0, -1)]
                    .into_iter()
                    .find_map(|(dx, dy)| {
                        let ix = x.checked_add_signed(dx * inset as isize)?;
                        let iy = y.checked_add_signed(dy * inset as isize)?;
                        (ix < width && iy < height && deep(ix, iy)).then_some((ix, iy))
                    });
                if let Some((ix, iy)) = inward {
                    border.push((ix as f32, iy as f32));
                }
            }
        }
    }
    let every = border.len().div_ceil(MAX_BORDER_POINTS).max(1);
    pts.extend(border.into_iter().step_by(every));
    pts
}

/// The object's mask in the new frame and its image motion, or `None` when
/// it is lost.
#[allow(clippy::too_many_arguments)]
fn follow(
    prev: &Pyramid,
    cur: &Pyramid,
    depth: Option<(DepthImage, &[bool])>,
    mask: &[bool],
    guess: (f32, f32),
    width: usize,
    height: usize,
    p: &PropagatorParams,
) -> Option<(Vec<bool>, (f32, f32))> {
    let pts = object_points(mask, width, height, p)?;
    let (kept, dst) = track_points(prev, cur, &pts, guess, p)?;
    let src: Vec<(f32, f32)> = kept.iter().map(|&i| pts[i]).collect();
    warp_mask(prev, cur, depth, mask, &src, &dst, width, height, p)
}

/// Points to follow an object by (a grid inside its mask and its border;
/// [`sample_points`]); None when fewer than 6.
fn object_points(
    mask: &[bool],
    width: usize,
    height: usize,
    p: &PropagatorParams,
) -> Option<Vec<(f32, f32)>> {
    let mut pts = sample_points(mask, width, height, p.grid_step, p.lk.radius);
    if pts.len() < 6 {
        // A thin or small object: its window overlaps the background anyway.
        pts = sample_points(mask, width, height, p.grid_step, 0);
    }
    (pts.len() >= 6).then_some(pts)
}

/// The points of `pts` that LK tracks from `prev` to `cur` and back to
/// where they started (forward-backward check), as (their indices in `pts`,
/// where they are now); None when too few of them (`min_tracked_fraction`,
/// 6).
fn track_points(
    prev: &Pyramid,
    cur: &Pyramid,
    pts: &[(f32, f32)],
    motion: (f32, f32),
    p: &PropagatorParams,
) -> Option<Tracked> {
    let fwd = track(prev, cur, pts, motion, p.lk);
    let ok: Vec<usize> = (0..pts.len()).filter(|&i| fwd[i].is_some()).collect();
    let there: Vec<(f32, f32)> = ok.iter().map(|&i| fwd[i].unwrap()).collect();
    let back = track(cur, prev, &there, (-motion.0, -motion.1), p.lk);
    let (mut kept, mut dst) = (Vec::new(), Vec::new());
    for (k, &i) in ok.iter().enumerate() {
        if let Some(b) = back[k] {
            if (b.0 - pts[i].0).powi(2) + (b.1 - pts[i].1).powi(2) <= p.max_forward_backward.powi(2)
            {
                kept.push(i);
                dst.push(there[k]);
            }
        }
    }
    if (kept.len() as f32) < p.min_tracked_fraction * pts.len() as f32 || kept.len() < 6 {
        return None;
    }
    Some((kept, dst))
}

/// Indices of the points that were tracked, and where they are now.
type Tracked = (Vec<usize>, Vec<(f32, f32)>);

/// The mask in `cur` of the object whose `mask` in `prev` moved its points
/// from `src` to `dst` (a robust affine plus the inliers' residual motion,
/// kept where the grey values agree), and its mean image motion; None when
/// the motion fits no affine or the mask leaves the view.
#[allow(clippy::too_many_arguments)]
fn warp_mask(
    prev: &Pyramid,
    cur: &Pyramid,
    depth: Option<(DepthImage, &[bool])>,
    mask: &[bool],
    src: &[(f32, f32)],
    dst: &[(f32, f32)],
    width: usize,
    height: usize,
    p: &PropagatorParams,
) -> Option<(Vec<bool>, (f32, f32))> {
    let (affine, inliers) = robust_affine(src, dst, p.inlier_px)?;
    let inv = affine.inverse()?;
    // Residual motion of the inliers at their new positions.
    let residuals: Vec<((f32, f32), (f32, f32))> = src
        .iter()
        .zip(dst)
        .zip(&inliers)
        .filter(|(_, &k)| k)
        .map(|((s, d), _)| {
            let a = affine.apply(*s);
            (*d, (d.0 - a.0, d.1 - a.1))
        })
        .collect();
    let gate = depth.and_then(|(d, measurable)| {
        DepthGate::new(
            d,
            measurable,
            residuals.iter().map(|(at, _)| *at),
            width,
            height,
        )
    });
    // Target region: the warped bounding box of the mask, with margin.
    let (mut bx0, mut by0, mut bx1, mut by1) = (f32::MAX, f32::MAX, f32::MIN, f32::MIN);
    let (mut mx0, mut my0, mut mx1, mut my1) = (width, height, 0, 0);
    for (i, &m) in mask.iter().enumerate() {
        if m {
            let (x, y) = (i % width, i / width);
            mx0 = mx0.min(x);
            my0 = my0.min(y);
            mx1 = mx1.max(x);
            my1 = my1.max(y);
        }
    }
    for c in [(mx0, my0), (mx1, my0), (mx0, my1), (mx1, my1)] {
        let (x, y) = affine.apply((c.0 as f32, c.1 as f32));
        bx0 = bx0.min(x);
        by0 = by0.min(y);
        bx1 = bx1.max(x);
        by1 = by1.max(y);
    }
    let margin = 4.0
        + residuals
            .iter()
            .map(|(_, r)| r.0.abs().max(r.1.abs()))
            .fold(0.0, f32::max);
    // An object cut by the image border continues beyond it: what comes
    // into view there is taken as the continuation of the mask's outermost
    // row or column (a person walking in is mostly vertical), so the
    // region extends to that border.
    let cut = BorderCut {
        left: (mx0 <= BORDER_PX).then_some(mx0),
        right: (mx1 + 1 + BORDER_PX >= width).then_some(mx1),
        top: (my0 <= BORDER_PX).then_some(my0),
        bottom: (my1 + 1 + BORDER_PX >= height).then_some(my1),
    };
    let tx0 = match cut.left {
        Some(_) => 0,
        None => (bx0 - margin).floor().max(0.0) as usize,
    };
    let ty0 = match cut.top {
        Some(_) => 0,
        None => (by0 - margin).floor().max(0.0) as usize,
    };
    let tx1 = match cut.right {
        Some(_) => width,
        None => ((bx1 + margin).ceil().max(0.0) as usize).min(width),
    };
    let ty1 = match cut.bottom {
        Some(_) => height,
        None => ((by1 + margin).ceil().max(0.0) as usize).min(height),
    };
    if tx0 >= tx1 || ty0 >= ty1 {
        return None; // left the view
    }
    // Residual field on a coarse grid over the target region (IDW).
    const CELL: usize = 8;
    let (gw, gh) = ((tx1 - tx0) / CELL + 2, (ty1 - ty0) / CELL + 2);
    let mut field = vec![(0.0f32, 0.0f32); gw * gh];
    for gy in 0..gh {
        for gx in 0..gw {
            let (x, y) = ((tx0 + gx * CELL) as f32, (ty0 + gy * CELL) as f32);
            let (mut sx, mut sy, mut sw) = (0.0, 0.0, 0.0);
            for (pos, r) in &residuals {
                let d2 = (pos.0 - x).powi(2) + (pos.1 - y).powi(2);
                let w = 1.0 / (d2 + 64.0);
                sx += w * r.0;
                sy += w * r.1;
                sw += w;
            }
            if sw > 0.0 {
                field[gy * gw + gx] = (sx / sw, sy / sw);
            }
        }
    }
    let residual_at = |x: usize, y: usize| -> (f32, f32) {
        let (fx, fy) = (
            (x - tx0) as f32 / CELL as f32,
            (y - ty0) as f32 / CELL as f32,
        );
        let (gx, gy) = ((fx as usize).min(gw - 2), (fy as usize).min(gh - 2));
        let (wx, wy) = (fx - gx as f32, fy - gy as f32);
        let f = |i: usize, j: usize| field[j * gw + i];
        let (a, b, c, d) = (f(gx, gy), f(gx + 1, gy), f(gx, gy + 1), f(gx + 1, gy + 1));
        (
            (a.0 * (1.0 - wx) + b.0 * wx) * (1.0 - wy) + (c.0 * (1.0 - wx) + d.0 * wx) * wy,
            (a.1 * (1.0 - wx) + b.1 * wx) * (1.0 - wy) + (c.1 * (1.0 - wx) + d.1 * wx) * wy,
        )
    };
    // Grey-value consistency on the half-resolution level (smoothed, so that
    // texture and blur do not flip single pixels).
    let (prev_half, cur_half) = (
        &prev.levels[1.min(prev.levels.len() - 1)],
        &cur.levels[1.min(cur.levels.len() - 1)],
    );
    let half = prev_half.width as f32 / width as f32;
    let mut out = vec![false; width * height];
    let mut area = 0usize;
    for y in ty0..ty1 {
        for x in tx0..tx1 {
            // Where this pixel came from: undo the residual, then the affine.
            let r = residual_at(x, y);
            let (sx, sy) = inv.apply((x as f32 - r.0, y as f32 - r.1));
            let inside = match cut.source(sx.round(), sy.round(), width, height) {
                // Seen in the previous frame: in the mask there and of the
                // same grey value here.
                Some((ix, iy, true)) => {
                    mask[iy * width + ix]
                        && (cur_half.sample(x as f32 * half, y as f32 * half)
                            - prev_half.sample(sx * half, sy * half))
                        .abs()
                            <= p.max_grey_difference
                }
                // Come into view across a border the object was cut by: an
                // extrapolation, so with depth only where the depth is the
                // object's (else the band between the border and an object
                // that walked in grows with every frame), or where the
                // camera never measures depth.
                Some((ix, iy, false)) => {
                    mask[iy * width + ix] && gate.as_ref().is_none_or(|g| g.allows(x, y))
                }
                None => false,
            };
            if inside {
                out[y * width + x] = true;
                area += 1;
            }
        }
    }
    let n = inliers.iter().filter(|&&k| k).count().max(1) as f32;
    let moved = src
        .iter()
        .zip(dst)
        .zip(&inliers)
        .filter(|(_, &k)| k)
        .fold((0.0, 0.0), |acc, ((s, d), _)| {
            (acc.0 + (d.0 - s.0) / n, acc.1 + (d.1 - s.1) / n)
        });
    (area >= 30).then_some((out, moved))
}

/// Where an object that came into view across an image border may be: at
/// the depth of its tracked points (10th to 90th percentile, a few points
/// slide onto the background; widened by 0.1 m and 5 % for a body's relief
/// and depth noise), or where the camera never measures depth.
struct DepthGate<'a> {
    depth: DepthImage<'a>,
    measurable: &'a [bool],
    width: usize,
    near: f32,
    far: f32,
}

impl<'a> DepthGate<'a> {
    /// From the positions of the object's tracked points in the new frame;
    /// None with fewer than 6 of them on measured depth.
    fn new(
        depth: DepthImage<'a>,
        measurable: &'a [bool],
        points: impl Iterator<Item = (f32, f32)>,
        width: usize,
        height: usize,
    ) -> Option<Self> {
        let mut z: Vec<f32> = points
            .filter_map(|(x, y)| {
                let (ix, iy) = (x.round(), y.round());
                (ix >= 0.0 && iy >= 0.0 && (ix as usize) < width && (iy as usize) < height)
                    .then(|| depth.metres_at(ix as usize, iy as usize, width))
                    .flatten()
            })
            .collect();
        if z.len() < 6 {
            return None;
        }
        z.sort_by(f32::total_cmp);
        let (near, far) = (z[z.len() / 10], z[z.len() * 9 / 10]);
        Some(Self {
            depth,
            measurable,
            width,
            near: near - 0.1 - 0.05 * near,
            far: far + 0.1 + 0.05 * far,
        })
    }

    fn allows(&self, x: usize, y: usize) -> bool {
        match self.depth.metres_at(x, y, self.width) {
            Some(z) => (self.near..=self.far).contains(&z),
            None => !self
                .measurable
                .get(y * self.width + x)
                .copied()
                .unwrap_or(false),
        }
    }
}

/// A mask this close to the image border (pixels) is cut by it: the
/// segmenter's masks stop a pixel or two short of the edge.
const BORDER_PX: usize = 3;

/// The image borders an object's mask is cut by, each with the mask's
/// outermost column or row on that side.
#[derive(Debug, Clone, Copy)]
struct BorderCut {
    left: Option<usize>,
    right: Option<usize>,
    top: Option<usize>,
    bottom: Option<usize>,
}

impl BorderCut {
    /// The previous-frame pixel a source position reads, and whether it was
    /// seen there: beyond the mask's outermost column or row on a cut side
    /// the position moves onto it (not seen: extrapolated into what has
    /// come into view); elsewhere outside the image, None.
    fn source(&self, x: f32, y: f32, width: usize, height: usize) -> Option<(usize, usize, bool)> {
        if !x.is_finite() || !y.is_finite() {
            return None;
        }
        let mut seen = true;
        let mut axis = |v: f32, low: Option<usize>, high: Option<usize>, size: usize| {
            let v = match (low, high) {
                (Some(l), _) if v < l as f32 => {
                    seen = false;
                    l as f32
                }
                (_, Some(h)) if v > h as f32 => {
                    seen = false;
                    h as f32
                }
                _ => v,
            };
            (v >= 0.0 && v < size as f32).then_some(v as usize)
        };
        let ix = axis(x, self.left, self.right, width)?;
        let iy = axis(y, self.top, self.bottom, height)?;
        Some((ix, iy, seen))
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn affine_fit_and_inverse_round_trip() {
        let a = Affine([1.05, 0.1, 3.0, -0.08, 0.97, -2.0]);
        let src: Vec<(f32, f32)> = (0..10)
            .map(|i| ((i * 7 % 13) as f32 * 5.0, (i * 3 % 11) as f32 * 4.0))
            .collect();
        let mut dst: Vec<(f32, f32)> = src.iter().map(|&p| a.apply(p)).collect();
        dst[2] = (500.0, 500.0); // an outlier
        let (fit, inl) = robust_affine(&src, &dst, 1.0).unwrap();
        assert!(!inl[2] && inl.iter().filter(|&&b| b).count() == 9);
        for k in 0..6 {
            assert!((fit.0[k] - a.0[k]).abs() < 1e-3, "{fit:?}");
        }
        let p = fit.inverse().unwrap().apply(fit.apply((10.0, 20.0)));
        assert!((p.0 - 10.0).abs() < 1e-3 && (p.1 - 20.0).abs() < 1e-3);
    }
}
