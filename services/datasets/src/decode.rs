//! PNG decoding straight into a destination byte slice.
//!
//! The destination is the loaned shared-memory sample, so a frame's pixels are
//! written exactly once, by the decoder, and then read in place by every
//! other process. Every failure names the file and what is wrong with it.

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use image::codecs::png::PngDecoder;
use image::{ColorType, ImageDecoder};

/// Why an image could not be decoded; each names the file.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DecodeError {
    /// The file could not be opened.
    #[error("{path}: cannot open: {message}")]
    Open {
        /// The image file.
        path: PathBuf,
        /// The system's reason.
        message: String,
    },
    /// The PNG is damaged.
    #[error("{path}: corrupt or truncated PNG: {message}")]
    Corrupt {
        /// The image file.
        path: PathBuf,
        /// The decoder's reason.
        message: String,
    },
    /// The image is not the size the run's frames have.
    #[error("{path}: frame is {found_w}x{found_h}, expected {expected_w}x{expected_h}")]
    WrongSize {
        /// The image file.
        path: PathBuf,
        /// The size expected (pixels).
        expected_w: u32,
        /// The size expected (pixels).
        expected_h: u32,
        /// The file's size (pixels).
        found_w: u32,
        /// The file's size (pixels).
        found_h: u32,
    },
    /// The pixel format is not one the role takes (colour: 8-bit RGB, RGBA
    /// or grey; depth: 16-bit grey).
    #[error(
        "{path}: pixel format {found} is not supported for {role} images (expected {expected})"
    )]
    Format {
        /// The image file.
        path: PathBuf,
        /// "colour" or "depth".
        role: &'static str,
        /// The file's pixel format.
        found: String,
        /// The formats the role takes.
        expected: &'static str,
    },
}

