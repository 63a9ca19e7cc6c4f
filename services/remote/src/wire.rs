//! What crosses the network: a routed frame (colour as JPEG, PNG or raw,
//! depth as 16-bit PNG or raw, the masks before it) and the masks made for
//! it (labels as PNG), each one postcard message. Decoding trusts nothing: a message of
//! the wrong run, a truncated or hostile one (sizes that do not agree,
//! images larger than announced, more instances than a frame holds) is an
//! error naming what is wrong, never a panic or an unbounded allocation.

use std::io::Cursor;

use anyhow::{bail, ensure, Context, Result};
use image::{DynamicImage, ExtendedColorType, ImageEncoder, ImageFormat, ImageReader, Limits};
use pipeline::views::{FrameView, MasksView};
use serde::{Deserialize, Serialize};
use shared_types::{FrameHeader, Instance, MaskSource, MasksHeader, PixelFormat, MAX_INSTANCES};

/// The message layout's version (both ends must agree).
pub const VERSION: u16 = 1;

/// The largest frame side accepted from the network (pixels).
pub const MAX_SIDE: u32 = 4096;

/// How a frame's images travel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ImageEncoding {
    /// The pixels as they are (depth little-endian): no CPU on either end,
    /// 1.5 MB a 640x480 frame with depth (a wired link).
    Raw,
    /// Lossless: the worker segments the very pixels the robot has.
    Png,
    /// Lossy, with its quality (1..=100): a tenth of PNG's bytes.
    Jpeg(u8),
}

impl ImageEncoding {
    /// From `[remote] encoding` and `jpeg_quality`.
    pub fn from_config(encoding: &str, jpeg_quality: u8) -> Self {
        match encoding {
            "jpeg" => Self::Jpeg(jpeg_quality),
            "raw" => Self::Raw,
            _ => Self::Png,
        }
    }

    /// How depth travels with colour of this encoding: raw with raw,
    /// else 16-bit PNG (lossless: depth must not be blurred).
    pub fn for_depth(self) -> Self {
        match self {
            Self::Raw => Self::Raw,
            _ => Self::Png,
        }
    }
}

/// Bytes that serialise as one blob (postcard: length and the bytes, one
/// copy), not element by element.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Blob(pub Vec<u8>);

impl Serialize for Blob {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_bytes(&self.0)
    }
}

impl<'de> Deserialize<'de> for Blob {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct V;
        impl serde::de::Visitor<'_> for V {
            type Value = Blob;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("bytes")
            }
            fn visit_bytes<E: serde::de::Error>(self, v: &[u8]) -> std::result::Result<Blob, E> {
                Ok(Blob(v.to_vec()))
            }
            fn visit_byte_buf<E: serde::de::Error>(
                self,
                v: Vec<u8>,
            ) -> std::result::Result<Blob, E> {
                Ok(Blob(v))
            }
        }
        d.deserialize_byte_buf(V)
    }
}

/// What an image plane holds, as the services keep it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Plane {
    /// RGB8.
    Rgb8,
    /// u16 depth, native-endian in memory.
    Depth16,
    /// u8 labels.
    Labels8,
}

impl Plane {
    fn bytes_per_pixel(self) -> usize {
        match self {
            Self::Rgb8 => 3,
            Self::Depth16 => 2,
            Self::Labels8 => 1,
        }
    }
    fn colour_type(self) -> ExtendedColorType {
        match self {
            Self::Rgb8 => ExtendedColorType::Rgb8,
            Self::Depth16 => ExtendedColorType::L16,
            Self::Labels8 => ExtendedColorType::L8,
        }
    }
}

/// One instance as it travels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WireInstance {
    /// See [`Instance::object_id`].
    pub object_id: u32,
    /// See [`Instance::class_id`].
    pub class_id: u32,
    /// See [`Instance::score`].
    pub score: f32,
    /// See [`Instance::bbox`].
    pub bbox: [f32; 4],
}

impl From<&Instance> for WireInstance {
    fn from(i: &Instance) -> Self {
        Self {
            object_id: i.object_id,
            class_id: i.class_id,
            score: i.score,
            bbox: i.bbox,
        }
    }
}

