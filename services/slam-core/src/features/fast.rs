//! FAST-9 corners (Rosten and Drummond 2006) on a grey image: a pixel is a
//! corner for threshold `t` when 9 contiguous pixels of the radius-3 circle
//! around it are all brighter than centre + t or all darker than centre - t.
//!
//! Two stages, because almost every pixel is no corner. First a pre-test on
//! 8 of the 16 pixels, written over whole row spans in saturating `u8`
//! arithmetic so that the compiler vectorises it: any arc of 9 holds one of
//! the two vertical (0, 8) and one of the two horizontal (4, 12) compass
//! pixels, and likewise one of each opposite pair of diagonals (2, 10 and 6,
//! 14), so a pixel without them cannot be a corner. Then, on the
//! few survivors, the full test: the 16 comparisons as two bit masks and the
//! contiguity check by shifts. The score is the sum of the differences beyond
//! `t` over the winning side's pixels (ORB-SLAM2's FAST score is the same
//! idea; any monotone score works for non-maximum suppression).

use super::orb::GrayU8;

/// The radius-3 Bresenham circle, clockwise from the top.
pub(crate) const CIRCLE: [(isize, isize); 16] = [
    (0, -3),
    (1, -3),
    (2, -2),
    (3, -1),
    (3, 0),
    (3, 1),
    (2, 2),
    (1, 3),
    (0, 3),
    (-1, 3),
    (-2, 2),
    (-3, 1),
    (-3, 0),
    (-3, -1),
    (-2, -2),
    (-1, -3),
];

/// Pixels the circle needs on every side of a tested pixel.
pub const RADIUS: usize = 3;

/// FAST scores of one image at one threshold; keeps the circle's offsets
/// for the image's row stride.
pub struct Fast<'a> {
    img: &'a GrayU8,
    offsets: [isize; 16],
    candidates: Vec<u8>,
}

impl<'a> Fast<'a> {
    pub fn new(img: &'a GrayU8) -> Self {
        let w = img.width as isize;
        Self {
            img,
            offsets: CIRCLE.map(|(dx, dy)| dy * w + dx),
            candidates: Vec::new(),
        }
    }

    /// Scores of the pixels `x0..x1` of row `y` into `out` (0 where no
    /// corner); true when any pixel scored. The span must keep `RADIUS`
    /// pixels from every image border.
    pub fn score_row(&mut self, y: usize, x0: usize, x1: usize, t: u8, out: &mut [f32]) -> bool {
        let (w, h) = (self.img.width, self.img.height);
        assert!(
            y >= RADIUS && y + RADIUS < h && x0 >= RADIUS && x1 + RADIUS <= w && x0 <= x1,
            "FAST span {x0}..{x1} of row {y} within {RADIUS} px of the {w}x{h} image's border"
        );
        let n = x1 - x0;
        let d = &self.img.data;
        let at = |dy: isize, dx: isize| {
            let start = ((y as isize + dy) * w as isize + x0 as isize + dx) as usize;
            &d[start..start + n]
        };
        // Circle pixels 0, 8, 4, 12 (compass) and 2, 10, 6, 14 (diagonals).
        let (centre, up, down, right, left) = (at(0, 0), at(-3, 0), at(3, 0), at(0, 3), at(0, -3));
        let (up_right, down_left) = (at(-2, 2), at(2, -2));
        let (down_right, up_left) = (at(2, 2), at(-2, -2));
        let compass = centre.iter().zip(up).zip(down).zip(right).zip(left);
        let diagonals = up_right.iter().zip(down_left).zip(down_right).zip(up_left);
        self.candidates.clear();
        self.candidates.extend(compass.zip(diagonals).map(
            |(((((&p, &u), &dn), &r), &l), (((&ur, &dl), &dr), &ul))| {
                let b = |q: u8| q.saturating_sub(t) > p;
                let k = |q: u8| q.saturating_add(t) < p;
                // An arc of 9 holds two neighbouring points of each set of
                // four evenly spaced circle pixels.
                let bright = (b(u) | b(dn)) & (b(r) | b(l)) & (b(ur) | b(dl)) & (b(dr) | b(ul));
                let dark = (k(u) | k(dn)) & (k(r) | k(l)) & (k(ur) | k(dl)) & (k(dr) | k(ul));
                (bright | dark) as u8
            },
        ));
        // Survivors are few: skip 8 rejected pixels at a time.
        let out = &mut out[..n];
        out.fill(0.0);
        let mut any = false;
        for (chunk, flags) in self.candidates.chunks(8).enumerate() {
            if flags.iter().all(|&f| f == 0) {
                continue;
            }
            for (j, &candidate) in flags.iter().enumerate() {
                if candidate != 0 {
                    let i = chunk * 8 + j;
                    out[i] = self.full_test(y * w + x0 + i, t);
                    any |= out[i] > 0.0;
                }
            }
        }
        any
    }

