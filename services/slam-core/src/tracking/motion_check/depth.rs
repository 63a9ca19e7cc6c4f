//! The motion check's depth cells: a depth image as the nearest surface of
//! each 4x4 block, the nearest surface around each cell (what an older
//! frame saw as free space), and the dense depth warp that puts every cell
//! of the current frame into an older one.

use nalgebra::Isometry3;

use super::{MotionCheckParams, MovingRegion};
use crate::camera::Camera;

/// A depth image at a quarter of its resolution, each cell the nearest
/// surface of its 4x4 block (metres; 0: none seen): what was free space.
pub(super) struct NearestDepth {
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) metres: Vec<f32>,
}

pub(super) const CELL: usize = 4;
/// Cells each side of a lookup (5x5 cells, 20 px) at least: depth noise
/// and pose error at an edge.
pub(super) const WINDOW: usize = 2;
/// How far apart in time a depth image and the colour image whose pose it
/// is looked up with are (s): in the shared fr1 sequence's associations
/// the depth image comes 0-17 ms after the colour one, 13 ms at the 90th
/// percentile. In a turn that moves the depth image against the colour
/// pose by `fx * turn rate * this` pixels (fr1_rpy at 2.5 rad/s: 17 px),
/// so the lookup window grows by that: with a fixed 5x5 the static shared
/// sequence's fast turns looked like free space being filled (0.51 % of
/// its features dropped, 0.24 % with the growing window). A window much
/// larger than that hides movers over surfaces that slope towards the
/// camera (the nearest surface in a wide window is nearer than the one
/// behind the mover): 20 ms, 100 of the carried box's 132 frames found; 13
/// ms, 101; 10 ms, 102 but 0.26 % of the static features.
pub(super) const DEPTH_OFFSET_S: f64 = 0.013;

/// Cells each side of a lookup in a depth image taken while the camera
/// turned at `then` (rad/s), for a point of a frame taken while it turned at
/// `now`: the two misregistrations add up.
pub(super) fn lookup_window(camera: &Camera, now: f64, then: f64) -> usize {
    let px = camera.fx * (now + then) * DEPTH_OFFSET_S;
    WINDOW + (px / CELL as f64).ceil().clamp(0.0, 8.0) as usize
}

impl NearestDepth {
    pub(super) fn new(depth: &[u16], width: usize, height: usize, depth_scale: f64) -> Self {
        let (w, h) = (width.div_ceil(CELL), height.div_ceil(CELL));
        // The nearest raw depth per cell in integers (0, nothing seen,
        // wraps to the largest value under the subtraction, so one `min`
        // per pixel and no branch), turned into metres once per cell: the
        // same values as converting every pixel first (the conversion
        // keeps the order), at a fraction of the cost.
        // A band of CELL rows is first folded into one row, pixel by pixel
        // (a loop the compiler vectorises), then that row into cells.
        let mut nearest = vec![u16::MAX; w * h];
        if depth.len() == width * height {
            let mut band = vec![u16::MAX; width];
            for (cells, rows) in nearest.chunks_exact_mut(w).zip(depth.chunks(CELL * width)) {
                band.fill(u16::MAX);
                for row in rows.chunks_exact(width) {
                    for (b, &d) in band.iter_mut().zip(row) {
                        *b = (*b).min(d.wrapping_sub(1));
                    }
                }
                for (cell, pixels) in cells.iter_mut().zip(band.chunks(CELL)) {
                    *cell = pixels.iter().copied().fold(u16::MAX, u16::min);
                }
            }
        }
        let metres = nearest
            .into_iter()
            .map(|d| match d {
                u16::MAX => 0.0,
                d => ((d as u32 + 1) as f64 / depth_scale) as f32,
            })
            .collect();
        Self {
            width: w,
            height: h,
            metres,
        }
    }

