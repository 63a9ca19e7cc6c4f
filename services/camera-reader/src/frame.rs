//! Filling one frame (header + pixels) from a source entry.

use shared_types::{frame_flags, write_error_text, FrameHeader, PixelFormat};

use datasets::decode::{decode_depth_into, decode_rgb_into, DecodeError};
use datasets::source::FrameEntry;

/// Size and depth scale of the frames of one run.
#[derive(Debug, Clone, Copy)]
pub struct FrameGeometry {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Depth units per metre (TUM: 5000).
    pub depth_scale: f32,
}

impl FrameGeometry {
    /// Bytes of a frame's colour (RGB8).
    pub fn rgb_len(&self) -> usize {
        self.width as usize * self.height as usize * 3
    }
    /// Bytes of a frame's depth (u16 a pixel).
    pub fn depth_len(&self) -> usize {
        self.width as usize * self.height as usize * 2
    }
    /// Bytes of a frame's payload with or without depth.
    pub fn payload_len(&self, with_depth: bool) -> usize {
        self.rgb_len() + if with_depth { self.depth_len() } else { 0 }
    }
}

/// Header of a frame before its pixels are decoded.
pub fn header_for(seq: u64, entry: &FrameEntry, geometry: FrameGeometry) -> FrameHeader {
    FrameHeader {
        seq,
        source_timestamp: entry.timestamp,
        width: geometry.width,
        height: geometry.height,
        pixel_format: PixelFormat::Rgb8 as u32,
        has_depth: entry.depth.is_some() as u32,
        depth_scale: geometry.depth_scale,
        ..Default::default()
    }
}

/// Decodes a frame's colour and depth into `payload` (the loaned sample).
pub fn decode_frame(
    entry: &FrameEntry,
    geometry: FrameGeometry,
    payload: &mut [u8],
) -> Result<(), DecodeError> {
    let size = (geometry.width, geometry.height);
    let (rgb, depth) = payload.split_at_mut(geometry.rgb_len());
    decode_rgb_into(&entry.rgb, size, rgb)?;
    if let Some(depth_path) = &entry.depth {
        decode_depth_into(depth_path, size, &mut depth[..geometry.depth_len()])?;
    }
    Ok(())
}

/// Marks a header as a bad-input frame with the reason; its payload is empty.
pub fn mark_bad(header: &mut FrameHeader, why: &impl std::fmt::Display) {
    header.flags |= frame_flags::BAD_INPUT;
    header.has_depth = 0;
    write_error_text(&mut header.error, &why.to_string());
}
