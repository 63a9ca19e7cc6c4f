//! Rotated BRIEF descriptors (steered by the keypoint's angle, as ORB and
//! ORB-SLAM2 compute them): 256 intensity comparisons between pairs of
//! points of a fixed pattern, rotated into the image.
//!
//! The pattern is drawn once from an isotropic Gaussian (sigma = patch/5,
//! the distribution Calonder et al. found best) with a fixed seed:
//! descriptors are comparable across runs and machines.

use super::orb::{Descriptor, GrayU8};
use super::simd::Kernels;
use crate::rng::SplitMix64;

/// How far a rotated pattern point may land from the keypoint, in pixels
/// along each axis: the pattern is clamped to +-13, so rotated it stays
/// within 13 sqrt(2) = 18.4, rounded to 18.
pub const REACH: usize = 18;

/// The fixed test pattern.
pub struct Brief {
    /// The pattern's points, test after test (first, second, first, ...).
    pattern_x: [f32; 512],
    pattern_y: [f32; 512],
}

impl Default for Brief {
    fn default() -> Self {
        Self::new()
    }
}

impl Brief {
    /// The fixed 256-test pattern (ORB-SLAM2's).
    pub fn new() -> Self {
        // Box-Muller on a fixed-seed stream: the descriptor layout never changes.
        let mut rng = SplitMix64::new(0x0DB5_1A11_0000_0001);
        let mut gauss = || {
            let (u1, u2) = (rng.uniform(0.0, 1.0).max(1e-12), rng.uniform(0.0, 1.0));
            ((-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()) as f32
        };
        let sigma = 31.0 / 5.0;
        let mut brief = Self {
            pattern_x: [0.0; 512],
            pattern_y: [0.0; 512],
        };
        for i in 0..512 {
            brief.pattern_x[i] = (gauss() * sigma).clamp(-13.0, 13.0);
            brief.pattern_y[i] = (gauss() * sigma).clamp(-13.0, 13.0);
        }
        brief
    }

    /// The descriptor of the keypoint at (`x`, `y`) of `smooth` (at least
    /// `REACH` pixels from every border) with orientation `angle`.
    pub fn describe(
        &self,
        smooth: &GrayU8,
        x: usize,
        y: usize,
        angle: f32,
        kernels: Kernels,
    ) -> Descriptor {
        let w = smooth.width;
        assert!(
            x >= REACH && y >= REACH && x + REACH < w && y + REACH < smooth.height,
            "BRIEF patch at ({x}, {y}) crosses the {w}x{} image's border",
            smooth.height
        );
        let (s, c) = angle.sin_cos();
        let offsets = match kernels {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: every x86-64 CPU has SSE2.
            Kernels::Sse2 => unsafe { sse2::offsets(self, s, c, w) },
            _ => self.offsets(s, c, w),
        };
        // The patch, from REACH rows and columns before the keypoint to
        // REACH after: every offset lands in it.
        let reach = REACH * w + REACH;
        let centre = y * w + x;
        let patch = &smooth.data[centre - reach..=centre + reach];
        let at = |o: i32| patch[(reach as isize + o as isize) as usize];
        match kernels {
            #[cfg(target_arch = "x86_64")]
            Kernels::Sse2 => {
                let (mut first, mut second) = ([0u8; 256], [0u8; 256]);
                for (i, pair) in offsets.chunks_exact(2).enumerate() {
                    (first[i], second[i]) = (at(pair[0]), at(pair[1]));
                }
                // SAFETY: every x86-64 CPU has SSE2.
                unsafe { sse2::less(&first, &second) }
            }
            _ => {
                let mut d = [0u64; 4];
                for (i, pair) in offsets.chunks_exact(2).enumerate() {
                    // A data-dependent branch here would be mispredicted half the time.
                    d[i / 64] |= ((at(pair[0]) < at(pair[1])) as u64) << (i % 64);
                }
                d
            }
        }
    }

    /// The pattern's 512 points rotated by the angle whose sine and cosine
    /// are `s`, `c`, as offsets from the keypoint in an image `w` wide.
    fn offsets(&self, s: f32, c: f32, w: usize) -> [i32; 512] {
        let mut offsets = [0i32; 512];
        for ((o, &px), &py) in offsets.iter_mut().zip(&self.pattern_x).zip(&self.pattern_y) {
            *o = round_half_away(s * px + c * py) * w as i32 + round_half_away(c * px - s * py);
        }
        offsets
    }
}

/// `v.round()` (half away from zero) for |v| < 2^23 without the libm call
/// that `f32::round` is on x86-64 (SSE4.1 has no such rounding mode): the
/// truncation and the fraction are exact in that range.
#[inline]
fn round_half_away(v: f32) -> i32 {
    let t = v as i32;
    let fraction = v - t as f32;
    // Comparisons as integers, not branches: the fractions of the rotated
    // pattern are random, a branch would be mispredicted half the time.
    t + (fraction >= 0.5) as i32 - (fraction <= -0.5) as i32
}

/// The rotation and the comparisons 4 and 16 lanes at a time, with the same
/// arithmetic as the portable code (no fused multiply-add there either).
#[cfg(target_arch = "x86_64")]
mod sse2 {
    use std::arch::x86_64::*;

