//! Pyramidal Lucas-Kanade point tracking (Bouguet, "Pyramidal implementation
//! of the Lucas Kanade feature tracker"): per level, iterative Gauss-Newton on
//! a square window, the estimate carried from coarse to fine.

use super::pyramid::{GrayF32, Pyramid};

/// Tracking parameters.
#[derive(Debug, Clone, Copy)]
pub struct LkParams {
    /// Half size of the square window (window = 2*r+1 pixels).
    pub radius: usize,
    /// Gauss-Newton iterations per level at most.
    pub iterations: usize,
    /// Stop iterating when the update is smaller than this (pixels).
    pub epsilon: f32,
    /// Reject a point whose window has too little texture (min eigenvalue of
    /// the structure tensor per pixel).
    pub min_eigen: f32,
    /// The finest pyramid level refined (0: full resolution; 1: half,
    /// a quarter of the cost per level saved and precision about a pixel).
    pub finest_level: usize,
}

impl Default for LkParams {
    fn default() -> Self {
        Self {
            radius: 7,
            iterations: 10,
            epsilon: 0.02,
            min_eigen: 1e-2,
            finest_level: 0,
        }
    }
}

/// Tracks `points` (level-0 pixel coordinates in `prev`) into `next`,
/// starting from the displacement `guess` (level-0 pixels: e.g. the
/// object's motion in the previous frame, so that fast objects stay within
/// the pyramid's reach); `None` where a point is untextured or leaves the
/// image.
pub fn track(
    prev: &Pyramid,
    next: &Pyramid,
    points: &[(f32, f32)],
    guess: (f32, f32),
    p: LkParams,
) -> Vec<Option<(f32, f32)>> {
    points
        .iter()
        .map(|&pt| track_one(prev, next, pt, guess, p))
        .collect()
}

/// [`track`] with a displacement guess per point (e.g. where the motion
/// model projects each point's map point).
pub fn track_each(
    prev: &Pyramid,
    next: &Pyramid,
    points: &[(f32, f32)],
    guesses: &[(f32, f32)],
    p: LkParams,
) -> Vec<Option<(f32, f32)>> {
    points
        .iter()
        .zip(guesses)
        .map(|(&pt, &guess)| track_one(prev, next, pt, guess, p))
        .collect()
}

