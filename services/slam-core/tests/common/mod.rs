//! The shared TUM sequence for the SLAM core's tests.

use std::path::{Path, PathBuf};

use datasets::source::tum_folder;

pub type Depth = image::ImageBuffer<image::Luma<u16>, Vec<u16>>;

pub fn tum() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/tum/rgbd_dataset_freiburg1_rpy_first300")
}

/// The first `n` frames: timestamp, rgb, depth.
pub fn load(n: usize) -> Vec<(f64, image::RgbImage, Depth)> {
    tum_folder(&tum(), 0.02)
        .unwrap()
        .iter()
        .take(n)
        .map(|f| {
            (
                f.timestamp,
                image::open(&f.rgb).unwrap().to_rgb8(),
                image::open(f.depth.as_ref().unwrap())
                    .unwrap()
                    .into_luma16(),
            )
        })
        .collect()
}
