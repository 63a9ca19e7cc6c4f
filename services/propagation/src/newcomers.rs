//! Early segmenter requests: something moves in the background that no
//! followed object covers (a person who walked in after the keyframe).
//!
//! The propagator follows only the objects it was prompted with; a person
//! who enters between keyframes stays unmasked until the next segmenter run.
//! This check notices such a region so that the supervisor can route the
//! next frame to the segmenter at once instead of waiting for
//! `max_segment_age`.
//!
//! The most trackable point of each cell of a coarse grid outside the
//! followed objects is tracked from the previous frame with the
//! propagator's LK (at half resolution).
//! With the depth of the new frame, the camera's instantaneous motion (the
//! Longuet-Higgins and Prazdny flow field: 3 translation and 3 rotation
//! parameters, linear in them given inverse depth: [`Motion`]) explains the
//! flow of the static scene, parallax included; it is found by the one
//! RANSAC driver of the SLAM core. Grid cells whose points move more than
//! `min_residual_px` unlike that motion are movers; a connected group of at
//! least `min_cells` of them that moves alike, found in two frames in a row,
//! is a newcomer. A newcomer the segmenter then does not find (a person
//! just in view at the border is a sliver it misses) is asked for once more
//! a frame later. And the view itself: once the camera has turned by
//! `unseen_view_share` of the image since the segmenter last saw it, what
//! has come into view is asked for (a person brought into view by the
//! camera's turn, walking along with it, shows no motion of their own).
//! The pixel size of a cell and the group size make
//! the smallest region that asks (24x24 px cells, 3 of them: 1728 px, under
//! the 2000 px from which `masks-eval` scores a person). About 4 ms a
//! 640x480 frame on one core of the 2-core machine (`propagator-bench`).

use nalgebra::{SMatrix, SVector};
use pipeline_config::{CameraConfig, ClockMode, RoutingConfig};
use slam_core::geometry::ransac::Ransac;
use slam_core::Camera;

use crate::lk::{track, LkParams};
use crate::pyramid::{GrayF32, Pyramid};

/// The newcomer check's parameters.
#[derive(Debug, Clone, Copy)]
pub struct NewcomerParams {
    /// Spacing of the background grid (pixels).
    pub cell_px: usize,
    /// A point the camera's motion explains within this is static scene
    /// (pixels; RANSAC's inlier distance).
    pub inlier_px: f64,
    /// The share of the tracked points the camera's motion must explain
    /// for the frame to be judged (a blurred background tracks badly).
    pub min_agreement: f64,
    /// A point off the camera's motion by more than this, and by more than
    /// `relative_residual` of the image motion the camera gives it, moves
    /// on its own (fast turns blur, and small model errors grow with the
    /// motion).
    pub min_residual_px: f64,
    /// See `min_residual_px`.
    pub relative_residual: f64,
    /// A cell's point is tracked only where LK's window has this much
    /// texture in both directions (smallest structure-tensor eigenvalue
    /// per pixel, grey levels squared, at the tracking resolution).
    pub min_corner_score: f32,
    /// Connected mover cells that make a newcomer...
    pub min_cells: usize,
    /// ... when they move alike: the length of their mean residual over
    /// their mean residual length (1: all one way; mistracked points on
    /// blur and depth edges scatter).
    pub min_coherence: f64,
    /// After a request, frames in which no other is made near the region
    /// that asked (a mover no class list names would otherwise ask on every
    /// frame); "near" grows by a cell a frame (it moves on). A region
    /// elsewhere (another person walking in) asks at once.
    pub cooldown_frames: u32,
    /// A moving region's request whose segmenter run found nothing over
    /// the region is made again this many frames after the answer, once: by
    /// then more of them is in view.
    pub retry_frames: u32,
    /// A request once the image has shifted by this share of its width (or
    /// height) since the last segmenter run (the background's median flow,
    /// summed); 0: never (`routing.unseen_view_share`).
    pub unseen_view_share: f32,
}

impl Default for NewcomerParams {
    fn default() -> Self {
        Self {
            cell_px: 24,
            inlier_px: 2.5,
            min_agreement: 0.4,
            min_residual_px: 6.0,
            relative_residual: 0.25,
            min_cells: 3,
            min_corner_score: 60.0,
            min_coherence: 0.7,
            cooldown_frames: 5,
            retry_frames: 1,
            unseen_view_share: RoutingConfig::default().unseen_view_share,
        }
    }
}

pub use shared_types::views::DepthImage;

/// A region that asked for a segmenter run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Newcomer {
    /// Mover cells in the group (0 for the unseen view).
    pub cells: usize,
    /// Bounding box of the group in the new frame: x0, y0, x1, y1 (pixels).
    pub bbox: [usize; 4],
    /// Why it asks.
    pub why: Why,
}

/// Why a segmenter run is asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Why {
    /// A group of cells moves unlike the camera.
    Moving,
    /// Again: the segmenter found nothing where a moving group asked.
    Unanswered,
    /// The camera has turned by `unseen_view_share` since the segmenter
    /// last saw the view: the band that came into view.
    UnseenView,
}

