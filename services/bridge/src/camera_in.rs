//! ROS 2 cameras in (`source.kind = "ros2"`): the bridge binary in the
//! camera-reader's place. A camera driver's colour (`sensor_msgs/Image`
//! rgb8/bgr8 or `CompressedImage` jpeg/png) and depth (`Image` 16UC1 in
//! millimetres or 32FC1 in metres) are paired by stamp within
//! `source.max_time_diff` and written, decoded, into the run's frame
//! samples as any source's; the CameraInfo gives the intrinsics
//! ([`camera_section`], asked for by the supervisor before the run starts).
//!
//! What a restart cannot mend (a wrong encoding, a change of size, no
//! CameraInfo) ends the stream with an [`InputError`] naming the topic: the
//! run fails with it, no crash loop. A sample that cannot be read (wrong
//! type, truncated or hostile CDR, an image that does not decode) is
//! dropped and counted.

use std::collections::{BTreeMap, VecDeque};
use std::time::{Duration, Instant};

use anyhow::Result;
use pipeline::clock::now_ns;
use pipeline::config::PipelineConfig;
use pipeline::runtime::{InputError, ServiceContext};
use pipeline::service_loop::{self, Drain, Event, Flow, Service};
use pipeline::transport::{attach, waitset, Receiver, Sender};
use scheduling::source::{Backlog, SourceCommand};
use shared_types::names::Topic;
use shared_types::{frame_flags, write_error_text, Control, FrameHeader, PixelFormat, Track};

use crate::msgs::{self, Time};
use crate::node::{RosNode, TopicSubscriber};

/// Samples of one topic kept while they wait for their pair.
const PAIRING_QUEUE: usize = 8;
/// How long one look at the topics sleeps at most.
const POLL: Duration = Duration::from_millis(5);

fn ns(t: Time) -> i64 {
    t.sec as i64 * 1_000_000_000 + t.nanosec as i64
}

/// Why a sample was dropped, counted and reported.
#[derive(Debug, Default)]
struct Dropped(BTreeMap<String, u64>);

impl Dropped {
    fn add(&mut self, topic: &str, why: &str) {
        let n = self.0.entry(format!("{topic}: {why}")).or_default();
        *n += 1;
        if n.is_power_of_two() {
            tracing::warn!("dropped {n} sample(s) so far on {topic}: {why}");
        }
    }
}

/// A colour image as RGB8 rows.
pub struct Rgb {
    /// When it was taken (the sample's header).
    pub stamp: Time,
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// RGB8, row by row, no padding.
    pub pixels: Vec<u8>,
}

/// What a colour sample says: a decodable image, a sample to drop, or a
/// stream that cannot work.
pub enum Decoded<T> {
    /// The image.
    Ok(T),
    /// This sample cannot be used (why); later ones may.
    Drop(String),
    /// The stream cannot be used at all (why).
    Fatal(String),
}

/// A colour sample (`Image` or `CompressedImage`, by the key's type).
pub fn decode_colour(dds: &str, payload: &[u8]) -> Decoded<Rgb> {
    if dds == msgs::COMPRESSED_IMAGE.dds {
        let m = match msgs::read_compressed_image(payload) {
            Ok(m) => m,
            Err(e) => return Decoded::Drop(format!("unreadable CompressedImage: {e}")),
        };
        let format = m.format.to_ascii_lowercase();
        if !(format.contains("jpeg") || format.contains("jpg") || format.contains("png")) {
            return Decoded::Fatal(format!(
                "CompressedImage format \"{}\" is neither jpeg nor png",
                m.format
            ));
        }
        return match image::load_from_memory(m.data) {
            Ok(img) => {
                let rgb = img.to_rgb8();
                Decoded::Ok(Rgb {
                    stamp: m.header.stamp,
                    width: rgb.width(),
                    height: rgb.height(),
                    pixels: rgb.into_raw(),
                })
            }
            Err(e) => Decoded::Drop(format!("a {} image that does not decode: {e}", m.format)),
        };
    }
    if dds != msgs::IMAGE.dds {
        return Decoded::Drop(format!(
            "type {dds}, not sensor_msgs/Image or CompressedImage"
        ));
    }
    let m = match msgs::read_image(payload) {
        Ok(m) => m,
        Err(e) => return Decoded::Drop(format!("unreadable Image: {e}")),
    };
    let (w, h) = (m.width as usize, m.height as usize);
    let (r, b) = match m.encoding.as_str() {
        "rgb8" => (0, 2),
        "bgr8" => (2, 0),
        other => {
            return Decoded::Fatal(format!(
                "encoding \"{other}\" is not a colour encoding dynslam reads (rgb8, bgr8; or CompressedImage jpeg/png)"
            ))
        }
    };
    let step = m.step as usize;
    if step < w * 3 || m.data.len() < step.saturating_mul(h) || w == 0 || h == 0 {
        return Decoded::Drop(format!(
            "{w}x{h} {} with step {step} needs {} bytes, has {}",
            m.encoding,
            step.saturating_mul(h),
            m.data.len()
        ));
    }
    let mut pixels = Vec::with_capacity(w * h * 3);
    for row in m.data.chunks_exact(step).take(h) {
        for px in row[..w * 3].chunks_exact(3) {
            pixels.extend_from_slice(&[px[r], px[1], px[b]]);
        }
    }
    Decoded::Ok(Rgb {
        stamp: m.header.stamp,
        width: m.width,
        height: m.height,
        pixels,
    })
}

