//! ORB features (Rublee et al. 2011, as ORB-SLAM2 uses them): an 8-level
//! x1.2 scale pyramid, FAST-9 corners with an adaptive threshold per grid
//! cell (20, then 7 where a cell has none), an even spread over the image
//! (round-robin over cells, best corner first), orientation by intensity
//! centroid, and 256-bit rotated BRIEF descriptors on a smoothed image.
//!
//! The descriptors are in `brief`, the corner test in `fast`.

use std::borrow::Cow;
use std::sync::Arc;

use super::brief::Brief;
use super::fast::Fast;
use super::simd::Kernels;

/// One keypoint, in level-0 pixel coordinates of the (distorted) image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyPoint {
    /// Column at level 0 (pixels).
    pub x: f32,
    /// Row at level 0 (pixels).
    pub y: f32,
    /// Pyramid level it was found at (0: full size).
    pub level: u8,
    /// Orientation (radians).
    pub angle: f32,
    /// FAST corner score.
    pub score: f32,
}

/// A 256-bit ORB (rotated BRIEF) descriptor.
pub type Descriptor = [u64; 4];

/// Largest Hamming distance at which two descriptors are taken for the
/// same point (ORB-SLAM2's TH_LOW): tracking, relocalisation,
/// triangulation and fusion all match with it.
pub const MATCH_MAX_DISTANCE: u32 = 50;

/// Hamming distance of two descriptors.
#[inline]
pub fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    (a[0] ^ b[0]).count_ones()
        + (a[1] ^ b[1]).count_ones()
        + (a[2] ^ b[2]).count_ones()
        + (a[3] ^ b[3]).count_ones()
}

/// What ORB extraction is tuned with (ORB-SLAM2's settings).
#[derive(Debug, Clone, Copy)]
pub struct OrbParams {
    /// Keypoints per frame, over all levels.
    pub features: usize,
    /// Pyramid levels.
    pub levels: usize,
    /// Scale between consecutive levels.
    pub scale_factor: f32,
    /// FAST threshold tried first in each cell.
    pub fast_threshold: u8,
    /// FAST threshold where the first finds nothing in a cell.
    pub fast_min_threshold: u8,
    /// Worker threads for the pyramid levels (1: the caller's thread only).
    pub threads: usize,
    /// Whose extractor runs (ours unless built with the `kornia` feature and asked).
    pub backend: OrbBackend,
}

/// Which ORB implementation extracts the features.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum OrbBackend {
    /// This module's extractor.
    #[default]
    Own,
    /// kornia-imgproc's `OrbDetector` (ORB-SLAM3's layout: Harris-scored
    /// FAST, quadtree distribution), for comparison; see `kornia_orb`.
    #[cfg(feature = "kornia")]
    Kornia,
}

impl Default for OrbParams {
    fn default() -> Self {
        Self {
            features: 1000,
            levels: 8,
            scale_factor: 1.2,
            fast_threshold: 20,
            fast_min_threshold: 7,
            threads: 2,
            backend: OrbBackend::Own,
        }
    }
}

pub use raster::GrayU8;

/// The pyramid's two image operations, on the one image type.
trait PyramidLevels {
    fn resized(&self, w: usize, h: usize) -> Self;
    fn smoothed(&self) -> Self;
}