impl From<&WireInstance> for Instance {
    fn from(i: &WireInstance) -> Self {
        Self {
            object_id: i.object_id,
            class_id: i.class_id,
            score: i.score,
            bbox: i.bbox,
        }
    }
}

/// A set of masks as it travels: instances and their label image (PNG).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WireMasks {
    /// The frame the masks are of.
    pub seq: u64,
    /// A [`MaskSource`] value.
    pub source: u32,
    /// Instances; label `i + 1` is instance `i`.
    pub instances: Vec<WireInstance>,
    /// 8-bit grey PNG of the labels.
    pub labels_png: Blob,
}

/// A routed frame for a remote worker.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameRequest {
    /// [`VERSION`].
    pub version: u16,
    /// The run it belongs to (a worker answers only its own).
    pub run: String,
    /// The frame's sequence number in the run.
    pub seq: u64,
    /// The source's timestamp.
    pub source_timestamp: f64,
    /// Pixels.
    pub width: u32,
    /// Pixels.
    pub height: u32,
    /// Depth units per metre.
    pub depth_scale: f32,
    /// How `colour` is encoded (depth: [`ImageEncoding::for_depth`]).
    pub encoding: ImageEncoding,
    /// The RGB image.
    pub colour: Blob,
    /// The depth image, when sent.
    pub depth: Option<Blob>,
    /// The newest masks before this frame (weak detections that continue
    /// one of their objects are kept).
    pub previous: Option<WireMasks>,
}

/// What a worker answers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Outcome {
    /// The masks, and the model's time on them.
    Masks {
        /// Model time (nanoseconds).
        inference_ns: u64,
        /// The masks (their `seq` is the request's).
        masks: WireMasks,
    },
    /// The model failed on the frame (the message says why).
    Failed(String),
}

/// A worker's answer to a [`FrameRequest`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MasksReply {
    /// [`VERSION`].
    pub version: u16,
    /// The run of the request.
    pub run: String,
    /// The request's frame.
    pub seq: u64,
    /// Masks or the failure.
    pub outcome: Outcome,
}

/// Encodes a frame (and the masks before it) for the network.
pub fn encode_request(
    run: &str,
    frame: &FrameView,
    previous: Option<&MasksView>,
    encoding: ImageEncoding,
    with_depth: bool,
) -> Result<Vec<u8>> {
    let (w, h) = (frame.header.width, frame.header.height);
    let colour = encode_plane(frame.rgb, w, h, Plane::Rgb8, encoding)?;
    let depth = match frame.depth.filter(|_| with_depth) {
        Some(raw) => Some(encode_plane(
            raw,
            w,
            h,
            Plane::Depth16,
            encoding.for_depth(),
        )?),
        None => None,
    };
    let previous = match previous {
        Some(m) => Some(encode_masks(m.header, m.labels)?),
        None => None,
    };
    let request = FrameRequest {
        version: VERSION,
        run: run.to_string(),
        seq: frame.header.seq,
        source_timestamp: frame.header.source_timestamp,
        width: w,
        height: h,
        depth_scale: frame.header.depth_scale,
        encoding,
        colour,
        depth,
        previous,
    };
    postcard::to_stdvec(&request).context("cannot encode the frame request")
}

/// A set of masks for the network.
pub fn encode_masks(header: &MasksHeader, labels: &[u8]) -> Result<WireMasks> {
    Ok(WireMasks {
        seq: header.seq,
        source: header.source,
        instances: header.instances().iter().map(WireInstance::from).collect(),
        labels_png: encode_plane(
            labels,
            header.width,
            header.height,
            Plane::Labels8,
            ImageEncoding::Png,
        )?,
    })
}

/// Encodes a reply.
pub fn encode_reply(run: &str, seq: u64, outcome: Outcome) -> Result<Vec<u8>> {
    postcard::to_stdvec(&MasksReply {
        version: VERSION,
        run: run.to_string(),
        seq,
        outcome,
    })
    .context("cannot encode the masks reply")
}

/// A frame decoded from a request: owned pixels a [`FrameView`] can borrow.
#[derive(Debug)]
pub struct DecodedFrame {
    /// The frame's header as the local services would have it.
    pub header: FrameHeader,
    /// RGB8, then native-endian u16 depth when `header.has_depth`.
    pub payload: Vec<u8>,
    /// The masks before it, decoded.
    pub previous: Option<(MasksHeader, Vec<u8>)>,
}