fn track_one(
    prev: &Pyramid,
    next: &Pyramid,
    pt: (f32, f32),
    guess: (f32, f32),
    p: LkParams,
) -> Option<(f32, f32)> {
    let levels = prev.levels.len().min(next.levels.len());
    let r = p.radius as isize;
    let n = ((2 * r + 1) * (2 * r + 1)) as f32;
    // Displacement guess, in the current level's pixels.
    let top = (1u32 << (levels - 1)) as f32;
    let (mut gx, mut gy) = (guess.0 / top, guess.1 / top);
    let mut grads = Vec::with_capacity(n as usize);
    let mut patch = Vec::with_capacity((2 * p.radius + 3).pow(2));
    let mut moved = Vec::with_capacity(n as usize);
    let finest = p.finest_level.min(levels - 1);
    for level in (finest..levels).rev() {
        let scale = (1u32 << level) as f32;
        let (a, b) = (&prev.levels[level], &next.levels[level]);
        let (ux, uy) = (pt.0 / scale, pt.1 / scale);
        // Structure tensor and template gradients on the window of `a`. The
        // window's offsets are whole pixels, so one set of bilinear weights
        // serves every pixel of it (here and in the iterations below).
        // The window and a one-pixel frame around it, for the gradients.
        let template = Window::at(ux, uy);
        let side = 2 * r + 3;
        template.fill(a, r + 1, &mut patch);
        let at = |dx: isize, dy: isize| patch[((dy + r + 1) * side + dx + r + 1) as usize];
        let (mut gxx, mut gxy, mut gyy) = (0.0f32, 0.0f32, 0.0f32);
        grads.clear();
        for dy in -r..=r {
            for dx in -r..=r {
                let ix = 0.5 * (at(dx + 1, dy) - at(dx - 1, dy));
                let iy = 0.5 * (at(dx, dy + 1) - at(dx, dy - 1));
                gxx += ix * ix;
                gxy += ix * iy;
                gyy += iy * iy;
                grads.push((ix, iy, at(dx, dy)));
            }
        }
        let det = gxx * gyy - gxy * gxy;
        let trace = gxx + gyy;
        let min_eig = 0.5 * (trace - ((gxx - gyy).powi(2) + 4.0 * gxy * gxy).sqrt());
        if det.abs() < 1e-9 || min_eig / n < p.min_eigen {
            return None;
        }
        let (mut vx, mut vy) = (0.0f32, 0.0f32);
        for _ in 0..p.iterations {
            Window::at(ux + gx + vx, uy + gy + vy).fill(b, r, &mut moved);
            let (mut bx, mut by) = (0.0f32, 0.0f32);
            for (&(ix, iy, ia), &ib) in grads.iter().zip(&moved) {
                let diff = ia - ib;
                bx += diff * ix;
                by += diff * iy;
            }
            let (sx, sy) = ((gyy * bx - gxy * by) / det, (gxx * by - gxy * bx) / det);
            vx += sx;
            vy += sy;
            if sx * sx + sy * sy < p.epsilon * p.epsilon {
                break;
            }
        }
        gx += vx;
        gy += vy;
        if level > 0 {
            gx *= 2.0;
            gy *= 2.0;
        }
    }
    // Ended on a coarser level: its estimate in full-resolution pixels.
    let rest = (1u32 << finest.saturating_sub(1)) as f32;
    let (gx, gy) = (gx * rest, gy * rest);
    let (x, y) = (pt.0 + gx, pt.1 + gy);
    let base = &next.levels[0];
    (x.is_finite()
        && y.is_finite()
        && x >= 0.0
        && y >= 0.0
        && x <= (base.width - 1) as f32
        && y <= (base.height - 1) as f32)
        .then_some((x, y))
}

/// Bilinear sampling around a point at whole-pixel offsets: the weights
/// are the same for every offset, so they are computed once.
struct Window {
    x0: isize,
    y0: isize,
    wx: f32,
    wy: f32,
}

impl Window {
    fn at(x: f32, y: f32) -> Self {
        // Far outside the image reads its border anyway; the clamp keeps a
        // diverged estimate from overflowing the offsets.
        let (x, y) = (x.clamp(-1e6, 1e6), y.clamp(-1e6, 1e6));
        let (fx, fy) = (x.floor(), y.floor());
        Self {
            x0: fx as isize,
            y0: fy as isize,
            wx: x - fx,
            wy: y - fy,
        }
    }

    /// The square of offsets -r..=r around the point, row by row, into
    /// `out`: straight from the image's rows where it lies inside (the
    /// same arithmetic as [`Window::value`], without its clamps per
    /// pixel), else pixel by pixel.
    fn fill(&self, img: &GrayF32, r: isize, out: &mut Vec<f32>) {
        out.clear();
        let (w, h) = (img.width as isize, img.height as isize);
        let inside =
            self.x0 - r >= 0 && self.y0 - r >= 0 && self.x0 + r + 1 < w && self.y0 + r + 1 < h;
        if !inside {
            for dy in -r..=r {
                for dx in -r..=r {
                    out.push(self.value(img, dx, dy));
                }
            }
            return;
        }
        let side = (2 * r + 1) as usize;
        let (wx, wy) = (self.wx, self.wy);
        for dy in -r..=r {
            let start = ((self.y0 + dy) * w + self.x0 - r) as usize;
            let upper = &img.data[start..start + side + 1];
            let lower = &img.data[start + img.width..start + img.width + side + 1];
            out.extend(upper.windows(2).zip(lower.windows(2)).map(|(a, b)| {
                let top = a[0] * (1.0 - wx) + a[1] * wx;
                let bottom = b[0] * (1.0 - wx) + b[1] * wx;
                top * (1.0 - wy) + bottom * wy
            }));
        }
    }

