//! Grey images and Gaussian-ish pyramids for point tracking.

/// A single-channel float image, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Gray {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl Gray {
    /// Luma of an RGB8 image (BT.601 weights).
    pub fn from_rgb(rgb: &[u8], width: usize, height: usize) -> Self {
        let data = rgb
            .chunks_exact(3)
            .map(|p| 0.299 * p[0] as f32 + 0.587 * p[1] as f32 + 0.114 * p[2] as f32)
            .collect();
        Self {
            width,
            height,
            data,
        }
    }

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
        for y in 0..h {
            for x in 0..w {
                let (cx, cy) = ((2 * x) as isize, (2 * y) as isize);
                let mut acc = 0.0;
                for (dy, wy) in [(-1, 1.0), (0, 2.0), (1, 1.0)] {
                    for (dx, wx) in [(-1, 1.0), (0, 2.0), (1, 1.0)] {
                        acc += wx * wy * px(cx + dx, cy + dy);
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
    pub levels: Vec<Gray>,
}

impl Pyramid {
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
}

#[cfg(test)]
mod tests {
    use super::*;

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
