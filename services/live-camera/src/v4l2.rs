//! A live V4L2 camera (`source.kind = "v4l2"`, `[source.v4l2]`): the colour
//! node in YUYV or MJPEG, optionally a depth node in Z16, streamed through
//! mmap buffers (the `linuxvideo` crate: pure Rust, no libv4l, no bindgen).
//!
//! Every failure a user can meet (no device, no permission, not a camera,
//! busy, no format we read) is a [`CameraError`] naming the device and what
//! to do.

use std::io;
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};
use std::time::Duration;

use linuxvideo::format::{PixFormat, PixelFormat};
use linuxvideo::stream::ReadStream;
use linuxvideo::{BufType, CapabilityFlags, Device, Fract};
use pipeline::config::SourceConfig;

use crate::convert::{mjpeg_to_rgb, yuyv_to_rgb, z16_to_depth, ConvertError, DepthPairer};

/// The colour formats read, in the order "auto" tries them (YUYV needs no
/// decoding; MJPEG is what cameras offer at higher rates and sizes).
const YUYV: PixelFormat = PixelFormat::YUYV;
const MJPG: PixelFormat = PixelFormat::MJPG;
const Z16: PixelFormat = PixelFormat::from_fourcc(*b"Z16 ");

/// Why a camera cannot be used; each names the device node.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    /// The node does not exist.
    #[error("camera {}: no such device (is it plugged in? `ls /dev/video*` lists the nodes; key source.v4l2.{key})", .path.display())]
    NoDevice {
        /// The device node.
        path: PathBuf,
        /// The config key that named it.
        key: &'static str,
    },
    /// The user may not open it.
    #[error("camera {}: permission denied (add your user to the `video` group, then log in again)", .path.display())]
    Permission {
        /// The device node.
        path: PathBuf,
    },
    /// Another program streams from it.
    #[error("camera {}: busy, another program is streaming from it (`fuser {}` names it)", .path.display(), .path.display())]
    Busy {
        /// The device node.
        path: PathBuf,
    },
    /// The node is not a video capture device.
    #[error("camera {}: not a V4L2 video capture device ({why})", .path.display())]
    NotACamera {
        /// The device node.
        path: PathBuf,
        /// What it is instead.
        why: String,
    },
    /// No format or size the run can use.
    #[error("camera {}: {why}", .path.display())]
    Format {
        /// The device node.
        path: PathBuf,
        /// What it offers, against what is wanted.
        why: String,
    },
    /// A system call on the node failed.
    #[error("camera {}: {what}: {source}", .path.display())]
    Io {
        /// The device node.
        path: PathBuf,
        /// What was being done.
        what: &'static str,
        /// The system's error.
        source: io::Error,
    },
}

/// An `io::Error` of a step on `path` as the error a user can act on.
fn classify(path: &Path, key: &'static str, what: &'static str, e: io::Error) -> CameraError {
    let path = path.to_path_buf();
    match (e.kind(), e.raw_os_error()) {
        (io::ErrorKind::NotFound, _) | (_, Some(libc::ENODEV)) | (_, Some(libc::ENXIO)) => {
            CameraError::NoDevice { path, key }
        }
        (io::ErrorKind::PermissionDenied, _) => CameraError::Permission { path },
        (_, Some(libc::EBUSY)) => CameraError::Busy { path },
        (_, Some(libc::ENOTTY)) => CameraError::NotACamera {
            path,
            why: "it does not answer V4L2 queries".into(),
        },
        _ => CameraError::Io {
            path,
            what,
            source: e,
        },
    }
}

/// The colour format to ask for: `wanted` ("auto", "yuyv", "mjpeg") among
/// what the device `offered`. The error lists the offers.
pub fn choose_format(offered: &[PixelFormat], wanted: &str) -> Result<PixelFormat, String> {
    let candidates: &[PixelFormat] = match wanted {
        "yuyv" => &[YUYV],
        "mjpeg" => &[MJPG],
        _ => &[YUYV, MJPG],
    };
    candidates
        .iter()
        .copied()
        .find(|f| offered.contains(f))
        .ok_or_else(|| {
            let list: Vec<String> = offered.iter().map(|f| f.to_string()).collect();
            format!(
                "offers {} and source.v4l2.pixel_format = \"{wanted}\" needs {}",
                if list.is_empty() {
                    "no capture format".to_string()
                } else {
                    list.join(", ")
                },
                candidates
                    .iter()
                    .map(|f| f.to_string())
                    .collect::<Vec<_>>()
                    .join(" or ")
            )
        })
}

