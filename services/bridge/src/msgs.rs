//! The ROS 2 messages the bridge publishes, in CDR, field for field as
//! their Jazzy definitions (`ros2 interface show nav_msgs/msg/Odometry`),
//! with each type's DDS name and RIHS01 type hash.
//!
//! The hashes are those rosidl generates from the Jazzy definitions (the
//! same for Kilted and Rolling: these types have not changed);
//! `tests/ros2_bridge.rs` checks every one against the independent
//! implementation in the `rosbags` package (its Jazzy type store).

use crate::cdr::{CdrError, Reader, Writer};

/// A message type as rmw_zenoh names it in key expressions and tokens.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MsgType {
    /// `nav_msgs/msg/Odometry`
    pub ros: &'static str,
    /// `nav_msgs::msg::dds_::Odometry_`
    pub dds: &'static str,
    /// `RIHS01_<sha256 of the type description>`
    pub hash: &'static str,
}

/// `nav_msgs/msg/Odometry`.
pub const ODOMETRY: MsgType = MsgType {
    ros: "nav_msgs/msg/Odometry",
    dds: "nav_msgs::msg::dds_::Odometry_",
    hash: "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
};
/// `tf2_msgs/msg/TFMessage`.
pub const TF_MESSAGE: MsgType = MsgType {
    ros: "tf2_msgs/msg/TFMessage",
    dds: "tf2_msgs::msg::dds_::TFMessage_",
    hash: "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
};
/// `nav_msgs/msg/Path`.
pub const PATH: MsgType = MsgType {
    ros: "nav_msgs/msg/Path",
    dds: "nav_msgs::msg::dds_::Path_",
    hash: "RIHS01_1957a5bb3cee5da65c4e52e52b65a93df227efce4c20f8458b36e73066ca334b",
};
/// `geometry_msgs/msg/PoseArray`.
pub const POSE_ARRAY: MsgType = MsgType {
    ros: "geometry_msgs/msg/PoseArray",
    dds: "geometry_msgs::msg::dds_::PoseArray_",
    hash: "RIHS01_af0cc36d190e104d546d168d6b39df04fa4b4ccecf59cb4c9ed328d3d5004aa0",
};
/// `diagnostic_msgs/msg/DiagnosticArray`.
pub const DIAGNOSTIC_ARRAY: MsgType = MsgType {
    ros: "diagnostic_msgs/msg/DiagnosticArray",
    dds: "diagnostic_msgs::msg::dds_::DiagnosticArray_",
    hash: "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e",
};
/// `std_msgs/msg/String`.
pub const STRING: MsgType = MsgType {
    ros: "std_msgs/msg/String",
    dds: "std_msgs::msg::dds_::String_",
    hash: "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
};

/// `sensor_msgs/msg/Image`.
pub const IMAGE: MsgType = MsgType {
    ros: "sensor_msgs/msg/Image",
    dds: "sensor_msgs::msg::dds_::Image_",
    hash: "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47",
};
/// `sensor_msgs/msg/CompressedImage`.
pub const COMPRESSED_IMAGE: MsgType = MsgType {
    ros: "sensor_msgs/msg/CompressedImage",
    dds: "sensor_msgs::msg::dds_::CompressedImage_",
    hash: "RIHS01_15640771531571185e2efc8a100baf923961a4d15d5569652e6cb6691e8e371a",
};
/// `sensor_msgs/msg/CameraInfo`.
pub const CAMERA_INFO: MsgType = MsgType {
    ros: "sensor_msgs/msg/CameraInfo",
    dds: "sensor_msgs::msg::dds_::CameraInfo_",
    hash: "RIHS01_b3dfd68ff46c9d56c80fd3bd4ed22c7a4ddce8c8348f2f59c299e73118e7e275",
};