/// A depth image in the run's depth units (`depth_scale` per metre).
pub struct Depth {
    /// When it was taken (the sample's header).
    pub stamp: Time,
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Depth values, row by row (0: no measurement).
    pub values: Vec<u16>,
}

/// A depth sample (`Image` 16UC1 in millimetres or 32FC1 in metres) in the run's units, `depth_scale` per metre.
pub fn decode_depth(dds: &str, payload: &[u8], depth_scale: f32) -> Decoded<Depth> {
    if dds != msgs::IMAGE.dds {
        return Decoded::Drop(format!("type {dds}, not sensor_msgs/Image"));
    }
    let m = match msgs::read_image(payload) {
        Ok(m) => m,
        Err(e) => return Decoded::Drop(format!("unreadable Image: {e}")),
    };
    let (w, h) = (m.width as usize, m.height as usize);
    let bytes = match m.encoding.as_str() {
        "16UC1" | "mono16" => 2,
        "32FC1" => 4,
        other => {
            return Decoded::Fatal(format!(
                "encoding \"{other}\" is not a depth encoding dynslam reads (16UC1 millimetres, 32FC1 metres)"
            ))
        }
    };
    let step = m.step as usize;
    if step < w * bytes || m.data.len() < step.saturating_mul(h) || w == 0 || h == 0 {
        return Decoded::Drop(format!(
            "{w}x{h} {} with step {step} needs {} bytes, has {}",
            m.encoding,
            step.saturating_mul(h),
            m.data.len()
        ));
    }
    let scale = depth_scale as f64;
    let to_units = |metres: f64| -> u16 {
        if metres.is_finite() && metres > 0.0 {
            (metres * scale).round().min(u16::MAX as f64) as u16
        } else {
            0
        }
    };
    let mut values = Vec::with_capacity(w * h);
    for row in m.data.chunks_exact(step).take(h) {
        for px in row[..w * bytes].chunks_exact(bytes) {
            let v = if bytes == 2 {
                let raw = if m.is_bigendian {
                    u16::from_be_bytes([px[0], px[1]])
                } else {
                    u16::from_le_bytes([px[0], px[1]])
                };
                to_units(raw as f64 / 1000.0)
            } else {
                let a = [px[0], px[1], px[2], px[3]];
                let metres = if m.is_bigendian {
                    f32::from_be_bytes(a)
                } else {
                    f32::from_le_bytes(a)
                };
                to_units(metres as f64)
            };
            values.push(v);
        }
    }
    Decoded::Ok(Depth {
        stamp: m.header.stamp,
        width: m.width,
        height: m.height,
        values,
    })
}