    use super::Brief;
    use crate::features::orb::Descriptor;

    /// [`Brief::offsets`], 4 points at a time.
    #[target_feature(enable = "sse2")]
    pub fn offsets(brief: &Brief, s: f32, c: f32, w: usize) -> [i32; 512] {
        let (s, c, wf) = (_mm_set1_ps(s), _mm_set1_ps(c), _mm_set1_ps(w as f32));
        let (half, minus_half) = (_mm_set1_ps(0.5), _mm_set1_ps(-0.5));
        // `round_half_away`: the truncation, plus one where the fraction is
        // >= 0.5, minus one where it is <= -0.5 (all-ones lanes are -1).
        let round = |v: __m128| {
            let t = _mm_cvttps_epi32(v);
            let fraction = _mm_sub_ps(v, _mm_cvtepi32_ps(t));
            let up = _mm_castps_si128(_mm_cmpge_ps(fraction, half));
            let down = _mm_castps_si128(_mm_cmple_ps(fraction, minus_half));
            _mm_add_epi32(_mm_sub_epi32(t, up), down)
        };
        let mut offsets = [0i32; 512];
        for ((o, px), py) in offsets
            .chunks_exact_mut(4)
            .zip(brief.pattern_x.chunks_exact(4))
            .zip(brief.pattern_y.chunks_exact(4))
        {
            // SAFETY: each chunk holds 4 lanes.
            let (px, py) = unsafe { (_mm_loadu_ps(px.as_ptr()), _mm_loadu_ps(py.as_ptr())) };
            let dy = round(_mm_add_ps(_mm_mul_ps(s, px), _mm_mul_ps(c, py)));
            let dx = round(_mm_sub_ps(_mm_mul_ps(c, px), _mm_mul_ps(s, py)));
            // dy w + dx is below 2^24: exact in f32.
            let offset = _mm_add_ps(_mm_mul_ps(_mm_cvtepi32_ps(dy), wf), _mm_cvtepi32_ps(dx));
            // SAFETY: the chunk holds 4 lanes.
            unsafe { _mm_storeu_si128(o.as_mut_ptr().cast(), _mm_cvttps_epi32(offset)) };
        }
        offsets
    }

    /// Bit i set where `first[i] < second[i]`, 16 tests at a time.
    #[target_feature(enable = "sse2")]
    pub fn less(first: &[u8; 256], second: &[u8; 256]) -> Descriptor {
        // Unsigned order as signed order: flip the top bit.
        let flip = _mm_set1_epi8(i8::MIN);
        let mut d = [0u64; 4];
        for (i, (a, b)) in first
            .chunks_exact(16)
            .zip(second.chunks_exact(16))
            .enumerate()
        {
            // SAFETY: each chunk holds 16 bytes.
            let (a, b) = unsafe {
                (
                    _mm_loadu_si128(a.as_ptr().cast()),
                    _mm_loadu_si128(b.as_ptr().cast()),
                )
            };
            let lt = _mm_cmplt_epi8(_mm_xor_si128(a, flip), _mm_xor_si128(b, flip));
            d[i / 4] |= (_mm_movemask_epi8(lt) as u32 as u64) << (16 * (i % 4));
        }
        d
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounding_without_libm_is_f32_round() {
        let mut v = -40.0f32;
        while v <= 40.0 {
            for x in [v, v.next_up(), v.next_down()] {
                assert_eq!(round_half_away(x), x.round() as i32, "{x}");
            }
            v += 0.125;
        }
    }

    #[test]
    fn every_kernel_rotates_the_pattern_alike_and_stays_within_reach() {
        let brief = Brief::new();
        let w = 640;
        for step in 0..3600 {
            let angle = (step as f32 * 0.1 - 180.0).to_radians() + 1e-4 * (step % 7) as f32;
            let (s, c) = angle.sin_cos();
            let portable = brief.offsets(s, c, w);
            for o in portable {
                let (dy, dx) = ((o as f32 / w as f32).round() as i32, 0);
                let dx = o - dy * w as i32 + dx;
                assert!(dy.unsigned_abs() as usize <= REACH && dx.unsigned_abs() as usize <= REACH);
            }
            #[cfg(target_arch = "x86_64")]
            // SAFETY: every x86-64 CPU has SSE2.
            assert_eq!(
                unsafe { sse2::offsets(&brief, s, c, w) },
                portable,
                "{angle}"
            );
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_sse2_comparisons_are_the_portable_ones() {
        let mut rng = SplitMix64::new(3);
        for _ in 0..200 {
            let mut byte = || (rng.uniform(0.0, 1.0) * 256.0) as u8;
            let first: [u8; 256] = std::array::from_fn(|_| byte());
            let second: [u8; 256] =
                std::array::from_fn(|i| if i % 5 == 0 { first[i] } else { byte() });
            let mut d = [0u64; 4];
            for i in 0..256 {
                d[i / 64] |= ((first[i] < second[i]) as u64) << (i % 64);
            }
            // SAFETY: every x86-64 CPU has SSE2.
            assert_eq!(unsafe { sse2::less(&first, &second) }, d);
        }
    }
}
