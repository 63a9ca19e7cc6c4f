//! A camera's pixel formats into the frame layout (RGB8, then `u16` depth),
//! written straight into the loaned shared-memory sample.
//!
//! - YUYV (YUY2, V4L2 `YUYV`): 4:2:2, two pixels in 4 bytes `Y0 U Y1 V`,
//!   BT.601 limited range as UVC cameras send it.
//! - MJPEG (V4L2 `MJPG`): one JPEG per frame. UVC cameras leave out the
//!   Huffman tables (their spec says the decoder has the standard ones);
//!   the decoder is given those when a frame has none.
//! - Z16 (V4L2 `Z16 `): little-endian 16-bit depth.

use std::io::Cursor;

use image::ImageDecoder;

/// Why a camera buffer could not become a frame.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ConvertError {
    /// The buffer holds fewer bytes than the negotiated frame needs.
    #[error("{format} buffer of {got} bytes, {width}x{height} needs {need} (stride {stride})")]
    Short {
        /// The pixel format (fourcc).
        format: &'static str,
        /// Bytes in the buffer.
        got: usize,
        /// Bytes the frame needs.
        need: usize,
        /// The negotiated size (pixels).
        width: u32,
        /// The negotiated size (pixels).
        height: u32,
        /// Bytes per row as the driver lays them out.
        stride: usize,
    },
    /// 4:2:2 needs an even width.
    #[error("{width}x{height}: an odd width for 4:2:2, or a frame buffer too small for it")]
    Odd {
        /// The negotiated size (pixels).
        width: u32,
        /// The negotiated size (pixels).
        height: u32,
    },
    /// The MJPEG frame is not a decodable JPEG (the decoder's reason).
    #[error("MJPEG frame does not decode: {0}")]
    Jpeg(String),
    /// The MJPEG frame's size is not the stream's.
    #[error("MJPEG frame is {got_w}x{got_h}, the stream was negotiated at {width}x{height}")]
    JpegSize {
        /// The JPEG's size (pixels).
        got_w: u32,
        /// The JPEG's size (pixels).
        got_h: u32,
        /// The negotiated size (pixels).
        width: u32,
        /// The negotiated size (pixels).
        height: u32,
    },
}

/// A 2-bytes-per-pixel buffer's row length and stride (`bytesperline`,
/// at least a row), checked to hold `height` rows.
fn packed_rows(
    format: &'static str,
    src: &[u8],
    width: u32,
    height: u32,
    stride: usize,
) -> Result<(usize, usize), ConvertError> {
    let row = width as usize * 2;
    let stride = stride.max(row);
    let need = stride * (height as usize).saturating_sub(1) + row;
    if src.len() < need {
        return Err(ConvertError::Short {
            format,
            got: src.len(),
            need,
            width,
            height,
            stride,
        });
    }
    Ok((row, stride))
}

fn clamp_u8(v: i32) -> u8 {
    v.clamp(0, 255) as u8
}

/// One BT.601 limited-range YUV sample as RGB (fixed point, 1/256 steps).
fn yuv_to_rgb(y: u8, u: u8, v: u8) -> [u8; 3] {
    let c = 298 * (y as i32 - 16);
    let d = u as i32 - 128;
    let e = v as i32 - 128;
    [
        clamp_u8((c + 409 * e + 128) >> 8),
        clamp_u8((c - 100 * d - 208 * e + 128) >> 8),
        clamp_u8((c + 516 * d + 128) >> 8),
    ]
}

/// YUYV with `stride` bytes per row (`bytesperline`, >= width*2) into RGB8.
pub fn yuyv_to_rgb(
    src: &[u8],
    width: u32,
    height: u32,
    stride: usize,
    dst: &mut [u8],
) -> Result<(), ConvertError> {
    let (w, h) = (width as usize, height as usize);
    let (row, stride) = packed_rows("YUYV", src, width, height, stride)?;
    if w % 2 != 0 || dst.len() < w * h * 3 {
        return Err(ConvertError::Odd { width, height });
    }
    for (y, out) in dst.chunks_exact_mut(w * 3).take(h).enumerate() {
        let line = &src[y * stride..y * stride + row];
        for (quad, px) in line.chunks_exact(4).zip(out.chunks_exact_mut(6)) {
            let (y0, u, y1, v) = (quad[0], quad[1], quad[2], quad[3]);
            px[..3].copy_from_slice(&yuv_to_rgb(y0, u, v));
            px[3..].copy_from_slice(&yuv_to_rgb(y1, u, v));
        }
    }
    Ok(())
}

