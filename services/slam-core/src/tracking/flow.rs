//! Frames between keyframes tracked without ORB extraction (NGD-SLAM's
//! hybrid tracking): the last tracked frame's inliers are followed into the
//! new frame with pyramidal Lucas-Kanade ([`crate::flow::lk`]), each from
//! where the motion model moves it (with its depth), and the pose is
//! optimised against their map points as after search by projection. A
//! frame tracked so keeps the descriptors of its map points (it never
//! becomes a keyframe) and is not given to the motion check; the next
//! full extraction (a keyframe due, too few points followed, or
//! `SlamParams::flow_frames` in a row) starts afresh from the local map.

use std::sync::Arc;

use nalgebra::Point3;

use super::{Tracked, Tracking, TrackingState};
use crate::features::orb::{Descriptor, KeyPoint};
use crate::flow::lk::{track_each, LkParams};
use crate::flow::pyramid::Pyramid;
use crate::frame::{Detected, Frame};
use crate::map::Map;
use crate::optimizer::pose::{is_finite_pose, optimize_pose};

/// A frame tracked by flow keeps at least this share of the reference
/// keyframe's inliers (or, while a keyframe waits for its masks, of that
/// keyframe's), else it is extracted in full: above the keyframe rule's
/// 0.75 so that the rule always sees a fully extracted frame.
const KEEP_OF_REFERENCE: f64 = 0.8;

/// Lucas-Kanade as flow tracking runs it: a 9x9 window (ORB keypoints are
/// corners: textured by construction), few iterations from a guess that is
/// within a pixel or two.
const LK: LkParams = LkParams {
    radius: 4,
    iterations: 6,
    epsilon: 0.03,
    min_eigen: 1e-2,
    finest_level: 0,
};

/// The last tracked frame, as the next frame's flow tracking needs it.
pub(crate) struct FlowSource {
    pyramid: Arc<Pyramid>,
    /// Its inliers: keypoint (raw pixels, level, angle), undistorted pixel,
    /// depth, descriptor and map point.
    kps: Vec<KeyPoint>,
    un: Vec<(f64, f64)>,
    depth: Vec<Option<f64>>,
    descs: Vec<Descriptor>,
    points: Vec<usize>,
    /// Frames tracked by flow in a row up to it.
    run: u32,
}

impl Tracking {
    /// Remembers a tracked `frame` (with its pyramid) and its inliers for
    /// the next frame's flow tracking; `by_flow`: it was itself tracked so.
    pub(crate) fn remember_flow(
        &mut self,
        frame: &Frame,
        matched: &[Option<usize>],
        by_flow: bool,
    ) {
        let run = match (&self.flow, by_flow) {
            (Some(last), true) => last.run + 1,
            _ => 0,
        };
        self.flow = frame.pyramid.clone().map(|pyramid| {
            let inliers: Vec<(usize, usize)> = matched
                .iter()
                .enumerate()
                .filter_map(|(k, m)| m.map(|p| (k, p)))
                .collect();
            FlowSource {
                pyramid,
                kps: inliers.iter().map(|&(k, _)| frame.kps[k]).collect(),
                un: inliers.iter().map(|&(k, _)| frame.un[k]).collect(),
                depth: inliers.iter().map(|&(k, _)| frame.depth[k]).collect(),
                descs: inliers.iter().map(|&(k, _)| frame.descs[k]).collect(),
                points: inliers.iter().map(|&(_, p)| p).collect(),
                run,
            }
        });
    }

    /// Whether the frame at `timestamp` may be tracked by flow: on, a
    /// source to follow, the run not yet at its limit, tracking not lost and
    /// no keyframe due (the rule must see the frame's own keypoints).
    pub(crate) fn may_follow(&self, timestamp: f64) -> bool {
        let limit = self.params.flow_frames;
        self.params.flow_on()
            && !self.lost
            && !self.keyframe_due()
            && self.last_pose.is_some()
            && self.last_timestamp().is_some_and(|t| timestamp > t)
            && self
                .flow
                .as_ref()
                .is_some_and(|f| f.run < limit && !f.points.is_empty())
    }

