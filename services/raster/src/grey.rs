//! Grey images: the one RGB-to-grey formula, and what optical flow does
//! with float grey images (bilinear samples, half-size levels).

use crate::{GrayF32, GrayU8};

/// The project's one RGB-to-grey formula: BT.601 luma weights in 1/256
/// (0.301, 0.586, 0.113; they sum to 256), rounded down to whole levels.
/// ORB extraction reads it ([`GrayU8::from_rgb`]), and so does optical flow
/// ([`GrayF32::from_rgb`]).
pub const LUMA_WEIGHTS: [u32; 3] = [77, 150, 29];

/// The grey level of one RGB8 pixel ([`LUMA_WEIGHTS`], rounded down).
#[inline]
pub fn luma(p: &[u8]) -> u8 {
    let [wr, wg, wb] = LUMA_WEIGHTS;
    ((wr * p[0] as u32 + wg * p[1] as u32 + wb * p[2] as u32) >> 8) as u8
}

impl GrayU8 {
    /// Luma of an RGB8 image, three bytes a pixel ([`luma`] per pixel).
    pub fn from_rgb(rgb: &[u8], width: usize, height: usize) -> Self {
        let data = rgb.chunks_exact(3).map(luma).collect();
        Self {
            width,
            height,
            data,
        }
    }
}

impl GrayF32 {
    /// Luma of an RGB8 image by the one formula ([`GrayU8::from_rgb`], what
    /// ORB extraction reads), as floats: the propagator's flow and the
    /// SLAM's flow frames see the grey values the features do.
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
        gray.map(f32::from)
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
            let g = GrayF32 {
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
    fn bilinear_sample_interpolates() {
        let g = GrayF32 {
            width: 2,
            height: 1,
            data: vec![0.0, 10.0],
        };
        assert!((g.sample(0.25, 0.0) - 2.5).abs() < 1e-6);
        assert_eq!(g.sample(5.0, 3.0), 10.0);
    }

    #[test]
    fn both_grey_images_read_the_one_formula() {
        let rgb = [255, 0, 0, 0, 255, 0, 0, 0, 255, 10, 20, 30];
        let u8s = GrayU8::from_rgb(&rgb, 2, 2);
        assert_eq!(u8s.data, vec![76, 149, 28, 18]);
        assert_eq!(GrayF32::from_rgb(&rgb, 2, 2), GrayF32::from_u8(&u8s));
    }
}
