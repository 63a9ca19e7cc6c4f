//! Grey images and Gaussian-ish pyramids for point tracking.

use crate::features::orb::{luma, GrayU8};

/// A single-channel float image, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Gray {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Grey values (0-255), row by row.
    pub data: Vec<f32>,
}

impl Gray {
    /// Luma of an RGB8 image by the project's one RGB-to-grey formula
    /// ([`GrayU8::from_rgb`], what ORB extraction reads), as floats: the
    /// propagator's flow and the SLAM's flow frames see the grey values the
    /// features do.
    pub fn from_rgb(rgb: &[u8], width: usize, height: usize) -> Self {
        // One pass, no grey u8 image in between (the propagator does this
        // every frame).
        let data = rgb.chunks_exact(3).map(|p| luma(p) as f32).collect();
        Self {
            width,
            height,
            data,
        }
    }

    /// A grey image's values as floats.
    pub fn from_u8(gray: &GrayU8) -> Self {
        Self {
            width: gray.width,
            height: gray.height,
            data: gray.data.iter().map(|&v| v as f32).collect(),
        }
    }

    /// The value at `(x, y)` (inside the image).
    #[inline]
    pub fn at(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    /// Bilinear sample with border clamping.
    #[inline]
    pub fn sample(&self, x: f32, y: f32) -> f32 {
        let x = x.clamp(0.0, (self.width - 1) as f32);
        let y = y.clamp(0.0, (self.height - 1) as f32);
        let (x0, y0) = (x as usize, y as usize);
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        let (wx, wy) = (x - x0 as f32, y - y0 as f32);
        let top = self.at(x0, y0) * (1.0 - wx) + self.at(x1, y0) * wx;
        let bottom = self.at(x0, y1) * (1.0 - wx) + self.at(x1, y1) * wx;
        top * (1.0 - wy) + bottom * wy
    }

    /// Half-size image: [1 2 1]/4 smoothing in both directions, then every
    /// second pixel.
    pub fn half(&self) -> Self {
        let (w, h) = ((self.width / 2).max(1), (self.height / 2).max(1));
        let mut data = Vec::with_capacity(w * h);
        let px = |x: isize, y: isize| {
            let x = x.clamp(0, self.width as isize - 1) as usize;
            let y = y.clamp(0, self.height as isize - 1) as usize;
            self.at(x, y)
        };
        // Weights of the 3x3 kernel (row weight times column weight).
        const K: [[f32; 3]; 3] = [[1.0, 2.0, 1.0], [2.0, 4.0, 2.0], [1.0, 2.0, 1.0]];
        for y in 0..h {
            let cy = (2 * y) as isize;
            for x in 0..w {
                let cx = (2 * x) as isize;
                let inside = cx >= 1
                    && cy >= 1
                    && cx + 1 < self.width as isize
                    && cy + 1 < self.height as isize;
                let mut acc = 0.0;
                if inside {
                    // The same sums in the same order, without the clamps.
                    let (cx, cy) = (cx as usize, cy as usize);
                    for (dy, k) in K.iter().enumerate() {
                        let row = &self.data[(cy + dy - 1) * self.width + cx - 1..][..3];
                        for (w, v) in k.iter().zip(row) {
                            acc += w * v;
                        }
                    }
                } else {
                    for (dy, wy) in [(-1, 1.0), (0, 2.0), (1, 1.0)] {
                        for (dx, wx) in [(-1, 1.0), (0, 2.0), (1, 1.0)] {
                            acc += wx * wy * px(cx + dx, cy + dy);
                        }
                    }
                }
                data.push(acc / 16.0);
            }
        }
        Self {
            width: w,
            height: h,
            data,
        }
    }
}

/// Level 0 is the full image; each further level has half the size.
#[derive(Debug, Clone)]
pub struct Pyramid {
    /// Level 0 is the image, each next one half its size.
    pub levels: Vec<Gray>,
}

impl Pyramid {
    /// `levels` levels built from `base`.
    pub fn new(base: Gray, levels: usize) -> Self {
        let mut out = vec![base];
        while out.len() < levels.max(1) {
            let next = out.last().unwrap().half();
            if next.width < 16 || next.height < 16 {
                break;
            }
            out.push(next);
        }
        Self { levels: out }
    }