impl Newcomer {
    /// Whether the two boxes overlap once grown by `margin` pixels.
    fn near(&self, other: &Newcomer, margin: usize) -> bool {
        let ([ax0, ay0, ax1, ay1], [bx0, by0, bx1, by1]) = (self.bbox, other.bbox);
        ax0 < bx1 + margin && bx0 < ax1 + margin && ay0 < by1 + margin && by0 < ay1 + margin
    }
}

/// The check, with what it carries from frame to frame.
#[derive(Debug, Clone)]
pub struct NewcomerCheck {
    params: NewcomerParams,
    camera: Camera,
    /// The background's median image motion in the last frame: the starting
    /// guess for tracking into the next (fast camera turns).
    flow_guess: (f32, f32),
    /// Frames to go before another request may be made near `asked`.
    cooldown: u32,
    /// The region of the last request.
    asked: Option<Newcomer>,
    /// The groups found in the previous frame: a newcomer is a group found
    /// in two frames in a row at about the same place (a flicker of
    /// mistracked points is not).
    last: Vec<Newcomer>,
    /// Whether the last request (`asked`) waits for the segmenter's objects
    /// on a frame after it ([`NewcomerCheck::answered`]).
    awaiting: bool,
    /// Frames to go before the last request, left unanswered, is made again.
    retry_in: Option<u32>,
    /// The image's shift since the last segmenter run (pixels).
    unseen_shift: (f32, f32),
    requests: u64,
    retries: u64,
    unseen_views: u64,
}

/// One background point tracked into the new frame.
struct Flow {
    cell: (usize, usize),
    /// Ideal (undistorted) normalised coordinates in the previous frame.
    x: f64,
    y: f64,
    /// Its image motion in normalised coordinates.
    du: f64,
    dv: f64,
    inverse_depth: f64,
}

/// Camera motion: translation (in units of the inverse depth's metres) and
/// rotation (radians), in the small-motion flow field of Longuet-Higgins
/// and Prazdny. Its second-order error (a fraction of a pixel at TUM's
/// fastest turns of about 0.05 rad a frame) is under the residual limits.
/// An exact model (`M x + rho t` by the direct linear transform) was tried:
/// it has a trivial solution on scenes of one depth and did not remove the
/// false requests on the shared sequence either.
type Motion = SVector<f64, 6>;

/// Corners to track: each one's cell on the grid, and the corners (pixels).
type CellPoints = (Vec<(usize, usize)>, Vec<(f32, f32)>);

impl Flow {
    /// The two rows of the flow equation `(du, dv) = J * motion`.
    fn rows(&self) -> [([f64; 6], f64); 2] {
        let (x, y, r) = (self.x, self.y, self.inverse_depth);
        [
            ([-r, 0.0, r * x, x * y, -(1.0 + x * x), y], self.du),
            ([0.0, -r, r * y, 1.0 + y * y, -x * y, -x], self.dv),
        ]
    }

    /// The image motion `motion` gives the point (normalised coordinates).
    fn predicted(&self, motion: &Motion) -> (f64, f64) {
        let [(ju, _), (jv, _)] = self.rows();
        let dot = |j: [f64; 6]| j.iter().zip(motion.iter()).map(|(a, b)| a * b).sum::<f64>();
        (dot(ju), dot(jv))
    }

    /// How the point moved unlike `motion` (pixels).
    fn residual(&self, motion: &Motion, camera: &Camera) -> (f64, f64) {
        let (pu, pv) = self.predicted(motion);
        ((self.du - pu) * camera.fx, (self.dv - pv) * camera.fy)
    }

    /// How far (pixels) the point moved unlike `motion`.
    fn residual_px(&self, motion: &Motion, camera: &Camera) -> f64 {
        let (ru, rv) = self.residual(motion, camera);
        (ru * ru + rv * rv).sqrt()
    }

    /// How far (pixels) `motion` moves the point.
    fn predicted_px(&self, motion: &Motion, camera: &Camera) -> f64 {
        let (pu, pv) = self.predicted(motion);
        ((pu * camera.fx).powi(2) + (pv * camera.fy).powi(2)).sqrt()
    }
}

/// Least-squares camera motion for the flows at `indices` (None when they
/// do not fix it: too few, or all on a line at one depth).
fn fit_motion(flows: &[Flow], indices: &[usize]) -> Option<Motion> {
    let mut ata = SMatrix::<f64, 6, 6>::zeros();
    let mut atb = Motion::zeros();
    for &i in indices {
        for (row, b) in flows[i].rows() {
            let j = SVector::<f64, 6>::from(row);
            ata += j * j.transpose();
            atb += j * b;
        }
    }
    let solution = ata.cholesky()?.solve(&atb);
    solution.iter().all(|v| v.is_finite()).then_some(solution)
}

impl NewcomerCheck {
    /// A check for `camera` with `params`.
    pub fn new(camera: Camera, params: NewcomerParams) -> Self {
        Self {
            params,
            camera,
            flow_guess: (0.0, 0.0),
            cooldown: 0,
            asked: None,
            last: Vec::new(),
            awaiting: false,
            retry_in: None,
            unseen_shift: (0.0, 0.0),
            requests: 0,
            retries: 0,
            unseen_views: 0,
        }
    }

