//! Borrowed, typed views of samples read in place from shared memory.
//! A view never copies pixels; it checks lengths once so that the rest of a
//! service can index without surprises.

use crate::{read_error_text, FrameHeader, MaskSource, MasksHeader};
use anyhow::{bail, Result};
use raster::{ImageView, RgbView};

/// One frame read in place.
#[derive(Clone, Copy)]
pub struct FrameView<'a> {
    /// The frame's header (sequence number, size, stamps).
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

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.header.width as usize
    }
    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.header.height as usize
    }

    /// The frame's colour, read in place.
    pub fn colour(&self) -> RgbView<'a> {
        // `new` checked the length against the header's size.
        RgbView::from_bytes(self.rgb, self.width(), self.height())
            .expect("FrameView::new checked the colour's size")
    }

    /// The frame's depth with its scale, when it has depth.
    pub fn depth_image(&self) -> Option<DepthImage<'a>> {
        let raw = self.depth?;
        DepthImage::new(raw, self.width(), self.height(), self.header.depth_scale)
    }

    /// Depth value at a pixel (raw units; divide by `depth_scale` for metres).
    pub fn depth_at(&self, x: usize, y: usize) -> Option<u16> {
        let d = self.depth?;
        let i = (y * self.width() + x) * 2;
        Some(u16::from_ne_bytes([d[i], d[i + 1]]))
    }
}

/// Depth of a frame: native-endian u16 values, `per_metre` units a metre,
/// read in place (the bytes need no alignment).
#[derive(Debug, Clone, Copy)]
pub struct DepthImage<'a> {
    /// Each pixel's two bytes (0: no measurement).
    pub image: ImageView<'a, [u8; 2]>,
    /// Raw units per metre (TUM: 5000).
    pub per_metre: f32,
}

impl<'a> DepthImage<'a> {
    /// `raw` (two native-endian bytes a pixel) as a `width x height` depth
    /// image; None when it is not exactly that size.
    pub fn new(raw: &'a [u8], width: usize, height: usize, per_metre: f32) -> Option<Self> {
        Some(Self {
            image: ImageView::from_bytes(raw, width, height)?,
            per_metre,
        })
    }

    /// The raw value at a pixel, None where there is no measurement.
    fn raw_at(&self, x: usize, y: usize) -> Option<f64> {
        let raw = u16::from_ne_bytes(self.image.get(x, y)?);
        (raw > 0 && self.per_metre > 0.0).then_some(raw as f64)
    }

    /// Inverse depth (1/m) at a pixel, None where there is no measurement.
    pub fn inverse_at(&self, x: usize, y: usize) -> Option<f64> {
        self.raw_at(x, y).map(|raw| self.per_metre as f64 / raw)
    }

    /// Depth (m) at a pixel, None where there is no measurement.
    pub fn metres_at(&self, x: usize, y: usize) -> Option<f32> {
        self.raw_at(x, y)
            .map(|raw| (raw / self.per_metre as f64) as f32)
    }
}

/// One set of masks read in place.
#[derive(Clone, Copy)]
pub struct MasksView<'a> {
    /// The masks' header (frame, size, instances, source).
    pub header: &'a MasksHeader,
    /// Label image, `width*height` bytes: 0 background, `i+1` instance `i`.
    pub labels: &'a [u8],
}

impl<'a> MasksView<'a> {
    /// Checks that the payload holds the label image the header announces.
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

    /// Which worker made them.
    pub fn source(&self) -> MaskSource {
        MaskSource::from_u32(self.header.source).unwrap_or(MaskSource::None)
    }
}

/// One point of a map snapshot ([`crate::MapHeader`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapPointEntry {
    /// World position (the SLAM's world frame, metres).
    pub position: [f32; 3],
    /// RGB of the point as a keyframe saw it (black when unknown).
    pub colour: [u8; 3],
    /// Index (in the snapshot) of the keyframe that observed it first.
    pub keyframe: u32,
}

impl MapPointEntry {
    fn write(&self, out: &mut [u8]) {
        for (i, v) in self.position.iter().enumerate() {
            out[i * 4..i * 4 + 4].copy_from_slice(&v.to_ne_bytes());
        }
        out[12..15].copy_from_slice(&self.colour);
        out[15] = 0;
        out[16..20].copy_from_slice(&self.keyframe.to_ne_bytes());
    }

