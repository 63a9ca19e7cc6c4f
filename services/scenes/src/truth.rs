//! How predicted masks are scored against the ground-truth masks of a
//! synthesised sequence (read with `camera_reader::source::MaskList`).
//!
//! Scoring is per ground-truth person: its IoU with the best-overlapping
//! predicted instance. Union-of-everything IoU would punish a segmenter for
//! finding a real person in the background footage (the TUM sequences have
//! some), which is correct behaviour.

use std::collections::HashMap;

/// One ground-truth person's score in one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InstanceIou {
    pub id: u8,
    pub pixels: usize,
    pub iou: f64,
}

/// For every ground-truth id covering at least `min_px` pixels: IoU with
/// the predicted instance (label != 0) that overlaps it best, 0 if none.
pub fn instance_ious(predicted: &[u8], truth: &[u8], min_px: usize) -> Vec<InstanceIou> {
    let mut pred_area: HashMap<u8, usize> = HashMap::new();
    let mut truth_area: HashMap<u8, usize> = HashMap::new();
    let mut overlap: HashMap<(u8, u8), usize> = HashMap::new();
    for (&p, &t) in predicted.iter().zip(truth) {
        if p != 0 {
            *pred_area.entry(p).or_default() += 1;
        }
        if t != 0 {
            *truth_area.entry(t).or_default() += 1;
            if p != 0 {
                *overlap.entry((t, p)).or_default() += 1;
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
            InstanceIou { id, pixels: n, iou }
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
        let r = instance_ious(&pred, &truth, 1);
        assert_eq!(r.len(), 2);
        assert_eq!(r[0].id, 1);
        assert!((r[0].iou - 3.0 / 5.0).abs() < 1e-12);
        assert!((r[1].iou - 0.5).abs() < 1e-12);
        // A person smaller than min_px is not scored; a missed one scores 0.
        assert_eq!(instance_ious(&pred, &truth, 3).len(), 1);
        assert_eq!(instance_ious(&[0; 10], &truth, 1)[0].iou, 0.0);
    }
}
