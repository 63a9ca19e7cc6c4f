//! kornia-imgproc's ORB extractor behind [`super::orb::OrbExtractor::extract`]
//! (feature `kornia`, `OrbBackend::Kornia`), so both can be compared on
//! the same frames with the same tracker (`slam-bench --extractor kornia`).
//!
//! kornia detects on the whole image and has no mask input, so the dynamic
//! mask is applied to its keypoints afterwards (same `keep` test, same
//! count of rejected corners); the features it would have spent on masked
//! areas are not redistributed, unlike ours.

use kornia_image::{Image, ImageSize};
use kornia_imgproc::features::OrbDetector;

use super::orb::{Descriptor, GrayU8, KeyPoint, OrbParams};

/// Keypoints and descriptors of `img` by kornia's `OrbDetector` configured
/// from `params` (features, levels, scale factor, FAST thresholds); those
/// `keep` rejects are dropped and counted. An image kornia refuses (too
/// small for its pyramid) gives no features, as a blank frame does.
pub fn extract(
    params: &OrbParams,
    img: &GrayU8,
    keep: &(dyn Fn(f32, f32) -> bool + Sync),
) -> (Vec<KeyPoint>, Vec<Descriptor>, usize) {
    let detector = OrbDetector {
        n_keypoints: params.features,
        n_scales: params.levels,
        downscale: params.scale_factor,
        ini_fast_threshold: params.fast_threshold as f32 / 255.0,
        min_fast_threshold: params.fast_min_threshold as f32 / 255.0,
        ..OrbDetector::default()
    };
    let size = ImageSize {
        width: img.width,
        height: img.height,
    };
    let features = Image::<u8, 1>::new(size, img.data.clone())
        .and_then(|image| detector.detect_and_extract_u8(&image));
    let Ok(features) = features else {
        return (Vec::new(), Vec::new(), 0);
    };
    let (mut kps, mut descs, mut rejected) = (Vec::new(), Vec::new(), 0);
    for i in 0..features.len() {
        let [x, y] = features.keypoints_xy[i];
        if !keep(x, y) {
            rejected += 1;
            continue;
        }
        kps.push(KeyPoint {
            x,
            y,
            level: features.octaves[i],
            angle: features.orientations[i],
            score: 0.0,
        });
        descs.push(descriptor(&features.descriptors[i]));
    }
    (kps, descs, rejected)
}

/// kornia's 32 packed bytes as our four words (Hamming distance unchanged).
fn descriptor(bytes: &[u8; 32]) -> Descriptor {
    let word = |i: usize| u64::from_le_bytes(bytes[8 * i..8 * i + 8].try_into().unwrap());
    [word(0), word(1), word(2), word(3)]
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;
    use crate::features::orb::hamming;

    /// A real TUM frame (../shared), grey.
    fn frame() -> GrayU8 {
        let rgb = image::open(Path::new(env!("CARGO_MANIFEST_DIR")).join(
            "../../../shared/data/tum/rgbd_dataset_freiburg1_rpy_first300/rgb/1305031229.528748.png",
        ))
        .unwrap()
        .to_rgb8();
        GrayU8::from_rgb(rgb.as_raw(), rgb.width() as usize, rgb.height() as usize)
    }

    #[test]
    fn masked_half_keeps_no_keypoint_and_counts_what_it_dropped() {
        let img = frame();
        let params = OrbParams::default();
        let (all, all_descs, none) = extract(&params, &img, &|_, _| true);
        assert_eq!(none, 0);
        assert!(
            all.len() > 500,
            "{} features on a textured frame",
            all.len()
        );
        assert_eq!(all.len(), all_descs.len());
        assert!(all.iter().all(|k| (k.level as usize) < params.levels));
        let (right, _, dropped) = extract(&params, &img, &|x, _| x >= 320.0);
        assert!(right.iter().all(|k| k.x >= 320.0));
        assert_eq!(right.len() + dropped, all.len());
        assert!(dropped > 100);
    }

    #[test]
    fn descriptor_words_keep_the_hamming_distance() {
        let mut a = [0u8; 32];
        let mut b = [0u8; 32];
        a[0] = 0b1011;
        b[31] = 0xff;
        let bits = |x: &[u8; 32], y: &[u8; 32]| -> u32 {
            x.iter().zip(y).map(|(p, q)| (p ^ q).count_ones()).sum()
        };
        assert_eq!(hamming(&descriptor(&a), &descriptor(&b)), bits(&a, &b));
        assert_eq!(bits(&a, &b), 11);
    }
}