    fn read(b: &[u8]) -> Self {
        let f = |i: usize| f32::from_ne_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
        Self {
            position: [f(0), f(4), f(8)],
            colour: [b[12], b[13], b[14]],
            keyframe: u32::from_ne_bytes([b[16], b[17], b[18], b[19]]),
        }
    }
}

/// Writes a snapshot's keyframes (world-from-camera tx ty tz qx qy qz qw)
/// and points into `payload`, which holds exactly
/// [`crate::MapHeader::payload_len`] bytes for them.
pub fn write_map(payload: &mut [u8], keyframes: &[[f64; 7]], points: &[MapPointEntry]) {
    use crate::{MAP_KEYFRAME_BYTES, MAP_POINT_BYTES};
    let (kf_bytes, point_bytes) = payload.split_at_mut(keyframes.len() * MAP_KEYFRAME_BYTES);
    for (k, out) in keyframes
        .iter()
        .zip(kf_bytes.chunks_exact_mut(MAP_KEYFRAME_BYTES))
    {
        for (i, v) in k.iter().enumerate() {
            out[i * 8..i * 8 + 8].copy_from_slice(&v.to_ne_bytes());
        }
    }
    for (p, out) in points
        .iter()
        .zip(point_bytes.chunks_exact_mut(MAP_POINT_BYTES))
    {
        p.write(out);
    }
}

/// A map snapshot read in place.
#[derive(Clone, Copy)]
pub struct MapView<'a> {
    /// The snapshot's header (counts, stamp).
    pub header: &'a crate::MapHeader,
    keyframes: &'a [u8],
    points: &'a [u8],
}

impl<'a> MapView<'a> {
    /// Checks that the payload holds what the header announces and that
    /// every point names a keyframe of the snapshot.
    pub fn new(header: &'a crate::MapHeader, payload: &'a [u8]) -> Result<Self> {
        let need = header.payload_len();
        if payload.len() < need {
            bail!(
                "map snapshot {}: payload has {} bytes, header announces {} keyframes and {} points = {need} bytes",
                header.version,
                payload.len(),
                header.keyframes,
                header.points
            );
        }
        let split = header.keyframes as usize * crate::MAP_KEYFRAME_BYTES;
        let view = Self {
            header,
            keyframes: &payload[..split],
            points: &payload[split..need],
        };
        if let Some(p) = view.points().find(|p| p.keyframe >= header.keyframes) {
            bail!(
                "map snapshot {}: a point names keyframe {} of {}",
                header.version,
                p.keyframe,
                header.keyframes
            );
        }
        Ok(view)
    }

    /// World-from-camera poses: tx ty tz qx qy qz qw.
    pub fn keyframes(&self) -> impl Iterator<Item = [f64; 7]> + 'a {
        self.keyframes
            .chunks_exact(crate::MAP_KEYFRAME_BYTES)
            .map(|b| {
                let mut k = [0.0; 7];
                for (i, v) in k.iter_mut().enumerate() {
                    *v = f64::from_ne_bytes(b[i * 8..i * 8 + 8].try_into().unwrap_or_default());
                }
                k
            })
    }

    /// The snapshot's points.
    pub fn points(&self) -> impl Iterator<Item = MapPointEntry> + 'a {
        self.points
            .chunks_exact(crate::MAP_POINT_BYTES)
            .map(MapPointEntry::read)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::MapHeader;

    #[test]
    fn a_map_snapshot_round_trips_and_a_bad_one_is_refused() {
        let keyframes = [[1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0], [4.0; 7]];
        let points = [
            MapPointEntry {
                position: [0.5, -1.0, 2.0],
                colour: [1, 2, 3],
                keyframe: 1,
            },
            MapPointEntry {
                position: [9.0, 8.0, 7.0],
                colour: [4, 5, 6],
                keyframe: 0,
            },
        ];
        let mut header = MapHeader {
            version: 3,
            keyframes: 2,
            points: 2,
            ..Default::default()
        };
        let mut payload = vec![0u8; header.payload_len()];
        write_map(&mut payload, &keyframes, &points);
        let view = MapView::new(&header, &payload).unwrap();
        assert_eq!(view.keyframes().collect::<Vec<_>>(), keyframes);
        assert_eq!(view.points().collect::<Vec<_>>(), points);
        assert!(MapView::new(&header, &payload[..payload.len() - 1])
            .err()
            .unwrap()
            .to_string()
            .contains("2 points"));
        header.keyframes = 1; // the first point names keyframe 1
        let short = &payload[56..];
        assert!(MapView::new(&header, short).is_err());
    }
}
