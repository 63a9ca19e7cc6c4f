//! Borrowed, typed views of samples read in place from shared memory.
//! A view never copies pixels; it checks lengths once so that the rest of a
//! service can index without surprises.

use anyhow::{bail, Result};
use shared_types::{read_error_text, FrameHeader, MaskSource, MasksHeader};

/// One frame read in place.
#[derive(Clone, Copy)]
pub struct FrameView<'a> {
    pub header: &'a FrameHeader,
    /// RGB8, row-major, `width*height*3` bytes.
    pub rgb: &'a [u8],
    /// Native-endian u16 depth bytes, `width*height*2`, when present.
    pub depth: Option<&'a [u8]>,
}

impl<'a> FrameView<'a> {
    /// Checks that the payload holds what the header announces.
    pub fn new(header: &'a FrameHeader, payload: &'a [u8]) -> Result<Self> {
        if !header.carries_pixels() {
            bail!(
                "frame {} carries no pixels (flags {:#x}): {}",
                header.seq,
                header.flags,
                read_error_text(&header.error)
            );
        }
        let (rgb_len, depth_len) = (header.rgb_len(), header.depth_len());
        if payload.len() < rgb_len + depth_len || rgb_len == 0 {
            bail!(
                "frame {}: payload has {} bytes, header announces {}x{} (+depth {}) = {} bytes",
                header.seq,
                payload.len(),
                header.width,
                header.height,
                header.has_depth != 0,
                rgb_len + depth_len
            );
        }
        Ok(Self {
            header,
            rgb: &payload[..rgb_len],
            depth: (depth_len > 0).then(|| &payload[rgb_len..rgb_len + depth_len]),
        })
    }

    pub fn width(&self) -> usize {
        self.header.width as usize
    }
    pub fn height(&self) -> usize {
        self.header.height as usize
    }

    /// The frame's depth with its scale, when it has depth.
    pub fn depth_image(&self) -> Option<DepthImage<'a>> {
        self.depth.map(|raw| DepthImage {
            raw,
            per_metre: self.header.depth_scale,
        })
    }

    /// Depth value at a pixel (raw units; divide by `depth_scale` for metres).
    pub fn depth_at(&self, x: usize, y: usize) -> Option<u16> {
        let d = self.depth?;
        let i = (y * self.width() + x) * 2;
        Some(u16::from_ne_bytes([d[i], d[i + 1]]))
    }
}

/// Depth of a frame: native-endian u16 values, `per_metre` units a metre.
#[derive(Debug, Clone, Copy)]
pub struct DepthImage<'a> {
    pub raw: &'a [u8],
    pub per_metre: f32,
}

impl DepthImage<'_> {
    /// The raw value at a pixel, None where there is no measurement.
    fn raw_at(&self, x: usize, y: usize, width: usize) -> Option<f64> {
        let i = (y * width + x) * 2;
        let raw = u16::from_ne_bytes([*self.raw.get(i)?, *self.raw.get(i + 1)?]);
        (raw > 0 && self.per_metre > 0.0).then_some(raw as f64)
    }

    /// Inverse depth (1/m) at a pixel, None where there is no measurement.
    pub fn inverse_at(&self, x: usize, y: usize, width: usize) -> Option<f64> {
        self.raw_at(x, y, width)
            .map(|raw| self.per_metre as f64 / raw)
    }

    /// Depth (m) at a pixel, None where there is no measurement.
    pub fn metres_at(&self, x: usize, y: usize, width: usize) -> Option<f32> {
        self.raw_at(x, y, width)
            .map(|raw| (raw / self.per_metre as f64) as f32)
    }
}

/// One set of masks read in place.
#[derive(Clone, Copy)]
pub struct MasksView<'a> {
    pub header: &'a MasksHeader,
    /// Label image, `width*height` bytes: 0 background, `i+1` instance `i`.
    pub labels: &'a [u8],
}

impl<'a> MasksView<'a> {
    pub fn new(header: &'a MasksHeader, payload: &'a [u8]) -> Result<Self> {
        let len = header.width as usize * header.height as usize;
        if payload.len() < len {
            bail!(
                "masks {}: payload has {} bytes, header announces {}x{}",
                header.seq,
                payload.len(),
                header.width,
                header.height
            );
        }
        Ok(Self {
            header,
            labels: &payload[..len],
        })
    }

    pub fn source(&self) -> MaskSource {
        MaskSource::from_u32(self.header.source).unwrap_or(MaskSource::None)
    }
}