/// A node opened as a camera (capture with streaming) and the format
/// `choose` picks among what it offers.
fn open_device(
    path: &Path,
    key: &'static str,
    choose: impl Fn(&[PixelFormat]) -> Result<PixelFormat, String>,
) -> Result<(Device, PixelFormat), CameraError> {
    let device = Device::open(path).map_err(|e| classify(path, key, "open", e))?;
    let caps = device
        .capabilities()
        .map_err(|e| classify(path, key, "query capabilities", e))?
        .device_capabilities();
    if !caps.contains(CapabilityFlags::VIDEO_CAPTURE) || !caps.contains(CapabilityFlags::STREAMING)
    {
        return Err(CameraError::NotACamera {
            path: path.into(),
            why: format!("capabilities {caps:?} lack video capture with streaming"),
        });
    }
    let mut offered = Vec::new();
    for f in device.formats(BufType::VIDEO_CAPTURE) {
        let f = f.map_err(|e| classify(path, key, "list formats", e))?;
        offered.push(f.pixel_format());
    }
    let format = choose(&offered).map_err(|why| CameraError::Format {
        path: path.into(),
        why,
    })?;
    Ok((device, format))
}

/// The depth node's format: Z16 or an error listing what it offers.
fn choose_depth(offered: &[PixelFormat]) -> Result<PixelFormat, String> {
    offered.contains(&Z16).then_some(Z16).ok_or_else(|| {
        let list: Vec<String> = offered.iter().map(|f| f.to_string()).collect();
        format!(
            "offers {} and a depth node must offer Z16 (16-bit depth)",
            list.join(", ")
        )
    })
}

/// Checks, before any process of the run starts, that the configured
/// nodes open as cameras with a format the reader takes (no streaming):
/// a wrong device fails the run at once, not after the models load.
pub fn probe(src: &SourceConfig) -> Result<(), CameraError> {
    let v = &src.v4l2;
    open_device(&v.device, "device", |offered| {
        choose_format(offered, &v.pixel_format)
    })?;
    if !v.depth_device.as_os_str().is_empty() {
        open_device(&v.depth_device, "depth_device", choose_depth)?;
    }
    Ok(())
}

/// A V4L2 capture node as `dynslam cameras` lists it.
#[derive(Debug)]
pub struct CameraInfo {
    /// The device node (`/dev/video0`).
    pub path: PathBuf,
    /// The driver's name for the device ("HD Pro Webcam C920").
    pub card: String,
    /// fourcc codes it offers for capture, in its order.
    pub formats: Vec<String>,
    /// What `source.v4l2` can read from it: "colour (YUYV)", "depth (Z16)", or
    /// why neither.
    pub use_as: String,
}

/// The capture nodes under /dev (`video*`), in name order; nodes that are
/// not cameras (metadata, output, codecs) are left out.
pub fn list_cameras() -> io::Result<Vec<CameraInfo>> {
    let mut nodes: Vec<PathBuf> = std::fs::read_dir("/dev")?
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("video"))
        })
        .collect();
    nodes.sort();
    let mut found = Vec::new();
    for path in nodes {
        let Ok(device) = Device::open(&path) else {
            continue;
        };
        let Ok(caps) = device.capabilities() else {
            continue;
        };
        if !caps
            .device_capabilities()
            .contains(CapabilityFlags::VIDEO_CAPTURE)
        {
            continue;
        }
        let offered: Vec<PixelFormat> = device
            .formats(BufType::VIDEO_CAPTURE)
            .filter_map(|f| f.ok())
            .map(|f| f.pixel_format())
            .collect();
        let use_as = match (choose_format(&offered, "auto"), choose_depth(&offered)) {
            (Ok(f), _) => format!("colour ({f}): source.v4l2.device"),
            (_, Ok(_)) => "depth (Z16): source.v4l2.depth_device".to_string(),
            (Err(_), Err(_)) => "not readable (no YUYV, MJPG or Z16)".to_string(),
        };
        found.push(CameraInfo {
            card: caps.card().to_string(),
            formats: offered.iter().map(|f| f.to_string()).collect(),
            use_as,
            path,
        });
    }
    Ok(found)
}