impl DecodedFrame {
    /// The frame as the models take it.
    pub fn view(&self) -> Result<FrameView<'_>> {
        FrameView::new(&self.header, &self.payload)
    }

    /// The masks before it, as the models take them.
    pub fn previous_view(&self) -> Option<MasksView<'_>> {
        self.previous
            .as_ref()
            .and_then(|(h, labels)| MasksView::new(h, labels).ok())
    }
}

/// Decodes a request for run `run`; anything else is an error that says
/// what is wrong with it.
pub fn decode_request(bytes: &[u8], run: &str) -> Result<DecodedFrame> {
    let r: FrameRequest = postcard::from_bytes(bytes)
        .map_err(|e| anyhow::anyhow!("not a frame request ({} bytes): {e}", bytes.len()))?;
    ensure!(
        r.version == VERSION,
        "frame request of version {} (this worker speaks {VERSION})",
        r.version
    );
    ensure!(
        r.run == run,
        "frame {} of run '{}': this worker serves run '{run}'",
        r.seq,
        r.run.escape_debug()
    );
    check_size(r.width, r.height).with_context(|| format!("frame {}", r.seq))?;
    ensure!(
        r.depth_scale.is_finite() && r.depth_scale >= 0.0,
        "frame {}: depth scale {} is not a number of units per metre",
        r.seq,
        r.depth_scale
    );
    let (w, h) = (r.width, r.height);
    let mut payload = decode_plane(&r.colour, r.encoding, w, h, Plane::Rgb8)
        .with_context(|| format!("frame {} colour", r.seq))?;
    if let Some(depth) = &r.depth {
        let raw = decode_plane(depth, r.encoding.for_depth(), w, h, Plane::Depth16)
            .with_context(|| format!("frame {} depth", r.seq))?;
        payload.extend(raw);
    }
    let has_depth = r.depth.is_some();
    let previous =
        match &r.previous {
            Some(m) => Some(decode_masks(m, w, h).with_context(|| {
                format!("frame {}: the masks before it (frame {})", r.seq, m.seq)
            })?),
            None => None,
        };
    Ok(DecodedFrame {
        header: FrameHeader {
            seq: r.seq,
            source_timestamp: r.source_timestamp,
            width: w,
            height: h,
            pixel_format: PixelFormat::Rgb8 as u32,
            has_depth: has_depth as u32,
            depth_scale: r.depth_scale,
            ..Default::default()
        },
        payload,
        previous,
    })
}

/// A reply decoded for the request of frame `seq` (`width` x `height`) of
/// run `run`: the masks' header (instances, source segmenter) with the
/// labels written into `labels`, or the worker's failure message.
pub fn decode_reply(
    bytes: &[u8],
    run: &str,
    seq: u64,
    (width, height): (u32, u32),
    labels: &mut [u8],
) -> Result<std::result::Result<(Vec<Instance>, u64), String>> {
    let r: MasksReply = postcard::from_bytes(bytes)
        .map_err(|e| anyhow::anyhow!("not a masks reply ({} bytes): {e}", bytes.len()))?;
    ensure!(
        r.version == VERSION,
        "masks reply of version {} (this link speaks {VERSION})",
        r.version
    );
    ensure!(
        r.run == run && r.seq == seq,
        "a reply for frame {} of run '{}' (asked: frame {seq} of run '{run}')",
        r.seq,
        r.run.escape_debug()
    );
    match r.outcome {
        Outcome::Failed(why) => Ok(Err(why)),
        Outcome::Masks {
            inference_ns,
            masks,
        } => {
            ensure!(
                masks.seq == seq,
                "reply for frame {seq} holds masks of frame {}",
                masks.seq
            );
            let (header, decoded) = decode_masks(&masks, width, height)?;
            ensure!(
                labels.len() == decoded.len(),
                "frame {seq}: {} label bytes for a {} byte image",
                decoded.len(),
                labels.len()
            );
            labels.copy_from_slice(&decoded);
            Ok(Ok((header.instances().to_vec(), inference_ns)))
        }
    }
}