/// `sensor_msgs/msg/PointCloud2`.
pub const POINT_CLOUD2: MsgType = MsgType {
    ros: "sensor_msgs/msg/PointCloud2",
    dds: "sensor_msgs::msg::dds_::PointCloud2_",
    hash: "RIHS01_9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5",
};
/// `nav_msgs/msg/OccupancyGrid`.
pub const OCCUPANCY_GRID: MsgType = MsgType {
    ros: "nav_msgs/msg/OccupancyGrid",
    dds: "nav_msgs::msg::dds_::OccupancyGrid_",
    hash: "RIHS01_8d348150c12913a31ee0ec170fbf25089e4745d17035792a1ba94d6f0bc0cfc7",
};

/// Every message type the bridge publishes or reads (the interop test
/// checks each hash against rosbags').
pub const ALL_TYPES: [MsgType; 11] = [
    POINT_CLOUD2,
    OCCUPANCY_GRID,
    ODOMETRY,
    TF_MESSAGE,
    PATH,
    POSE_ARRAY,
    DIAGNOSTIC_ARRAY,
    STRING,
    IMAGE,
    COMPRESSED_IMAGE,
    CAMERA_INFO,
];

/// `builtin_interfaces/Time`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Time {
    /// Seconds.
    pub sec: i32,
    /// Nanoseconds within the second.
    pub nanosec: u32,
}

impl Time {
    /// Seconds since the epoch (a camera's stamp) to ROS time; a stamp
    /// outside ROS's 32-bit seconds is clamped.
    pub fn from_secs(t: f64) -> Self {
        if !t.is_finite() || t <= 0.0 {
            return Self::default();
        }
        let sec = t.floor();
        let mut nanosec = ((t - sec) * 1e9).round() as u32;
        let mut sec = sec.min(i32::MAX as f64) as i32;
        if nanosec >= 1_000_000_000 {
            nanosec -= 1_000_000_000;
            sec = sec.saturating_add(1);
        }
        Self { sec, nanosec }
    }
    /// Seconds as a float.
    pub fn as_secs(self) -> f64 {
        self.sec as f64 + self.nanosec as f64 * 1e-9
    }
}

/// `std_msgs/Header`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Header {
    /// When.
    pub stamp: Time,
    /// The frame the data is in.
    pub frame_id: String,
}

/// A rigid transform: translation (metres) and unit quaternion (x y z w).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RosPose {
    /// x, y, z (metres).
    pub position: [f64; 3],
    /// Quaternion x, y, z, w.
    pub orientation: [f64; 4],
}

/// `nav_msgs/Odometry` (the twist in `child_frame_id`'s axes).
#[derive(Debug, Clone, PartialEq)]
pub struct Odometry {
    /// Stamp and the pose's frame (`odom` or `map`).
    pub header: Header,
    /// The frame that moves (the robot's base or the camera).
    pub child_frame_id: String,
    /// The pose.
    pub pose: RosPose,
    /// Its covariance, row-major 6x6 (x y z and rotations about x y z).
    pub pose_covariance: [f64; 36],
    /// Linear velocity (m/s, child frame).
    pub linear: [f64; 3],
    /// Angular velocity (rad/s, child frame).
    pub angular: [f64; 3],
    /// The twist's covariance, row-major 6x6.
    pub twist_covariance: [f64; 36],
}

/// `geometry_msgs/TransformStamped`.
#[derive(Debug, Clone, PartialEq)]
pub struct TransformStamped {
    /// Stamp and the parent frame.
    pub header: Header,
    /// The child frame.
    pub child_frame_id: String,
    /// Child in parent.
    pub transform: RosPose,
}

/// `diagnostic_msgs/DiagnosticStatus`.
#[derive(Debug, Clone, PartialEq)]
pub struct DiagnosticStatus {
    /// 0 OK, 1 WARN, 2 ERROR, 3 STALE.
    pub level: u8,
    /// Which part reports.
    pub name: String,
    /// Its state in words.
    pub message: String,
    /// The machine or process it is.
    pub hardware_id: String,
    /// Key-value figures.
    pub values: Vec<(String, String)>,
}

/// `DiagnosticStatus` levels.
pub mod level {
    /// Working.
    pub const OK: u8 = 0;
    /// Working, degraded.
    pub const WARN: u8 = 1;
    /// Not working.
    pub const ERROR: u8 = 2;
    /// No recent report.
    pub const STALE: u8 = 3;
}