/// One opened, streaming node.
struct Node {
    path: PathBuf,
    stream: ReadStream,
    format: PixelFormat,
    width: u32,
    height: u32,
    stride: usize,
}

impl Node {
    fn open(
        path: &Path,
        key: &'static str,
        choose: impl Fn(&[PixelFormat]) -> Result<PixelFormat, String>,
        size: (u32, u32),
        fps: u32,
    ) -> Result<Self, CameraError> {
        let (device, format) = open_device(path, key, choose)?;
        let capture = device
            .video_capture(PixFormat::new(size.0, size.1, format))
            .map_err(|e| classify(path, key, "set the format", e))?;
        let got = capture.format();
        if got.pixel_format() != format {
            return Err(CameraError::Format {
                path: path.into(),
                why: format!("asked for {format}, the driver set {}", got.pixel_format()),
            });
        }
        let (width, height, stride) = (got.width(), got.height(), got.bytes_per_line() as usize);
        if (width, height) != size {
            tracing::warn!(
                "camera {}: asked for {}x{}, the driver gives {width}x{height}",
                path.display(),
                size.0,
                size.1
            );
        }
        match capture.set_frame_interval(Fract::new(1, fps)) {
            Ok(got) => tracing::info!(
                "camera {}: {format} {width}x{height}, frame interval {got:?}",
                path.display()
            ),
            // Not every driver lets the rate be set; it streams at its own.
            Err(e) => tracing::warn!(
                "camera {}: frame rate {fps} not set ({e}); streaming at the driver's",
                path.display()
            ),
        }
        let stream = capture
            .into_stream()
            .map_err(|e| classify(path, key, "start streaming", e))?;
        Ok(Self {
            path: path.into(),
            stream,
            format,
            width,
            height,
            stride,
        })
    }

    /// Whether a filled buffer is ready within `timeout` (poll(2) on the node).
    fn ready(&self, timeout: Duration) -> Result<bool, CameraError> {
        let mut fd = libc::pollfd {
            fd: self.stream.as_raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        };
        // SAFETY: one pollfd we own, valid for the call.
        let n = unsafe { libc::poll(&mut fd, 1, timeout.as_millis().min(i32::MAX as u128) as i32) };
        if n < 0 {
            let e = io::Error::last_os_error();
            if e.kind() == io::ErrorKind::Interrupted {
                return Ok(false);
            }
            return Err(classify(&self.path, "device", "wait for a frame", e));
        }
        if fd.revents & (libc::POLLERR | libc::POLLHUP) != 0 && fd.revents & libc::POLLIN == 0 {
            return Err(CameraError::NoDevice {
                path: self.path.clone(),
                key: "device",
            });
        }
        Ok(n > 0)
    }
}

/// A live camera: colour, and depth when `source.v4l2.depth_device` names a node.
pub struct Camera {
    colour: Node,
    depth: Option<Node>,
    pairer: DepthPairer,
    scratch: Vec<u8>,
}

/// What became of one colour buffer.
pub enum Captured {
    /// The frame is in the payload.
    Frame {
        /// Whether depth came with it.
        depth: bool,
    },
    /// The buffer could not be used (the reason); the frame goes out bad.
    Bad(String),
}

