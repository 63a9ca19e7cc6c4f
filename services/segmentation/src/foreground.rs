//! Evidence that keeps a weak detection: does its mask continue an object
//! of the frame before ([`continues`]), or stand in front of what surrounds
//! it in depth ([`stands_out`])?
//!
//! The segmenter keeps detections down to `score_threshold`; below it, the
//! network still finds people that are cut by the border, partly hidden or
//! blurred, among many false detections on clutter (at 0.05 on the static
//! shared sequence: 23 % of the features masked against 10 %). A tracker
//! keeps a low-score detection that extends a track; the same holds for a
//! mask lying on an object the propagator followed. And a person (or
//! any object the class list names) is a compact blob in depth with the room
//! behind it; clutter on a desk, a wall or a desk's edge is continuous in
//! depth with its surroundings. So a weak detection is kept only where it
//! continues such an object, or where its mask is compact in depth and most
//! of a ring around it (leaving out what is in front of it: an occluding
//! desk) lies clearly behind it.

use shared_types::views::DepthImage;

/// Thresholds of the test (defaults chosen on the synth sequences and the
/// static shared sequence; docs/models.md "Weak detections").
#[derive(Debug, Clone, Copy)]
pub struct ForegroundParams {
    /// Share of the mask's pixels that must have a depth measurement.
    pub min_measured: f32,
    /// The mask's 10th-90th percentile depth span may be at most this many
    /// metres, or `max_span_ratio` of its median depth if that is more.
    pub max_span_m: f32,
    /// See `max_span_m`.
    pub max_span_ratio: f32,
    /// Ring pixels count as behind the mask when farther than its median by
    /// this many metres, or `gap_ratio` of the median if that is more.
    pub gap_m: f32,
    /// See `gap_m`.
    pub gap_ratio: f32,
    /// Share of the ring (pixels not in front of the mask) that must be
    /// behind it.
    pub min_behind: f32,
    /// The ring's width as a share of the mask's larger box side (at least
    /// 8 pixels).
    pub ring_ratio: f32,
}

impl Default for ForegroundParams {
    fn default() -> Self {
        Self {
            min_measured: 0.3,
            max_span_m: 0.6,
            max_span_ratio: 0.3,
            gap_m: 0.25,
            gap_ratio: 0.15,
            min_behind: 0.6,
            ring_ratio: 0.25,
        }
    }
}

/// Share of a weak detection's mask that must lie on an object of the
/// frame before for it to continue that object.
pub const MIN_CONTINUED: f32 = 0.3;

/// Whether the mask (`pixels`) continues an object of the frame before:
/// at least [`MIN_CONTINUED`] of it lies on that frame's labels.
pub fn continues(pixels: &[u32], previous: &[u8]) -> bool {
    let on = pixels
        .iter()
        .filter(|&&i| previous.get(i as usize).is_some_and(|&l| l > 0))
        .count();
    !pixels.is_empty() && on as f32 >= MIN_CONTINUED * pixels.len() as f32
}

/// Fewest measured pixels inside the mask and in the ring for a verdict.
const MIN_SAMPLES: usize = 20;