    /// The check with the default parameters for the configured camera
    /// (depth units come with each frame; only the intrinsics and the
    /// distortion are used) and routing, in a run of `mode` (the unseen
    /// view's share is a per-mode default:
    /// [`scheduling::mode::unseen_view_share`]).
    pub fn for_pipeline(c: &CameraConfig, routing: &RoutingConfig, mode: ClockMode) -> Self {
        let camera = Camera::new([c.fx, c.fy, c.cx, c.cy], c.distortion, 1.0, 0.0);
        let params = NewcomerParams {
            unseen_view_share: scheduling::mode::unseen_view_share(mode, routing.unseen_view_share),
            ..NewcomerParams::default()
        };
        Self::new(camera, params)
    }

    /// Requests made so far (all kinds).
    pub fn requests(&self) -> u64 {
        self.requests
    }

    /// Of [`Self::requests`]: made again because the segmenter found
    /// nothing where a moving group asked ([`Why::Unanswered`]).
    pub fn retries(&self) -> u64 {
        self.retries
    }

    /// Of [`Self::requests`]: for a view the segmenter has not seen
    /// ([`Why::UnseenView`]).
    pub fn unseen_views(&self) -> u64 {
        self.unseen_views
    }

    /// The segmenter's objects on a frame (`labels`: non-zero on an object,
    /// `width` pixels a row): the view is seen again. When the frame comes
    /// after the last request (`after_request`), a moving group's request
    /// with no object over its region (grown by a cell: it moved on a
    /// frame) is made again [`NewcomerParams::retry_frames`] frames later,
    /// once.
    pub fn answered(&mut self, labels: &[u8], width: usize, after_request: bool) {
        self.unseen_shift = (0.0, 0.0);
        if !after_request {
            return;
        }
        let awaiting = std::mem::take(&mut self.awaiting);
        let Some(asked) = self.asked.filter(|a| awaiting && a.why == Why::Moving) else {
            return;
        };
        if width == 0 {
            return;
        }
        let height = labels.len() / width;
        let margin = self.params.cell_px;
        let [x0, y0, x1, y1] = asked.bbox;
        let (x0, y0) = (
            x0.saturating_sub(margin).min(width),
            y0.saturating_sub(margin),
        );
        let (x1, y1) = ((x1 + margin).clamp(x0, width), (y1 + margin).min(height));
        let found = (y0..y1).any(|y| {
            labels[y * width + x0..y * width + x1]
                .iter()
                .any(|&l| l != 0)
        });
        if !found {
            self.retry_in = Some(self.params.retry_frames);
        }
    }

    /// Looks for a newcomer between `prev` and `cur`: `followed` are the
    /// full-frame masks of the objects followed in the previous frame
    /// (their pixels are left out, with a cell of margin), `depth` is the
    /// new frame's. Some when a segmenter run is to be asked for now.
    pub fn check(
        &mut self,
        prev: &Pyramid,
        cur: &Pyramid,
        followed: &[&[bool]],
        depth: DepthImage,
        lk: LkParams,
    ) -> Option<Newcomer> {
        self.cooldown = self.cooldown.saturating_sub(1);
        self.retry_in = self.retry_in.map(|n| n.saturating_sub(1));
        let found = self
            .find(prev, cur, followed, depth, lk)
            .unwrap_or_default();
        let before = std::mem::replace(&mut self.last, found);
        if let Some(band) = self.unseen_band(prev) {
            return Some(self.request(band));
        }
        if self.retry_in == Some(0) {
            self.retry_in = None;
            if let Some(asked) = self.asked {
                return Some(self.request(Newcomer {
                    why: Why::Unanswered,
                    ..asked
                }));
            }
        }
        let margin = self.params.cell_px;
        // Any group near any of the last frame's: a large person near the
        // camera breaks into several groups (where their texture is), and
        // which is the largest changes from frame to frame.
        let since_asked =
            (self.params.cooldown_frames - self.cooldown.min(self.params.cooldown_frames)) as usize;
        let cooling = |f: &Newcomer| {
            self.cooldown > 0
                && self
                    .asked
                    .is_some_and(|a| f.near(&a, margin * (1 + since_asked)))
        };
        let found = self
            .last
            .iter()
            .filter(|f| before.iter().any(|b| f.near(b, margin)) && !cooling(f))
            .max_by_key(|f| f.cells)
            .copied()?;
        Some(self.request(found))
    }

    /// The band that has come into view since the segmenter last saw the
    /// view, once the image has shifted by `unseen_view_share` of its size
    /// (on the side the shift brought in: a shift to the right brings in
    /// the left edge).
    fn unseen_band(&mut self, frame: &Pyramid) -> Option<Newcomer> {
        let share = self.params.unseen_view_share;
        let base = frame.levels.first()?;
        let (w, h) = (base.width, base.height);
        let (sx, sy) = self.unseen_shift;
        if share <= 0.0 || (sx.abs() <= share * w as f32 && sy.abs() <= share * h as f32) {
            return None;
        }
        self.unseen_shift = (0.0, 0.0);
        let bbox = if sx.abs() * h as f32 >= sy.abs() * w as f32 {
            let band = (sx.abs() as usize).min(w);
            if sx > 0.0 {
                [0, 0, band, h]
            } else {
                [w - band, 0, w, h]
            }
        } else {
            let band = (sy.abs() as usize).min(h);
            if sy > 0.0 {
                [0, 0, w, band]
            } else {
                [0, h - band, w, h]
            }
        };
        Some(Newcomer {
            cells: 0,
            bbox,
            why: Why::UnseenView,
        })
    }

