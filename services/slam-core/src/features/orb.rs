//! ORB features (Rublee et al. 2011, as ORB-SLAM2 uses them): an 8-level
//! x1.2 scale pyramid, FAST-9 corners with an adaptive threshold per grid
//! cell (20, then 7 where a cell has none), an even spread over the image
//! (round-robin over cells, best corner first), orientation by intensity
//! centroid, and 256-bit rotated BRIEF descriptors on a smoothed image.
//!
//! The BRIEF test pattern is drawn once from an isotropic Gaussian
//! (sigma = patch/5, the distribution Calonder et al. found best) with a
//! fixed seed: descriptors are comparable across runs and machines.

use std::borrow::Cow;

use crate::rng::SplitMix64;

/// One keypoint, in level-0 pixel coordinates of the (distorted) image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyPoint {
    pub x: f32,
    pub y: f32,
    pub level: u8,
    /// Orientation (radians).
    pub angle: f32,
    pub score: f32,
}

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

#[derive(Debug, Clone, Copy)]
pub struct OrbParams {
    pub features: usize,
    pub levels: usize,
    pub scale_factor: f32,
    pub fast_threshold: u8,
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

/// Grey image, row-major u8.
#[derive(Debug, Clone)]
pub struct GrayU8 {
    pub width: usize,
    pub height: usize,
    pub data: Vec<u8>,
}

impl GrayU8 {
    pub fn from_rgb(rgb: &[u8], width: usize, height: usize) -> Self {
        let data = rgb
            .chunks_exact(3)
            .map(|p| ((77 * p[0] as u32 + 150 * p[1] as u32 + 29 * p[2] as u32) >> 8) as u8)
            .collect();
        Self {
            width,
            height,
            data,
        }
    }

    #[inline]
    fn at(&self, x: usize, y: usize) -> u8 {
        self.data[y * self.width + x]
    }

    /// Bilinear resize to `w x h`.
    fn resized(&self, w: usize, h: usize) -> Self {
        let (sx, sy) = (self.width as f32 / w as f32, self.height as f32 / h as f32);
        let mut data = Vec::with_capacity(w * h);
        for y in 0..h {
            let fy = ((y as f32 + 0.5) * sy - 0.5).clamp(0.0, (self.height - 1) as f32);
            let (y0, wy) = (fy as usize, fy - fy.floor());
            let y1 = (y0 + 1).min(self.height - 1);
            for x in 0..w {
                let fx = ((x as f32 + 0.5) * sx - 0.5).clamp(0.0, (self.width - 1) as f32);
                let (x0, wx) = (fx as usize, fx - fx.floor());
                let x1 = (x0 + 1).min(self.width - 1);
                let top = self.at(x0, y0) as f32 * (1.0 - wx) + self.at(x1, y0) as f32 * wx;
                let bot = self.at(x0, y1) as f32 * (1.0 - wx) + self.at(x1, y1) as f32 * wx;
                data.push((top * (1.0 - wy) + bot * wy + 0.5) as u8);
            }
        }
        Self {
            width: w,
            height: h,
            data,
        }
    }