    /// The 16-pixel test at one pixel (flat index), after the pre-test.
    #[inline]
    fn full_test(&self, centre: usize, t: u8) -> f32 {
        let d = &self.img.data;
        // One bounds check for the whole circle: `score_row` keeps the
        // circle inside the image, and the window holds every offset.
        let reach = 3 * self.img.width + 3;
        let window = &d[centre - reach..=centre + reach];
        let circle: [i16; 16] =
            std::array::from_fn(|k| window[(reach as isize + self.offsets[k]) as usize] as i16);
        let p = d[centre] as i16;
        let t = t as i16;
        let (mut bright, mut dark) = (0u32, 0u32);
        for (k, &q) in circle.iter().enumerate() {
            bright |= ((q - p > t) as u32) << k;
            dark |= ((q - p < -t) as u32) << k;
        }
        // Both sides cannot hold 9 of 16 at once.
        let sign = if has_arc_of_9(bright) {
            1
        } else if has_arc_of_9(dark) {
            -1
        } else {
            return 0.0;
        };
        let sum: i32 = circle
            .iter()
            .map(|&q| (sign * (q - p) - t).max(0) as i32)
            .sum();
        sum as f32
    }
}

/// Whether the 16-bit circular mask has 9 contiguous set bits.
#[inline]
fn has_arc_of_9(mask: u32) -> bool {
    let m = mask | (mask << 16); // unrolled once: arcs may wrap
    let two = m & (m >> 1);
    let four = two & (two >> 2);
    let eight = four & (four >> 4);
    eight & (m >> 8) != 0
}

#[cfg(test)]
mod tests {
    use super::*;

    /// FAST-9 as defined, pixel by pixel: the reference for the fast path.
    fn definition(img: &GrayU8, x: usize, y: usize, t: i16) -> f32 {
        let p = img.data[y * img.width + x] as i16;
        let v: Vec<i16> = CIRCLE
            .iter()
            .map(|(dx, dy)| {
                img.data[(y as isize + dy) as usize * img.width + (x as isize + dx) as usize] as i16
                    - p
            })
            .collect();
        for sign in [1i16, -1] {
            let mut run = 0;
            for i in 0..25 {
                if sign * v[i % 16] > t {
                    run += 1;
                    if run >= 9 {
                        return v.iter().map(|&d| ((sign * d) - t).max(0) as f32).sum();
                    }
                } else {
                    run = 0;
                }
            }
        }
        0.0
    }

    fn noise(w: usize, h: usize, seed: u64) -> GrayU8 {
        let mut rng = crate::rng::SplitMix64::new(seed);
        // Blocky noise plus saturated patches: corners of both signs, and
        // pixels near 0 and 255 where the saturating pre-test matters.
        let data = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let block = ((x / 3) * 31 + (y / 4) * 17) as u64;
                let v = (rng.uniform(0.0, 1.0) * 60.0) as u64 + (block * 2654435761 % 200);
                if (x / 16 + y / 16) % 7 == 0 {
                    if x % 2 == 0 {
                        255
                    } else {
                        0
                    }
                } else {
                    v.min(255) as u8
                }
            })
            .collect();
        GrayU8 {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn the_fast_path_scores_every_pixel_as_the_definition_does() {
        let img = noise(97, 61, 7);
        let mut fast = Fast::new(&img);
        let mut corners = 0;
        for t in [1u8, 7, 20, 60, 200] {
            for y in RADIUS..img.height - RADIUS {
                let (x0, x1) = (RADIUS, img.width - RADIUS);
                let mut row = vec![-1.0; x1 - x0];
                fast.score_row(y, x0, x1, t, &mut row);
                for (i, &s) in row.iter().enumerate() {
                    assert_eq!(
                        s,
                        definition(&img, x0 + i, y, t as i16),
                        "t {t} at ({}, {y})",
                        x0 + i
                    );
                    corners += (s > 0.0) as usize;
                }
            }
        }
        assert!(corners > 500, "the image should have corners: {corners}");
    }

    #[test]
    fn arcs_of_9_are_found_also_across_the_wrap() {
        assert!(has_arc_of_9(0b1_1111_1111));
        assert!(has_arc_of_9(0xF81F)); // bits 0-4 and 11-15: 10 across the wrap
        assert!(!has_arc_of_9(0b1111_1111));
        assert!(!has_arc_of_9(0xF00F)); // 8 across the wrap
        assert!(!has_arc_of_9(0b1110_1111_0111_1110)); // runs of 6, 4 and 3
    }
}