fn header(w: &mut Writer, h: &Header) {
    w.i32(h.stamp.sec);
    w.u32(h.stamp.nanosec);
    w.string(&h.frame_id);
}

fn pose(w: &mut Writer, p: &RosPose) {
    for v in p.position.iter().chain(&p.orientation) {
        w.f64(*v);
    }
}

fn read_header(r: &mut Reader) -> Result<Header, CdrError> {
    Ok(Header {
        stamp: Time {
            sec: r.i32("header.stamp.sec")?,
            nanosec: r.u32("header.stamp.nanosec")?,
        },
        frame_id: r.string("header.frame_id")?,
    })
}

fn read_pose(r: &mut Reader, what: &'static str) -> Result<RosPose, CdrError> {
    let mut p = RosPose::default();
    for v in p.position.iter_mut().chain(p.orientation.iter_mut()) {
        *v = r.f64(what)?;
    }
    Ok(p)
}

/// The CDR of an `Odometry`.
pub fn odometry(o: &Odometry) -> Vec<u8> {
    let mut w = Writer::new();
    header(&mut w, &o.header);
    w.string(&o.child_frame_id);
    pose(&mut w, &o.pose);
    for v in o.pose_covariance {
        w.f64(v);
    }
    for v in o.linear.iter().chain(&o.angular) {
        w.f64(*v);
    }
    for v in o.twist_covariance {
        w.f64(v);
    }
    w.finish()
}

fn transform_stamped(w: &mut Writer, t: &TransformStamped) {
    header(w, &t.header);
    w.string(&t.child_frame_id);
    pose(w, &t.transform);
}

/// `tf2_msgs/TFMessage`.
pub fn tf_message(transforms: &[TransformStamped]) -> Vec<u8> {
    let mut w = Writer::new();
    w.len(transforms.len());
    for t in transforms {
        transform_stamped(&mut w, t);
    }
    w.finish()
}

/// Smallest CDR size of a `TransformStamped` (empty names): the bound that
/// keeps a hostile count from allocating.
const MIN_TRANSFORM_BYTES: usize = 4 + 4 + 4 + 1 + 4 + 1 + 7 * 8;

/// Reads a `tf2_msgs/TFMessage` (a robot's odom -> base_link, tests).
pub fn read_tf_message(message: &[u8]) -> Result<Vec<TransformStamped>, CdrError> {
    let mut r = Reader::new(message)?;
    let n = r.len("transforms", MIN_TRANSFORM_BYTES)?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let header = read_header(&mut r)?;
        let child_frame_id = r.string("child_frame_id")?;
        let transform = read_pose(&mut r, "transform")?;
        out.push(TransformStamped {
            header,
            child_frame_id,
            transform,
        });
    }
    Ok(out)
}

/// `sensor_msgs/Image`, its pixels borrowed from the message.
#[derive(Debug, Clone, PartialEq)]
pub struct Image<'a> {
    /// Stamp and frame.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Pixel format (`rgb8`, `bgr8`, `16UC1`, ...).
    pub encoding: String,
    /// Multi-byte values are big-endian.
    pub is_bigendian: bool,
    /// Bytes per row.
    pub step: u32,
    /// The pixels, in place.
    pub data: &'a [u8],
}

/// Reads an `Image`; the pixels stay in `message`.
pub fn read_image(message: &[u8]) -> Result<Image<'_>, CdrError> {
    let mut r = Reader::new(message)?;
    Ok(Image {
        header: read_header(&mut r)?,
        height: r.u32("height")?,
        width: r.u32("width")?,
        encoding: r.string("encoding")?,
        is_bigendian: r.u8("is_bigendian")? != 0,
        step: r.u32("step")?,
        data: r.bytes("data")?,
    })
}