/// The `[camera]` section from the first CameraInfo on the configured
/// topic (plumb_bob, or no distortion), waiting at most the configured time.
pub fn camera_section(config: &PipelineConfig) -> Result<String> {
    let node = RosNode::open(&config.bridge)?;
    let topic = &config.source.ros2.camera_info_topic;
    let info = node.subscriber(topic)?;
    let timeout = Duration::from_secs_f64(config.source.ros2.camera_info_timeout_s);
    let start = Instant::now();
    let mut refused = Dropped::default();
    while start.elapsed() < timeout {
        let Some((dds, payload)) = info.next() else {
            std::thread::sleep(POLL);
            continue;
        };
        if dds != msgs::CAMERA_INFO.dds {
            refused.add(
                &info.topic,
                &format!("type {dds}, not sensor_msgs/CameraInfo"),
            );
            continue;
        }
        let ci = match msgs::read_camera_info(&payload) {
            Ok(ci) => ci,
            Err(e) => {
                refused.add(&info.topic, &format!("unreadable CameraInfo: {e}"));
                continue;
            }
        };
        let d: [f64; 5] = match ci.distortion_model.as_str() {
            "plumb_bob" | "rational_polynomial" | "" => {
                let mut d = [0.0; 5];
                for (o, v) in d.iter_mut().zip(&ci.d) {
                    *o = *v;
                }
                d
            }
            other => {
                return Err(InputError(format!(
                "{}: distortion model \"{other}\" is not plumb_bob; give the camera with --camera",
                info.topic
            ))
                .into())
            }
        };
        let k = ci.k;
        tracing::info!(
            "camera from {}: {}x{} fx {} fy {} cx {} cy {}",
            info.topic,
            ci.width,
            ci.height,
            k[0],
            k[4],
            k[2],
            k[5]
        );
        return Ok(format!(
            "[camera]\nfx = {:?}\nfy = {:?}\ncx = {:?}\ncy = {:?}\ndistortion = [{:?}, {:?}, {:?}, {:?}, {:?}]\n",
            k[0], k[4], k[2], k[5], d[0], d[1], d[2], d[3], d[4]
        ));
    }
    Err(InputError(format!(
        "no sensor_msgs/CameraInfo on {} within {:.0} s (source.ros2.camera_info_topic; is the camera driver running, on ROS_DOMAIN_ID {} through the router at {:?}?), or name the camera with --camera",
        info.topic,
        timeout.as_secs_f64(),
        config.bridge.domain_id,
        config.bridge.connect
    ))
    .into())
}

/// The camera stream: runs until SIGTERM, or until no frame came for
/// `end_after_idle_s` after the first.
pub fn serve(ctx: ServiceContext, start_seq: u64) -> Result<()> {
    let cfg = &ctx.config;
    let ros2 = &cfg.source.ros2;
    let sender = ctx
        .transport
        .slice_sender::<FrameHeader>(Topic::Frames, cfg.max_frame_bytes())?;
    let tracks = ctx.transport.receiver::<Track>(Topic::Tracks)?;
    let node = RosNode::open(&cfg.bridge)?;
    let colour = node.subscriber(&ros2.colour_topic)?;
    let depth = (!ros2.depth_topic.is_empty())
        .then(|| node.subscriber(&ros2.depth_topic))
        .transpose()?;
    let control = ctx.transport.receiver::<Control>(Topic::Control)?;
    let ws = waitset()?;
    let _t = attach(&ws, &tracks)?;
    let _c = attach(&ws, &control)?;
    ctx.announce_ready()?;
    tracing::info!(
        "ROS 2 camera: colour {}{}",
        colour.topic,
        depth
            .as_ref()
            .map_or(", no depth".to_string(), |d| format!(", depth {}", d.topic))
    );
    let stream = Stream {
        cfg,
        sender,
        seq: start_seq,
        size: None,
        colours: VecDeque::new(),
        depths: VecDeque::new(),
        dropped: Dropped::default(),
        backlog: Backlog::default(),
    };
    let idle_end =
        (ros2.end_after_idle_s > 0.0).then(|| Duration::from_secs_f64(ros2.end_after_idle_s));
    let mut camera = CameraIn {
        stream,
        tracks: &tracks,
        control: &control,
        colour: &colour,
        depth: depth.as_ref(),
        idle_end,
        last_frame: None,
        start_seq,
        ended: false,
        drain: Drain::default(),
    };
    service_loop::run(&ws, &mut camera)?;
    let dropped: u64 = camera.stream.dropped.0.values().sum();
    if dropped > 0 {
        tracing::warn!("samples dropped: {:?}", camera.stream.dropped.0);
    }
    Ok(())
}

/// What arrives for the camera stream from the run, in the order a wake-up
/// drains it (the ROS 2 topics are read at each tick: Zenoh does not wake
/// the WaitSet).
enum Arrival {
    Control(Control),
    Track(Track),
}

