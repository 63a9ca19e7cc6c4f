//! What the bridge publishes, from what the run's services say: the SLAM's
//! pose stream becomes odometry, TF, the path, the keyframes and the state;
//! the Tracks and the supervisor's `status.json` become diagnostics.
//!
//! The bridge may be killed at any time (its users test that): what it has
//! published is kept in the run folder (`ros2_bridge.json`: the last frame,
//! written before its messages go out, and each topic's sequence number;
//! `ros2_path.txt`: the path), so that a restarted bridge publishes no frame
//! twice, continues every topic's sequence numbers (after a gap of one)
//! and the path.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use nalgebra::Isometry3;
use pipeline::config::BridgeConfig;
use pipeline::views::MapView;
use serde::{Deserialize, Serialize};
use shared_types::{mask_flags, MapHeader, MaskSource, MasksHeader, Pose, Track, TrackState};

use crate::frames::{self, Frames};
use crate::grid::{self, GridParams};
use crate::msgs::{
    self, level, CloudPoint, DiagnosticStatus, Header, Odometry, RosPose, Time, TransformStamped,
};
use crate::node::{RosNode, RosPublisher};
use crate::odom::OdomBuffer;
use crate::rmw::Durability;
use zenoh::qos::Priority;

/// The bridge's record in the run folder.
pub const STATE_FILE: &str = "ros2_bridge.json";
/// The published path (one tracked frame a line: seq, stamp, pose in the
/// map frame, keyframe flag).
pub const PATH_FILE: &str = "ros2_path.txt";

#[derive(Debug, Default, Serialize, Deserialize)]
struct State {
    /// The newest frame whose pose was handled.
    last_seq: Option<u64>,
    /// Each topic's sequence number so far.
    sequence_numbers: BTreeMap<String, i64>,
}

/// Pose covariance on the diagonal (m², rad²): a tracked frame, and a
/// relocalised one (found again in the map: its pose does not follow from
/// the last, so a filter should trust it less).
const TRACKED_VARIANCE: f64 = 1e-4;
const RELOCALISED_VARIANCE: f64 = 1e-2;
/// A twist is not known (first frame, after a gap longer than this).
const UNKNOWN_VARIANCE: f64 = 1e3;
const MAX_TWIST_GAP_S: f64 = 0.5;

fn diagonal(v: f64) -> [f64; 36] {
    let mut c = [0.0; 36];
    for i in 0..6 {
        c[i * 7] = v;
    }
    c
}

/// Cells on a side of the occupancy grid at most (at 5 cm, 200 m): a
/// stray far point cuts the grid rather than inflating the message.
const GRID_MAX_SIDE: usize = 4000;

/// Frame `t` was tracked, with masks.
fn tracked_with_masks(t: &Track) -> bool {
    TrackState::from_u32(t.state).is_some_and(TrackState::is_tracked)
        && t.mask_source != MaskSource::None as u32
}

/// Where in `pending` the masks are that frame `t` was tracked with.
fn masks_used(pending: &[PendingMasks], t: &Track) -> Option<usize> {
    pending
        .iter()
        .position(|m| m.seq == t.seq && m.source == t.mask_source)
}

/// A frame's masks waiting for its Track.
struct PendingMasks {
    seq: u64,
    /// A `MaskSource` value.
    source: u32,
    width: u32,
    height: u32,
    labels: Vec<u8>,
}

/// Per-period counts for the diagnostics.
#[derive(Debug, Default)]
struct Window {
    answered: u64,
    tracked: u64,
    first_seq: Option<u64>,
    last_seq: Option<u64>,
    latencies_ms: Vec<f64>,
}