    /// A request for `region` now.
    fn request(&mut self, region: Newcomer) -> Newcomer {
        self.cooldown = self.params.cooldown_frames;
        self.asked = Some(region);
        self.awaiting = true;
        self.requests += 1;
        match region.why {
            Why::Moving => {}
            Why::Unanswered => self.retries += 1,
            Why::UnseenView => self.unseen_views += 1,
        }
        region
    }

    /// The groups of connected mover cells that move alike between `prev`
    /// and `cur`; None where the frame says nothing (too little tracked
    /// background, or no camera motion most of it agrees on).
    fn find(
        &mut self,
        prev: &Pyramid,
        cur: &Pyramid,
        followed: &[&[bool]],
        depth: DepthImage,
        lk: LkParams,
    ) -> Option<Vec<Newcomer>> {
        let base = prev.levels.first()?;
        let (width, height) = (base.width, base.height);
        if cur.levels.first().map(|g| (g.width, g.height)) != Some((width, height))
            || followed.iter().any(|m| m.len() != width * height)
            || (depth.image.width, depth.image.height) != (width, height)
        {
            return None;
        }
        let step = self.params.cell_px.max(4);
        // Half resolution is precise enough for residuals of several
        // pixels, and a flat or occluded point gives up sooner.
        let lk = LkParams {
            finest_level: 1.min(prev.levels.len() - 1),
            iterations: lk.iterations.min(6),
            ..lk
        };
        let (cells, points) = self.corner_points(prev, followed, lk, step);
        let flows = self.flows(prev, cur, &cells, &points, depth, lk);
        if let Some(median) = median_flow(&flows, &self.camera) {
            self.flow_guess = median;
            self.unseen_shift.0 += median.0;
            self.unseen_shift.1 += median.1;
        }
        // Too little background to say what the camera did.
        if flows.len() < 24 {
            return None;
        }
        let motion = self.camera_motion(&flows)?;
        Some(self.moving_groups(&flows, &motion, step, (width / step, height / step)))
    }

    /// A corner per cell of `step` pixels (its grid position, its pixel),
    /// for the cells no followed object covers.
    fn corner_points(
        &self,
        prev: &Pyramid,
        followed: &[&[bool]],
        lk: LkParams,
        step: usize,
    ) -> CellPoints {
        let (width, height) = (prev.levels[0].width, prev.levels[0].height);
        let (cols, rows) = (width / step, height / step);
        // A cell's point is left out when an object covers it or the pixel
        // a cell away in any of the four directions (objects move; their
        // borders blur).
        let covered = |x: usize, y: usize| {
            let m = step as isize;
            [(0, 0), (-m, 0), (m, 0), (0, -m), (0, m)]
                .iter()
                .any(|&(dx, dy)| {
                    let (px, py) = (x as isize + dx, y as isize + dy);
                    px >= 0
                        && py >= 0
                        && (px as usize) < width
                        && (py as usize) < height
                        && followed
                            .iter()
                            .any(|m| m[py as usize * width + px as usize])
                })
        };
        let tensor = StructureTensor::new(&prev.levels[lk.finest_level]);
        let scale = 1 << lk.finest_level;
        let min_score = self.params.min_corner_score;
        let mut cells = Vec::new();
        let mut points = Vec::new();
        for gy in 0..rows {
            for gx in 0..cols {
                let cell = (gx * step, gy * step, step);
                if let Some((x, y)) = corner_in_cell(&tensor, scale, cell, lk.radius, min_score) {
                    if !covered(x, y) {
                        cells.push((gx, gy));
                        points.push((x as f32, y as f32));
                    }
                }
            }
        }
        (cells, points)
    }

    /// The points' image motion from `prev` to `cur`, normalised, for
    /// those tracked onto measured depth.
    fn flows(
        &self,
        prev: &Pyramid,
        cur: &Pyramid,
        cells: &[(usize, usize)],
        points: &[(f32, f32)],
        depth: DepthImage,
        lk: LkParams,
    ) -> Vec<Flow> {
        let (width, height) = (prev.levels[0].width, prev.levels[0].height);
        let guess = self.flow_guess;
        // No forward-backward check (it would double the cost): a point
        // LK gets wrong is one outlier, and a newcomer takes a group.
        let fwd = track(prev, cur, points, guess, lk);
        let mut flows = Vec::new();
        for (i, there) in fwd.into_iter().enumerate() {
            let Some((tx, ty)) = there else {
                continue;
            };
            let (sx, sy) = points[i];
            let (ix, iy) = (tx.round() as usize, ty.round() as usize);
            if ix >= width || iy >= height {
                continue;
            }
            let Some(inverse_depth) = depth.inverse_at(ix, iy) else {
                continue;
            };
            let c = &self.camera;
            let (u0, v0) = c.undistort(sx as f64, sy as f64);
            let (u1, v1) = c.undistort(tx as f64, ty as f64);
            let (x, y) = ((u0 - c.cx) / c.fx, (v0 - c.cy) / c.fy);
            flows.push(Flow {
                cell: cells[i],
                x,
                y,
                du: (u1 - u0) / c.fx,
                dv: (v1 - v0) / c.fy,
                inverse_depth,
            });
        }
        flows
    }

