//! The SIMD and the portable pixel kernels give the same ORB features, bit
//! for bit, on real frames: whole, cropped to odd sizes (spans that end
//! mid-block) and masked. Run again with `DYNSLAM_SIMD=off` by `just test`,
//! where the selected kernels must be the portable ones.

use std::path::Path;

use datasets::source::tum_folder;
use slam_core::features::orb::{GrayU8, OrbExtractor, OrbParams};
use slam_core::features::simd::{Kernels, SIMD_ENV};

/// Every 37th frame of the shared sequence, grey.
fn frames() -> Vec<GrayU8> {
    let tum = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/tum/rgbd_dataset_freiburg1_rpy_first300");
    tum_folder(&tum, 0.02)
        .unwrap()
        .iter()
        .step_by(37)
        .map(|f| {
            let rgb = image::open(&f.rgb).unwrap().to_rgb8();
            GrayU8::from_rgb(rgb.as_raw(), rgb.width() as usize, rgb.height() as usize)
        })
        .collect()
}

fn crop(img: &GrayU8, x0: usize, y0: usize, w: usize, h: usize) -> GrayU8 {
    let data = (y0..y0 + h)
        .flat_map(|y| {
            img.data[y * img.width + x0..y * img.width + x0 + w]
                .iter()
                .copied()
        })
        .collect();
    GrayU8 {
        width: w,
        height: h,
        data,
    }
}

#[test]
fn every_kernel_extracts_the_same_features_from_real_frames() {
    let frames = frames();
    assert!(frames.len() >= 8);
    let kernels = Kernels::all();
    if cfg!(target_arch = "x86_64") {
        assert!(kernels.len() == 2, "x86-64 has SSE2 kernels: {kernels:?}");
    }
    let mask = |x: f32, y: f32| !((200.0..380.0).contains(&x) && (100.0..300.0).contains(&y));
    for (i, frame) in frames.iter().enumerate() {
        let images = [
            frame.clone(),
            crop(frame, 3, 5, 333, 251),
            crop(frame, 17, 0, 601, 477),
        ];
        for img in &images {
            for threads in [1, 2] {
                let extractors: Vec<OrbExtractor> = kernels
                    .iter()
                    .map(|&k| {
                        OrbExtractor::new(OrbParams {
                            threads,
                            ..OrbParams::default()
                        })
                        .with_kernels(k)
                    })
                    .collect();
                let keep_all = |_: f32, _: f32| true;
                for keep in [&keep_all as &(dyn Fn(f32, f32) -> bool + Sync), &mask] {
                    let results: Vec<_> = extractors.iter().map(|e| e.extract(img, keep)).collect();
                    let (kps, descs, rejected) = &results[0];
                    assert!(
                        kps.len() > 300,
                        "frame {i} {}x{}: {}",
                        img.width,
                        img.height,
                        kps.len()
                    );
                    for (k, other) in kernels.iter().zip(&results).skip(1) {
                        assert_eq!(
                            &other.0, kps,
                            "{k:?} keypoints, frame {i} {}x{}",
                            img.width, img.height
                        );
                        assert_eq!(&other.1, descs, "{k:?} descriptors, frame {i}");
                        assert_eq!(other.2, *rejected, "{k:?} rejected corners, frame {i}");
                    }
                }
            }
        }
    }
}

#[test]
fn the_environment_variable_selects_the_kernels() {
    let off = matches!(std::env::var(SIMD_ENV).as_deref(), Ok("off"));
    let selected = Kernels::selected();
    if off {
        assert_eq!(selected, Kernels::Portable);
    } else {
        assert_eq!(selected, Kernels::fastest());
    }
    let frame = &frames()[0];
    let default = OrbExtractor::new(OrbParams::default());
    let chosen = OrbExtractor::new(OrbParams::default()).with_kernels(selected);
    let keep = |_: f32, _: f32| true;
    assert_eq!(
        default.extract(frame, &keep).1,
        chosen.extract(frame, &keep).1
    );
}