/// What the bridge publishes, and when: the SLAM's tracks and map turned into ROS 2 messages.
pub struct Outputs {
    cfg: BridgeConfig,
    run_dir: PathBuf,
    frames: Frames,
    state: State,
    node_name: String,
    odometry: RosPublisher,
    tf: RosPublisher,
    tf_static: RosPublisher,
    path: RosPublisher,
    keyframes: RosPublisher,
    slam_state: RosPublisher,
    diagnostics: RosPublisher,
    /// `mask_image`: the masks of the frames SLAM has not answered yet,
    /// oldest first.
    masks: Option<(RosPublisher, Vec<PendingMasks>)>,
    /// `map_cloud` and `grid`: the map's points, the occupancy grid.
    map_cloud: Option<RosPublisher>,
    grid: Option<(RosPublisher, GridParams)>,
    path_poses: Vec<(Time, RosPose)>,
    keyframe_poses: Vec<RosPose>,
    path_file: std::fs::File,
    last_tracked: Option<(f64, Isometry3<f64>)>,
    current_state: Option<TrackState>,
    last_track: Option<Track>,
    window: Window,
    path_dirty: bool,
    /// The robot's `odom -> base` (bridge.odom_frame set).
    odom: Option<OdomBuffer>,
    /// Tracked frames for which the robot's odometry was not known: no
    /// `map -> odom` was published for them.
    pub without_odom: u64,
    without_odom_reported: u64,
    refused_reported: String,
    next_path: Instant,
    next_diagnostics: Instant,
    /// Samples dropped because they made no sense (counted, warned once a period).
    pub refused: u64,
}