impl PyramidLevels for GrayU8 {
    /// Bilinear resize to `w x h` (pixel centres aligned): each source row
    /// is interpolated horizontally once (every output row blends two of
    /// them), then the rows are blended in contiguous, vectorisable passes.
    /// Coordinates are never negative, so `as usize` is the floor.
    fn resized(&self, w: usize, h: usize) -> Self {
        let (sx, sy) = (self.width as f32 / w as f32, self.height as f32 / h as f32);
        let taps = |i: usize, s: f32, n: usize| {
            let f = ((i as f32 + 0.5) * s - 0.5).clamp(0.0, (n - 1) as f32);
            let i0 = f as usize;
            (i0, (i0 + 1).min(n - 1), f - i0 as f32)
        };
        // Per output column: the left tap and the two weights. The source
        // row is converted to f32 once, with its last pixel repeated, so the
        // right tap is always the next one (where the left tap is the last
        // pixel its weight is 0, as with a clamped right tap).
        let (mut left, mut w_left, mut w_right) = (Vec::with_capacity(w), Vec::new(), Vec::new());
        for x in 0..w {
            let (x0, _, wx) = taps(x, sx, self.width);
            left.push(x0 as u32);
            w_left.push(1.0 - wx);
            w_right.push(wx);
        }
        let mut source = vec![0f32; self.width + 1];
        let mut horizontal = |y: usize, out: &mut Vec<f32>| {
            let row = &self.data[y * self.width..(y + 1) * self.width];
            for (s, &v) in source.iter_mut().zip(row) {
                *s = v as f32;
            }
            source[self.width] = row[self.width - 1] as f32;
            out.clear();
            out.extend(
                left.iter()
                    .zip(&w_left)
                    .zip(&w_right)
                    .map(|((&x0, &a), &b)| {
                        let pair = &source[x0 as usize..x0 as usize + 2];
                        pair[0] * a + pair[1] * b
                    }),
            );
        };
        // The two source rows of the previous output row, by source index.
        let (mut top, mut bot) = (Vec::with_capacity(w), Vec::with_capacity(w));
        let (mut top_y, mut bot_y) = (usize::MAX, usize::MAX);
        let mut data = Vec::with_capacity(w * h);
        for y in 0..h {
            let (y0, y1, wy) = taps(y, sy, self.height);
            if y0 != top_y {
                if y0 == bot_y {
                    std::mem::swap(&mut top, &mut bot);
                    bot_y = usize::MAX;
                } else {
                    horizontal(y0, &mut top);
                }
                top_y = y0;
            }
            if y1 != bot_y {
                horizontal(y1, &mut bot);
                bot_y = y1;
            }
            data.extend(top.iter().zip(&bot).map(|(&t, &b)| {
                let v = t * (1.0 - wy) + b * wy + 0.5;
                // SAFETY: v is finite and in [0.5, 255.5] (a blend of
                // bytes plus 0.5). Unchecked, the conversion
                // vectorises; `as u8` saturates pixel by pixel.
                unsafe { v.to_int_unchecked::<i32>() as u8 }
            }));
        }
        Self {
            width: w,
            height: h,
            data,
        }
    }

    /// Separable [1 4 6 4 1]/16 smoothing (BRIEF tests are noise-sensitive),
    /// borders replicated. Sums fit `u16` (16 x 16 x 255 + 128 < 65536), so
    /// the interior loops vectorise 8 or 16 pixels wide.
    fn smoothed(&self) -> Self {
        let (w, h) = (self.width, self.height);
        let mut tmp = vec![0u16; w * h];
        for (row, out) in self.data.chunks_exact(w).zip(tmp.chunks_exact_mut(w)) {
            let at = |i: isize| row[i.clamp(0, w as isize - 1) as usize] as u16;
            let tap = |i: isize| at(i - 2) + 4 * at(i - 1) + 6 * at(i) + 4 * at(i + 1) + at(i + 2);
            for i in (0..w.min(2)).chain(w.saturating_sub(2).max(2)..w) {
                out[i] = tap(i as isize);
            }
            if w > 4 {
                // Five shifted views rather than `windows(5)`: lane-wise
                // sums that the compiler vectorises.
                let n = w - 4;
                let tap = |k: usize| &row[k..k + n];
                let taps = tap(0)
                    .iter()
                    .zip(tap(1))
                    .zip(tap(2))
                    .zip(tap(3))
                    .zip(tap(4));
                for (o, ((((&a, &b), &c), &d), &e)) in out[2..w - 2].iter_mut().zip(taps) {
                    *o = a as u16 + 4 * b as u16 + 6 * c as u16 + 4 * d as u16 + e as u16;
                }
            }
        }
        let mut data = vec![0u8; w * h];
        for (y, out) in data.chunks_exact_mut(w).enumerate() {
            let row = |dy: isize| {
                let r = (y as isize + dy).clamp(0, h as isize - 1) as usize;
                &tmp[r * w..(r + 1) * w]
            };
            let (a, b, c, d, e) = (row(-2), row(-1), row(0), row(1), row(2));
            for (x, o) in out.iter_mut().enumerate() {
                let acc = a[x] + 4 * b[x] + 6 * c[x] + 4 * d[x] + e[x];
                *o = ((acc as u32 + 128) >> 8) as u8;
            }
        }
        Self {
            width: w,
            height: h,
            data,
        }
    }
}

/// Border kept free at every level: the rotated 31x31 BRIEF patch and the
/// orientation circle must fit.
const BORDER: usize = 20;
const CELL: usize = 30;
const HALF_PATCH: isize = 15;