impl Camera {
    /// Opens the colour node (and the depth node, when configured) as
    /// `source.v4l2` asks: format, size and rate negotiated.
    pub fn open(src: &SourceConfig) -> Result<Self, CameraError> {
        let v = &src.v4l2;
        let wanted = v.pixel_format.clone();
        let colour = Node::open(
            &v.device,
            "device",
            |offered| choose_format(offered, &wanted),
            (v.width, v.height),
            v.fps,
        )?;
        let depth = if v.depth_device.as_os_str().is_empty() {
            None
        } else {
            let node = Node::open(
                &v.depth_device,
                "depth_device",
                choose_depth,
                (colour.width, colour.height),
                v.fps,
            )?;
            if (node.width, node.height) != (colour.width, colour.height) {
                return Err(CameraError::Format {
                    path: v.depth_device.clone(),
                    why: format!(
                        "depth is {}x{}, colour {}x{}: depth must be registered to the colour image",
                        node.width, node.height, colour.width, colour.height
                    ),
                });
            }
            Some(node)
        };
        Ok(Self {
            colour,
            depth,
            pairer: DepthPairer::new(src.max_time_diff),
            scratch: Vec::new(),
        })
    }

    /// The negotiated frame size (pixels).
    pub fn size(&self) -> (u32, u32) {
        (self.colour.width, self.colour.height)
    }

    /// Whether a depth node streams beside the colour one.
    pub fn has_depth(&self) -> bool {
        self.depth.is_some()
    }

    /// Depth frames that have arrived, converted and kept for pairing.
    fn drain_depth(&mut self, now_ns: &impl Fn() -> u64) -> Result<(), CameraError> {
        let Some(node) = &mut self.depth else {
            return Ok(());
        };
        while node.ready(Duration::ZERO)? {
            let (w, h, stride) = (node.width, node.height, node.stride);
            let mut out = vec![0u8; w as usize * h as usize * 2];
            let arrived = now_ns();
            let converted = node
                .stream
                .dequeue(|buf| Ok(z16_to_depth(&buf, w, h, stride, &mut out)))
                .map_err(|e| classify(&node.path, "depth_device", "take a depth frame", e))?;
            match converted {
                Ok(()) => self.pairer.push(arrived, out),
                Err(e) => tracing::warn!("depth node {}: {e}", node.path.display()),
            }
        }
        Ok(())
    }

    /// Real time, the pipeline behind: waits up to `timeout` for a colour
    /// frame and gives its buffer back unread (as a driver drops for a
    /// slow reader, but counted). When it arrived; `None` when none came.
    pub fn skip(
        &mut self,
        timeout: Duration,
        now_ns: impl Fn() -> u64,
    ) -> anyhow::Result<Option<u64>> {
        self.drain_depth(&now_ns)?;
        if !self.colour.ready(timeout)? {
            return Ok(None);
        }
        let arrived = now_ns();
        self.colour
            .stream
            .dequeue(|_| Ok(()))
            .map_err(|e| classify(&self.colour.path, "device", "take a frame", e))?;
        Ok(Some(arrived))
    }