/// The camera's topics into the run's frames, one look at them a tick.
struct CameraIn<'a> {
    stream: Stream<'a>,
    tracks: &'a Receiver<Track, ()>,
    control: &'a Receiver<Control, ()>,
    colour: &'a TopicSubscriber,
    depth: Option<&'a TopicSubscriber>,
    /// No frame for this long after the first ends the stream.
    idle_end: Option<Duration>,
    last_frame: Option<Instant>,
    start_seq: u64,
    /// The end of the stream is out: waiting for the supervisor's stop.
    ended: bool,
    drain: Drain,
}

impl CameraIn<'_> {
    /// Reads what the topics brought, publishes the newest pair; after
    /// `idle_end` without a frame, the end of the stream.
    fn look(&mut self) -> Result<()> {
        let mut got = false;
        while let Some((dds, payload)) = self.colour.next() {
            got = true;
            self.stream.on_colour(self.colour, &dds, payload)?;
        }
        if let Some(d) = self.depth {
            while let Some((dds, payload)) = d.next() {
                got = true;
                self.stream.on_depth(d, &dds, &payload)?;
            }
        }
        if self.stream.pair(self.depth.is_some())? {
            self.last_frame = Some(Instant::now());
        }
        if let (false, Some(limit), Some(last)) = (got, self.idle_end, self.last_frame) {
            if last.elapsed() > limit {
                tracing::info!(
                    frames = self.stream.seq - self.start_seq,
                    "no frame for {:.1} s: the ROS 2 stream ended",
                    limit.as_secs_f64()
                );
                publish_header(
                    &self.stream.sender,
                    FrameHeader {
                        seq: self.stream.seq,
                        flags: frame_flags::END_OF_STREAM,
                        ..Default::default()
                    },
                )?;
                // The supervisor stops the run; its SIGTERM ends the loop.
                self.ended = true;
            }
        }
        Ok(())
    }
}

impl Service for CameraIn<'_> {
    type Event = Arrival;

    fn patience(&self) -> Duration {
        if self.ended {
            Duration::from_secs(1)
        } else {
            POLL
        }
    }

    fn woke(&mut self) {
        self.drain.restart();
    }

    fn next_event(&mut self) -> Result<Option<Arrival>> {
        let (control, tracks) = (self.control, self.tracks);
        self.drain.next(2, |stage, entering| {
            Ok(match stage {
                0 => control.entered(entering).next()?.map(Arrival::Control),
                _ => tracks.entered(entering).next()?.map(Arrival::Track),
            })
        })
    }

    fn handle(&mut self, event: Event<Arrival>) -> Result<Flow> {
        match event {
            // A restarted SLAM never answers for the frames before it.
            Event::Arrived(Arrival::Control(c)) => {
                if SourceCommand::from_control(&c) == Some(SourceCommand::ForgetBacklog) {
                    self.stream.backlog.forget();
                }
            }
            Event::Arrived(Arrival::Track(t)) => self.stream.backlog.on_track(t.seq),
            Event::Tick if !self.ended => self.look()?,
            Event::Tick | Event::Shutdown => {}
        }
        Ok(Flow::Continue)
    }
}

fn publish_header(sender: &Sender<[u8], FrameHeader>, mut header: FrameHeader) -> Result<()> {
    header.stamps.published_ns = now_ns();
    let mut sample = sender.loan(0)?;
    *sample.user_header_mut() = header;
    sender.publish(sample)
}

struct Stream<'a> {
    cfg: &'a PipelineConfig,
    sender: Sender<[u8], FrameHeader>,
    seq: u64,
    /// The stream's size, from its first frame.
    size: Option<(u32, u32)>,
    colours: VecDeque<(Rgb, u64)>,
    depths: VecDeque<Depth>,
    dropped: Dropped,
    backlog: Backlog,
}