    /// The camera's motion most of the flows agree on; None when too few
    /// agree (motion blur, a view filled by movers).
    fn camera_motion(&self, flows: &[Flow]) -> Option<Motion> {
        let camera = self.camera;
        let inlier = self.params.inlier_px;
        let search = Ransac {
            sample: 3,
            iterations: 60,
            seed: 0x6e65_7763_6f6d_6572,
        };
        let (_, inliers) = search.run(
            flows.len(),
            |s| fit_motion(flows, s),
            |m, i| flows[i].residual_px(m, &camera) <= inlier,
        )?;
        // Enough of the points must agree on a motion, else this frame says
        // nothing (motion blur, a view filled by movers).
        if (inliers.len() as f64) < self.params.min_agreement * flows.len() as f64 {
            return None;
        }
        fit_motion(flows, &inliers)
    }

    /// The groups of connected cells whose flow the camera's `motion` does
    /// not explain, large and coherent enough to be a mover.
    fn moving_groups(
        &self,
        flows: &[Flow],
        motion: &Motion,
        step: usize,
        (cols, rows): (usize, usize),
    ) -> Vec<Newcomer> {
        let camera = self.camera;
        let mut mover = vec![false; cols * rows];
        let mut residual = vec![(0.0, 0.0); cols * rows];
        for f in flows {
            let limit = self
                .params
                .min_residual_px
                .max(self.params.relative_residual * f.predicted_px(motion, &camera));
            if f.residual_px(motion, &camera) > limit {
                mover[f.cell.1 * cols + f.cell.0] = true;
                residual[f.cell.1 * cols + f.cell.0] = f.residual(motion, &camera);
            }
        }
        let coherence = |group: &[(usize, usize)]| {
            let (mut sx, mut sy, mut length) = (0.0, 0.0, 0.0);
            for &(gx, gy) in group {
                let (rx, ry) = residual[gy * cols + gx];
                sx += rx;
                sy += ry;
                length += (rx * rx + ry * ry).sqrt();
            }
            (sx * sx + sy * sy).sqrt() / length.max(1e-9)
        };
        connected_groups(&mover, cols, rows)
            .into_iter()
            .filter(|g| {
                g.len() >= self.params.min_cells && coherence(g) >= self.params.min_coherence
            })
            .map(|group| {
                let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
                for &(gx, gy) in &group {
                    x0 = x0.min(gx * step);
                    y0 = y0.min(gy * step);
                    x1 = x1.max((gx + 1) * step);
                    y1 = y1.max((gy + 1) * step);
                }
                Newcomer {
                    cells: group.len(),
                    bbox: [x0, y0, x1, y1],
                    why: Why::Moving,
                }
            })
            .collect()
    }
}

/// Box sums of the structure tensor's entries over an image (integral
/// images of `Ix^2`, `Ix Iy`, `Iy^2`, central differences): any window's
/// Shi-Tomasi score in constant time, instead of a window's worth of
/// gradients per candidate point (which was half the check's time).
struct StructureTensor {
    width: usize,
    height: usize,
    /// `(width + 1) * (height + 1)` running sums each.
    sums: [Vec<f64>; 3],
}

impl StructureTensor {
    fn new(g: &GrayF32) -> Self {
        let (w, h) = (g.width, g.height);
        let stride = w + 1;
        let mut sums = [
            vec![0.0; stride * (h + 1)],
            vec![0.0; stride * (h + 1)],
            vec![0.0; stride * (h + 1)],
        ];
        for y in 0..h {
            let mut row = [0.0f64; 3];
            for x in 0..w {
                let (ix, iy) = if x > 0 && y > 0 && x + 1 < w && y + 1 < h {
                    (
                        0.5 * (g.at(x + 1, y) - g.at(x - 1, y)) as f64,
                        0.5 * (g.at(x, y + 1) - g.at(x, y - 1)) as f64,
                    )
                } else {
                    (0.0, 0.0)
                };
                row[0] += ix * ix;
                row[1] += ix * iy;
                row[2] += iy * iy;
                for (k, sum) in sums.iter_mut().enumerate() {
                    sum[(y + 1) * stride + x + 1] = sum[y * stride + x + 1] + row[k];
                }
            }
        }
        Self {
            width: w,
            height: h,
            sums,
        }
    }

    /// Smallest eigenvalue per pixel over the window of half size `r`
    /// around (x, y), which must lie inside the image with a pixel to spare.
    fn min_eigen(&self, x: usize, y: usize, r: usize) -> f32 {
        let stride = self.width + 1;
        let (x0, y0, x1, y1) = (x - r, y - r, x + r + 1, y + r + 1);
        let n = ((2 * r + 1) * (2 * r + 1)) as f64;
        let [xx, xy, yy] = self.sums.each_ref().map(|s| {
            (s[y1 * stride + x1] - s[y0 * stride + x1] - s[y1 * stride + x0] + s[y0 * stride + x0])
                / n
        });
        (0.5 * (xx + yy - ((xx - yy).powi(2) + 4.0 * xy * xy).sqrt())) as f32
    }
}