    /// For every cell, the nearest surface seen within `window` cells of
    /// it, where two thirds of those cells saw one (else 0): a foreground
    /// edge a pose error away still counts, so edges do not look like free
    /// space. The minima: rows, then columns, each a running minimum over
    /// the image padded with "nothing seen" ([`running_min`]); the counts:
    /// sums over a summed-area table. (Per-cell window loops were a third of
    /// the check's time; these give the same values.)
    pub(super) fn around(&self, window: usize) -> Around {
        let (w, h, r) = (self.width, self.height, window);
        let span = 2 * r + 1;
        // Nothing seen: infinitely far, for the minima.
        let far = |m: f32| if m > 0.0 { m } else { f32::INFINITY };
        let padded_w = w + 2 * r;
        let mut rows = vec![f32::INFINITY; h * padded_w];
        for (dst, src) in rows
            .chunks_exact_mut(padded_w)
            .zip(self.metres.chunks_exact(w))
        {
            for (d, &m) in dst[r..r + w].iter_mut().zip(src) {
                *d = far(m);
            }
        }
        running_min(&mut rows, 1, span);
        let mut columns = vec![f32::INFINITY; (h + 2 * r) * w];
        for (dst, src) in columns[r * w..(r + h) * w]
            .chunks_exact_mut(w)
            .zip(rows.chunks_exact(padded_w))
        {
            dst.copy_from_slice(&src[..w]);
        }
        running_min(&mut columns, w, span);
        // Cells that saw something, summed: sums[(y * (w + 1)) + x] over
        // the cells above and left of (x, y).
        let mut sums = vec![0u32; (w + 1) * (h + 1)];
        for y in 0..h {
            let mut row = 0;
            for x in 0..w {
                row += (self.metres[y * w + x] > 0.0) as u32;
                sums[(y + 1) * (w + 1) + x + 1] = sums[y * (w + 1) + x + 1] + row;
            }
        }
        let cells = (span * span) as u32;
        let mut metres = vec![0f32; w * h];
        for y in 0..h {
            let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(h));
            for x in 0..w {
                let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(w));
                let seen = sums[y1 * (w + 1) + x1] + sums[y0 * (w + 1) + x0]
                    - sums[y0 * (w + 1) + x1]
                    - sums[y1 * (w + 1) + x0];
                if seen * 3 >= cells * 2 {
                    metres[y * w + x] = columns[y * w + x];
                }
            }
        }
        Around {
            width: w,
            height: h,
            metres,
        }
    }
}

/// In place: element `i` of `data` (elements `unit` floats wide, side by
/// side) becomes the minimum of elements `i..i + len`, for every `i` with
/// `i + len` elements there (the rest is left undefined). Minima over
/// doubling spans, then two overlapping spans: about log2(len) passes, each
/// from one buffer into another so that the loop is a plain zip the
/// compiler vectorises.
pub(super) fn running_min(data: &mut Vec<f32>, unit: usize, len: usize) {
    let n = data.len() / unit;
    if len <= 1 || n < len {
        return;
    }
    let mut spare = vec![f32::INFINITY; data.len()];
    let mut pass = |data: &mut Vec<f32>, ahead: usize| {
        let step = ahead * unit;
        for (out, (&a, &b)) in spare.iter_mut().zip(data.iter().zip(&data[step..])) {
            *out = a.min(b);
        }
        std::mem::swap(data, &mut spare);
    };
    let mut covered = 1;
    while covered * 2 <= len {
        pass(data, covered);
        covered *= 2;
    }
    if covered < len {
        pass(data, len - covered);
    }
}

/// [`NearestDepth::around`]: per cell, the nearest surface seen around it.
pub(super) struct Around {
    width: usize,
    height: usize,
    pub(super) metres: Vec<f32>,
}

impl Around {
    /// The nearest surface seen around the (raw) pixel, if enough was seen.
    pub(super) fn nearest_at(&self, (u, v): (f64, f64)) -> Option<f64> {
        if !(u >= 0.0 && v >= 0.0) {
            return None;
        }
        let (cx, cy) = ((u as usize) / CELL, (v as usize) / CELL);
        if cx >= self.width || cy >= self.height {
            return None;
        }
        let m = self.metres[cy * self.width + cx];
        (m > 0.0).then_some(m as f64)
    }
}

/// The ideal (undistorted) pixel of each depth cell's centre of a
/// `width x height` image, row by row, and its normalised ray ((u - cx) /
/// fx, (v - cy) / fy: the point at depth z is z times (x, y, 1)).
pub(super) fn cell_centres(camera: &Camera, width: usize, height: usize) -> CellCentres {
    let (cw, ch) = (width.div_ceil(CELL), height.div_ceil(CELL));
    let pixels: Vec<(f64, f64)> = (0..cw * ch)
        .map(|c| {
            let (x, y) = ((c % cw) * CELL, (c / cw) * CELL);
            camera.undistort(x as f64 + CELL as f64 / 2.0, y as f64 + CELL as f64 / 2.0)
        })
        .collect();
    let rays_f32 = pixels
        .iter()
        .map(|&(u, v)| {
            (
                ((u - camera.cx) / camera.fx) as f32,
                ((v - camera.cy) / camera.fy) as f32,
            )
        })
        .collect();
    CellCentres { pixels, rays_f32 }
}

/// [`cell_centres`]: per depth cell, its ideal pixel and its ray.
pub(super) struct CellCentres {
    pub(super) pixels: Vec<(f64, f64)>,
    rays_f32: Vec<(f32, f32)>,
}