impl Stream<'_> {
    fn on_colour(&mut self, sub: &TopicSubscriber, dds: &str, payload: Vec<u8>) -> Result<()> {
        let arrived = now_ns();
        match decode_colour(dds, &payload) {
            Decoded::Ok(rgb) => {
                self.check_size(&sub.topic, rgb.width, rgb.height)?;
                self.colours.push_back((rgb, arrived));
                if self.colours.len() > PAIRING_QUEUE {
                    self.colours.pop_front();
                    self.dropped
                        .add(&sub.topic, "no depth to pair with in time");
                }
            }
            Decoded::Drop(why) => self.dropped.add(&sub.topic, &why),
            Decoded::Fatal(why) => return Err(InputError(format!("{}: {why}", sub.topic)).into()),
        }
        Ok(())
    }

    fn on_depth(&mut self, sub: &TopicSubscriber, dds: &str, payload: &[u8]) -> Result<()> {
        match decode_depth(dds, payload, self.cfg.source.depth_scale) {
            Decoded::Ok(d) => {
                self.check_size(&sub.topic, d.width, d.height)?;
                self.depths.push_back(d);
                if self.depths.len() > PAIRING_QUEUE {
                    self.depths.pop_front();
                }
            }
            Decoded::Drop(why) => self.dropped.add(&sub.topic, &why),
            Decoded::Fatal(why) => return Err(InputError(format!("{}: {why}", sub.topic)).into()),
        }
        Ok(())
    }

    fn check_size(&mut self, topic: &str, width: u32, height: u32) -> Result<()> {
        let run = &self.cfg.run;
        match self.size {
            None => {
                if width > run.max_width || height > run.max_height {
                    return Err(InputError(format!(
                        "{topic}: {width}x{height} images, larger than run.max_width x run.max_height = {}x{}",
                        run.max_width, run.max_height
                    ))
                    .into());
                }
                self.size = Some((width, height));
            }
            Some((w, h)) if (w, h) != (width, height) => {
                return Err(InputError(format!(
                    "{topic}: the images changed size from {w}x{h} to {width}x{height} (one size per run; a depth image must be registered to the colour image)"
                ))
                .into())
            }
            Some(_) => {}
        }
        Ok(())
    }

    /// Publishes the newest colour image that has its depth (or every
    /// colour image without depth); older colour images are left out.
    fn pair(&mut self, with_depth: bool) -> Result<bool> {
        let tolerance = (self.cfg.source.max_time_diff * 1e9) as i64;
        let mut chosen = None;
        for (i, (rgb, _)) in self.colours.iter().enumerate().rev() {
            if !with_depth {
                chosen = Some((i, None));
                break;
            }
            let t = ns(rgb.stamp);
            if let Some(j) = self
                .depths
                .iter()
                .position(|d| (ns(d.stamp) - t).abs() <= tolerance)
            {
                chosen = Some((i, Some(j)));
                break;
            }
        }
        let Some((i, j)) = chosen else {
            return Ok(false);
        };
        // Older colour images are left out, newest wins; they are frames of
        // the run all the same, recorded as dropped.
        for _ in 0..i {
            let (old, arrived) = self.colours.pop_front().expect("older than chosen");
            let mut header = self.header(&old, false, arrived);
            header.flags |= frame_flags::DROPPED_AT_SOURCE;
            publish_header(&self.sender, header)?;
            self.seq += 1;
        }
        let (rgb, arrived) = self.colours.pop_front().expect("chosen");
        let depth = j.map(|j| {
            let d = self.depths.remove(j).expect("chosen");
            self.depths.retain(|o| ns(o.stamp) > ns(d.stamp));
            d
        });
        self.publish(rgb, depth, arrived)?;
        Ok(true)
    }

    fn header(&self, rgb: &Rgb, has_depth: bool, arrived: u64) -> FrameHeader {
        let mut header = FrameHeader {
            seq: self.seq,
            source_timestamp: rgb.stamp.as_secs(),
            width: rgb.width,
            height: rgb.height,
            pixel_format: PixelFormat::Rgb8 as u32,
            has_depth: has_depth as u32,
            depth_scale: self.cfg.source.depth_scale,
            ..Default::default()
        };
        header.stamps.capture_ns = arrived;
        header
    }

    fn publish(&mut self, rgb: Rgb, depth: Option<Depth>, arrived: u64) -> Result<()> {
        let mut header = self.header(&rgb, depth.is_some(), arrived);
        if self.backlog.full(now_ns()) {
            header.flags |= frame_flags::DROPPED_AT_SOURCE;
            header.has_depth = 0;
            publish_header(&self.sender, header)?;
            self.seq += 1;
            return Ok(());
        }
        let len = rgb.pixels.len() + depth.as_ref().map_or(0, |d| d.values.len() * 2);
        if len > self.sender.max_len() {
            header.flags |= frame_flags::BAD_INPUT;
            write_error_text(
                &mut header.error,
                "frame larger than the shared-memory slot",
            );
            publish_header(&self.sender, header)?;
            self.seq += 1;
            return Ok(());
        }
        let mut sample = self.sender.loan(len)?;
        let out = sample.payload_mut();
        out[..rgb.pixels.len()].copy_from_slice(&rgb.pixels);
        if let Some(d) = &depth {
            for (o, v) in out[rgb.pixels.len()..].chunks_exact_mut(2).zip(&d.values) {
                o.copy_from_slice(&v.to_ne_bytes());
            }
        }
        header.stamps.published_ns = now_ns();
        *sample.user_header_mut() = header;
        self.sender.publish(sample)?;
        self.backlog.published(self.seq, now_ns());
        self.seq += 1;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cdr::Writer;

    fn image(encoding: &str, w: u32, h: u32, step: u32, data: &[u8]) -> Vec<u8> {
        let mut m = Writer::new();
        m.i32(5);
        m.u32(7);
        m.string("cam");
        m.u32(h);
        m.u32(w);
        m.string(encoding);
        m.u8(0);
        m.u32(step);
        m.bytes(data);
        m.finish()
    }

    #[test]
    fn colour_encodings_become_rgb_rows() {
        // 2x1 bgr8 with a padded row (step 8).
        let m = image("bgr8", 2, 1, 8, &[1, 2, 3, 4, 5, 6, 0, 0]);
        let Decoded::Ok(rgb) = decode_colour(msgs::IMAGE.dds, &m) else {
            panic!("bgr8 not decoded")
        };
        assert_eq!(rgb.pixels, vec![3, 2, 1, 6, 5, 4]);
        assert_eq!(rgb.stamp, Time { sec: 5, nanosec: 7 });
        assert!(matches!(
            decode_colour(msgs::IMAGE.dds, &image("yuv422", 2, 1, 4, &[0; 4])),
            Decoded::Fatal(_)
        ));
        // Too few bytes for its size: dropped, not fatal.
        assert!(matches!(
            decode_colour(msgs::IMAGE.dds, &image("rgb8", 4, 4, 12, &[0; 10])),
            Decoded::Drop(_)
        ));
        assert!(matches!(
            decode_colour(msgs::CAMERA_INFO.dds, &m),
            Decoded::Drop(_)
        ));
        // A JPEG in a CompressedImage.
        let mut jpeg = Vec::new();
        image::RgbImage::from_pixel(16, 8, image::Rgb([200, 100, 50]))
            .write_to(
                &mut std::io::Cursor::new(&mut jpeg),
                image::ImageFormat::Jpeg,
            )
            .unwrap();
        let mut c = Writer::new();
        c.i32(1);
        c.u32(0);
        c.string("cam");
        c.string("jpeg");
        c.bytes(&jpeg);
        let Decoded::Ok(rgb) = decode_colour(msgs::COMPRESSED_IMAGE.dds, &c.finish()) else {
            panic!("jpeg not decoded")
        };
        assert_eq!((rgb.width, rgb.height), (16, 8));
        assert!((rgb.pixels[0] as i32 - 200).abs() < 8);
    }

    #[test]
    fn depth_in_millimetres_or_metres_becomes_the_runs_units() {
        let mm: Vec<u8> = [1000u16, 0].iter().flat_map(|v| v.to_le_bytes()).collect();
        let Decoded::Ok(d) = decode_depth(msgs::IMAGE.dds, &image("16UC1", 2, 1, 4, &mm), 5000.0)
        else {
            panic!("16UC1 not decoded")
        };
        assert_eq!(d.values, vec![5000, 0]);
        let m: Vec<u8> = [1.5f32, f32::NAN]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let Decoded::Ok(d) = decode_depth(msgs::IMAGE.dds, &image("32FC1", 2, 1, 8, &m), 5000.0)
        else {
            panic!("32FC1 not decoded")
        };
        assert_eq!(d.values, vec![7500, 0]);
        assert!(matches!(
            decode_depth(msgs::IMAGE.dds, &image("rgb8", 2, 1, 6, &[0; 6]), 5000.0),
            Decoded::Fatal(_)
        ));
    }
}