    /// The last frame's inliers followed into the frame at `timestamp`
    /// whose pyramid is `next`, where `keep` (the dynamic mask) allows: the
    /// keypoints (with the descriptors they had), and the map point of
    /// each. None when there is nothing to follow. It reads no map: it runs
    /// while local mapping has it.
    pub(crate) fn follow(
        &self,
        next: &Pyramid,
        keep: &(dyn Fn(f32, f32) -> bool + Sync),
        timestamp: f64,
    ) -> Option<(Detected, Vec<usize>)> {
        let source = self.flow.as_ref()?;
        let last = self.last_pose?;
        // Each point starts from where the motion model moves it: with its
        // depth as a 3D point, without as a bearing (the displacement of
        // the undistorted pixel; distortion changes it by a fraction of a
        // pixel).
        let step = self.predicted(&last, timestamp) * last.inverse();
        let guesses: Vec<(f32, f32)> = source
            .un
            .iter()
            .zip(&source.depth)
            .map(|(&(u, v), d)| {
                let seen = match d {
                    Some(z) => step * Point3::from(self.camera.unproject(u, v, *z)),
                    None => Point3::from(step.rotation * self.camera.unproject(u, v, 1.0)),
                };
                if seen.z <= 1e-6 {
                    return (0.0, 0.0);
                }
                let (pu, pv) = self.camera.project(&seen.coords);
                ((pu - u) as f32, (pv - v) as f32)
            })
            .collect();
        let from: Vec<(f32, f32)> = source.kps.iter().map(|k| (k.x, k.y)).collect();
        let followed = track_each(&source.pyramid, next, &from, &guesses, LK);
        let mut detected = Detected {
            kps: Vec::with_capacity(followed.len()),
            descs: Vec::with_capacity(followed.len()),
            masked: 0,
        };
        let mut points = Vec::with_capacity(followed.len());
        for (i, to) in followed.iter().enumerate() {
            let Some((x, y)) = *to else {
                continue;
            };
            if !keep(x, y) {
                detected.masked += 1;
                continue;
            }
            detected.kps.push(KeyPoint {
                x,
                y,
                ..source.kps[i]
            });
            detected.descs.push(source.descs[i]);
            points.push(source.points[i]);
        }
        Some((detected, points))
    }

    /// Tracks a frame whose keypoints were followed by flow (`points`: the
    /// map point of each): the pose optimised from the motion model's
    /// prediction against them. None when fewer than [`KEEP_OF_REFERENCE`]
    /// of `reference` inliers hold (the frame is then extracted in full).
    pub(crate) fn track_followed(
        &self,
        map: &Map,
        frame: &Frame,
        (points, reference): (&[usize], usize),
        timestamp: f64,
    ) -> Option<Tracked> {
        let needed = (KEEP_OF_REFERENCE * reference as f64).max(self.params.min_inliers as f64);
        if (points.len() as f64) < needed {
            return None;
        }
        let predicted = self.predicted(&self.last_pose?, timestamp);
        // Local mapping may have culled some meanwhile.
        let pairs: Vec<(usize, usize)> = points
            .iter()
            .copied()
            .enumerate()
            .filter(|&(_, p)| map.points.get(p).is_some_and(|p| p.is_live()))
            .collect();
        let obs = self.observations(map, frame, &pairs);
        let (pose_cw, inlier) = optimize_pose(&self.camera, &predicted, &obs);
        let inliers = inlier.iter().filter(|&&b| b).count();
        if (inliers as f64) < needed || !is_finite_pose(&pose_cw) {
            return None;
        }
        let mut matched = vec![None; points.len()];
        for (&(k, p), &ok) in pairs.iter().zip(&inlier) {
            if ok {
                matched[k] = Some(p);
            }
        }
        Some(Tracked {
            state: TrackingState::Ok,
            pose_cw,
            inliers,
            matched,
        })
    }
}