    /// The image's dominant shift from this image to `to` (level-0 pixels):
    /// the translation with the least mean absolute difference at the
    /// coarsest level (up to [`SHIFT_SEARCH`] of its pixels each way, 128 at
    /// 640x480 with 4 levels), refined a pixel each way a level down. A
    /// starting guess for LK where the frames are far apart (frames the
    /// propagator skipped: the camera turned 40-100 px between them on
    /// fr1_rpy at 60 fps, beyond the pyramid's reach from no motion, and
    /// forward-backward agreement held for 0-12 of ~100 points).
    pub fn shift_to(&self, to: &Pyramid) -> (f32, f32) {
        let top = self.levels.len().min(to.levels.len()) - 1;
        let (dx, dy) = best_shift(&self.levels[top], &to.levels[top], (0, 0), SHIFT_SEARCH, 3);
        let (mut dx, mut dy, mut scale) = (dx, dy, 1usize << top);
        if top > 0 {
            let (rx, ry) = best_shift(
                &self.levels[top - 1],
                &to.levels[top - 1],
                (2 * dx, 2 * dy),
                1,
                2,
            );
            (dx, dy, scale) = (rx, ry, scale / 2);
        }
        ((dx * scale as isize) as f32, (dy * scale as isize) as f32)
    }
}

/// How far [`Pyramid::shift_to`] searches at the coarsest level (pixels).
const SHIFT_SEARCH: isize = 16;

/// The shift within `reach` of `around` (pixels of `a`'s level) that moves
/// `a` onto `b` with the least mean absolute difference, compared on every
/// `every`-th pixel of `a` whose shifted position stays in `b`; `around`
/// when no shift overlaps enough (a quarter of the image).
fn best_shift(
    a: &Gray,
    b: &Gray,
    around: (isize, isize),
    reach: isize,
    every: usize,
) -> (isize, isize) {
    let (w, h) = (
        a.width.min(b.width) as isize,
        a.height.min(b.height) as isize,
    );
    let enough = (w * h) as usize / (4 * every * every);
    let mut best = (f32::MAX, around);
    for dy in around.1 - reach..=around.1 + reach {
        for dx in around.0 - reach..=around.0 + reach {
            let (x0, x1) = (0.max(-dx), w.min(w - dx));
            let (y0, y1) = (0.max(-dy), h.min(h - dy));
            if x0 >= x1 || y0 >= y1 {
                continue;
            }
            let (mut sum, mut n) = (0.0f32, 0usize);
            for y in (y0..y1).step_by(every) {
                let (ra, rb) = (y as usize * a.width, (y + dy) as usize * b.width);
                for x in (x0..x1).step_by(every) {
                    sum += (a.data[ra + x as usize] - b.data[rb + (x + dx) as usize]).abs();
                    n += 1;
                }
            }
            if n >= enough && sum / (n as f32) < best.0 {
                best = (sum / n as f32, (dx, dy));
            }
        }
    }
    best.1
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Halving reads the interior without clamps: the same values, to the
    /// bit, as the 3x3 kernel over clamped pixels everywhere.
    #[test]
    fn half_is_the_clamped_kernel() {
        for (w, h) in [(37, 23), (40, 30)] {
            let data: Vec<f32> = (0..w * h)
                .map(|i| ((i * 7919) % 251) as f32 * 0.37 + (i % 13) as f32)
                .collect();
            let g = Gray {
                width: w,
                height: h,
                data,
            };
            let half = g.half();
            for y in 0..half.height {
                for x in 0..half.width {
                    let mut acc = 0.0f32;
                    for (dy, wy) in [(-1isize, 1.0f32), (0, 2.0), (1, 1.0)] {
                        for (dx, wx) in [(-1isize, 1.0f32), (0, 2.0), (1, 1.0)] {
                            let px = (2 * x as isize + dx).clamp(0, w as isize - 1) as usize;
                            let py = (2 * y as isize + dy).clamp(0, h as isize - 1) as usize;
                            acc += wx * wy * g.at(px, py);
                        }
                    }
                    assert_eq!(half.at(x, y), acc / 16.0, "{w}x{h} at ({x}, {y})");
                }
            }
        }
    }

    #[test]
    fn half_of_a_constant_is_the_constant_and_sizes_halve() {
        let g = Gray {
            width: 64,
            height: 48,
            data: vec![7.0; 64 * 48],
        };
        let p = Pyramid::new(g, 4);
        // 64x48 -> 32x24; 16x12 would be under 16 pixels high, so it stops.
        assert_eq!(p.levels.len(), 2);
        assert_eq!((p.levels[1].width, p.levels[1].height), (32, 24));
        assert!(p.levels[1].data.iter().all(|&v| (v - 7.0).abs() < 1e-5));
    }

    #[test]
    fn the_shift_between_two_crops_of_a_real_frame_is_found() {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../../shared/data/tum/rgbd_dataset_freiburg1_rpy_first300/rgb/1305031229.564425.png"
        );
        let rgb = image::open(path).expect("shared frame").to_rgb8();
        // Two 480x360 windows of the 640x480 frame, the second 70 px right
        // and 45 px down of the first: the content moves (-70, -45).
        let crop = |ox: u32, oy: u32| {
            let c = image::imageops::crop_imm(&rgb, ox, oy, 480, 360).to_image();
            Pyramid::new(Gray::from_rgb(c.as_raw(), 480, 360), 4)
        };
        let (a, b) = (crop(20, 10), crop(90, 55));
        let (dx, dy) = a.shift_to(&b);
        assert!(
            (dx + 70.0).abs() <= 4.0 && (dy + 45.0).abs() <= 4.0,
            "{dx} {dy}"
        );
        let (dx, dy) = a.shift_to(&a);
        assert_eq!((dx, dy), (0.0, 0.0));
    }

    #[test]
    fn bilinear_sample_interpolates() {
        let g = Gray {
            width: 2,
            height: 1,
            data: vec![0.0, 10.0],
        };
        assert!((g.sample(0.25, 0.0) - 2.5).abs() < 1e-6);
        assert_eq!(g.sample(5.0, 3.0), 10.0);
    }
}