/// Whether the mask (`pixels`: indices into a `width` x `height` image)
/// stands in front of its surroundings in `depth`.
pub fn stands_out(
    pixels: &[u32],
    depth: &DepthImage,
    width: usize,
    height: usize,
    p: &ForegroundParams,
) -> bool {
    if pixels.is_empty() || (depth.image.width, depth.image.height) != (width, height) {
        return false;
    }
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    for &i in pixels {
        let (x, y) = (i as usize % width, i as usize / width);
        x0 = x0.min(x);
        y0 = y0.min(y);
        x1 = x1.max(x + 1);
        y1 = y1.max(y + 1);
    }
    // Inside: every pixel's depth, on a stride that keeps a few thousand.
    let stride = (pixels.len() / 4000).max(1);
    let mut inside: Vec<f32> = pixels
        .iter()
        .step_by(stride)
        .filter_map(|&i| depth.metres_at(i as usize % width, i as usize / width))
        .collect();
    let sampled = pixels.len().div_ceil(stride);
    if inside.len() < MIN_SAMPLES || (inside.len() as f32) < p.min_measured * sampled as f32 {
        return false;
    }
    inside.sort_by(f32::total_cmp);
    let at = |q: f32| inside[((inside.len() - 1) as f32 * q).round() as usize];
    let median = at(0.5);
    if at(0.9) - at(0.1) > p.max_span_m.max(p.max_span_ratio * median) {
        return false;
    }
    // The ring: the box grown on every side, less the mask itself.
    let (bw, bh) = (x1 - x0, y1 - y0);
    let mut member = vec![false; bw * bh];
    for &i in pixels {
        let (x, y) = (i as usize % width, i as usize / width);
        member[(y - y0) * bw + (x - x0)] = true;
    }
    let grow = ((p.ring_ratio * bw.max(bh) as f32) as usize).max(8);
    let (rx0, ry0) = (x0.saturating_sub(grow), y0.saturating_sub(grow));
    let (rx1, ry1) = ((x1 + grow).min(width), (y1 + grow).min(height));
    let gap = p.gap_m.max(p.gap_ratio * median);
    let ring_stride = (((rx1 - rx0) * (ry1 - ry0)) as f64 / 8000.0)
        .sqrt()
        .ceil()
        .max(1.0) as usize;
    let (mut behind, mut level) = (0usize, 0usize);
    for y in (ry0..ry1).step_by(ring_stride) {
        for x in (rx0..rx1).step_by(ring_stride) {
            let in_box = (x0..x1).contains(&x) && (y0..y1).contains(&y);
            if in_box && member[(y - y0) * bw + (x - x0)] {
                continue;
            }
            let Some(d) = depth.metres_at(x, y) else {
                continue;
            };
            if d > median + gap {
                behind += 1;
            } else if d >= median - gap {
                level += 1;
            }
        }
    }
    let around = behind + level;
    around >= MIN_SAMPLES && behind as f32 >= p.min_behind * around as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: usize = 64;
    const H: usize = 48;

    /// A depth image (mm, per_metre 1000) from a function of the pixel.
    fn depth_bytes(f: impl Fn(usize, usize) -> u16) -> Vec<u8> {
        let mut raw = Vec::with_capacity(W * H * 2);
        for y in 0..H {
            for x in 0..W {
                raw.extend_from_slice(&f(x, y).to_ne_bytes());
            }
        }
        raw
    }

    fn square(x0: usize, y0: usize, side: usize) -> Vec<u32> {
        let mut v = Vec::new();
        for y in y0..y0 + side {
            for x in x0..x0 + side {
                v.push((y * W + x) as u32);
            }
        }
        v
    }

    fn inside(x: usize, y: usize) -> bool {
        (20..36).contains(&x) && (16..32).contains(&y)
    }

    fn check(raw: &[u8], mask: &[u32]) -> bool {
        let depth = DepthImage::new(raw, W, H, 1000.0).unwrap();
        stands_out(mask, &depth, W, H, &ForegroundParams::default())
    }

    #[test]
    fn a_blob_in_front_of_the_wall_stands_out() {
        let raw = depth_bytes(|x, y| if inside(x, y) { 1200 } else { 3000 });
        assert!(check(&raw, &square(20, 16, 16)));
    }

    #[test]
    fn a_patch_of_the_wall_itself_does_not() {
        let raw = depth_bytes(|x, y| if inside(x, y) { 1200 } else { 3000 });
        // A square of the wall, away from the blob.
        assert!(!check(&raw, &square(40, 4, 12)));
        // The same square on a flat wall.
        let flat = depth_bytes(|_, _| 2000);
        assert!(!check(&flat, &square(20, 16, 16)));
    }

    #[test]
    fn an_occluder_in_front_does_not_count_against_it() {
        // The blob's lower ring is a desk nearer than the blob; the rest
        // of the ring is the wall behind.
        let raw = depth_bytes(|x, y| {
            if inside(x, y) {
                1500
            } else if y >= 32 {
                700
            } else {
                3000
            }
        });
        assert!(check(&raw, &square(20, 16, 16)));
    }

    #[test]
    fn a_slanted_surface_is_not_compact() {
        // A floor receding from 1 m to 4.5 m across the mask's rows.
        let raw = depth_bytes(|_, y| 1000 + 75 * y as u16);
        assert!(!check(&raw, &square(10, 0, 46)));
    }

    #[test]
    fn a_mask_on_last_frame_s_object_continues_it() {
        let mut previous = vec![0u8; W * H];
        for i in square(20, 16, 16) {
            previous[i as usize] = 3;
        }
        // Shifted by 6 px: 10 of 16 columns on the object.
        assert!(continues(&square(26, 16, 16), &previous));
        // Shifted by 12 px: a quarter on it.
        assert!(!continues(&square(32, 16, 16), &previous));
        assert!(!continues(&[], &previous));
    }

    #[test]
    fn without_depth_there_is_no_verdict() {
        let raw = depth_bytes(|x, y| if inside(x, y) { 0 } else { 3000 });
        assert!(!check(&raw, &square(20, 16, 16)));
        // Depth of another size than the mask's image: no verdict (and an
        // empty buffer is no depth image at all).
        let standing = depth_bytes(|x, y| if inside(x, y) { 1000 } else { 3000 });
        let shorter = DepthImage::new(&standing[..W * (H - 1) * 2], W, H - 1, 1000.0).unwrap();
        assert!(!stands_out(
            &square(20, 16, 16),
            &shorter,
            W,
            H,
            &ForegroundParams::default()
        ));
        assert!(DepthImage::new(&[], W, H, 1000.0).is_none());
    }
}