/// A `sensor_msgs/Image` of one byte a pixel (`mono8`), rows packed.
pub fn mono8_image(h: &Header, width: u32, height: u32, pixels: &[u8]) -> Vec<u8> {
    let mut w = Writer::new();
    header(&mut w, h);
    w.u32(height);
    w.u32(width);
    w.string("mono8");
    w.u8(0);
    w.u32(width);
    w.bytes(pixels);
    w.finish()
}

/// `sensor_msgs/CompressedImage`.
#[derive(Debug, Clone, PartialEq)]
pub struct CompressedImage<'a> {
    /// Stamp and frame.
    pub header: Header,
    /// `jpeg` or `png` (and what image_transport adds).
    pub format: String,
    /// The compressed bytes, in place.
    pub data: &'a [u8],
}

/// Reads a `CompressedImage`; the bytes stay in `message`.
pub fn read_compressed_image(message: &[u8]) -> Result<CompressedImage<'_>, CdrError> {
    let mut r = Reader::new(message)?;
    Ok(CompressedImage {
        header: read_header(&mut r)?,
        format: r.string("format")?,
        data: r.bytes("data")?,
    })
}

/// `sensor_msgs/CameraInfo`, up to the intrinsic matrix.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraInfo {
    /// Stamp and frame.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// `plumb_bob` or `rational_polynomial`.
    pub distortion_model: String,
    /// Distortion coefficients.
    pub d: Vec<f64>,
    /// Row-major 3x3 intrinsics: fx 0 cx / 0 fy cy / 0 0 1.
    pub k: [f64; 9],
}

/// Reads a `CameraInfo`.
pub fn read_camera_info(message: &[u8]) -> Result<CameraInfo, CdrError> {
    let mut r = Reader::new(message)?;
    let header = read_header(&mut r)?;
    let height = r.u32("height")?;
    let width = r.u32("width")?;
    let distortion_model = r.string("distortion_model")?;
    let n = r.len("d", 8)?;
    let d = (0..n).map(|_| r.f64("d")).collect::<Result<_, _>>()?;
    let mut k = [0.0; 9];
    for v in &mut k {
        *v = r.f64("k")?;
    }
    Ok(CameraInfo {
        header,
        height,
        width,
        distortion_model,
        d,
        k,
    })
}

/// `nav_msgs/Path`: every pose a `PoseStamped` with its own stamp.
pub fn path(h: &Header, poses: &[(Time, RosPose)]) -> Vec<u8> {
    let mut w = Writer::new();
    header(&mut w, h);
    w.len(poses.len());
    for (stamp, p) in poses {
        header(
            &mut w,
            &Header {
                stamp: *stamp,
                frame_id: h.frame_id.clone(),
            },
        );
        pose(&mut w, p);
    }
    w.finish()
}

/// `geometry_msgs/PoseArray`.
pub fn pose_array(h: &Header, poses: &[RosPose]) -> Vec<u8> {
    let mut w = Writer::new();
    header(&mut w, h);
    w.len(poses.len());
    for p in poses {
        pose(&mut w, p);
    }
    w.finish()
}

/// `diagnostic_msgs/DiagnosticArray`.
pub fn diagnostic_array(h: &Header, status: &[DiagnosticStatus]) -> Vec<u8> {
    let mut w = Writer::new();
    header(&mut w, h);
    w.len(status.len());
    for s in status {
        w.u8(s.level);
        w.string(&s.name);
        w.string(&s.message);
        w.string(&s.hardware_id);
        w.len(s.values.len());
        for (k, v) in &s.values {
            w.string(k);
            w.string(v);
        }
    }
    w.finish()
}

/// `std_msgs/String`.
pub fn string(data: &str) -> Vec<u8> {
    let mut w = Writer::new();
    w.string(data);
    w.finish()
}

/// `sensor_msgs/PointField.datatype` of a 32-bit float.
const POINT_FIELD_FLOAT32: u8 = 7;
/// Bytes of one cloud point: x y z and the colour packed as PCL does
/// (0x00RRGGBB in a float's bits: RViz's and Foxglove's "rgb" field).
pub const CLOUD_POINT_STEP: usize = 16;