fn open(path: &Path) -> Result<PngDecoder<BufReader<File>>, DecodeError> {
    // A folder opens on Linux and then reads as garbage: name it for what it is.
    if path.is_dir() {
        return Err(DecodeError::Open {
            path: path.to_path_buf(),
            message: "is a directory, not an image file".into(),
        });
    }
    let file = File::open(path).map_err(|e| DecodeError::Open {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    PngDecoder::new(BufReader::new(file)).map_err(|e| corrupt(path, e))
}

fn corrupt(path: &Path, e: image::ImageError) -> DecodeError {
    DecodeError::Corrupt {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

fn check_size(
    path: &Path,
    decoder: &impl ImageDecoder,
    expected: (u32, u32),
) -> Result<(), DecodeError> {
    let (w, h) = decoder.dimensions();
    if (w, h) != expected {
        return Err(DecodeError::WrongSize {
            path: path.to_path_buf(),
            expected_w: expected.0,
            expected_h: expected.1,
            found_w: w,
            found_h: h,
        });
    }
    Ok(())
}

/// Width and height from the PNG header (reads only the header).
pub fn png_size(path: &Path) -> Result<(u32, u32), DecodeError> {
    Ok(open(path)?.dimensions())
}

/// Decodes an RGB image of exactly `expected` size into `out`
/// (`w*h*3` bytes, RGB8). 8-bit RGB PNGs are decoded in place; grey and RGBA
/// images are converted (they need one temporary row-major buffer).
pub fn decode_rgb_into(
    path: &Path,
    expected: (u32, u32),
    out: &mut [u8],
) -> Result<(), DecodeError> {
    let decoder = open(path)?;
    check_size(path, &decoder, expected)?;
    debug_assert_eq!(out.len(), expected.0 as usize * expected.1 as usize * 3);
    match decoder.color_type() {
        ColorType::Rgb8 => decoder.read_image(out).map_err(|e| corrupt(path, e)),
        ColorType::Rgba8 | ColorType::L8 | ColorType::La8 => {
            let color = decoder.color_type();
            let mut tmp = vec![0u8; decoder.total_bytes() as usize];
            decoder.read_image(&mut tmp).map_err(|e| corrupt(path, e))?;
            let channels = color.channel_count() as usize;
            for (dst, src) in out.chunks_exact_mut(3).zip(tmp.chunks_exact(channels)) {
                if channels >= 3 {
                    dst.copy_from_slice(&src[..3]);
                } else {
                    dst.fill(src[0]);
                }
            }
            Ok(())
        }
        other => Err(DecodeError::Format {
            path: path.to_path_buf(),
            role: "colour",
            found: format!("{other:?}"),
            expected: "8-bit RGB, RGBA or grey",
        }),
    }
}

/// Decodes a 16-bit depth image of exactly `expected` size into `out`
/// (`w*h*2` bytes, native-endian u16).
pub fn decode_depth_into(
    path: &Path,
    expected: (u32, u32),
    out: &mut [u8],
) -> Result<(), DecodeError> {
    let decoder = open(path)?;
    check_size(path, &decoder, expected)?;
    match decoder.color_type() {
        // The decoder reorders PNG's big-endian samples to native endianness.
        ColorType::L16 => decoder.read_image(out).map_err(|e| corrupt(path, e)),
        other => Err(DecodeError::Format {
            path: path.to_path_buf(),
            role: "depth",
            found: format!("{other:?}"),
            expected: "16-bit grey",
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tum() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../../shared/data/tum/rgbd_dataset_freiburg1_rpy_first300")
    }

    #[test]
    fn rgb_decodes_in_place_like_the_reference_decoder() {
        let path = tum().join("rgb/1305031229.528748.png");
        let mut out = vec![0u8; 640 * 480 * 3];
        decode_rgb_into(&path, (640, 480), &mut out).unwrap();
        let reference = image::open(&path).unwrap().to_rgb8();
        assert_eq!(out, reference.into_raw());
    }

    #[test]
    fn depth_is_native_endian_u16() {
        let path = tum().join("depth/1305031229.528784.png");
        let mut out = vec![0u8; 640 * 480 * 2];
        decode_depth_into(&path, (640, 480), &mut out).unwrap();
        let reference = image::open(&path).unwrap().to_luma16();
        let ours: Vec<u16> = out
            .chunks_exact(2)
            .map(|b| u16::from_ne_bytes([b[0], b[1]]))
            .collect();
        assert_eq!(ours, reference.into_raw());
        // Plausible indoor depths (factor 5000): most valid readings 0.3..6 m.
        let valid: Vec<_> = ours.iter().filter(|&&d| d > 0).collect();
        assert!(valid.len() > 640 * 480 / 2);
        let median = {
            let mut v: Vec<u16> = valid.into_iter().copied().collect();
            v.sort();
            v[v.len() / 2]
        };
        assert!(
            (1500..30000).contains(&median),
            "median depth value {median}"
        );
    }

    #[test]
    fn wrong_size_names_both_sizes() {
        let path = tum().join("rgb/1305031229.528748.png");
        let mut out = vec![0u8; 320 * 240 * 3];
        let err = decode_rgb_into(&path, (320, 240), &mut out).unwrap_err();
        assert!(
            err.to_string()
                .ends_with("frame is 640x480, expected 320x240"),
            "{err}"
        );
    }

    #[test]
    fn corrupt_and_truncated_files_are_errors_not_panics() {
        let dir = std::env::temp_dir().join(format!("dynslam-decode-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let good = std::fs::read(tum().join("rgb/1305031229.528748.png")).unwrap();
        let truncated = dir.join("truncated.png");
        std::fs::write(&truncated, &good[..good.len() / 2]).unwrap();
        let garbage = dir.join("garbage.png");
        std::fs::write(&garbage, b"this is not a png at all").unwrap();
        let mut out = vec![0u8; 640 * 480 * 3];
        for p in [&truncated, &garbage] {
            let err = decode_rgb_into(p, (640, 480), &mut out).unwrap_err();
            assert!(matches!(err, DecodeError::Corrupt { .. }), "{err}");
            assert!(err.to_string().contains(p.to_str().unwrap()));
        }
        let err = decode_rgb_into(&dir.join("missing.png"), (640, 480), &mut out).unwrap_err();
        assert!(matches!(err, DecodeError::Open { .. }));
        // A depth PNG where colour is expected is a format error.
        let depth = tum().join("depth/1305031229.528784.png");
        let err = decode_rgb_into(&depth, (640, 480), &mut out).unwrap_err();
        assert!(matches!(err, DecodeError::Format { .. }), "{err}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
