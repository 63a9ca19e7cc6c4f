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
use super::simd::Kernels;

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

/// FAST corners of one image; keeps the circle's offsets for the image's
/// row stride.
pub struct Fast<'a> {
    img: &'a GrayU8,
    offsets: [isize; 16],
    kernels: Kernels,
    candidates: Vec<u8>,
}

impl<'a> Fast<'a> {
    /// A detector over `img`, with the kernels to run.
    pub fn new(img: &'a GrayU8, kernels: Kernels) -> Self {
        let w = img.width as isize;
        Self {
            img,
            offsets: CIRCLE.map(|(dx, dy)| dy * w + dx),
            kernels,
            candidates: Vec::new(),
        }
    }

    /// The corners among pixels `x0..x1` of row `y` at threshold `t`: each
    /// corner's x pushed to `corners` (ascending) and its score written to
    /// `scores[x]` (`scores` is the row); other pixels of `scores` are left
    /// as they are. The span must keep `RADIUS` pixels from every border.
    pub fn corners_in_row(
        &mut self,
        y: usize,
        (x0, x1): (usize, usize),
        t: u8,
        scores: &mut [u16],
        corners: &mut Vec<u32>,
    ) {
        let (w, h) = (self.img.width, self.img.height);
        assert!(
            y >= RADIUS && y + RADIUS < h && x0 >= RADIUS && x1 + RADIUS <= w && x0 <= x1,
            "FAST span {x0}..{x1} of row {y} within {RADIUS} px of the {w}x{h} image's border"
        );
        assert!(scores.len() >= x1, "a score row shorter than the span");
        match self.kernels {
            #[cfg(target_arch = "x86_64")]
            Kernels::Sse2 if x1 - x0 >= sse2::LANES => {
                // SAFETY: every x86-64 CPU has SSE2.
                unsafe { sse2::corners_in_row(self, y, (x0, x1), t, scores, corners) }
            }
            _ => self.portable_row(y, (x0, x1), t, scores, corners),
        }
    }

    /// The pre-test over the span as plain Rust (the compiler vectorises
    /// it), then the full test on its survivors.
    fn portable_row(
        &mut self,
        y: usize,
        (x0, x1): (usize, usize),
        t: u8,
        scores: &mut [u16],
        corners: &mut Vec<u32>,
    ) {
        let w = self.img.width;
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
        for (chunk, flags) in self.candidates.chunks(8).enumerate() {
            if flags.iter().all(|&f| f == 0) {
                continue;
            }
            for (j, &candidate) in flags.iter().enumerate() {
                if candidate != 0 {
                    let x = x0 + chunk * 8 + j;
                    self.score_candidate(y * w + x, t, x, scores, corners);
                }
            }
        }
    }

    /// The full test at a candidate; a corner is recorded.
    #[inline]
    fn score_candidate(
        &self,
        centre: usize,
        t: u8,
        x: usize,
        scores: &mut [u16],
        corners: &mut Vec<u32>,
    ) {
        let score = self.full_test(centre, t);
        if score > 0 {
            scores[x] = score;
            corners.push(x as u32);
        }
    }

    /// The 16-pixel test at one pixel (flat index), after the pre-test: the
    /// corner's score, 0 for none.
    #[inline]
    fn full_test(&self, centre: usize, t: u8) -> u16 {
        let circle = self.circle(centre);
        let p = self.img.data[centre] as i16;
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
            return 0;
        };
        arc_score(&circle, p, t, sign)
    }

    /// The score of a corner known to be one (`bright` or dark) at a flat
    /// index.
    #[cfg(target_arch = "x86_64")]
    #[inline]
    fn corner_score(&self, centre: usize, t: u8, bright: bool) -> u16 {
        let p = self.img.data[centre] as i16;
        arc_score(
            &self.circle(centre),
            p,
            t as i16,
            if bright { 1 } else { -1 },
        )
    }

    /// The 16 circle pixels around a flat index.
    #[inline]
    fn circle(&self, centre: usize) -> [i16; 16] {
        // One bounds check for the whole circle: `corners_in_row` keeps the
        // circle inside the image, and the window holds every offset.
        let reach = 3 * self.img.width + 3;
        let window = &self.img.data[centre - reach..=centre + reach];
        std::array::from_fn(|k| window[(reach as isize + self.offsets[k]) as usize] as i16)
    }
}