/// The JPEG standard's Huffman tables (ITU T.81 K.3) as one DHT segment:
/// what a UVC MJPEG frame without tables was encoded with.
const STANDARD_DHT: &[u8] = &[
    0xFF, 0xC4, 0x01, 0xA2, // DHT, length 418
    // DC luminance
    0x00, 0x00, 0x01, 0x05, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x09, 0x0A, 0x0B,
    // DC chrominance
    0x01, 0x00, 0x03, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x01, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x09, 0x0A, 0x0B,
    // AC luminance
    0x10, 0x00, 0x02, 0x01, 0x03, 0x03, 0x02, 0x04, 0x03, 0x05, 0x05, 0x04, 0x04, 0x00, 0x00, 0x01,
    0x7D, 0x01, 0x02, 0x03, 0x00, 0x04, 0x11, 0x05, 0x12, 0x21, 0x31, 0x41, 0x06, 0x13, 0x51, 0x61,
    0x07, 0x22, 0x71, 0x14, 0x32, 0x81, 0x91, 0xA1, 0x08, 0x23, 0x42, 0xB1, 0xC1, 0x15, 0x52, 0xD1,
    0xF0, 0x24, 0x33, 0x62, 0x72, 0x82, 0x09, 0x0A, 0x16, 0x17, 0x18, 0x19, 0x1A, 0x25, 0x26, 0x27,
    0x28, 0x29, 0x2A, 0x34, 0x35, 0x36, 0x37, 0x38, 0x39, 0x3A, 0x43, 0x44, 0x45, 0x46, 0x47, 0x48,
    0x49, 0x4A, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5A, 0x63, 0x64, 0x65, 0x66, 0x67, 0x68,
    0x69, 0x6A, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7A, 0x83, 0x84, 0x85, 0x86, 0x87, 0x88,
    0x89, 0x8A, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97, 0x98, 0x99, 0x9A, 0xA2, 0xA3, 0xA4, 0xA5, 0xA6,
    0xA7, 0xA8, 0xA9, 0xAA, 0xB2, 0xB3, 0xB4, 0xB5, 0xB6, 0xB7, 0xB8, 0xB9, 0xBA, 0xC2, 0xC3, 0xC4,
    0xC5, 0xC6, 0xC7, 0xC8, 0xC9, 0xCA, 0xD2, 0xD3, 0xD4, 0xD5, 0xD6, 0xD7, 0xD8, 0xD9, 0xDA, 0xE1,
    0xE2, 0xE3, 0xE4, 0xE5, 0xE6, 0xE7, 0xE8, 0xE9, 0xEA, 0xF1, 0xF2, 0xF3, 0xF4, 0xF5, 0xF6, 0xF7,
    0xF8, 0xF9, 0xFA, // AC chrominance
    0x11, 0x00, 0x02, 0x01, 0x02, 0x04, 0x04, 0x03, 0x04, 0x07, 0x05, 0x04, 0x04, 0x00, 0x01, 0x02,
    0x77, 0x00, 0x01, 0x02, 0x03, 0x11, 0x04, 0x05, 0x21, 0x31, 0x06, 0x12, 0x41, 0x51, 0x07, 0x61,
    0x71, 0x13, 0x22, 0x32, 0x81, 0x08, 0x14, 0x42, 0x91, 0xA1, 0xB1, 0xC1, 0x09, 0x23, 0x33, 0x52,
    0xF0, 0x15, 0x62, 0x72, 0xD1, 0x0A, 0x16, 0x24, 0x34, 0xE1, 0x25, 0xF1, 0x17, 0x18, 0x19, 0x1A,
    0x26, 0x27, 0x28, 0x29, 0x2A, 0x35, 0x36, 0x37, 0x38, 0x39, 0x3A, 0x43, 0x44, 0x45, 0x46, 0x47,
    0x48, 0x49, 0x4A, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5A, 0x63, 0x64, 0x65, 0x66, 0x67,
    0x68, 0x69, 0x6A, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7A, 0x82, 0x83, 0x84, 0x85, 0x86,
    0x87, 0x88, 0x89, 0x8A, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97, 0x98, 0x99, 0x9A, 0xA2, 0xA3, 0xA4,
    0xA5, 0xA6, 0xA7, 0xA8, 0xA9, 0xAA, 0xB2, 0xB3, 0xB4, 0xB5, 0xB6, 0xB7, 0xB8, 0xB9, 0xBA, 0xC2,
    0xC3, 0xC4, 0xC5, 0xC6, 0xC7, 0xC8, 0xC9, 0xCA, 0xD2, 0xD3, 0xD4, 0xD5, 0xD6, 0xD7, 0xD8, 0xD9,
    0xDA, 0xE2, 0xE3, 0xE4, 0xE5, 0xE6, 0xE7, 0xE8, 0xE9, 0xEA, 0xF2, 0xF3, 0xF4, 0xF5, 0xF6, 0xF7,
    0xF8, 0xF9, 0xFA,
];