/// A cloud point: position and colour.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CloudPoint {
    /// x, y, z (metres, the cloud's frame).
    pub position: [f32; 3],
    /// RGB colour.
    pub rgb: [u8; 3],
}

/// `sensor_msgs/PointCloud2`, unordered (height 1), fields x y z rgb.
pub fn point_cloud2(h: &Header, points: &[CloudPoint]) -> Vec<u8> {
    let mut w = Writer::new();
    header(&mut w, h);
    w.u32(1);
    w.u32(points.len() as u32);
    w.len(4);
    for (i, name) in ["x", "y", "z", "rgb"].iter().enumerate() {
        w.string(name);
        w.u32(i as u32 * 4);
        w.u8(POINT_FIELD_FLOAT32);
        w.u32(1);
    }
    w.u8(0); // little endian
    w.u32(CLOUD_POINT_STEP as u32);
    w.u32((CLOUD_POINT_STEP * points.len()) as u32);
    let mut data = Vec::with_capacity(CLOUD_POINT_STEP * points.len());
    for p in points {
        for v in p.position {
            data.extend_from_slice(&v.to_le_bytes());
        }
        let [r, g, b] = p.rgb;
        data.extend_from_slice(&u32::from_be_bytes([0, r, g, b]).to_le_bytes());
    }
    w.bytes(&data);
    w.u8(1); // is_dense: no invalid point
    w.finish()
}

/// `nav_msgs/OccupancyGrid`: `cells` row-major from the cell at `origin`,
/// -1 unknown, 0 free, 100 occupied.
pub struct Grid<'a> {
    /// Stamp and frame.
    pub header: Header,
    /// Metres per cell.
    pub resolution: f32,
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// The pose of cell (0, 0)'s corner in the header's frame.
    pub origin: RosPose,
    /// Cells, row by row.
    pub cells: &'a [i8],
}

/// The CDR of a `nav_msgs/msg/OccupancyGrid`.
pub fn occupancy_grid(g: &Grid) -> Vec<u8> {
    let mut w = Writer::new();
    header(&mut w, &g.header);
    // info.map_load_time: when this grid was made, its header's stamp.
    w.i32(g.header.stamp.sec);
    w.u32(g.header.stamp.nanosec);
    w.f32(g.resolution);
    w.u32(g.width);
    w.u32(g.height);
    pose(&mut w, &g.origin);
    let bytes: Vec<u8> = g.cells.iter().map(|&c| c as u8).collect();
    w.bytes(&bytes);
    w.finish()
}

// The services (rmw_zenoh: a queryable on the service's key expression,
// requests and responses in CDR like messages).

/// `std_srvs/srv/Trigger`.
pub const TRIGGER: MsgType = MsgType {
    ros: "std_srvs/srv/Trigger",
    dds: "std_srvs::srv::dds_::Trigger_",
    hash: "RIHS01_eeff2cd6fa5ad9d27cdf4dec64818317839b62f212a91e6b5304b634b2062c5f",
};
/// `std_srvs/srv/SetBool`.
pub const SET_BOOL: MsgType = MsgType {
    ros: "std_srvs/srv/SetBool",
    dds: "std_srvs::srv::dds_::SetBool_",
    hash: "RIHS01_abe9e4bb6b41b40e6789712c00ec8871923e089af3f667a79992a428cff2da0a",
};
/// Ours (`docs/ros2/dynslam_interfaces`: `string name` ->
/// `bool success, string message`): no standard service takes a name.
pub const SAVE_MAP: MsgType = MsgType {
    ros: "dynslam_interfaces/srv/SaveMap",
    dds: "dynslam_interfaces::srv::dds_::SaveMap_",
    hash: "RIHS01_bdbc61beccb17cf3a949bee02596aa8dfb03c530bdf3c09d84924998c05d2dd7",
};

/// `std_srvs/SetBool` request: its `data`.
pub fn read_set_bool_request(message: &[u8]) -> Result<bool, CdrError> {
    let mut r = Reader::new(message)?;
    Ok(r.u8("data")? != 0)
}