    /// The image at offset (dx, dy) from the point; positions outside it
    /// read its border (as `GrayF32::sample`).
    #[inline]
    fn value(&self, img: &GrayF32, dx: isize, dy: isize) -> f32 {
        let (w, h) = (img.width as isize - 1, img.height as isize - 1);
        let (x, y) = (self.x0 + dx, self.y0 + dy);
        let (xa, xb) = (x.clamp(0, w) as usize, (x + 1).clamp(0, w) as usize);
        let (ya, yb) = (y.clamp(0, h) as usize, (y + 1).clamp(0, h) as usize);
        let top = img.at(xa, ya) * (1.0 - self.wx) + img.at(xb, ya) * self.wx;
        let bottom = img.at(xa, yb) * (1.0 - self.wx) + img.at(xb, yb) * self.wx;
        top * (1.0 - self.wy) + bottom * self.wy
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flow::pyramid::GrayF32;

    /// A smooth textured image and the same image shifted by (sx, sy).
    fn pair(sx: f32, sy: f32) -> (Pyramid, Pyramid) {
        let (w, h) = (120, 90);
        let f = |x: f32, y: f32| {
            100.0 + 40.0 * (0.21 * x).sin() * (0.17 * y).cos() + 30.0 * (0.05 * (x + 2.0 * y)).sin()
        };
        let mut a = Vec::new();
        let mut b = Vec::new();
        for y in 0..h {
            for x in 0..w {
                a.push(f(x as f32, y as f32));
                b.push(f(x as f32 - sx, y as f32 - sy));
            }
        }
        (
            Pyramid::new(
                GrayF32 {
                    width: w,
                    height: h,
                    data: a,
                },
                3,
            ),
            Pyramid::new(
                GrayF32 {
                    width: w,
                    height: h,
                    data: b,
                },
                3,
            ),
        )
    }

    #[test]
    fn recovers_a_subpixel_and_a_large_shift() {
        for (sx, sy) in [(0.4, -0.3), (6.5, 4.25)] {
            let (a, b) = pair(sx, sy);
            let pts: Vec<(f32, f32)> = (0..5).map(|i| (35.0 + 10.0 * i as f32, 45.0)).collect();
            for (p, t) in pts
                .iter()
                .zip(track(&a, &b, &pts, (0.0, 0.0), LkParams::default()))
            {
                let (x, y) = t.expect("tracked");
                assert!(
                    (x - p.0 - sx).abs() < 0.05 && (y - p.1 - sy).abs() < 0.05,
                    "{p:?} -> {x},{y} for shift {sx},{sy}"
                );
            }
        }
    }

    /// A window read row by row inside the image gives what the clamped
    /// pixel-by-pixel read gives, to the bit; near the border it falls back.
    #[test]
    fn a_window_inside_reads_as_pixel_by_pixel() {
        let (a, _) = pair(0.0, 0.0);
        let img = &a.levels[0];
        let mut out = Vec::new();
        for (x, y) in [
            (30.3, 40.7),
            (5.0, 5.5),
            (0.2, 88.9),
            (118.6, 1.0),
            (60.999, 44.001),
        ] {
            let w = Window::at(x, y);
            for r in [1, 4, 7] {
                w.fill(img, r, &mut out);
                let expected: Vec<f32> = (-r..=r)
                    .flat_map(|dy| (-r..=r).map(move |dx| (dx, dy)))
                    .map(|(dx, dy)| w.value(img, dx, dy))
                    .collect();
                assert_eq!(out, expected, "({x}, {y}) r {r}");
            }
        }
    }

    #[test]
    fn flat_regions_are_not_tracked() {
        let flat = Pyramid::new(
            GrayF32 {
                width: 60,
                height: 60,
                data: vec![50.0; 3600],
            },
            2,
        );
        assert_eq!(
            track(
                &flat,
                &flat,
                &[(30.0, 30.0)],
                (0.0, 0.0),
                LkParams::default()
            ),
            vec![None]
        );
    }
}