/// The sum of the differences beyond `t` on the corner's side (`sign` 1:
/// brighter, -1: darker); at most 16 x 255, so it fits.
#[inline]
fn arc_score(circle: &[i16; 16], p: i16, t: i16, sign: i16) -> u16 {
    circle
        .iter()
        .map(|&q| (sign * (q - p) - t).max(0) as u16)
        .sum()
}

/// FAST with SSE2, 16 pixels at a time: the pre-test straight into a bit
/// mask (no byte per pixel to write and scan again), the full test on the
/// blocks with a candidate as run lengths per lane, the score per corner.
#[cfg(target_arch = "x86_64")]
mod sse2 {
    use std::arch::x86_64::*;

    use super::{Fast, CIRCLE};

    pub const LANES: usize = 16;

    #[target_feature(enable = "sse2")]
    pub fn corners_in_row(
        fast: &Fast,
        y: usize,
        (x0, x1): (usize, usize),
        t: u8,
        scores: &mut [u16],
        corners: &mut Vec<u32>,
    ) {
        debug_assert!(x1 - x0 >= LANES);
        let w = fast.img.width;
        let data = &fast.img.data;
        let mut x = x0;
        while x < x1 {
            // The last block overlaps the one before rather than reading
            // past the span; the overlap's pixels are masked off.
            let start = x.min(x1 - LANES);
            let centre = y * w + start;
            // Every lane's circle pixel (up to 3 rows and columns away) is
            // inside the image: `Fast::corners_in_row` checked the span.
            let block = Block::new(
                &data[centre - (3 * w + 3)..centre + 3 * w + 3 + LANES],
                w,
                t,
            );
            if block.candidates() >> (x - start) != 0 {
                let (bright, dark) = block.arcs_of_9();
                let mut found = (bright | dark) >> (x - start);
                while found != 0 {
                    let lane = found.trailing_zeros() as usize;
                    found &= found - 1;
                    let is_bright = bright >> (x - start + lane) & 1 != 0;
                    let at = x + lane;
                    scores[at] = fast.corner_score(y * w + at, t, is_bright);
                    corners.push(at as u32);
                }
            }
            x = start + LANES;
        }
    }

