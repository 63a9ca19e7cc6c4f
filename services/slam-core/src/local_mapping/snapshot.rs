//! Map snapshots for whoever shows the map outside (the ROS 2 bridge's point
//! cloud, keyframe poses and occupancy grid). Like a checkpoint copy, a
//! snapshot is taken by local mapping once a keyframe is mapped (on its
//! thread, off the frame path), and only when asked: at most one per
//! period, and after every keyframe whose mapping merged a closed loop (the
//! loop moved keyframes and points, and whoever shows them must know). A
//! snapshot waits in a one-snapshot slot; a newer one replaces it.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use nalgebra::{Isometry3, Vector3};

use crate::map::Map;

/// The map as local mapping left it.
#[derive(Debug, Clone, Default)]
pub struct MapSnapshot {
    /// The newest keyframe's id.
    pub newest_keyframe: usize,
    /// World-from-camera poses of the live keyframes, in id order.
    pub keyframes: Vec<Isometry3<f64>>,
    /// The live map points.
    pub points: Vec<SnapshotPoint>,
}

/// One map point of a snapshot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SnapshotPoint {
    /// Position (world frame).
    pub position: Vector3<f64>,
    /// RGB colour.
    pub colour: [u8; 3],
    /// The first live keyframe that observed it (an index into
    /// `keyframes`): where it was seen from, for free-space rays.
    pub keyframe: u32,
}

impl MapSnapshot {
    /// The live keyframes and points of `map`; a point no live keyframe
    /// observes is left out.
    pub fn of(map: &Map, newest_keyframe: usize) -> Self {
        let mut index = HashMap::new();
        let keyframes = map
            .live_keyframes()
            .enumerate()
            .map(|(i, (id, k))| {
                index.insert(id, i as u32);
                k.pose_cw.inverse()
            })
            .collect();
        let points = map
            .live_points()
            .filter_map(|(_, p)| {
                let keyframe = p.observers.iter().find_map(|o| index.get(o).copied())?;
                Some(SnapshotPoint {
                    position: p.position,
                    colour: p.colour,
                    keyframe,
                })
            })
            .collect();
        Self {
            newest_keyframe,
            keyframes,
            points,
        }
    }
}

/// Where local mapping leaves the newest snapshot.
#[derive(Debug, Clone, Default)]
pub struct SnapshotSlot {
    slot: Arc<Mutex<Option<MapSnapshot>>>,
}

impl SnapshotSlot {
    /// Leaves `snapshot` for the reader, replacing one not taken yet.
    pub fn offer(&self, snapshot: MapSnapshot) {
        if let Ok(mut slot) = self.slot.lock() {
            *slot = Some(snapshot);
        }
    }

    /// The newest snapshot, if one was left since the last take.
    pub fn take(&self) -> Option<MapSnapshot> {
        self.slot.lock().ok()?.take()
    }
}

/// What local mapping is asked for with a keyframe.
#[derive(Debug, Clone)]
pub struct SnapshotRequest {
    /// Where the snapshot goes.
    pub slot: SnapshotSlot,
    /// The period is over: a snapshot now. Otherwise one only if this
    /// keyframe's mapping merged a closed loop.
    pub due: bool,
}

impl SnapshotRequest {
    /// Leaves a snapshot of `map` (just mapped for `keyframe`) in the slot
    /// when it is due or a loop closed.
    pub fn fulfil(&self, map: &Map, keyframe: usize, report: &crate::map::MappingReport) {
        let loop_closed = report.loops.iter().any(|r| r.closed.is_some());
        if self.due || loop_closed {
            self.slot.offer(MapSnapshot::of(map, keyframe));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::{KeyFrame, KeyFrameObservation, MapPoint, MappingReport};

    const M: KeyFrameObservation = KeyFrameObservation {
        u: 1.0,
        v: 1.0,
        ur: None,
        info: 1.0,
        descriptor: [0; 4],
        angle: 0.0,
    };

    fn keyframe(x: f64, points: &[usize], culled: bool) -> KeyFrame {
        KeyFrame {
            pose_cw: Isometry3::translation(x, 0.0, 0.0),
            points: points.to_vec(),
            measurements: points.iter().map(|_| M).collect(),
            spare: Vec::new(),
            bounds: (0.0, 640.0, 0.0, 480.0),
            covisible: Vec::new(),
            parent: None,
            loops: Vec::new(),
            culled,
        }
    }

    #[test]
    fn a_snapshot_holds_the_live_map_and_comes_when_asked() {
        let mut map = Map::default();
        for i in 0..3 {
            let mut p = MapPoint::new(Vector3::new(i as f64, 0.0, 2.0), 0, &M, 2.0, [i; 3]);
            p.observers.clear();
            map.add_point(p);
        }
        // Keyframe 0 is culled; 1 sees points 0 and 1; point 2 is seen by
        // the culled one only.
        map.add_keyframe(keyframe(5.0, &[2], true));
        map.add_keyframe(keyframe(1.0, &[0, 1], false));
        let slot = SnapshotSlot::default();
        let request = SnapshotRequest {
            slot: slot.clone(),
            due: false,
        };
        request.fulfil(&map, 1, &MappingReport::default());
        assert!(slot.take().is_none(), "not due and no loop: nothing");
        let due = SnapshotRequest {
            due: true,
            ..request
        };
        due.fulfil(&map, 1, &MappingReport::default());
        let s = slot.take().unwrap();
        assert_eq!(s.newest_keyframe, 1);
        assert_eq!(s.keyframes.len(), 1);
        assert!((s.keyframes[0].translation.vector.x + 1.0).abs() < 1e-12);
        assert_eq!(s.points.len(), 2);
        assert!(s.points.iter().all(|p| p.keyframe == 0));
        assert_eq!(s.points[1].colour, [1; 3]);
        assert!(slot.take().is_none(), "taken once");
        // A closed loop moved the map: a snapshot though the period is not
        // over (whoever shows the keyframes must redraw them).
        let looped = MappingReport {
            loops: vec![crate::loop_closing::LoopReport {
                keyframe: 1,
                closed: Some(crate::loop_closing::LoopClosure {
                    keyframe: 1,
                    matched: 0,
                    inliers: 50,
                    confirmed: 3,
                    correction_m: 0.1,
                    correction_deg: 1.0,
                    fused: 10,
                    keyframes_moved: 1,
                    scale: 1.0,
                }),
                ..Default::default()
            }],
            ..MappingReport::default()
        };
        SnapshotRequest { due: false, ..due }.fulfil(&map, 1, &looped);
        assert_eq!(slot.take().map(|s| s.keyframes.len()), Some(1));
    }
}