/// A pixel of a pyramid level in level-0 coordinates. The levels are
/// resized with pixel centres aligned (`resized`), so pixel x of a level
/// with scale s covers level-0 x' = (x + 0.5) s - 0.5, not x s (which would
/// shift coarse-level keypoints by up to 1.3 px at level 7).
#[inline]
fn to_level0(x: usize, scale: f32) -> f32 {
    (x as f32 + 0.5) * scale - 0.5
}

/// What one pyramid level contributes.
struct LevelFeatures {
    kps: Vec<KeyPoint>,
    descs: Vec<Descriptor>,
    rejected: usize,
}

struct Level<'a> {
    img: &'a GrayU8,
    smooth: GrayU8,
    scale: f32,
}

/// Pixel offsets of the orientation disc's rows: half-width per dy.
fn disc_half_widths() -> [isize; 16] {
    let mut u = [0isize; 16];
    for (dy, slot) in u.iter_mut().enumerate() {
        *slot = ((HALF_PATCH * HALF_PATCH - (dy * dy) as isize) as f32).sqrt() as isize;
    }
    u
}

/// The extractor: holds the fixed BRIEF pattern.
pub struct OrbExtractor {
    /// The settings it extracts with.
    pub params: OrbParams,
    brief: Brief,
    disc: [isize; 16],
    /// Each level's scale relative to level 0 (`scale_factor^l`, f32 as
    /// the levels are resized), shared with the frames it extracts.
    level_scales: Arc<[f64]>,
    /// SIMD or portable pixel kernels (the same features either way).
    kernels: Kernels,
}

impl OrbExtractor {
    /// An extractor with `params`.
    pub fn new(params: OrbParams) -> Self {
        Self {
            params,
            brief: Brief::new(),
            disc: disc_half_widths(),
            level_scales: (0..params.levels)
                .map(|l| params.scale_factor.powi(l as i32) as f64)
                .collect(),
            kernels: Kernels::selected(),
        }
    }

    /// The same extractor with the given pixel kernels (tests compare them).
    pub fn with_kernels(mut self, kernels: Kernels) -> Self {
        self.kernels = kernels;
        self
    }

    /// Each pyramid level's scale relative to level 0.
    pub fn level_scales(&self) -> Arc<[f64]> {
        self.level_scales.clone()
    }

    /// Keypoints and descriptors of `img`. `keep(x, y)` (level-0 pixel
    /// coordinates) decides whether a corner may be used: the dynamic mask
    /// rejects corners on moving objects before anything is computed for
    /// them. Returns the kept features and how many corners were rejected.
    pub fn extract(
        &self,
        img: &GrayU8,
        keep: &(dyn Fn(f32, f32) -> bool + Sync),
    ) -> (Vec<KeyPoint>, Vec<Descriptor>, usize) {
        #[cfg(feature = "kornia")]
        if self.params.backend == OrbBackend::Kornia {
            return super::kornia_orb::extract(&self.params, img, keep);
        }
        let p = &self.params;
        let f = 1.0 / p.scale_factor;
        let first = p.features as f32 * (1.0 - f) / (1.0 - f.powi(p.levels as i32));
        // The pyramid: each level resized from the one above (cheap); the
        // per-level work (smoothing, FAST, orientation, BRIEF) is
        // independent and runs on `threads` workers, largest level first.
        let mut pyramid: Vec<Cow<GrayU8>> = Vec::with_capacity(p.levels);
        for level in 0..p.levels {
            let scale = p.scale_factor.powi(level as i32);
            let (w, h) = (
                (img.width as f32 / scale).round() as usize,
                (img.height as f32 / scale).round() as usize,
            );
            if w < 2 * BORDER + CELL || h < 2 * BORDER + CELL {
                break;
            }
            let lvl = match pyramid.last() {
                None => Cow::Borrowed(img),
                Some(prev) => Cow::Owned(prev.resized(w, h)),
            };
            pyramid.push(lvl);
        }
        let one_level = |level: usize| -> LevelFeatures {
            let lv = Level {
                smooth: pyramid[level].smoothed(),
                img: pyramid[level].as_ref(),
                scale: p.scale_factor.powi(level as i32),
            };
            let target = (first * f.powi(level as i32)).round() as usize;
            let (corners, rejected) = self.detect(&lv, target, keep);
            let mut out = LevelFeatures {
                kps: Vec::with_capacity(corners.len()),
                descs: Vec::with_capacity(corners.len()),
                rejected,
            };
            for (x, y, score) in corners {
                let angle = self.orientation(lv.img, x, y);
                out.descs
                    .push(self.brief.describe(&lv.smooth, x, y, angle, self.kernels));
                out.kps.push(KeyPoint {
                    x: to_level0(x, lv.scale),
                    y: to_level0(y, lv.scale),
                    level: level as u8,
                    angle,
                    score,
                });
            }
            out
        };
        let results: Vec<LevelFeatures> = if p.threads <= 1 {
            (0..pyramid.len()).map(one_level).collect()
        } else {
            let next = std::sync::atomic::AtomicUsize::new(0);
            let slots: Vec<std::sync::Mutex<Option<LevelFeatures>>> =
                (0..pyramid.len()).map(|_| Default::default()).collect();
            std::thread::scope(|scope| {
                for _ in 0..p.threads.min(pyramid.len()) {
                    scope.spawn(|| loop {
                        let level = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        if level >= pyramid.len() {
                            break;
                        }
                        let r = one_level(level);
                        *slots[level].lock().expect("no worker panics holding it") = Some(r);
                    });
                }
            });
            slots
                .into_iter()
                .map(|s| s.into_inner().ok().flatten().expect("every level ran"))
                .collect()
        };
        let (mut kps, mut descs, mut rejected) = (Vec::new(), Vec::new(), 0);
        for r in results {
            kps.extend(r.kps);
            descs.extend(r.descs);
            rejected += r.rejected;
        }
        (kps, descs, rejected)
    }