    /// 16 neighbouring pixels and their thresholds.
    struct Block<'a> {
        window: &'a [u8],
        w: usize,
        /// p + t and p - t per lane, saturated.
        hi: __m128i,
        lo: __m128i,
    }

    impl<'a> Block<'a> {
        /// `window` runs from 3 rows and 3 columns before the first pixel
        /// to 3 rows and 3 columns after the 16th.
        #[inline]
        #[target_feature(enable = "sse2")]
        fn new(window: &'a [u8], w: usize, t: u8) -> Self {
            assert_eq!(window.len(), 2 * (3 * w + 3) + LANES);
            let mut block = Self {
                window,
                w,
                hi: _mm_setzero_si128(),
                lo: _mm_setzero_si128(),
            };
            let (p, tv) = (block.load(0, 0), _mm_set1_epi8(t as i8));
            block.hi = _mm_adds_epu8(p, tv);
            block.lo = _mm_subs_epu8(p, tv);
            block
        }

        /// The 16 pixels `dx`, `dy` away from the block's.
        #[inline]
        #[target_feature(enable = "sse2")]
        fn load(&self, dx: isize, dy: isize) -> __m128i {
            assert!(dx.abs() <= 3 && dy.abs() <= 3);
            let at = ((3 * self.w + 3) as isize + dy * self.w as isize + dx) as usize;
            // SAFETY: at + 16 <= window.len() for |dx|, |dy| <= 3 (asserted
            // here and in `new`).
            unsafe { _mm_loadu_si128(self.window.as_ptr().add(at).cast()) }
        }

        /// All-ones lanes where `q` is not brighter than p + t, and where
        /// it is not darker than p - t.
        #[inline]
        #[target_feature(enable = "sse2")]
        fn not_bright_not_dark(&self, q: __m128i) -> (__m128i, __m128i) {
            let zero = _mm_setzero_si128();
            (
                _mm_cmpeq_epi8(_mm_subs_epu8(q, self.hi), zero),
                _mm_cmpeq_epi8(_mm_subs_epu8(self.lo, q), zero),
            )
        }

        /// One bit per pixel that may be a corner: `portable_row`'s test
        /// negated (no candidate when, for one pair of opposite circle
        /// pixels, neither is brighter, and likewise for darker).
        #[inline]
        #[target_feature(enable = "sse2")]
        fn candidates(&self) -> u32 {
            let pairs = [
                ((0, -3), (0, 3)),
                ((3, 0), (-3, 0)),
                ((2, -2), (-2, 2)),
                ((2, 2), (-2, -2)),
            ];
            let (mut no_bright, mut no_dark) = (_mm_setzero_si128(), _mm_setzero_si128());
            for ((ax, ay), (bx, by)) in pairs {
                let (a_bright, a_dark) = self.not_bright_not_dark(self.load(ax, ay));
                let (b_bright, b_dark) = self.not_bright_not_dark(self.load(bx, by));
                no_bright = _mm_or_si128(no_bright, _mm_and_si128(a_bright, b_bright));
                no_dark = _mm_or_si128(no_dark, _mm_and_si128(a_dark, b_dark));
            }
            !(_mm_movemask_epi8(_mm_and_si128(no_bright, no_dark)) as u32) & 0xFFFF
        }

        /// The lanes with 9 contiguous brighter circle pixels, and those
        /// with 9 darker: the longest run per lane, counted around the
        /// circle and 8 pixels further (runs may wrap).
        #[inline]
        #[target_feature(enable = "sse2")]
        fn arcs_of_9(&self) -> (u32, u32) {
            let ones = _mm_set1_epi8(-1);
            let sides: [(__m128i, __m128i); 16] = std::array::from_fn(|k| {
                let (dx, dy) = CIRCLE[k];
                let (not_bright, not_dark) = self.not_bright_not_dark(self.load(dx, dy));
                (
                    _mm_xor_si128(not_bright, ones),
                    _mm_xor_si128(not_dark, ones),
                )
            });
            let zero = _mm_setzero_si128();
            let (mut run_b, mut run_d, mut best_b, mut best_d) = (zero, zero, zero, zero);
            for &(bright, dark) in sides.iter().chain(&sides[..8]) {
                // A lane's run grows by one (minus all-ones) or is cut to 0.
                run_b = _mm_and_si128(_mm_sub_epi8(run_b, bright), bright);
                run_d = _mm_and_si128(_mm_sub_epi8(run_d, dark), dark);
                best_b = _mm_max_epu8(best_b, run_b);
                best_d = _mm_max_epu8(best_d, run_d);
            }
            let eight = _mm_set1_epi8(8);
            (
                _mm_movemask_epi8(_mm_cmpgt_epi8(best_b, eight)) as u32,
                _mm_movemask_epi8(_mm_cmpgt_epi8(best_d, eight)) as u32,
            )
        }
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
    fn every_kernel_scores_every_pixel_as_the_definition_does() {
        let img = noise(97, 61, 7);
        for kernels in Kernels::all() {
            let mut fast = Fast::new(&img, kernels);
            let mut corners = 0;
            for t in [1u8, 7, 20, 60, 200] {
                for y in RADIUS..img.height - RADIUS {
                    // The whole row, and spans that end mid-block.
                    for (x0, x1) in [(RADIUS, img.width - RADIUS), (5, 22), (40, 75), (9, 9)] {
                        let mut row = vec![0u16; img.width];
                        let mut found = Vec::new();
                        fast.corners_in_row(y, (x0, x1), t, &mut row, &mut found);
                        for (x, &s) in row.iter().enumerate() {
                            let expected = if (x0..x1).contains(&x) {
                                definition(&img, x, y, t as i16)
                            } else {
                                0.0
                            };
                            assert_eq!(s as f32, expected, "{kernels:?} t {t} at ({x}, {y})");
                        }
                        let listed: Vec<u32> =
                            (x0..x1).filter(|&x| row[x] > 0).map(|x| x as u32).collect();
                        assert_eq!(found, listed, "{kernels:?} t {t} row {y}");
                        corners += found.len();
                    }
                }
            }
            assert!(corners > 500, "the image should have corners: {corners}");
        }
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