/// The most trackable point of a cell (`x0, y0`, `step` pixels square, at
/// full resolution) where LK tracks it: the Shi-Tomasi score (smallest
/// eigenvalue of the structure tensor, per pixel) on `tensor`'s image, a
/// pyramid level `scale` times smaller, over LK's window of half size
/// `radius`, at candidates 2 level pixels apart. None when no candidate
/// reaches `min_score`: on a flat wall LK fails, and along a (blurred) edge
/// it slides, which reads as motion of its own.
fn corner_in_cell(
    tensor: &StructureTensor,
    scale: usize,
    (x0, y0, step): (usize, usize, usize),
    radius: usize,
    min_score: f32,
) -> Option<(usize, usize)> {
    let mut best: Option<(f32, (usize, usize))> = None;
    let (lx0, ly0, lstep) = (x0 / scale, y0 / scale, (step / scale).max(1));
    for cy in (ly0 + 1..ly0 + lstep).step_by(2) {
        for cx in (lx0 + 1..lx0 + lstep).step_by(2) {
            if cx <= radius
                || cy <= radius
                || cx + radius + 1 >= tensor.width
                || cy + radius + 1 >= tensor.height
            {
                continue;
            }
            let min_eigen = tensor.min_eigen(cx, cy, radius);
            if best.is_none_or(|b| min_eigen > b.0) {
                best = Some((min_eigen, (cx * scale, cy * scale)));
            }
        }
    }
    best.filter(|b| b.0 >= min_score).map(|b| b.1)
}