impl Outputs {
    /// The publishers on `node` that `cfg` asks for, with state kept in `run_dir` across restarts.
    pub fn new(node: &mut RosNode, cfg: &BridgeConfig, run_dir: &Path) -> Result<Self> {
        let state: State = std::fs::read_to_string(run_dir.join(STATE_FILE))
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok())
            .unwrap_or_default();
        let (path_poses, keyframe_poses) = load_path(&run_dir.join(PATH_FILE));
        let path_file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(run_dir.join(PATH_FILE))
            .with_context(|| format!("cannot open {}", run_dir.join(PATH_FILE).display()))?;
        let mut publisher =
            |topic: &str, ty, durability, depth, priority| -> Result<RosPublisher> {
                let mut p = node.publisher(topic, ty, durability, depth, priority)?;
                // The record is written before a frame's messages go out and
                // after the period's: a bridge killed in between may have sent
                // one more on a topic than it says, so the numbers go on one
                // further (a gap, never a number twice).
                p.sequence_number = state.sequence_numbers.get(&p.topic).map_or(0, |n| n + 1);
                Ok(p)
            };
        let volatile = Durability::Volatile;
        // Poses first: a robot's controller waits on them; images last.
        let (high, normal, low) = (Priority::DataHigh, Priority::Data, Priority::DataLow);
        let odometry = publisher(&cfg.odometry_topic, msgs::ODOMETRY, volatile, 10, high)?;
        let tf = publisher(&cfg.tf_topic, msgs::TF_MESSAGE, volatile, 100, high)?;
        let tf_static = publisher(
            &cfg.tf_static_topic,
            msgs::TF_MESSAGE,
            Durability::TransientLocal,
            1,
            high,
        )?;
        let path = publisher(&cfg.path_topic, msgs::PATH, volatile, 1, normal)?;
        let keyframes = publisher(&cfg.keyframes_topic, msgs::POSE_ARRAY, volatile, 1, normal)?;
        let slam_state = publisher(&cfg.state_topic, msgs::STRING, volatile, 10, high)?;
        let diagnostics = publisher(
            &cfg.diagnostics_topic,
            msgs::DIAGNOSTIC_ARRAY,
            volatile,
            10,
            normal,
        )?;
        let masks = if cfg.mask_image {
            Some((
                publisher(&cfg.mask_topic, msgs::IMAGE, volatile, 1, low)?,
                Vec::new(),
            ))
        } else {
            None
        };
        // The map's topics are latched in ROS (transient local): a viewer
        // or Nav2 opened later gets the last one.
        let latched = Durability::TransientLocal;
        let map_cloud = cfg
            .map_cloud
            .then(|| publisher(&cfg.map_cloud_topic, msgs::POINT_CLOUD2, latched, 1, low))
            .transpose()?;
        let grid = cfg
            .grid
            .then(|| publisher(&cfg.grid_topic, msgs::OCCUPANCY_GRID, latched, 1, low))
            .transpose()?
            .map(|p| {
                let params = GridParams {
                    resolution: cfg.grid_resolution,
                    min_height: cfg.grid_min_height,
                    max_height: cfg.grid_max_height,
                    min_points: cfg.grid_min_points,
                    max_side: GRID_MAX_SIDE,
                };
                (p, params)
            });
        let frames = Frames::new(
            &cfg.world_frame,
            frames::mounting(cfg.camera_xyz, cfg.camera_rpy),
        );
        let node_name = crate::rmw::resolve(&cfg.namespace, &cfg.node_name);
        let now = Instant::now();
        let mut out = Self {
            cfg: cfg.clone(),
            run_dir: run_dir.to_path_buf(),
            frames,
            state,
            node_name,
            odometry,
            tf,
            tf_static,
            path,
            keyframes,
            slam_state,
            diagnostics,
            masks,
            map_cloud,
            grid,
            path_poses,
            keyframe_poses,
            path_file,
            last_tracked: None,
            current_state: None,
            last_track: None,
            window: Window::default(),
            path_dirty: false,
            odom: (!cfg.odom_frame.is_empty())
                .then(|| OdomBuffer::new(&cfg.odom_frame, &cfg.base_frame)),
            without_odom: 0,
            without_odom_reported: 0,
            refused_reported: "0".into(),
            next_path: now,
            next_diagnostics: now,
            refused: 0,
        };
        out.publish_static()?;
        Ok(out)
    }

    fn header(&self, stamp: Time, frame: &str) -> Header {
        Header {
            stamp,
            frame_id: frame.to_string(),
        }
    }

    /// base -> camera (the mounting), on the transient-local topic (a late
    /// subscriber gets it from the publisher's cache); sent again every
    /// diagnostics period too, for subscribers that do not ask the cache
    /// (a volatile subscription, a bridge to DDS).
    fn publish_static(&mut self) -> Result<()> {
        let stamp = self.path_poses.first().map(|(t, _)| *t).unwrap_or_default();
        let t = TransformStamped {
            header: self.header(stamp, &self.cfg.base_frame),
            child_frame_id: self.cfg.camera_frame.clone(),
            transform: frames::to_ros(&self.frames.base_t_camera),
        };
        self.tf_static.publish(msgs::tf_message(&[t]))
    }

    /// One of the SLAM's answers. Poses the bridge handled before (the
    /// stream's history after a restart) are skipped.
    pub fn on_pose(&mut self, p: &Pose) -> Result<()> {
        if self.state.last_seq.is_some_and(|s| p.seq <= s) {
            return Ok(());
        }
        let Some(state) = TrackState::from_u32(p.state) else {
            self.refused += 1;
            return Ok(());
        };
        // Recorded before anything goes out: a bridge killed while
        // publishing this frame leaves it out, never sends it twice.
        self.state.last_seq = Some(p.seq);
        self.save_state()?;
        self.window.answered += 1;
        self.window.first_seq.get_or_insert(p.seq);
        self.window.last_seq = Some(p.seq);
        if self.current_state != Some(state) {
            self.current_state = Some(state);
            self.slam_state.publish(msgs::string(state.as_str()))?;
        }
        if state.is_tracked() {
            match frames::from_tum(&p.pose) {
                Some(world_t_camera) => {
                    self.window.tracked += 1;
                    self.publish_pose(p, state, &world_t_camera)?;
                }
                None => self.refused += 1,
            }
        } else {
            self.last_tracked = None;
        }
        Ok(())
    }

    fn publish_pose(
        &mut self,
        p: &Pose,
        state: TrackState,
        world_t_camera: &Isometry3<f64>,
    ) -> Result<()> {
        let stamp = Time::from_secs(p.timestamp);
        let map_t_base = self.frames.map_t_base(world_t_camera);
        let pose = frames::to_ros(&map_t_base);
        let (linear, angular, twist_var) = match &self.last_tracked {
            Some((t0, before)) if p.timestamp - t0 > 1e-6 && p.timestamp - t0 < MAX_TWIST_GAP_S => {
                let (v, w) = frames::twist(before, &map_t_base, p.timestamp - t0);
                (v, w, TRACKED_VARIANCE)
            }
            _ => ([0.0; 3], [0.0; 3], UNKNOWN_VARIANCE),
        };
        self.last_tracked = Some((p.timestamp, map_t_base));
        // A turning frame's position is held, not measured.
        let variance = if matches!(state, TrackState::Relocalised | TrackState::Turning) {
            RELOCALISED_VARIANCE
        } else {
            TRACKED_VARIANCE
        };
        let odometry = Odometry {
            header: self.header(stamp, &self.cfg.map_frame),
            child_frame_id: self.cfg.base_frame.clone(),
            pose,
            pose_covariance: diagonal(variance),
            linear,
            angular,
            twist_covariance: diagonal(twist_var),
        };
        self.odometry.publish(msgs::odometry(&odometry))?;
        // REP-105: with the robot's own odometry, the SLAM's transform is
        // the drift correction map -> odom; else map -> base.
        let tf = match &self.odom {
            None => Some((self.cfg.base_frame.clone(), pose)),
            Some(odom) => match odom.at(stamp) {
                Some(odom_t_base) => Some((
                    self.cfg.odom_frame.clone(),
                    frames::to_ros(&(map_t_base * odom_t_base.inverse())),
                )),
                None => {
                    self.without_odom += 1;
                    None
                }
            },
        };
        if let Some((child_frame_id, transform)) = tf {
            let tf = TransformStamped {
                header: self.header(stamp, &self.cfg.map_frame),
                child_frame_id,
                transform,
            };
            self.tf.publish(msgs::tf_message(&[tf]))?;
        }
        let keyframe = p.keyframe != 0;
        writeln!(
            self.path_file,
            "{} {:.9} {} {} {} {} {} {} {} {}",
            p.seq,
            stamp.as_secs(),
            pose.position[0],
            pose.position[1],
            pose.position[2],
            pose.orientation[0],
            pose.orientation[1],
            pose.orientation[2],
            pose.orientation[3],
            keyframe as u8
        )
        .with_context(|| format!("cannot append to {PATH_FILE}"))?;
        self.path_poses.push((stamp, pose));
        self.path_dirty = true;
        if keyframe {
            self.keyframe_poses.push(pose);
            let h = self.header(stamp, &self.cfg.map_frame);
            self.keyframes
                .publish(msgs::pose_array(&h, &self.keyframe_poses))?;
        }
        Ok(())
    }

    /// A map snapshot from the SLAM: the keyframes as the map holds them
    /// now (moved by bundle adjustment and closed loops, culled ones gone),
    /// the point cloud and the occupancy grid.
    pub fn on_map(&mut self, h: &MapHeader, payload: &[u8]) -> Result<()> {
        let view = match MapView::new(h, payload) {
            Ok(v) => v,
            Err(e) => {
                self.refused += 1;
                tracing::warn!("map snapshot dropped: {e:#}");
                return Ok(());
            }
        };
        let Some(cameras) = view
            .keyframes()
            .map(|k| frames::from_tum(&k))
            .collect::<Option<Vec<_>>>()
        else {
            self.refused += 1;
            tracing::warn!(
                "map snapshot {} dropped: a keyframe pose is not a pose",
                h.version
            );
            return Ok(());
        };
        let header = self.header(Time::from_secs(h.stamp), &self.cfg.map_frame);
        self.keyframe_poses = cameras
            .iter()
            .map(|c| frames::to_ros(&self.frames.map_t_base(c)))
            .collect();
        self.keyframes
            .publish(msgs::pose_array(&header, &self.keyframe_poses))?;
        if self.map_cloud.is_none() && self.grid.is_none() {
            return Ok(());
        }
        let map_t_world = self.frames.map_t_world.cast::<f32>();
        let points: Vec<(CloudPoint, usize)> = view
            .points()
            .map(|p| {
                let q = map_t_world * nalgebra::Point3::from(p.position);
                let point = CloudPoint {
                    position: [q.x, q.y, q.z],
                    rgb: p.colour,
                };
                (point, p.keyframe as usize)
            })
            .collect();
        if let Some(cloud) = &mut self.map_cloud {
            let cloud_points: Vec<CloudPoint> = points.iter().map(|(p, _)| *p).collect();
            cloud.publish(msgs::point_cloud2(&header, &cloud_points))?;
        }
        if let Some((publisher, params)) = &mut self.grid {
            let viewpoints: Vec<[f64; 3]> = cameras
                .iter()
                .map(|c| {
                    let t = (self.frames.map_t_world * c).translation;
                    [t.x, t.y, t.z]
                })
                .collect();
            let cells: Vec<([f64; 3], usize)> = points
                .iter()
                .map(|(p, k)| (p.position.map(f64::from), *k))
                .collect();
            if let Some(g) = grid::project(&cells, &viewpoints, params) {
                let origin = RosPose {
                    position: [g.origin[0], g.origin[1], 0.0],
                    orientation: [0.0, 0.0, 0.0, 1.0],
                };
                publisher.publish(msgs::occupancy_grid(&msgs::Grid {
                    header,
                    resolution: params.resolution as f32,
                    width: g.width as u32,
                    height: g.height as u32,
                    origin,
                    cells: &g.cells,
                }))?;
            }
        }
        Ok(())
    }

    /// A sample on the tf topic (only with `odom_frame`).
    pub fn on_tf_sample(&mut self, dds_type: &str, payload: &[u8]) {
        if let Some(odom) = &mut self.odom {
            odom.on_sample(dds_type, payload);
        }
    }

    /// Samples dropped from the network, by reason, in words.
    fn refused_messages(&self) -> String {
        let Some(odom) = &self.odom else {
            return "0".into();
        };
        let total: u64 = odom.refused.values().sum();
        if total == 0 {
            return "0".into();
        }
        let why: Vec<String> = odom
            .refused
            .iter()
            .map(|(r, n)| format!("{n} {}", r.as_str()))
            .collect();
        format!("{total} ({})", why.join(", "))
    }

    /// A set of masks (only with `mask_image`): kept until the SLAM says
    /// which masks it tracked the frame with.
    pub fn on_masks(&mut self, h: &MasksHeader, labels: &[u8]) {
        let Some((_, pending)) = &mut self.masks else {
            return;
        };
        let len = h.width as usize * h.height as usize;
        if h.has(mask_flags::GONE) || h.has(mask_flags::FAILED) || labels.len() < len || len == 0 {
            return;
        }
        pending.push(PendingMasks {
            seq: h.seq,
            source: h.source,
            width: h.width,
            height: h.height,
            labels: labels[..len].to_vec(),
        });
        // A frame has at most a segmenter's and a propagator's masks; a few
        // frames' worth waits for the SLAM.
        if pending.len() > 8 {
            pending.remove(0);
        }
    }

    /// Whether frame `t` was tracked with masks that have not come here
    /// yet: the caller reads more masks first. Masks are published before
    /// the Track that used them, but the bridge reads the two services one
    /// after the other, so a Track read just now may follow masks that came
    /// after the masks were read (under load a mask image went missing so).
    pub fn awaits_masks_for(&self, t: &Track) -> bool {
        self.masks
            .as_ref()
            .is_some_and(|(_, pending)| tracked_with_masks(t) && masks_used(pending, t).is_none())
    }

    /// The masks the SLAM tracked frame `t` with, as a mono8 image.
    fn publish_masks(&mut self, t: &Track) -> Result<()> {
        let stamp = Time::from_secs(t.source_timestamp);
        let frame = self.cfg.camera_frame.clone();
        let Some((publisher, pending)) = &mut self.masks else {
            return Ok(());
        };
        let result = match masks_used(pending, t) {
            Some(i) if tracked_with_masks(t) => {
                let m = &pending[i];
                let header = Header {
                    stamp,
                    frame_id: frame,
                };
                publisher.publish(msgs::mono8_image(&header, m.width, m.height, &m.labels))
            }
            _ => Ok(()),
        };
        pending.retain(|m| m.seq > t.seq);
        result
    }

    /// A Track: its latency and counts for the diagnostics.
    pub fn on_track(&mut self, t: &Track) -> Result<()> {
        self.publish_masks(t)?;
        let s = t.stamps;
        if s.capture_ns > 0 && s.track_done_ns > s.capture_ns {
            self.window
                .latencies_ms
                .push((s.track_done_ns - s.capture_ns) as f64 / 1e6);
        }
        self.last_track = Some(*t);
        Ok(())
    }

    /// Periodic work: the path, the diagnostics, the state and tf_static
    /// again for late subscribers.
    pub fn tick(&mut self, now: Instant) -> Result<()> {
        if now >= self.next_path {
            self.next_path = now + Duration::from_secs_f64(self.cfg.path_period_s);
            self.publish_path()?;
        }
        if now >= self.next_diagnostics {
            let period = self.cfg.diagnostics_period_s;
            self.next_diagnostics = now + Duration::from_secs_f64(period);
            let status = self.diagnostic_status(period);
            let h = self.header(wall_time(), "");
            self.diagnostics
                .publish(msgs::diagnostic_array(&h, &status))?;
            if let Some(state) = self.current_state {
                self.slam_state.publish(msgs::string(state.as_str()))?;
            }
            self.publish_static()?;
            if self.refused > 0 {
                tracing::warn!(
                    refused = self.refused,
                    "poses without a usable state or rotation were not published"
                );
            }
            let refused = self.refused_messages();
            if refused != "0" && refused != self.refused_reported {
                tracing::warn!("samples on {} dropped so far: {refused}", self.tf.topic);
                self.refused_reported = refused;
            }
            if self.without_odom > self.without_odom_reported {
                tracing::warn!(
                    "{} tracked frames had no {} -> {} on {} at their capture time: no {} -> {} published for them",
                    self.without_odom,
                    self.cfg.odom_frame,
                    self.cfg.base_frame,
                    self.tf.topic,
                    self.cfg.map_frame,
                    self.cfg.odom_frame
                );
                self.without_odom_reported = self.without_odom;
            }
            self.window = Window::default();
            self.save_state()?;
        }
        Ok(())
    }

    fn publish_path(&mut self) -> Result<()> {
        if !self.path_dirty {
            return Ok(());
        }
        self.path_dirty = false;
        let stamp = self.path_poses.last().map(|(t, _)| *t).unwrap_or_default();
        let h = self.header(stamp, &self.cfg.map_frame);
        self.path.publish(msgs::path(&h, &self.path_poses))
    }

    /// The end of the run: the path as it ends, the record saved.
    pub fn finish(&mut self) -> Result<()> {
        self.publish_path()?;
        self.save_state()
    }

    fn diagnostic_status(&self, period: f64) -> Vec<DiagnosticStatus> {
        let w = &self.window;
        let frames_seen = match (w.first_seq, w.last_seq) {
            (Some(a), Some(b)) => b - a + 1,
            _ => 0,
        };
        let dropped = frames_seen.saturating_sub(w.answered);
        let mut latencies = w.latencies_ms.clone();
        latencies.sort_by(f64::total_cmp);
        let p99 = latencies
            .get(((latencies.len() as f64 * 0.99).ceil() as usize).saturating_sub(1))
            .copied();
        let state = self.current_state;
        let (lvl, message) = match state {
            Some(s) if s.is_tracked() => (level::OK, s.as_str()),
            Some(s) => (level::WARN, s.as_str()),
            None => (level::STALE, "no frame answered yet"),
        };
        let counts = self.last_track.map(|t| t.counts).unwrap_or_default();
        let mut out = vec![DiagnosticStatus {
            level: lvl,
            name: format!("{}: slam", self.node_name),
            message: message.into(),
            hardware_id: String::new(),
            values: vec![
                ("state".into(), message.into()),
                (
                    "tracked_fps".into(),
                    format!("{:.1}", w.tracked as f64 / period),
                ),
                (
                    "dropped_fps".into(),
                    format!("{:.1}", dropped as f64 / period),
                ),
                (
                    "end_to_end_p99_ms".into(),
                    p99.map_or("n/a".into(), |v| format!("{v:.1}")),
                ),
                ("keyframes".into(), counts.keyframes.to_string()),
                ("map_points".into(), counts.map_points.to_string()),
                ("inliers".into(), counts.inliers.to_string()),
                ("refused_messages".into(), self.refused_messages()),
                ("frames_without_odom".into(), self.without_odom.to_string()),
            ],
        }];
        out.extend(self.service_status());
        out
    }

    /// Each service as the supervisor's `status.json` has it.
    fn service_status(&self) -> Vec<DiagnosticStatus> {
        let Some(status) = std::fs::read_to_string(self.run_dir.join("status.json"))
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        else {
            return Vec::new();
        };
        let children = status["children"].as_array().cloned().unwrap_or_default();
        children
            .iter()
            .filter_map(|c| {
                let service = c["service"].as_str()?;
                let state = c["state"].as_str().unwrap_or("unknown");
                let restarts = c["restarts"].as_u64().unwrap_or(0);
                let lvl = match state {
                    "ready" | "external" | "stopped" => level::OK,
                    "failed" => level::ERROR,
                    _ => level::WARN,
                };
                Some(DiagnosticStatus {
                    level: lvl,
                    name: format!("{}: {service}", self.node_name),
                    message: state.to_string(),
                    hardware_id: String::new(),
                    values: vec![
                        ("up".into(), (state == "ready").to_string()),
                        ("restarts".into(), restarts.to_string()),
                        (
                            "pid".into(),
                            c["pid"].as_u64().map_or("-".into(), |p| p.to_string()),
                        ),
                    ],
                })
            })
            .collect()
    }

    fn save_state(&mut self) -> Result<()> {
        for p in [
            &self.odometry,
            &self.tf,
            &self.tf_static,
            &self.path,
            &self.keyframes,
            &self.slam_state,
            &self.diagnostics,
        ]
        .into_iter()
        .chain(self.masks.as_ref().map(|(p, _)| p))
        {
            self.state
                .sequence_numbers
                .insert(p.topic.clone(), p.sequence_number);
        }
        let path = self.run_dir.join(STATE_FILE);
        let tmp = self.run_dir.join(format!("{STATE_FILE}.tmp"));
        let text = serde_json::to_string(&self.state)?;
        std::fs::write(&tmp, text)
            .and_then(|_| std::fs::rename(&tmp, &path))
            .with_context(|| format!("cannot write {}", path.display()))
    }
}

/// Now, as ROS time (diagnostics are stamped when they are made).
fn wall_time() -> Time {
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default();
    Time::from_secs(now.as_secs_f64())
}

/// The path a previous bridge of this run published (lines it cannot read
/// are left out: a line cut by a kill).
fn load_path(file: &Path) -> (Vec<(Time, RosPose)>, Vec<RosPose>) {
    let mut path = Vec::new();
    let mut keyframes = Vec::new();
    let text = std::fs::read_to_string(file).unwrap_or_default();
    for line in text.lines() {
        let v: Vec<f64> = line
            .split_whitespace()
            .filter_map(|x| x.parse().ok())
            .collect();
        if v.len() != 10 {
            continue;
        }
        let pose = RosPose {
            position: [v[2], v[3], v[4]],
            orientation: [v[5], v[6], v[7], v[8]],
        };
        path.push((Time::from_secs(v[1]), pose));
        if v[9] != 0.0 {
            keyframes.push(pose);
        }
    }
    (path, keyframes)
}
