//! How predicted masks are scored against the ground-truth masks of a
//! synthesised sequence (read with `datasets::source::MaskList`).
//!
//! Scoring is per ground-truth person: its IoU with the best-overlapping
//! predicted instance. Union-of-everything IoU would punish a segmenter for
//! finding a real person in the background footage (the TUM sequences have
//! some), which is correct behaviour.

use std::collections::HashMap;

/// One ground-truth person's score in one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InstanceIou {
    /// The person's instance id.
    pub id: u8,
    /// Pixels of the person outside the ignore regions.
    pub pixels: usize,
    /// Intersection over union of the best-matching predicted mask.
    pub iou: f64,
    /// The person touches the image border (walking in or out of view).
    pub border_cut: bool,
}

/// A person covering less than this share of the image counts as small
/// (2 %: a standing adult about 6 m away in a VGA frame of TUM's camera).
pub const SMALL_SHARE: f64 = 0.02;

impl InstanceIou {
    /// Whether the person is small in an image of `image_px` pixels.
    pub fn small(&self, image_px: usize) -> bool {
        (self.pixels as f64) < SMALL_SHARE * image_px as f64
    }
}

/// For every ground-truth id covering at least `min_px` pixels: IoU with
/// the predicted instance (label != 0) that overlaps it best, 0 if none.
/// Pixels where `ignore` is non-zero count for neither side (a real person
/// in the source footage that the ground truth does not contain: masking
/// him is right, so it must not cost IoU). `width` is the image's, to tell
/// which people touch its border.
pub fn instance_ious(
    predicted: &[u8],
    truth: &[u8],
    ignore: Option<&[u8]>,
    width: usize,
    min_px: usize,
) -> Vec<InstanceIou> {
    let height = truth.len() / width.max(1);
    let mut pred_area: HashMap<u8, usize> = HashMap::new();
    let mut truth_area: HashMap<u8, usize> = HashMap::new();
    let mut overlap: HashMap<(u8, u8), usize> = HashMap::new();
    let mut at_border: Vec<u8> = Vec::new();
    for (i, (&p, &t)) in predicted.iter().zip(truth).enumerate() {
        if ignore.is_some_and(|m| m[i] != 0) {
            continue;
        }
        if p != 0 {
            *pred_area.entry(p).or_default() += 1;
        }
        if t != 0 {
            *truth_area.entry(t).or_default() += 1;
            if p != 0 {
                *overlap.entry((t, p)).or_default() += 1;
            }
            let (x, y) = (i % width, i / width);
            if (x == 0 || y == 0 || x + 1 == width || y + 1 == height) && !at_border.contains(&t) {
                at_border.push(t);
            }
        }
    }
    let mut out: Vec<InstanceIou> = truth_area
        .iter()
        .filter(|(_, &n)| n >= min_px)
        .map(|(&id, &n)| {
            let iou = overlap
                .iter()
                .filter(|((t, _), _)| *t == id)
                .map(|((_, p), &inter)| inter as f64 / (n + pred_area[p] - inter) as f64)
                .fold(0.0, f64::max);
            InstanceIou {
                id,
                pixels: n,
                iou,
                border_cut: at_border.contains(&id),
            }
        })
        .collect();
    out.sort_by_key(|r| r.id);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn best_overlapping_prediction_scores_each_person() {
        // truth: id 1 on cells 0..4, id 2 on 6..8; prediction: 7 on 1..4 plus a
        // stray real person (9) elsewhere, 3 on 6..7.
        let truth = [1, 1, 1, 1, 0, 0, 2, 2, 0, 0];
        let pred = [0, 7, 7, 7, 7, 0, 3, 0, 9, 9];
        let r = instance_ious(&pred, &truth, None, 10, 1);
        assert_eq!(r.len(), 2);
        assert_eq!(r[0].id, 1);
        assert!((r[0].iou - 3.0 / 5.0).abs() < 1e-12);
        assert!((r[1].iou - 0.5).abs() < 1e-12);
        // A person smaller than min_px is not scored; a missed one scores 0.
        assert_eq!(instance_ious(&pred, &truth, None, 10, 3).len(), 1);
        assert_eq!(instance_ious(&[0; 10], &truth, None, 10, 1)[0].iou, 0.0);
    }

    #[test]
    fn ignored_pixels_count_for_neither_side_and_borders_are_found() {
        // 4x3 image. Truth id 1 in the middle column pair of row 1 (inside),
        // id 2 on the left column (border). The prediction covers id 1 and
        // spills onto an ignored real person at the right.
        #[rustfmt::skip]
        let truth = [
            2, 0, 0, 0,
            2, 1, 1, 0,
            2, 0, 0, 0,
        ];
        #[rustfmt::skip]
        let pred = [
            0, 0, 0, 0,
            0, 5, 5, 5,
            0, 0, 0, 5,
        ];
        #[rustfmt::skip]
        let ignore = [
            0, 0, 0, 0,
            0, 0, 0, 1,
            0, 0, 0, 1,
        ];
        let plain = instance_ious(&pred, &truth, None, 4, 1);
        assert!((plain[0].iou - 0.5).abs() < 1e-12, "{plain:?}");
        let ignoring = instance_ious(&pred, &truth, Some(&ignore), 4, 1);
        assert_eq!(ignoring[0].iou, 1.0, "{ignoring:?}");
        assert!(!ignoring[0].border_cut && ignoring[1].border_cut);
        assert_eq!(ignoring[1].iou, 0.0);
        assert!(ignoring[0].small(12 * 100) && !ignoring[0].small(12));
    }
}