/// Where the start-of-scan marker is, and whether a DHT segment comes
/// before it (walking the marker segments; entropy data is never entered).
fn scan_start(jpeg: &[u8]) -> Option<(usize, bool)> {
    let mut i = 2; // after SOI
    let mut has_dht = false;
    while i + 4 <= jpeg.len() {
        if jpeg[i] != 0xFF {
            return None;
        }
        let marker = jpeg[i + 1];
        if marker == 0xFF {
            i += 1; // fill byte
            continue;
        }
        if marker == 0xDA {
            return Some((i, has_dht));
        }
        has_dht |= marker == 0xC4;
        let len = u16::from_be_bytes([jpeg[i + 2], jpeg[i + 3]]) as usize;
        i += 2 + len;
    }
    None
}

/// One MJPEG frame into RGB8 (`dst`, width*height*3). `scratch` keeps the
/// frame with the standard Huffman tables put in, when it has none.
pub fn mjpeg_to_rgb(
    src: &[u8],
    width: u32,
    height: u32,
    scratch: &mut Vec<u8>,
    dst: &mut [u8],
) -> Result<(), ConvertError> {
    if src.len() < 4 || src[0] != 0xFF || src[1] != 0xD8 {
        return Err(ConvertError::Jpeg(format!(
            "{} bytes without a JPEG start marker",
            src.len()
        )));
    }
    // A frame cut short on the bus still "decodes" (the rest grey): its
    // missing end-of-image marker gives it away (some cameras pad with 0s).
    let end = src.len() - src.iter().rev().take_while(|&&b| b == 0).count();
    if end < 2 || src[end - 2..end] != [0xFF, 0xD9] {
        return Err(ConvertError::Jpeg(format!(
            "{} bytes, truncated (no end-of-image marker)",
            src.len()
        )));
    }
    let jpeg = match scan_start(src) {
        Some((sos, false)) => {
            scratch.clear();
            scratch.extend_from_slice(&src[..sos]);
            scratch.extend_from_slice(STANDARD_DHT);
            scratch.extend_from_slice(&src[sos..]);
            scratch.as_slice()
        }
        _ => src,
    };
    let decoder = image::codecs::jpeg::JpegDecoder::new(Cursor::new(jpeg))
        .map_err(|e| ConvertError::Jpeg(e.to_string()))?;
    let (got_w, got_h) = decoder.dimensions();
    if (got_w, got_h) != (width, height) {
        return Err(ConvertError::JpegSize {
            got_w,
            got_h,
            width,
            height,
        });
    }
    let need = width as usize * height as usize * 3;
    match decoder.color_type() {
        image::ColorType::Rgb8 => decoder
            .read_image(&mut dst[..need])
            .map_err(|e| ConvertError::Jpeg(e.to_string())),
        image::ColorType::L8 => {
            // A grey camera: each value into all three channels.
            let mut grey = vec![0u8; need / 3];
            decoder
                .read_image(&mut grey)
                .map_err(|e| ConvertError::Jpeg(e.to_string()))?;
            for (px, g) in dst.chunks_exact_mut(3).zip(grey) {
                px.fill(g);
            }
            Ok(())
        }
        other => Err(ConvertError::Jpeg(format!("colour type {other:?}"))),
    }
}