    /// Corners of one level spread over a grid: per cell FAST at the high
    /// threshold, the low one where the cell has none; then round-robin over
    /// cells, strongest first, until `target`.
    fn detect(
        &self,
        lv: &Level,
        target: usize,
        keep: &(dyn Fn(f32, f32) -> bool + Sync),
    ) -> (Vec<(usize, usize, f32)>, usize) {
        let img = lv.img;
        let (w, h) = (img.width, img.height);
        let cols = (w - 2 * BORDER).div_ceil(CELL);
        // Each cell's corners in scan order (row by row, x ascending).
        let mut cells: Vec<Vec<(usize, usize)>> =
            vec![Vec::new(); cols * (h - 2 * BORDER).div_ceil(CELL)];
        // Corner scores, 0 elsewhere: what non-maximum suppression compares.
        let mut scores = vec![0u16; w * h];
        let mut fast = Fast::new(img, self.kernels);
        let mut found = Vec::new();
        let (high, low) = (self.params.fast_threshold, self.params.fast_min_threshold);
        for (row, cy) in (BORDER..h - BORDER).step_by(CELL).enumerate() {
            let y1 = (cy + CELL).min(h - BORDER);
            let band = &mut cells[row * cols..(row + 1) * cols];
            // The high threshold over the band's whole rows (long spans
            // vectorise), then the low one in the cells left without a corner.
            for y in cy..y1 {
                found.clear();
                let span = (BORDER, w - BORDER);
                fast.corners_in_row(y, span, high, &mut scores[y * w..(y + 1) * w], &mut found);
                for &x in &found {
                    band[(x as usize - BORDER) / CELL].push((x as usize, y));
                }
            }
            for (cell, cx) in band.iter_mut().zip((BORDER..w - BORDER).step_by(CELL)) {
                if !cell.is_empty() {
                    continue;
                }
                let span = (cx, (cx + CELL).min(w - BORDER));
                for y in cy..y1 {
                    found.clear();
                    fast.corners_in_row(y, span, low, &mut scores[y * w..(y + 1) * w], &mut found);
                    cell.extend(found.iter().map(|&x| (x as usize, y)));
                }
            }
        }
        // 3x3 non-maximum suppression (ties go to the corner scanned
        // first), then the mask; each cell strongest first.
        let mut rejected = 0;
        let cells: Vec<Vec<(usize, usize, f32)>> = cells
            .into_iter()
            .map(|corners| {
                let mut cell = Vec::with_capacity(corners.len());
                for (x, y) in corners {
                    let s = scores[y * w + x];
                    let beaten = |dx: isize, dy: isize| {
                        let n = scores[(y as isize + dy) as usize * w + (x as isize + dx) as usize];
                        n > s || (n == s && (dy < 0 || (dy == 0 && dx < 0)))
                    };
                    const AROUND: [(isize, isize); 8] = [
                        (-1, -1),
                        (0, -1),
                        (1, -1),
                        (-1, 0),
                        (1, 0),
                        (-1, 1),
                        (0, 1),
                        (1, 1),
                    ];
                    if AROUND.iter().any(|&(dx, dy)| beaten(dx, dy)) {
                        continue;
                    }
                    if !keep(to_level0(x, lv.scale), to_level0(y, lv.scale)) {
                        rejected += 1;
                        continue;
                    }
                    cell.push((x, y, s as f32));
                }
                // Stable: equal scores stay in scan order.
                cell.sort_by(|a, b| b.2.total_cmp(&a.2));
                cell
            })
            .collect();
        let mut out = Vec::with_capacity(target);
        let mut round = 0;
        while out.len() < target {
            let mut took = false;
            for cell in &cells {
                if let Some(&c) = cell.get(round) {
                    out.push(c);
                    took = true;
                    if out.len() == target {
                        break;
                    }
                }
            }
            if !took {
                break;
            }
            round += 1;
        }
        (out, rejected)
    }