/// `dynslam_interfaces/SaveMap` request: its `name`.
pub fn read_save_map_request(message: &[u8]) -> Result<String, CdrError> {
    Reader::new(message)?.string("name")
}

/// The response of all three services: `bool success, string message`.
pub fn success_message_response(success: bool, message: &str) -> Vec<u8> {
    let mut w = Writer::new();
    w.u8(success as u8);
    w.string(message);
    w.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn capture_stamps_become_ros_time() {
        let t = Time::from_secs(1305031102.175304);
        assert_eq!(t.sec, 1305031102);
        assert!((t.nanosec as i64 - 175_304_000).abs() < 1000);
        assert_eq!(Time::from_secs(-1.0), Time::default());
        assert_eq!(Time::from_secs(f64::NAN), Time::default());
        assert_eq!(Time::from_secs(1.9999999999).nanosec, 0);
    }

    /// Fuzz: mutated and random messages are read or refused, never a
    /// panic nor an allocation beyond the message (xorshift, fixed seed).
    #[test]
    fn the_tf_reader_survives_mutated_and_random_input() {
        let t = TransformStamped {
            header: Header {
                stamp: Time { sec: 1, nanosec: 2 },
                frame_id: "odom".into(),
            },
            child_frame_id: "base_link".into(),
            transform: RosPose::default(),
        };
        let valid = tf_message(&[t.clone(), t.clone(), t]);
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let (mut read, mut refused) = (0, 0);
        for i in 0..200_000 {
            let mut m = if i % 4 == 0 {
                (0..next() % 200).map(|_| next() as u8).collect::<Vec<u8>>()
            } else {
                valid.clone()
            };
            for _ in 0..1 + next() % 4 {
                if m.is_empty() {
                    break;
                }
                let at = (next() as usize) % m.len();
                match next() % 4 {
                    0 => m[at] = next() as u8,
                    1 => m.truncate(at),
                    2 => m[at..].iter_mut().take(4).for_each(|b| *b = 0xFF),
                    _ => m.insert(at, next() as u8),
                }
            }
            match read_tf_message(&m) {
                Ok(v) => {
                    assert!(v.len() * MIN_TRANSFORM_BYTES <= m.len());
                    read += 1
                }
                Err(_) => refused += 1,
            }
        }
        assert!(
            read > 1000 && refused > 1000,
            "{read} read, {refused} refused"
        );
    }

    #[test]
    fn tf_messages_read_back_what_was_written() {
        let t = TransformStamped {
            header: Header {
                stamp: Time { sec: 5, nanosec: 7 },
                frame_id: "odom".into(),
            },
            child_frame_id: "base_link".into(),
            transform: RosPose {
                position: [1.0, 2.0, 3.0],
                orientation: [0.0, 0.0, 0.0, 1.0],
            },
        };
        let b = tf_message(&[t.clone(), t.clone()]);
        assert_eq!(read_tf_message(&b).unwrap(), vec![t.clone(), t]);
        // Every truncation is an error, never a panic.
        for cut in 0..b.len() {
            assert!(read_tf_message(&b[..cut]).is_err(), "cut at {cut}");
        }
    }

    #[test]
    fn service_requests_read_back_and_hostile_ones_are_errors() {
        let mut w = Writer::new();
        w.string("office");
        let good = w.finish();
        assert_eq!(read_save_map_request(&good).unwrap(), "office");
        let mut huge = good.clone();
        huge[4..8].copy_from_slice(&u32::MAX.to_le_bytes());
        for bad in [&good[..6], &huge[..], &[0u8, 1][..], &[][..]] {
            assert!(read_save_map_request(bad).is_err(), "{bad:?}");
        }
        let mut w = Writer::new();
        w.u8(1);
        assert!(read_set_bool_request(&w.finish()).unwrap());
        assert!(read_set_bool_request(&crate::cdr::CDR_LE).is_err());
        let r = success_message_response(false, "no");
        let mut rd = Reader::new(&r).unwrap();
        assert_eq!(rd.u8("success").unwrap(), 0);
        assert_eq!(rd.string("message").unwrap(), "no");
    }
}