/// The median image motion of the flows in pixels (of the distorted image
/// near enough for a tracking guess).
fn median_flow(flows: &[Flow], camera: &Camera) -> Option<(f32, f32)> {
    if flows.is_empty() {
        return None;
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let du = median(flows.iter().map(|f| f.du * camera.fx).collect());
    let dv = median(flows.iter().map(|f| f.dv * camera.fy).collect());
    Some((du as f32, dv as f32))
}

/// The 8-connected groups of set cells.
fn connected_groups(set: &[bool], cols: usize, rows: usize) -> Vec<Vec<(usize, usize)>> {
    let mut seen = vec![false; set.len()];
    let mut groups = Vec::new();
    for start in 0..set.len() {
        if !set[start] || seen[start] {
            continue;
        }
        seen[start] = true;
        let mut group = Vec::new();
        let mut stack = vec![(start % cols, start / cols)];
        while let Some((x, y)) = stack.pop() {
            group.push((x, y));
            for dy in -1isize..=1 {
                for dx in -1isize..=1 {
                    let (nx, ny) = (x as isize + dx, y as isize + dy);
                    if nx < 0 || ny < 0 || nx as usize >= cols || ny as usize >= rows {
                        continue;
                    }
                    let n = ny as usize * cols + nx as usize;
                    if set[n] && !seen[n] {
                        seen[n] = true;
                        stack.push((nx as usize, ny as usize));
                    }
                }
            }
        }
        groups.push(group);
    }
    groups
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: usize = 320;
    const H: usize = 240;

    /// A textured grey value (smooth enough for LK, varied enough to lock).
    fn texture(x: f32, y: f32) -> f32 {
        128.0
            + 50.0 * (x * 0.21).sin() * (y * 0.17).cos()
            + 40.0 * ((x + 2.0 * y) * 0.07).sin()
            + 25.0 * ((3.0 * x - y) * 0.05).cos()
    }

    fn pyramid(f: impl Fn(f32, f32) -> f32) -> Pyramid {
        let mut data = Vec::with_capacity(W * H);
        for y in 0..H {
            for x in 0..W {
                data.push(f(x as f32, y as f32));
            }
        }
        Pyramid::new(
            GrayF32 {
                width: W,
                height: H,
                data,
            },
            4,
        )
    }

    fn flat_depth(metres: f32) -> Vec<u8> {
        let raw = (metres * 5000.0) as u16;
        (0..W * H).flat_map(|_| raw.to_ne_bytes()).collect()
    }

    /// `raw` depth (5000 units a metre) as the check reads it.
    fn depth_view(raw: &[u8]) -> DepthImage<'_> {
        DepthImage::new(raw, W, H, 5000.0).unwrap()
    }

    fn camera() -> Camera {
        Camera::new([260.0, 260.0, 160.0, 120.0], [0.0; 5], 5000.0, 0.0)
    }

    /// The camera pans (the whole scene shifts 3 px) while a patch of it,
    /// 64x64 px, moves 10 px down on its own.
    fn pan_with_patch(patch: bool) -> (Pyramid, Pyramid) {
        pan_with_patch_at(patch, 200.0)
    }

    /// [`pan_with_patch`] with the patch's left edge at `x0` (y 80..144).
    fn pan_with_patch_at(patch: bool, x0: f32) -> (Pyramid, Pyramid) {
        let inside = |x: f32, y: f32| (x0..x0 + 64.0).contains(&x) && (80.0..144.0).contains(&y);
        let prev = pyramid(|x, y| {
            if patch && inside(x, y) {
                texture(x * 1.3 + 50.0, y * 1.3)
            } else {
                texture(x, y)
            }
        });
        let cur = pyramid(|x, y| {
            let (sx, sy) = (x + 3.0, y);
            if patch && inside(sx, sy - 10.0) {
                texture(sx * 1.3 + 50.0, (sy - 10.0) * 1.3)
            } else {
                texture(sx, sy)
            }
        });
        (prev, cur)
    }

    #[test]
    fn a_region_moving_unlike_the_camera_asks_once_per_cooldown() {
        let (prev, cur) = pan_with_patch(true);
        let depth = flat_depth(2.0);
        let depth = depth_view(&depth);
        let mut check = NewcomerCheck::new(camera(), NewcomerParams::default());
        // Found in a first frame, asked for when found again in the next.
        assert!(check
            .check(&prev, &cur, &[], depth, LkParams::default())
            .is_none());
        let found = check
            .check(&prev, &cur, &[], depth, LkParams::default())
            .expect("the patch moves unlike the pan");
        // The patch is at x 197..261, y 90..154 in the new frame.
        let [x0, y0, x1, y1] = found.bbox;
        assert!(x0 >= 176 && x1 <= 288 && y0 >= 64 && y1 <= 176, "{found:?}");
        assert!(found.cells >= 5, "{found:?}");
        // The same again within the cooldown: no second request.
        for _ in 1..NewcomerParams::default().cooldown_frames {
            assert!(check
                .check(&prev, &cur, &[], depth, LkParams::default())
                .is_none());
        }
        assert!(check
            .check(&prev, &cur, &[], depth, LkParams::default())
            .is_some());
        assert_eq!(check.requests(), 2);
    }

    #[test]
    fn a_region_elsewhere_asks_within_the_cooldown() {
        let depth = flat_depth(2.0);
        let depth = depth_view(&depth);
        let mut check = NewcomerCheck::new(camera(), NewcomerParams::default());
        let (prev, cur) = pan_with_patch_at(true, 200.0);
        let lk = LkParams::default();
        assert!(check.check(&prev, &cur, &[], depth, lk).is_none());
        assert!(check.check(&prev, &cur, &[], depth, lk).is_some());
        // Another mover 130 px to the left: found twice, asks at once.
        let (prev, cur) = pan_with_patch_at(true, 6.0);
        assert!(check.check(&prev, &cur, &[], depth, lk).is_none());
        let found = check
            .check(&prev, &cur, &[], depth, lk)
            .expect("a region away from the one that asked is not cooling down");
        assert!(found.bbox[2] <= 120, "{found:?}");
        assert_eq!(check.requests(), 2);
    }

    /// Labels (W x H) with an object over x0..x1, y0..y1.
    fn labels_over(x0: usize, y0: usize, x1: usize, y1: usize) -> Vec<u8> {
        (0..W * H)
            .map(|i| {
                let (x, y) = (i % W, i / W);
                u8::from((x0..x1).contains(&x) && (y0..y1).contains(&y))
            })
            .collect()
    }

    /// The moving patch of [`pan_with_patch`] (depth 2 m everywhere) after
    /// it asked: the frames, the depth and the check.
    fn patch_asked_for() -> (Pyramid, Pyramid, Vec<u8>, NewcomerCheck) {
        let (prev, cur) = pan_with_patch(true);
        let raw = flat_depth(2.0);
        let mut check = NewcomerCheck::new(camera(), NewcomerParams::default());
        let depth = depth_view(&raw);
        let lk = LkParams::default();
        assert!(check.check(&prev, &cur, &[], depth, lk).is_none());
        let asked = check.check(&prev, &cur, &[], depth, lk).unwrap();
        assert_eq!(asked.why, Why::Moving);
        (prev, cur, raw, check)
    }

    #[test]
    fn a_request_the_segmenter_finds_nothing_for_is_made_again_once() {
        let (prev, cur, raw, mut check) = patch_asked_for();
        let depth = depth_view(&raw);
        let lk = LkParams::default();
        let asked = check.asked.unwrap();
        // The segmenter's objects lie elsewhere: asked again a frame later,
        // for the same region, within the cooldown.
        check.answered(&labels_over(0, 0, 40, 40), W, true);
        let again = check
            .check(&prev, &cur, &[], depth, lk)
            .expect("the region the segmenter left unanswered asks again");
        assert_eq!(again.why, Why::Unanswered);
        assert_eq!(again.bbox, asked.bbox);
        // A retry is not retried: nothing until the cooldown is over.
        check.answered(&labels_over(0, 0, 40, 40), W, true);
        for _ in 1..NewcomerParams::default().cooldown_frames {
            assert!(check.check(&prev, &cur, &[], depth, lk).is_none());
        }
        assert_eq!((check.requests(), check.retries()), (2, 1));
    }

    #[test]
    fn a_request_answered_there_or_before_it_is_not_made_again() {
        let (prev, cur, raw, mut check) = patch_asked_for();
        let depth = depth_view(&raw);
        let lk = LkParams::default();
        // An answer on a frame segmented before the request (real time: the
        // segmenter was busy) says nothing about the region...
        check.answered(&[0; W * H], W, false);
        assert!(check.check(&prev, &cur, &[], depth, lk).is_none());
        // ... and an object over the patch (x 197..261, y 90..154) answers it.
        check.answered(&labels_over(200, 90, 260, 150), W, true);
        for _ in 2..NewcomerParams::default().cooldown_frames {
            assert!(check.check(&prev, &cur, &[], depth, lk).is_none());
        }
        assert_eq!((check.requests(), check.retries()), (1, 0));
    }

    #[test]
    fn a_turn_past_the_unseen_share_asks_for_the_band_it_brought_in() {
        // The scene shifts 3 px left a frame: new view comes in at the right.
        let (prev, cur) = pan_with_patch(false);
        let depth = flat_depth(2.0);
        let depth = depth_view(&depth);
        let lk = LkParams::default();
        let params = NewcomerParams {
            unseen_view_share: 0.05,
            ..NewcomerParams::default()
        };
        let mut check = NewcomerCheck::new(camera(), params);
        // 16 px of 320 is 0.05: asked on the 6th frame (18 px).
        for _ in 0..5 {
            assert!(check.check(&prev, &cur, &[], depth, lk).is_none());
        }
        let band = check.check(&prev, &cur, &[], depth, lk).unwrap();
        assert_eq!(band.why, Why::UnseenView);
        let [x0, y0, x1, y1] = band.bbox;
        assert!((15..=21).contains(&(x1 - x0)) && x1 == W, "{band:?}");
        assert_eq!((y0, y1), (0, H));
        // A segmenter run sees the view again: the count starts over.
        for _ in 0..3 {
            assert!(check.check(&prev, &cur, &[], depth, lk).is_none());
        }
        check.answered(&[0; W * H], W, false);
        for _ in 0..5 {
            assert!(check.check(&prev, &cur, &[], depth, lk).is_none());
        }
        assert!(check.check(&prev, &cur, &[], depth, lk).is_some());
        // Off at 0.
        let mut off = NewcomerCheck::new(
            camera(),
            NewcomerParams {
                unseen_view_share: 0.0,
                ..NewcomerParams::default()
            },
        );
        for _ in 0..40 {
            assert!(off.check(&prev, &cur, &[], depth, lk).is_none());
        }
        assert_eq!((check.unseen_views(), off.requests()), (2, 0));
    }

    #[test]
    fn a_pan_alone_or_a_covered_mover_asks_nothing() {
        let depth = flat_depth(2.0);
        let depth = depth_view(&depth);
        let (prev, cur) = pan_with_patch(false);
        let mut check = NewcomerCheck::new(camera(), NewcomerParams::default());
        assert_eq!(
            check.check(&prev, &cur, &[], depth, LkParams::default()),
            None
        );
        // The mover is an object the propagator already follows.
        let (prev, cur) = pan_with_patch(true);
        let covered: Vec<bool> = (0..W * H)
            .map(|i| {
                let (x, y) = (i % W, i / W);
                (196..268).contains(&x) && (76..150).contains(&y)
            })
            .collect();
        assert_eq!(
            check.check(&prev, &cur, &[&covered], depth, LkParams::default()),
            None
        );
        assert_eq!(check.requests(), 0);
    }

    #[test]
    fn parallax_of_a_translating_camera_is_not_a_mover() {
        // Sideways translation over two depths: the near half of the view
        // (1 m) shifts 4 px, the far half (2 m) 2 px, as the flow field
        // of the translation says; nothing moves on its own.
        let (f, t) = (260.0f32, 4.0 / 260.0);
        let near = |x: f32| x < 160.0;
        let prev = pyramid(texture);
        let cur = pyramid(|x, y| {
            let shift = if near(x) { f * t / 1.0 } else { f * t / 2.0 };
            texture(x + shift, y)
        });
        let depth: Vec<u8> = (0..W * H)
            .flat_map(|i| {
                let m = if near((i % W) as f32) { 1.0 } else { 2.0 };
                ((m * 5000.0) as u16).to_ne_bytes()
            })
            .collect();
        let depth = depth_view(&depth);
        let mut check = NewcomerCheck::new(camera(), NewcomerParams::default());
        assert_eq!(
            check.check(&prev, &cur, &[], depth, LkParams::default()),
            None
        );
    }

    #[test]
    fn box_sums_give_the_windowed_structure_tensor() {
        let g = pyramid(texture).levels[0].clone();
        let tensor = StructureTensor::new(&g);
        for (x, y, r) in [(20, 30, 7), (100, 60, 3), (250, 200, 7)] {
            let (mut xx, mut xy, mut yy) = (0.0f64, 0.0f64, 0.0f64);
            for v in y - r..=y + r {
                for u in x - r..=x + r {
                    let ix = 0.5 * (g.at(u + 1, v) - g.at(u - 1, v)) as f64;
                    let iy = 0.5 * (g.at(u, v + 1) - g.at(u, v - 1)) as f64;
                    xx += ix * ix;
                    xy += ix * iy;
                    yy += iy * iy;
                }
            }
            let n = ((2 * r + 1) * (2 * r + 1)) as f64;
            let (xx, xy, yy) = (xx / n, xy / n, yy / n);
            let direct = 0.5 * (xx + yy - ((xx - yy).powi(2) + 4.0 * xy * xy).sqrt());
            let fast = tensor.min_eigen(x, y, r) as f64;
            assert!(
                (fast - direct).abs() < 1e-3 * direct.max(1.0),
                "{fast} vs {direct}"
            );
        }
    }

    #[test]
    fn groups_are_eight_connected() {
        #[rustfmt::skip]
        let set = [
            true,  false, false, false,
            false, true,  false, true,
            false, false, true,  false,
            false, false, false, false,
            true,  true,  false, false,
        ];
        let mut sizes: Vec<usize> = connected_groups(&set, 4, 5).iter().map(Vec::len).collect();
        sizes.sort();
        assert_eq!(sizes, [2, 4]);
        assert!(connected_groups(&[false; 4], 2, 2).is_empty());
    }
}
