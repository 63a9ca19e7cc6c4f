//! How one object's mask moves from a frame to the next: points sampled
//! inside and along the mask, tracked with pyramidal LK and checked
//! forward-backward, a robust affine fit (RANSAC on 3-point samples, then
//! least squares on the inliers), and the mask warped by the affine plus
//! the inliers' interpolated residual motion, kept where the grey values
//! agree; across an image border the object was cut by, extrapolated where
//! the depth is the object's.

use nalgebra::{Matrix3, Vector3};

use crate::lk::track;
use crate::newcomers::DepthImage;
use crate::propagate::PropagatorParams;
use crate::pyramid::Pyramid;

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
pub(crate) fn follow(
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
pub(crate) fn object_points(
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
pub(crate) fn track_points(
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
pub(crate) fn warp_mask(
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
    let residuals: Vec<Residual> = src
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
    let target = Target::of(mask, &affine, &residuals, width, height)?;
    let field = ResidualField::new(&residuals, &target);
    // Grey-value consistency on the half-resolution level (smoothed, so that
    // texture and blur do not flip single pixels).
    let (prev_half, cur_half) = (
        &prev.levels[1.min(prev.levels.len() - 1)],
        &cur.levels[1.min(cur.levels.len() - 1)],
    );
    let half = prev_half.width as f32 / width as f32;
    let mut out = vec![false; width * height];
    let mut area = 0usize;
    for y in target.y0..target.y1 {
        for x in target.x0..target.x1 {
            // Where this pixel came from: undo the residual, then the affine.
            let r = field.at(x, y);
            let (sx, sy) = inv.apply((x as f32 - r.0, y as f32 - r.1));
            let inside = match target.cut.source(sx.round(), sy.round(), width, height) {
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
    (area >= 30).then(|| (out, mean_motion(src, dst, &inliers)))
}

/// The mean image motion of the inliers.
fn mean_motion(src: &[(f32, f32)], dst: &[(f32, f32)], inliers: &[bool]) -> (f32, f32) {
    let n = inliers.iter().filter(|&&k| k).count().max(1) as f32;
    src.iter()
        .zip(dst)
        .zip(inliers)
        .filter(|(_, &k)| k)
        .fold((0.0, 0.0), |acc, ((s, d), _)| {
            (acc.0 + (d.0 - s.0) / n, acc.1 + (d.1 - s.1) / n)
        })
}

/// The region of the new frame a warped mask can cover (`x0..x1`,
/// `y0..y1`), and the image borders the object is cut by.
struct Target {
    x0: usize,
    y0: usize,
    x1: usize,
    y1: usize,
    cut: BorderCut,
}

impl Target {
    /// The warped bounding box of `mask`, with a margin of the largest
    /// residual motion; None when it left the view.
    fn of(
        mask: &[bool],
        affine: &Affine,
        residuals: &[Residual],
        width: usize,
        height: usize,
    ) -> Option<Self> {
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
        let x0 = match cut.left {
            Some(_) => 0,
            None => (bx0 - margin).floor().max(0.0) as usize,
        };
        let y0 = match cut.top {
            Some(_) => 0,
            None => (by0 - margin).floor().max(0.0) as usize,
        };
        let x1 = match cut.right {
            Some(_) => width,
            None => ((bx1 + margin).ceil().max(0.0) as usize).min(width),
        };
        let y1 = match cut.bottom {
            Some(_) => height,
            None => ((by1 + margin).ceil().max(0.0) as usize).min(height),
        };
        (x0 < x1 && y0 < y1).then_some(Self {
            x0,
            y0,
            x1,
            y1,
            cut,
        })
    }
}

/// An inlier's position in the new frame, and its motion beyond the affine.
type Residual = ((f32, f32), (f32, f32));

/// Side of a residual field cell (pixels).
const CELL: usize = 8;

/// The inliers' residual motion interpolated over a target region:
/// inverse-distance weights on a coarse grid, bilinear between its nodes.
struct ResidualField {
    x0: usize,
    y0: usize,
    gw: usize,
    gh: usize,
    field: Vec<(f32, f32)>,
}

impl ResidualField {
    fn new(residuals: &[Residual], target: &Target) -> Self {
        let (tx0, ty0) = (target.x0, target.y0);
        let (gw, gh) = ((target.x1 - tx0) / CELL + 2, (target.y1 - ty0) / CELL + 2);
        let mut field = vec![(0.0f32, 0.0f32); gw * gh];
        for gy in 0..gh {
            for gx in 0..gw {
                let (x, y) = ((tx0 + gx * CELL) as f32, (ty0 + gy * CELL) as f32);
                let (mut sx, mut sy, mut sw) = (0.0, 0.0, 0.0);
                for (pos, r) in residuals {
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
        Self {
            x0: tx0,
            y0: ty0,
            gw,
            gh,
            field,
        }
    }

    /// The residual motion at pixel `(x, y)` of the target region.
    fn at(&self, x: usize, y: usize) -> (f32, f32) {
        let (gw, gh) = (self.gw, self.gh);
        let (fx, fy) = (
            (x - self.x0) as f32 / CELL as f32,
            (y - self.y0) as f32 / CELL as f32,
        );
        let (gx, gy) = ((fx as usize).min(gw - 2), (fy as usize).min(gh - 2));
        let (wx, wy) = (fx - gx as f32, fy - gy as f32);
        let f = |i: usize, j: usize| self.field[j * gw + i];
        let (a, b, c, d) = (f(gx, gy), f(gx + 1, gy), f(gx, gy + 1), f(gx + 1, gy + 1));
        (
            (a.0 * (1.0 - wx) + b.0 * wx) * (1.0 - wy) + (c.0 * (1.0 - wx) + d.0 * wx) * wy,
            (a.1 * (1.0 - wx) + b.1 * wx) * (1.0 - wy) + (c.1 * (1.0 - wx) + d.1 * wx) * wy,
        )
    }
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
                    .then(|| depth.metres_at(ix as usize, iy as usize))
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
        match self.depth.metres_at(x, y) {
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