    /// Waits up to `timeout` for a colour frame; `None` when none came.
    /// `loan` gives the payload to convert into, once a frame is there.
    pub fn next<'p>(
        &mut self,
        timeout: Duration,
        now_ns: impl Fn() -> u64,
        loan: impl FnOnce() -> anyhow::Result<&'p mut [u8]>,
    ) -> anyhow::Result<Option<(u64, Captured)>> {
        self.drain_depth(&now_ns)?;
        if !self.colour.ready(timeout)? {
            return Ok(None);
        }
        let arrived = now_ns();
        let payload = loan()?;
        let (w, h, stride, format) = (
            self.colour.width,
            self.colour.height,
            self.colour.stride,
            self.colour.format,
        );
        let rgb_len = w as usize * h as usize * 3;
        let scratch = &mut self.scratch;
        let converted: Result<(), ConvertError> = self
            .colour
            .stream
            .dequeue(|buf| {
                if buf.is_error() {
                    return Ok(Err(ConvertError::Jpeg(
                        "the driver flagged the buffer as corrupt".into(),
                    )));
                }
                Ok(if format == MJPG {
                    mjpeg_to_rgb(&buf, w, h, scratch, &mut payload[..rgb_len])
                } else {
                    yuyv_to_rgb(&buf, w, h, stride, &mut payload[..rgb_len])
                })
            })
            .map_err(|e| classify(&self.colour.path, "device", "take a frame", e))?;
        if let Err(e) = converted {
            return Ok(Some((arrived, Captured::Bad(e.to_string()))));
        }
        if self.depth.is_none() {
            return Ok(Some((arrived, Captured::Frame { depth: false })));
        }
        // The depth frame may come just after the colour one.
        let mut depth = self.pairer.take(arrived);
        let window = Duration::from_nanos(self.pairer.max_diff_ns());
        if depth.is_none()
            && self
                .depth
                .as_ref()
                .is_some_and(|d| d.ready(window).unwrap_or(false))
        {
            self.drain_depth(&now_ns)?;
            depth = self.pairer.take(arrived);
        }
        match depth {
            Some(d) => {
                payload[rgb_len..rgb_len + d.len()].copy_from_slice(&d);
                Ok(Some((arrived, Captured::Frame { depth: true })))
            }
            None => Ok(Some((
                arrived,
                Captured::Bad(format!(
                    "no depth frame within {:.3} s of the colour frame (source.max_time_diff)",
                    window.as_secs_f64()
                )),
            ))),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(device: &str) -> SourceConfig {
        let mut src = SourceConfig::default();
        src.v4l2.device = device.into();
        src
    }

    #[test]
    fn the_format_is_chosen_from_what_the_device_offers() {
        let grey = PixelFormat::from_fourcc(*b"GREY");
        let nv12 = PixelFormat::from_fourcc(*b"NV12");
        assert_eq!(choose_format(&[MJPG, YUYV], "auto"), Ok(YUYV));
        assert_eq!(choose_format(&[MJPG, nv12], "auto"), Ok(MJPG));
        assert_eq!(choose_format(&[MJPG, YUYV], "mjpeg"), Ok(MJPG));
        let e = choose_format(&[grey, nv12], "auto").unwrap_err();
        assert!(
            e.contains("GREY") && e.contains("NV12") && e.contains("YUYV or MJPG"),
            "{e}"
        );
        let e = choose_format(&[MJPG], "yuyv").unwrap_err();
        assert!(e.contains("pixel_format = \"yuyv\""), "{e}");
    }

    #[test]
    fn a_missing_device_is_named_with_what_to_check() {
        let e = Camera::open(&config("/dev/video-dynslam-none"))
            .err()
            .unwrap();
        let text = e.to_string();
        assert!(matches!(e, CameraError::NoDevice { .. }), "{e:?}");
        assert!(
            text.contains("/dev/video-dynslam-none") && text.contains("source.v4l2.device"),
            "{text}"
        );
    }

    #[test]
    fn a_node_that_is_not_a_camera_is_refused() {
        // /dev/null opens, but answers no V4L2 query (ENOTTY from the kernel).
        let e = Camera::open(&config("/dev/null")).err().unwrap();
        assert!(matches!(e, CameraError::NotACamera { .. }), "{e:?}");
        assert!(
            e.to_string().contains("not a V4L2 video capture device"),
            "{e}"
        );
    }

    #[test]
    fn errors_from_the_kernel_say_what_to_do() {
        let p = Path::new("/dev/video0");
        let busy = classify(
            p,
            "device",
            "start streaming",
            io::Error::from_raw_os_error(libc::EBUSY),
        );
        assert!(busy.to_string().contains("busy, another program"), "{busy}");
        let denied = classify(
            p,
            "device",
            "open",
            io::Error::from_raw_os_error(libc::EACCES),
        );
        assert!(denied.to_string().contains("`video` group"), "{denied}");
        let gone = classify(
            p,
            "device",
            "take a frame",
            io::Error::from_raw_os_error(libc::ENODEV),
        );
        assert!(gone.to_string().contains("no such device"), "{gone}");
        let other = classify(
            p,
            "device",
            "take a frame",
            io::Error::from_raw_os_error(libc::EIO),
        );
        assert!(other.to_string().contains("take a frame"), "{other}");
    }
}