/// Masks of a `width` x `height` frame, checked: at most
/// [`MAX_INSTANCES`], every label naming one of them.
fn decode_masks(m: &WireMasks, width: u32, height: u32) -> Result<(MasksHeader, Vec<u8>)> {
    ensure!(
        m.instances.len() <= MAX_INSTANCES,
        "{} instances (at most {MAX_INSTANCES})",
        m.instances.len()
    );
    ensure!(
        MaskSource::from_u32(m.source).is_some(),
        "mask source {} is not one of none, segmenter, propagator",
        m.source
    );
    let labels = decode_plane(
        &m.labels_png,
        ImageEncoding::Png,
        width,
        height,
        Plane::Labels8,
    )
    .context("labels")?;
    let n = m.instances.len();
    if let Some(bad) = labels.iter().find(|&&l| l as usize > n) {
        bail!("label {bad} names no instance ({n} instances)");
    }
    let mut header = MasksHeader {
        seq: m.seq,
        source: m.source,
        width,
        height,
        ..Default::default()
    };
    let instances: Vec<Instance> = m.instances.iter().map(Into::into).collect();
    header.set_instances(&instances);
    Ok((header, labels))
}

fn check_size(width: u32, height: u32) -> Result<()> {
    ensure!(
        (1..=MAX_SIDE).contains(&width) && (1..=MAX_SIDE).contains(&height),
        "size {width}x{height} is not a frame size (1..={MAX_SIDE} a side)"
    );
    Ok(())
}

/// One image plane in `encoding` (depth goes little-endian when raw).
fn encode_plane(
    raw: &[u8],
    width: u32,
    height: u32,
    plane: Plane,
    encoding: ImageEncoding,
) -> Result<Blob> {
    let colour = plane.colour_type();
    let mut out = Vec::new();
    match encoding {
        ImageEncoding::Raw if plane == Plane::Depth16 => {
            out.extend(
                raw.chunks_exact(2)
                    .flat_map(|b| u16::from_ne_bytes([b[0], b[1]]).to_le_bytes()),
            );
            return Ok(Blob(out));
        }
        ImageEncoding::Raw => return Ok(Blob(raw.to_vec())),
        ImageEncoding::Png => image::codecs::png::PngEncoder::new_with_quality(
            &mut out,
            image::codecs::png::CompressionType::Fast,
            image::codecs::png::FilterType::Sub,
        )
        .write_image(raw, width, height, colour),
        ImageEncoding::Jpeg(q) => {
            image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, q.clamp(1, 100))
                .write_image(raw, width, height, colour)
        }
    }
    .with_context(|| format!("cannot encode a {width}x{height} {colour:?} image"))?;
    Ok(Blob(out))
}

