//! The robot's own odometry frame (REP-105): when the robot publishes
//! `odom -> base_link` on `/tf`, the SLAM owns `map -> odom`, the correction
//! of the robot's drift, as slam_toolbox and rtabmap_ros do. The bridge
//! listens to `/tf`, keeps the robot's `odom -> base_link` by stamp and
//! looks it up at each frame's capture time.
//!
//! `/tf` is the network's: a sample on it that is not a readable
//! `tf2_msgs/TFMessage` is dropped and counted, never trusted.

use std::collections::BTreeMap;

use nalgebra::{Isometry3, Translation3, UnitQuaternion};

use crate::msgs::{self, Time};

/// How much history is kept (seconds before the newest stamp).
const KEEP_S: f64 = 10.0;
/// A frame newer than the newest odometry by at most this much uses the
/// newest (the robot's TF lags the camera by a few ms); older than the
/// oldest kept, or further ahead, has none.
const EXTRAPOLATE_S: f64 = 0.1;
/// At most this many transforms are kept (a flood of distinct stamps).
const MAX_ENTRIES: usize = 20_000;

fn ns(t: Time) -> i64 {
    t.sec as i64 * 1_000_000_000 + t.nanosec as i64
}

/// Why a sample on `/tf` was dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Refused {
    /// Its key names another type than `tf2_msgs/msg/TFMessage`.
    WrongType,
    /// Its CDR could not be read (truncated, hostile lengths, bad text).
    Unreadable,
    /// A transform whose numbers are not a rigid motion.
    NotATransform,
}

impl Refused {
    /// The reason as a word, for logs and counts.
    pub fn as_str(self) -> &'static str {
        match self {
            Refused::WrongType => "wrong type",
            Refused::Unreadable => "unreadable CDR",
            Refused::NotATransform => "not a rigid transform",
        }
    }
}

/// `odom -> base` by stamp.
#[derive(Debug)]
pub struct OdomBuffer {
    odom_frame: String,
    base_frame: String,
    by_stamp: BTreeMap<i64, Isometry3<f64>>,
    /// Samples refused, by reason.
    pub refused: BTreeMap<Refused, u64>,
}

impl OdomBuffer {
    /// A buffer for `odom_frame` -> `base_frame` transforms.
    pub fn new(odom_frame: &str, base_frame: &str) -> Self {
        Self {
            odom_frame: odom_frame.to_string(),
            base_frame: base_frame.to_string(),
            by_stamp: BTreeMap::new(),
            refused: BTreeMap::new(),
        }
    }

    fn refuse(&mut self, why: Refused) {
        *self.refused.entry(why).or_default() += 1;
    }

    /// One sample from the `/tf` key expression: its key's type part and
    /// its payload.
    pub fn on_sample(&mut self, dds_type: &str, payload: &[u8]) {
        if dds_type != msgs::TF_MESSAGE.dds {
            return self.refuse(Refused::WrongType);
        }
        let transforms = match msgs::read_tf_message(payload) {
            Ok(t) => t,
            Err(_) => return self.refuse(Refused::Unreadable),
        };
        for t in transforms {
            if t.header.frame_id != self.odom_frame || t.child_frame_id != self.base_frame {
                continue;
            }
            let p = t.transform;
            let [x, y, z] = p.position;
            let [qx, qy, qz, qw] = p.orientation;
            let q = nalgebra::Quaternion::new(qw, qx, qy, qz);
            let finite = p
                .position
                .iter()
                .chain(&p.orientation)
                .all(|v| v.is_finite());
            if !finite || (q.norm() - 1.0).abs() > 1e-3 {
                self.refuse(Refused::NotATransform);
                continue;
            }
            let iso = Isometry3::from_parts(
                Translation3::new(x, y, z),
                UnitQuaternion::from_quaternion(q),
            );
            self.by_stamp.insert(ns(t.header.stamp), iso);
        }
        self.prune();
    }

    fn prune(&mut self) {
        let Some((&newest, _)) = self.by_stamp.last_key_value() else {
            return;
        };
        let oldest_kept = newest - (KEEP_S * 1e9) as i64;
        self.by_stamp = self.by_stamp.split_off(&oldest_kept);
        while self.by_stamp.len() > MAX_ENTRIES {
            self.by_stamp.pop_first();
        }
    }

    /// `odom -> base` at `stamp`: interpolated between the two around it.
    pub fn at(&self, stamp: Time) -> Option<Isometry3<f64>> {
        let t = ns(stamp);
        let before = self.by_stamp.range(..=t).next_back();
        let after = self.by_stamp.range(t..).next();
        match (before, after) {
            (Some((&t0, a)), Some((&t1, b))) => {
                if t1 == t0 {
                    return Some(*a);
                }
                let s = (t - t0) as f64 / (t1 - t0) as f64;
                let translation = a.translation.vector.lerp(&b.translation.vector, s);
                let rotation = a.rotation.slerp(&b.rotation, s);
                Some(Isometry3::from_parts(translation.into(), rotation))
            }
            (Some((&t0, a)), None) if (t - t0) as f64 <= EXTRAPOLATE_S * 1e9 => Some(*a),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{Header, RosPose, TransformStamped};

    fn tf(sec: i32, x: f64, parent: &str) -> Vec<u8> {
        msgs::tf_message(&[TransformStamped {
            header: Header {
                stamp: Time { sec, nanosec: 0 },
                frame_id: parent.into(),
            },
            child_frame_id: "base_link".into(),
            transform: RosPose {
                position: [x, 0.0, 0.0],
                orientation: [0.0, 0.0, 0.0, 1.0],
            },
        }])
    }

    #[test]
    fn odometry_is_interpolated_at_the_frames_stamp() {
        let mut b = OdomBuffer::new("odom", "base_link");
        let dds = msgs::TF_MESSAGE.dds;
        b.on_sample(dds, &tf(10, 1.0, "odom"));
        b.on_sample(dds, &tf(11, 3.0, "odom"));
        b.on_sample(dds, &tf(12, 9.0, "map")); // another pair of frames
        let at = |sec, nanosec| b.at(Time { sec, nanosec }).map(|i| i.translation.x);
        assert_eq!(at(10, 500_000_000), Some(2.0));
        assert_eq!(at(11, 50_000_000), Some(3.0)); // just after the newest
        assert_eq!(at(11, 500_000_000), None); // too far ahead
        assert_eq!(at(9, 0), None); // before the first
        assert!(b.refused.is_empty());
    }

    #[test]
    fn hostile_samples_are_counted_and_dropped() {
        let mut b = OdomBuffer::new("odom", "base_link");
        let good = tf(10, 1.0, "odom");
        b.on_sample("std_msgs::msg::dds_::String_", &good);
        b.on_sample(msgs::TF_MESSAGE.dds, &good[..good.len() - 3]);
        let mut huge = good.clone();
        huge[4..8].copy_from_slice(&u32::MAX.to_le_bytes());
        b.on_sample(msgs::TF_MESSAGE.dds, &huge);
        let mut nan = good.clone();
        let n = nan.len();
        nan[n - 8..].copy_from_slice(&f64::NAN.to_le_bytes());
        b.on_sample(msgs::TF_MESSAGE.dds, &nan);
        assert_eq!(b.refused[&Refused::WrongType], 1);
        assert_eq!(b.refused[&Refused::Unreadable], 2);
        assert_eq!(b.refused[&Refused::NotATransform], 1);
        assert!(b
            .at(Time {
                sec: 10,
                nanosec: 0
            })
            .is_none());
    }
}