/// Z16 (little-endian u16 depth, `stride` bytes per row) into the frame's
/// native-endian depth bytes.
pub fn z16_to_depth(
    src: &[u8],
    width: u32,
    height: u32,
    stride: usize,
    dst: &mut [u8],
) -> Result<(), ConvertError> {
    let (w, h) = (width as usize, height as usize);
    let (row, stride) = packed_rows("Z16", src, width, height, stride)?;
    if dst.len() < w * h * 2 {
        return Err(ConvertError::Odd { width, height });
    }
    for (y, out) in dst.chunks_exact_mut(row).take(h).enumerate() {
        let line = &src[y * stride..y * stride + row];
        for (d, s) in out.chunks_exact_mut(2).zip(line.chunks_exact(2)) {
            d.copy_from_slice(&u16::from_le_bytes([s[0], s[1]]).to_ne_bytes());
        }
    }
    Ok(())
}

/// The depth frames of a depth node waiting for their colour frame: each
/// colour frame takes the one nearest in arrival time within `max_diff`
/// seconds (a depth frame is used once; older ones are let go).
#[derive(Debug)]
pub struct DepthPairer {
    max_diff_ns: u64,
    /// (arrival ns, native-endian depth bytes), oldest first.
    waiting: std::collections::VecDeque<(u64, Vec<u8>)>,
}

/// Depth frames kept while no colour frame takes them.
const DEPTH_KEPT: usize = 4;

impl DepthPairer {
    /// Pairs frames that arrived at most `max_diff_s` seconds apart.
    pub fn new(max_diff_s: f64) -> Self {
        Self {
            max_diff_ns: (max_diff_s * 1e9) as u64,
            waiting: Default::default(),
        }
    }

    /// How far apart a pair may have arrived.
    pub fn max_diff_ns(&self) -> u64 {
        self.max_diff_ns
    }

    /// Keeps a depth frame that arrived at `arrival_ns` (the oldest goes
    /// when `DEPTH_KEPT` wait).
    pub fn push(&mut self, arrival_ns: u64, depth: Vec<u8>) {
        if self.waiting.len() == DEPTH_KEPT {
            self.waiting.pop_front();
        }
        self.waiting.push_back((arrival_ns, depth));
    }