    /// Separable [1 4 6 4 1]/16 smoothing (BRIEF tests are noise-sensitive),
    /// borders replicated. The interior runs without index clamping.
    fn smoothed(&self) -> Self {
        let (w, h) = (self.width, self.height);
        let tap = |get: &dyn Fn(isize) -> u32, i: isize| {
            get(i - 2) + 4 * get(i - 1) + 6 * get(i) + 4 * get(i + 1) + get(i + 2)
        };
        let mut tmp = vec![0u32; w * h];
        for y in 0..h {
            let row = &self.data[y * w..(y + 1) * w];
            let out = &mut tmp[y * w..(y + 1) * w];
            let clamped = |i: isize| row[i.clamp(0, w as isize - 1) as usize] as u32;
            for x in 0..w {
                out[x] = if x >= 2 && x + 2 < w {
                    row[x - 2] as u32
                        + 4 * row[x - 1] as u32
                        + 6 * row[x] as u32
                        + 4 * row[x + 1] as u32
                        + row[x + 2] as u32
                } else {
                    tap(&clamped, x as isize)
                };
            }
        }
        let mut data = vec![0u8; w * h];
        for y in 0..h {
            let r = |dy: isize| (y as isize + dy).clamp(0, h as isize - 1) as usize * w;
            let rows = [r(-2), r(-1), r(0), r(1), r(2)];
            for x in 0..w {
                let acc = tmp[rows[0] + x]
                    + 4 * tmp[rows[1] + x]
                    + 6 * tmp[rows[2] + x]
                    + 4 * tmp[rows[3] + x]
                    + tmp[rows[4] + x];
                data[y * w + x] = ((acc + 128) >> 8) as u8;
            }
        }
        Self {
            width: w,
            height: h,
            data,
        }
    }
}

const CIRCLE: [(isize, isize); 16] = [
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

/// FAST-9 score at (x, y) for threshold `t`: the sum of absolute
/// differences beyond `t` over the circle when 9 contiguous pixels are all
/// brighter or all darker, else 0.
#[inline]
fn fast_score(img: &GrayU8, x: usize, y: usize, t: i16) -> f32 {
    let w = img.width as isize;
    let d = &img.data;
    let centre = y * img.width + x;
    let p = d[centre] as i16;
    let diff = |k: usize| {
        let (dx, dy) = CIRCLE[k];
        d[(centre as isize + dy * w + dx) as usize] as i16 - p
    };
    // Quick rejection on the compass points (at least 2 of 4 must pass)
    // before the other 12 pixels are read: most pixels end here.
    let compass = [diff(0), diff(4), diff(8), diff(12)];
    let bright = compass.iter().filter(|&&v| v > t).count();
    let dark = compass.iter().filter(|&&v| v < -t).count();
    if bright < 2 && dark < 2 {
        return 0.0;
    }
    let v: [i16; 16] = std::array::from_fn(diff);
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

fn pattern() -> Vec<[(f32, f32); 2]> {
    // Box-Muller on a fixed-seed stream: the descriptor layout never changes.
    let mut rng = SplitMix64::new(0x0DB5_1A11_0000_0001);
    let mut gauss = || {
        let (u1, u2) = (rng.uniform(0.0, 1.0).max(1e-12), rng.uniform(0.0, 1.0));
        ((-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()) as f32
    };
    let sigma = 31.0 / 5.0;
    (0..256)
        .map(|_| {
            let mut pt = || {
                (
                    (gauss() * sigma).clamp(-13.0, 13.0),
                    (gauss() * sigma).clamp(-13.0, 13.0),
                )
            };
            [pt(), pt()]
        })
        .collect()
}

/// The extractor: holds the fixed BRIEF pattern.
pub struct OrbExtractor {
    pub params: OrbParams,
    pattern: Vec<[(f32, f32); 2]>,
    disc: [isize; 16],
}

impl OrbExtractor {
    pub fn new(params: OrbParams) -> Self {
        Self {
            params,
            pattern: pattern(),
            disc: disc_half_widths(),
        }
    }

    /// Scale of `level` relative to level 0.
    pub fn scale(&self, level: u8) -> f32 {
        self.params.scale_factor.powi(level as i32)
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
                out.descs.push(self.describe(&lv.smooth, x, y, angle));
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
        let mut cells: Vec<Vec<(usize, usize, f32)>> = Vec::new();
        let mut rejected = 0;
        let mut scores = vec![0f32; w * h];
        for cy in (BORDER..h - BORDER).step_by(CELL) {
            for cx in (BORDER..w - BORDER).step_by(CELL) {
                let (x1, y1) = ((cx + CELL).min(w - BORDER), (cy + CELL).min(h - BORDER));
                for t in [self.params.fast_threshold, self.params.fast_min_threshold] {
                    let mut any = false;
                    for y in cy..y1 {
                        for x in cx..x1 {
                            let s = fast_score(img, x, y, t as i16);
                            scores[y * w + x] = s;
                            any |= s > 0.0;
                        }
                    }
                    if any {
                        break;
                    }
                }
            }
        }
        for cy in (BORDER..h - BORDER).step_by(CELL) {
            for cx in (BORDER..w - BORDER).step_by(CELL) {
                let (x1, y1) = ((cx + CELL).min(w - BORDER), (cy + CELL).min(h - BORDER));
                let mut cell = Vec::new();
                for y in cy..y1 {
                    for x in cx..x1 {
                        let s = scores[y * w + x];
                        if s <= 0.0 {
                            continue;
                        }
                        // 3x3 non-maximum suppression.
                        let mut best = true;
                        'nms: for dy in -1isize..=1 {
                            for dx in -1isize..=1 {
                                if (dx, dy) != (0, 0) {
                                    let n = scores[(y as isize + dy) as usize * w
                                        + (x as isize + dx) as usize];
                                    if n > s || (n == s && (dy < 0 || (dy == 0 && dx < 0))) {
                                        best = false;
                                        break 'nms;
                                    }
                                }
                            }
                        }
                        if !best {
                            continue;
                        }
                        if !keep(to_level0(x, lv.scale), to_level0(y, lv.scale)) {
                            rejected += 1;
                            continue;
                        }
                        cell.push((x, y, s));
                    }
                }
                cell.sort_by(|a, b| b.2.total_cmp(&a.2));
                cells.push(cell);
            }
        }
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

    fn orientation(&self, img: &GrayU8, x: usize, y: usize) -> f32 {
        let (mut m01, mut m10) = (0i64, 0i64);
        for dy in -HALF_PATCH..=HALF_PATCH {
            let half = self.disc[dy.unsigned_abs()];
            let yy = (y as isize + dy) as usize;
            for dx in -half..=half {
                let v = img.at((x as isize + dx) as usize, yy) as i64;
                m10 += dx as i64 * v;
                m01 += dy as i64 * v;
            }
        }
        (m01 as f32).atan2(m10 as f32)
    }

    fn describe(&self, smooth: &GrayU8, x: usize, y: usize, angle: f32) -> Descriptor {
        let (s, c) = angle.sin_cos();
        let at = |(px, py): (f32, f32)| {
            let rx = (c * px - s * py).round() as isize;
            let ry = (s * px + c * py).round() as isize;
            smooth.at((x as isize + rx) as usize, (y as isize + ry) as usize)
        };
        let mut d = [0u64; 4];
        for (i, [a, b]) in self.pattern.iter().enumerate() {
            if at(*a) < at(*b) {
                d[i / 64] |= 1 << (i % 64);
            }
        }
        d
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
