//! Grey images and Gaussian-ish pyramids for point tracking.

pub use raster::GrayF32;

/// Level 0 is the full image; each further level has half the size.
#[derive(Debug, Clone)]
pub struct Pyramid {
    /// Level 0 is the image, each next one half its size.
    pub levels: Vec<GrayF32>,
}

impl Pyramid {
    /// `levels` levels built from `base`.
    pub fn new(base: GrayF32, levels: usize) -> Self {
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
    a: &GrayF32,
    b: &GrayF32,
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

    #[test]
    fn half_of_a_constant_is_the_constant_and_sizes_halve() {
        let g = GrayF32 {
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
            Pyramid::new(GrayF32::from_rgb(c.as_raw(), 480, 360), 4)
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
}