/// One image plane that must be exactly `width` x `height` of `plane`'s
/// kind, as the services keep it. A compressed one is decoded with the
/// decoder limited to that size (and its bytes) before it allocates.
fn decode_plane(
    blob: &Blob,
    encoding: ImageEncoding,
    width: u32,
    height: u32,
    plane: Plane,
) -> Result<Vec<u8>> {
    let bytes = &blob.0;
    let expected = width as usize * height as usize * plane.bytes_per_pixel();
    let format = match encoding {
        ImageEncoding::Raw => {
            ensure!(
                bytes.len() == expected,
                "raw {plane:?} of {} bytes, the message says {width}x{height} ({expected} bytes)",
                bytes.len()
            );
            if plane == Plane::Depth16 {
                return Ok(bytes
                    .chunks_exact(2)
                    .flat_map(|b| u16::from_le_bytes([b[0], b[1]]).to_ne_bytes())
                    .collect());
            }
            return Ok(bytes.clone());
        }
        ImageEncoding::Png => ImageFormat::Png,
        ImageEncoding::Jpeg(_) => ImageFormat::Jpeg,
    };
    let mut reader = ImageReader::with_format(Cursor::new(bytes), format);
    let mut limits = Limits::default();
    limits.max_image_width = Some(width);
    limits.max_image_height = Some(height);
    // The largest image here: 16-bit RGBA of the announced size, plus slack
    // for the decoder's own buffers.
    limits.max_alloc = Some(width as u64 * height as u64 * 8 + (1 << 20));
    reader.limits(limits);
    let img = reader
        .decode()
        .map_err(|e| anyhow::anyhow!("{format:?} image: {e}"))?;
    ensure!(
        img.width() == width && img.height() == height,
        "{format:?} image is {}x{}, the message says {width}x{height}",
        img.width(),
        img.height()
    );
    match (plane, img) {
        (Plane::Rgb8, DynamicImage::ImageRgb8(i)) => Ok(i.into_raw()),
        (Plane::Depth16, DynamicImage::ImageLuma16(i)) => {
            Ok(i.into_raw().iter().flat_map(|v| v.to_ne_bytes()).collect())
        }
        (Plane::Labels8, DynamicImage::ImageLuma8(i)) => Ok(i.into_raw()),
        (plane, other) => bail!("{:?} image where {plane:?} was expected", other.color()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RUN: &str = "robot1";

    /// A small frame with depth, and masks before it.
    fn frame(w: u32, h: u32) -> (FrameHeader, Vec<u8>, MasksHeader, Vec<u8>) {
        let header = FrameHeader {
            seq: 7,
            source_timestamp: 12.5,
            width: w,
            height: h,
            has_depth: 1,
            depth_scale: 5000.0,
            ..Default::default()
        };
        let mut payload: Vec<u8> = (0..w * h * 3).map(|i| (i * 7 % 251) as u8).collect();
        payload.extend((0..w * h).flat_map(|i| ((i * 13) as u16).to_ne_bytes()));
        let mut masks = MasksHeader {
            seq: 5,
            source: MaskSource::Segmenter as u32,
            width: w,
            height: h,
            num_instances: 2,
            ..Default::default()
        };
        masks.instances[1].class_id = 3;
        masks.instances[1].bbox = [1.0, 2.0, 3.0, 4.0];
        let labels: Vec<u8> = (0..w * h).map(|i| (i % 3) as u8).collect();
        (header, payload, masks, labels)
    }

    fn request(encoding: ImageEncoding) -> Vec<u8> {
        let (header, payload, masks, labels) = frame(16, 12);
        let view = FrameView::new(&header, &payload).unwrap();
        let previous = MasksView::new(&masks, &labels).unwrap();
        encode_request(RUN, &view, Some(&previous), encoding, true).unwrap()
    }

    #[test]
    fn a_png_frame_arrives_exactly_as_it_left() {
        let (header, payload, masks, labels) = frame(16, 12);
        let got = decode_request(&request(ImageEncoding::Png), RUN).unwrap();
        assert_eq!(got.payload, payload);
        assert_eq!(
            (got.header.seq, got.header.width, got.header.has_depth),
            (header.seq, 16, 1)
        );
        assert_eq!(got.header.source_timestamp, 12.5);
        let (mh, ml) = got.previous.as_ref().unwrap();
        assert_eq!(ml, &labels);
        assert_eq!(mh.instances(), masks.instances());
        assert!(got.view().is_ok() && got.previous_view().is_some());
    }

    #[test]
    fn a_raw_frame_arrives_exactly_as_it_left() {
        let (_, payload, _, _) = frame(16, 12);
        let got = decode_request(&request(ImageEncoding::Raw), RUN).unwrap();
        assert_eq!(got.payload, payload);
    }

    #[test]
    fn a_jpeg_frame_arrives_close_and_depth_exact() {
        let (_, payload, _, _) = frame(16, 12);
        let got = decode_request(&request(ImageEncoding::Jpeg(90)), RUN).unwrap();
        let rgb = 16 * 12 * 3;
        assert_eq!(got.payload.len(), payload.len());
        assert_eq!(got.payload[rgb..], payload[rgb..], "depth is lossless");
    }

    #[test]
    fn a_reply_fills_the_labels_and_is_checked_against_the_request() {
        let (_, _, mut masks, labels) = frame(16, 12);
        masks.seq = 7;
        let wire = encode_masks(&masks, &labels).unwrap();
        let reply = encode_reply(
            RUN,
            7,
            Outcome::Masks {
                inference_ns: 42,
                masks: wire,
            },
        )
        .unwrap();
        let mut out = vec![0u8; 16 * 12];
        let (instances, ns) = decode_reply(&reply, RUN, 7, (16, 12), &mut out)
            .unwrap()
            .unwrap();
        assert_eq!((instances.len(), ns, &out), (2, 42, &labels));
        let e = decode_reply(&reply, RUN, 8, (16, 12), &mut [0; 192]).unwrap_err();
        assert!(e.to_string().contains("asked: frame 8"), "{e}");
        let e = decode_reply(&reply, RUN, 7, (16, 13), &mut [0; 208]).unwrap_err();
        assert!(format!("{e:#}").contains("16x12"), "{e:#}");
        let failed = encode_reply(RUN, 7, Outcome::Failed("model".into())).unwrap();
        assert_eq!(
            decode_reply(&failed, RUN, 7, (16, 12), &mut out).unwrap(),
            Err("model".to_string())
        );
    }

    #[test]
    fn another_runs_frame_is_refused_by_name() {
        let e = decode_request(&request(ImageEncoding::Png), "robot2").unwrap_err();
        assert!(
            e.to_string()
                .contains("frame 7 of run 'robot1': this worker serves run 'robot2'"),
            "{e}"
        );
    }

    #[test]
    fn hostile_requests_are_errors_that_say_what_is_wrong() {
        let good: FrameRequest = postcard::from_bytes(&request(ImageEncoding::Png)).unwrap();
        let cases: Vec<(FrameRequest, &str)> = vec![
            (
                FrameRequest {
                    width: 100_000,
                    ..good.clone()
                },
                "not a frame size",
            ),
            (
                FrameRequest {
                    width: 17,
                    ..good.clone()
                },
                "16x12, the message says 17x12",
            ),
            (
                FrameRequest {
                    width: 8,
                    ..good.clone()
                },
                "Png image",
            ),
            (
                FrameRequest {
                    version: 9,
                    ..good.clone()
                },
                "version 9",
            ),
            (
                FrameRequest {
                    colour: Blob(vec![0x89, b'P', b'N', b'G']),
                    ..good.clone()
                },
                "Png image",
            ),
            (
                FrameRequest {
                    encoding: ImageEncoding::Raw,
                    ..good.clone()
                },
                "raw Rgb8 of",
            ),
            (
                FrameRequest {
                    depth_scale: f32::NAN,
                    ..good.clone()
                },
                "depth scale",
            ),
        ];
        for (bad, expected) in cases {
            let bytes = postcard::to_stdvec(&bad).unwrap();
            let e = format!("{:#}", decode_request(&bytes, RUN).unwrap_err());
            assert!(e.contains(expected), "{expected}: {e}");
        }
        // Labels naming an instance that is not there.
        let mut bad = good.clone();
        let prev = bad.previous.as_mut().unwrap();
        prev.instances.truncate(1);
        let e = format!(
            "{:#}",
            decode_request(&postcard::to_stdvec(&bad).unwrap(), RUN).unwrap_err()
        );
        assert!(e.contains("label 2 names no instance (1 instances)"), "{e}");
    }

    /// Cheap fuzzing: truncations, flipped bytes and random messages never
    /// panic the decoders (they are errors, or by chance a valid message).
    #[test]
    fn the_decoders_survive_truncated_flipped_and_random_bytes() {
        let mut rng = fastrand::Rng::with_seed(51);
        let good = request(ImageEncoding::Png);
        let (_, _, mut masks, labels) = frame(16, 12);
        masks.seq = 7;
        let reply = encode_reply(
            RUN,
            7,
            Outcome::Masks {
                inference_ns: 1,
                masks: encode_masks(&masks, &labels).unwrap(),
            },
        )
        .unwrap();
        let mut out = vec![0u8; 16 * 12];
        for round in 0..3000 {
            let base = if round % 2 == 0 { &good } else { &reply };
            let mut bytes = base.clone();
            match round % 3 {
                0 => bytes.truncate(rng.usize(..bytes.len())),
                1 => {
                    for _ in 0..rng.usize(1..8) {
                        let i = rng.usize(..bytes.len());
                        bytes[i] = rng.u8(..);
                    }
                }
                _ => {
                    bytes = (0..rng.usize(..512)).map(|_| rng.u8(..)).collect();
                }
            }
            let _ = decode_request(&bytes, RUN);
            let _ = decode_reply(&bytes, RUN, 7, (16, 12), &mut out);
        }
    }
}