    /// The depth frame for a colour frame that arrived at `colour_ns`.
    pub fn take(&mut self, colour_ns: u64) -> Option<Vec<u8>> {
        let (i, gap) = self
            .waiting
            .iter()
            .enumerate()
            .map(|(i, (t, _))| (i, t.abs_diff(colour_ns)))
            .min_by_key(|&(_, gap)| gap)?;
        if gap > self.max_diff_ns {
            return None;
        }
        // Frames older than the one taken will never be nearer to a later
        // colour frame.
        self.waiting.drain(..i);
        self.waiting.pop_front().map(|(_, d)| d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    /// The inverse of `yuv_to_rgb` (BT.601 limited range), for building
    /// YUYV buffers from real frames.
    fn rgb_to_yuv(p: &[u8]) -> (f64, f64, f64) {
        let (r, g, b) = (p[0] as f64, p[1] as f64, p[2] as f64);
        let y = 16.0 + (65.481 * r + 128.553 * g + 24.966 * b) / 255.0;
        let u = 128.0 + (-37.797 * r - 74.203 * g + 112.0 * b) / 255.0;
        let v = 128.0 + (112.0 * r - 93.786 * g - 18.214 * b) / 255.0;
        (y, u, v)
    }

    fn shared_frame() -> image::RgbImage {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(
            "../../../shared/data/tum/rgbd_dataset_freiburg1_rpy_first300/rgb/1305031229.729064.png",
        );
        image::open(&path)
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
            .to_rgb8()
    }

    #[test]
    fn yuyv_colour_bars_come_out_as_the_standard_says() {
        // The eight 75 % colour bars of a camera's or vivid's test pattern
        // as BT.601 Y'CbCr (limited range) and the RGB they stand for.
        let bars: [([u8; 3], [u8; 3]); 8] = [
            ([180, 128, 128], [191, 191, 191]), // white
            ([162, 44, 142], [191, 191, 0]),    // yellow
            ([131, 156, 44], [0, 191, 191]),    // cyan
            ([112, 72, 58], [0, 191, 0]),       // green
            ([84, 184, 198], [191, 0, 191]),    // magenta
            ([65, 100, 212], [191, 0, 0]),      // red
            ([35, 212, 114], [0, 0, 191]),      // blue
            ([16, 128, 128], [0, 0, 0]),        // black
        ];
        let (w, h, stride) = (640u32, 4u32, 640 * 2 + 64); // padded rows
        let mut src = vec![0u8; stride * h as usize];
        for y in 0..h as usize {
            for x in (0..w as usize).step_by(2) {
                let ([yy, u, v], _) = bars[x * 8 / w as usize];
                src[y * stride + x * 2..][..4].copy_from_slice(&[yy, u, yy, v]);
            }
        }
        let mut rgb = vec![0u8; (w * h * 3) as usize];
        yuyv_to_rgb(&src, w, h, stride, &mut rgb).unwrap();
        for (i, (_, want)) in bars.iter().enumerate() {
            let x = i * 80 + 40;
            for y in 0..h as usize {
                let got = &rgb[(y * w as usize + x) * 3..][..3];
                for c in 0..3 {
                    assert!(
                        (got[c] as i32 - want[c] as i32).abs() <= 2,
                        "bar {i} at ({x}, {y}): {got:?} vs {want:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_real_frame_survives_yuyv_as_a_camera_would_send_it() {
        let frame = shared_frame();
        let (w, h) = frame.dimensions();
        // 4:2:2 as the camera makes it: Y per pixel, U and V per pair.
        let mut src = vec![0u8; (w * h * 2) as usize];
        for (px, out) in frame.as_raw().chunks_exact(6).zip(src.chunks_exact_mut(4)) {
            let (y0, u0, v0) = rgb_to_yuv(&px[..3]);
            let (y1, u1, v1) = rgb_to_yuv(&px[3..]);
            out.copy_from_slice(&[
                y0.round() as u8,
                ((u0 + u1) / 2.0).round() as u8,
                y1.round() as u8,
                ((v0 + v1) / 2.0).round() as u8,
            ]);
        }
        let mut rgb = vec![0u8; (w * h * 3) as usize];
        yuyv_to_rgb(&src, w, h, (w * 2) as usize, &mut rgb).unwrap();
        // Luma is kept per pixel: the grey images SLAM extracts from agree.
        let grey = |p: &[u8]| 0.299 * p[0] as f64 + 0.587 * p[1] as f64 + 0.114 * p[2] as f64;
        let (mut worst, mut sum) = (0.0f64, 0.0f64);
        for (a, b) in frame.as_raw().chunks_exact(3).zip(rgb.chunks_exact(3)) {
            let d = (grey(a) - grey(b)).abs();
            worst = worst.max(d);
            sum += d;
        }
        let mean = sum / (w * h) as f64;
        // Rounding to 8 bits twice, chroma shared by pixel pairs.
        assert!(
            worst <= 5.0 && mean <= 0.75,
            "grey differs by {mean:.2} on average, up to {worst:.2}"
        );
        // Truncated buffers are errors naming the sizes.
        let e = yuyv_to_rgb(&src[..1000], w, h, (w * 2) as usize, &mut rgb).unwrap_err();
        assert!(e.to_string().contains("YUYV buffer of 1000 bytes"), "{e}");
    }

    /// A UVC camera's MJPEG frame: a JPEG without its Huffman tables.
    fn without_dht(jpeg: &[u8]) -> Vec<u8> {
        let mut out = jpeg[..2].to_vec();
        let mut i = 2;
        while jpeg[i + 1] != 0xDA {
            let len = u16::from_be_bytes([jpeg[i + 2], jpeg[i + 3]]) as usize;
            if jpeg[i + 1] != 0xC4 {
                out.extend_from_slice(&jpeg[i..i + 2 + len]);
            }
            i += 2 + len;
        }
        out.extend_from_slice(&jpeg[i..]);
        out
    }

    #[test]
    fn mjpeg_frames_decode_with_and_without_their_huffman_tables() {
        let frame = shared_frame();
        let (w, h) = frame.dimensions();
        let mut jpeg = Vec::new();
        // The encoder writes the standard tables, as a UVC camera's encoder uses.
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90)
            .encode_image(&frame)
            .unwrap();
        let bare = without_dht(&jpeg);
        assert!(bare.len() < jpeg.len() && scan_start(&bare).is_some_and(|(_, dht)| !dht));
        let mut scratch = Vec::new();
        for (name, data) in [("with tables", &jpeg), ("without tables", &bare)] {
            let mut rgb = vec![0u8; (w * h * 3) as usize];
            mjpeg_to_rgb(data, w, h, &mut scratch, &mut rgb).unwrap();
            let mse: f64 = frame
                .as_raw()
                .iter()
                .zip(&rgb)
                .map(|(&a, &b)| (a as f64 - b as f64).powi(2))
                .sum::<f64>()
                / rgb.len() as f64;
            let psnr = 10.0 * (255.0f64.powi(2) / mse).log10();
            assert!(psnr > 30.0, "{name}: PSNR {psnr:.1} dB");
        }
        let mut rgb = vec![0u8; (w * h * 3) as usize];
        let e = mjpeg_to_rgb(&jpeg, 320, 240, &mut scratch, &mut rgb).unwrap_err();
        assert!(
            e.to_string().contains("640x480") && e.to_string().contains("320x240"),
            "{e}"
        );
        let e = mjpeg_to_rgb(&jpeg[..jpeg.len() / 3], w, h, &mut scratch, &mut rgb).unwrap_err();
        assert!(e.to_string().contains("truncated"), "{e}");
        let mut padded = jpeg.clone();
        padded.extend_from_slice(&[0; 64]);
        mjpeg_to_rgb(&padded, w, h, &mut scratch, &mut rgb).unwrap();
        let e = mjpeg_to_rgb(&[0u8; 100], w, h, &mut scratch, &mut rgb).unwrap_err();
        assert!(e.to_string().contains("start marker"), "{e}");
    }

    #[test]
    fn z16_depth_is_read_little_endian_with_its_stride() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(
            "../../../shared/data/tum/rgbd_dataset_freiburg1_rpy_first300/depth/1305031229.729077.png",
        );
        let depth = image::open(&path).unwrap().to_luma16();
        let (w, h) = depth.dimensions();
        let stride = w as usize * 2 + 32;
        let mut src = vec![0xEEu8; stride * h as usize];
        for (y, row) in depth.as_raw().chunks_exact(w as usize).enumerate() {
            for (x, d) in row.iter().enumerate() {
                src[y * stride + x * 2..][..2].copy_from_slice(&d.to_le_bytes());
            }
        }
        let mut out = vec![0u8; (w * h * 2) as usize];
        z16_to_depth(&src, w, h, stride, &mut out).unwrap();
        let back: Vec<u16> = out
            .chunks_exact(2)
            .map(|b| u16::from_ne_bytes([b[0], b[1]]))
            .collect();
        assert_eq!(back, *depth.as_raw());
        assert!(z16_to_depth(&src[..10], w, h, stride, &mut out).is_err());
    }

    #[test]
    fn depth_goes_to_the_colour_frame_nearest_in_time() {
        let ms = 1_000_000u64;
        let mut p = DepthPairer::new(0.02);
        assert_eq!(p.take(100 * ms), None);
        p.push(90 * ms, vec![1]);
        p.push(99 * ms, vec![2]);
        p.push(140 * ms, vec![3]);
        assert_eq!(p.take(100 * ms), Some(vec![2]), "the nearest, once");
        assert_eq!(p.take(101 * ms), None, "90 was let go, 140 is 39 ms off");
        assert_eq!(p.take(130 * ms), Some(vec![3]));
        for i in 0..10 {
            p.push(i * ms, vec![i as u8]);
        }
        assert_eq!(p.waiting.len(), DEPTH_KEPT);
    }
}