/// Every cell of `now` put into the older frame (`now_to_past`): its raw
/// pixel there (u, v) and its depth there, in f32 (a pixel's worth of
/// precision is far more than the 4-pixel cells need). A cell with no depth
/// or behind the older camera gives meaningless values: callers check.
pub(super) fn project_cells(
    now: &NearestDepth,
    cells: &CellCentres,
    now_to_past: &Isometry3<f64>,
    camera: &Camera,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let r = now_to_past
        .rotation
        .to_rotation_matrix()
        .into_inner()
        .cast::<f32>();
    let t = now_to_past.translation.vector.cast::<f32>();
    let [k1, k2, p1, p2, k3] = camera.dist.map(|k| k as f32);
    let (fx, fy, cx, cy) = (
        camera.fx as f32,
        camera.fy as f32,
        camera.cx as f32,
        camera.cy as f32,
    );
    let n = now.metres.len();
    let (mut raw_u, mut raw_v, mut depth_then) = (vec![0f32; n], vec![0f32; n], vec![0f32; n]);
    for ((((u, v), d), &z), &(x, y)) in raw_u
        .iter_mut()
        .zip(raw_v.iter_mut())
        .zip(depth_then.iter_mut())
        .zip(&now.metres)
        .zip(&cells.rays_f32)
    {
        let (px, py) = (x * z, y * z);
        let tx = r[(0, 0)] * px + r[(0, 1)] * py + r[(0, 2)] * z + t.x;
        let ty = r[(1, 0)] * px + r[(1, 1)] * py + r[(1, 2)] * z + t.y;
        let tz = r[(2, 0)] * px + r[(2, 1)] * py + r[(2, 2)] * z + t.z;
        // Kept away from 0 so the division is harmless; such cells are
        // skipped by the caller (tz < 0.1).
        let inv = 1.0 / tz.max(1e-3);
        let (xn, yn) = (tx * inv, ty * inv);
        let r2 = xn * xn + yn * yn;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        let xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn);
        let yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn;
        (*u, *v, *d) = (xd * fx + cx, yd * fy + cy, tz);
    }
    (raw_u, raw_v, depth_then)
}

/// The dense depth warp: cells of the current depth (`now`) that, put
/// into the older frame, lie in front of what it saw there (free space
/// then), in connected groups of at least `min_cells`, each grown over the
/// surface it is part of (a mover's other cells, which may overlap where
/// it was before); their boxes in ideal pixels.
pub(super) fn dense_regions(
    now: &NearestDepth,
    cells: &CellCentres,
    past: &Around,
    now_to_past: &Isometry3<f64>,
    camera: &Camera,
    p: &MotionCheckParams,
) -> Vec<MovingRegion> {
    let (w, h) = (now.width, now.height);
    let mut appeared = vec![false; w * h];
    // Per cell: its point put into the older frame and projected to a raw
    // pixel there (19200 cells, up to three older frames a frame: the
    // check's largest cost). First the arithmetic for every cell in f32,
    // branch-free, a loop the compiler vectorises; then the lookups.
    let (raw_u, raw_v, depth_then) = project_cells(now, cells, now_to_past, camera);
    for (c, flag) in appeared.iter_mut().enumerate() {
        let (z, tz) = (now.metres[c] as f64, depth_then[c] as f64);
        if z <= 0.0 || tz < 0.1 {
            continue;
        }
        if let Some(seen) = past.nearest_at((raw_u[c] as f64, raw_v[c] as f64)) {
            *flag = seen - tz > p.min_move_m + p.move_per_m2 * z * z;
        }
    }
    let neighbours = |c: usize| {
        let (x, y) = (c % w, c / w);
        [
            (x > 0).then(|| c - 1),
            (x + 1 < w).then(|| c + 1),
            (y > 0).then(|| c - w),
            (y + 1 < h).then(|| c + w),
        ]
        .into_iter()
        .flatten()
    };
    let mut label = vec![0u32; w * h];
    let mut regions = Vec::new();
    let mut next = 0u32;
    for start in 0..w * h {
        if !appeared[start] || label[start] != 0 {
            continue;
        }
        next += 1;
        let mut component = vec![start];
        label[start] = next;
        let mut i = 0;
        while i < component.len() {
            for n in neighbours(component[i]) {
                if appeared[n] && label[n] == 0 {
                    label[n] = next;
                    component.push(n);
                }
            }
            i += 1;
        }
        if component.len() < p.min_cells {
            continue;
        }
        let seed = component.len();
        // Grow over the same surface: a neighbour continues it when its
        // depth is close to the cell it is reached from.
        let mut i = 0;
        while i < component.len() && component.len() < seed * p.max_growth {
            let c = component[i];
            let z = now.metres[c] as f64;
            for n in neighbours(c) {
                let zn = now.metres[n] as f64;
                if label[n] == 0 && zn > 0.0 && (zn - z).abs() <= p.surface_m + p.surface_per_m * z
                {
                    label[n] = next;
                    component.push(n);
                }
            }
            i += 1;
        }
        let mut min = [f64::INFINITY; 2];
        let mut max = [f64::NEG_INFINITY; 2];
        for &c in &component {
            let (u, v) = cells.pixels[c];
            min = [min[0].min(u), min[1].min(v)];
            max = [max[0].max(u), max[1].max(v)];
        }
        let half = CELL as f64 / 2.0 + p.margin_px;
        regions.push(MovingRegion {
            min: [(min[0] - half) as f32, (min[1] - half) as f32],
            max: [(max[0] + half) as f32, (max[1] + half) as f32],
            evidence: seed,
        });
    }
    regions
}