    /// Intensity-centroid angle over the radius-15 disc, one row span at a
    /// time (the sums are exact integers, in any order).
    fn orientation(&self, img: &GrayU8, x: usize, y: usize) -> f32 {
        let (mut m01, mut m10) = (0i32, 0i32);
        for dy in -HALF_PATCH..=HALF_PATCH {
            let half = self.disc[dy.unsigned_abs()];
            let start = (y as isize + dy) as usize * img.width + x - half as usize;
            let span = &img.data[start..=start + 2 * half as usize];
            let (mut sum, mut moment) = (0i32, 0i32);
            for (dx, &v) in (-half as i32..).zip(span) {
                sum += v as i32;
                moment += dx * v as i32;
            }
            m10 += moment;
            m01 += dy as i32 * sum;
        }
        (m01 as f32).atan2(m10 as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A non-repeating textured image (two octaves of hashed value noise),
    /// shifted by `shift` pixels.
    fn texture(w: usize, h: usize, shift: (isize, isize)) -> GrayU8 {
        let hash = |x: i64, y: i64| {
            let mut z = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
                ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
            z = (z ^ (z >> 29)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            ((z ^ (z >> 32)) & 0xFF) as f32
        };
        let noise = |x: f32, y: f32, cell: f32| {
            let (gx, gy) = ((x / cell).floor(), (y / cell).floor());
            let (fx, fy) = (x / cell - gx, y / cell - gy);
            let (gx, gy) = (gx as i64, gy as i64);
            let top = hash(gx, gy) * (1.0 - fx) + hash(gx + 1, gy) * fx;
            let bot = hash(gx, gy + 1) * (1.0 - fx) + hash(gx + 1, gy + 1) * fx;
            top * (1.0 - fy) + bot * fy
        };
        let mut data = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                let (fx, fy) = ((x as isize - shift.0) as f32, (y as isize - shift.1) as f32);
                let v = 0.7 * noise(fx, fy, 9.0) + 0.3 * noise(fx + 1000.0, fy, 3.0);
                data[y * w + x] = v.clamp(0.0, 255.0) as u8;
            }
        }
        GrayU8 {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn finds_spread_features_on_all_levels_and_matches_them_after_a_shift() {
        let orb = OrbExtractor::new(OrbParams::default());
        let a = texture(320, 240, (0, 0));
        let b = texture(320, 240, (5, 3));
        let (ka, da, _) = orb.extract(&a, &|_, _| true);
        let (kb, db, _) = orb.extract(&b, &|_, _| true);
        assert!(ka.len() > 300, "{}", ka.len());
        assert!(ka.iter().any(|k| k.level >= 4));
        // Nearest-descriptor matches mostly move by the shift.
        let mut good = 0;
        let mut total = 0;
        for (k, d) in ka.iter().zip(&da).filter(|(k, _)| k.level == 0) {
            let (j, dist) = db
                .iter()
                .enumerate()
                .map(|(j, e)| (j, hamming(d, e)))
                .min_by_key(|x| x.1)
                .unwrap();
            if dist < 40 {
                total += 1;
                if (kb[j].x - k.x - 5.0).abs() <= 1.0 && (kb[j].y - k.y - 3.0).abs() <= 1.0 {
                    good += 1;
                }
            }
        }
        assert!(
            total > 50 && good as f32 > 0.8 * total as f32,
            "{good}/{total}"
        );
    }

    #[test]
    fn masked_region_yields_no_keypoints_and_is_counted() {
        let orb = OrbExtractor::new(OrbParams::default());
        let a = texture(320, 240, (0, 0));
        let inside = |x: f32, y: f32| (80.0..200.0).contains(&x) && (60.0..180.0).contains(&y);
        let (kps, _, rejected) = orb.extract(&a, &|x, y| !inside(x, y));
        assert!(rejected > 20);
        assert!(kps.iter().all(|k| !inside(k.x, k.y)));
        assert!(kps.len() > 200);
    }
}
