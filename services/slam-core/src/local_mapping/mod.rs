//! Local mapping (ORB-SLAM2's LocalMapping) after each keyframe: cull
//! points that are rarely found ([`culling`]), triangulate new points with
//! covisible keyframes ([`triangulation`]), optionally fuse duplicate
//! points ([`fusion`]), connect the keyframe in the covisibility graph,
//! optionally bundle-adjust the newest keyframes ([`bundle`]) and cull
//! keyframes whose points others see well enough.
//!
//! It runs on its own thread: after tracking inserts a keyframe it hands
//! the whole map to this thread and gets it back before it tracks the next
//! frame. The next frame's feature extraction, which needs no map, runs
//! meanwhile, so mapping leaves the frame path as long as it is shorter
//! than extraction; tracking waits for the rest. The map moves between the
//! threads (it is never shared), so there are no locks, and a run is as
//! repeatable as with mapping done inline: every keyframe's mapping is
//! finished before the next frame is tracked. A checkpoint copy of the map
//! is taken here too, off the frame path ([`checkpoint`]).

pub mod bundle;
pub mod checkpoint;
pub mod culling;
pub mod fusion;
pub mod snapshot;
pub mod triangulation;

use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::Arc;
use std::thread::JoinHandle;

use crate::camera::Camera;
use crate::loop_closing::thread::LoopClosing;
use crate::map::{Map, MappingReport};
use crate::params::SlamParams;
use crate::place_recognition::Vocabulary;
use checkpoint::CheckpointSender;
use snapshot::SnapshotRequest;

impl Map {
    /// Local mapping after keyframe `id` was inserted (its points and
    /// observations in place), in ORB-SLAM2's order: the keyframe into the
    /// keyframe database (its bag of words from `vocabulary`), recent-point culling,
    /// new points triangulated with its covisible keyframes, duplicate
    /// points fused with theirs (each step as `params` enables it),
    /// covisibility edges and spanning-tree parent, local bundle adjustment
    /// over the newest `params.local_ba_keyframes` keyframes (below 2: off),
    /// and keyframe culling among its neighbours.
    pub fn process_keyframe(
        &mut self,
        id: usize,
        camera: &Camera,
        params: &SlamParams,
        vocabulary: &Vocabulary,
    ) -> MappingReport {
        let t = std::time::Instant::now();
        let mut report = MappingReport::default();
        self.reindex(vocabulary);
        self.cull_points(id);
        let scale_factor = params.orb.scale_factor as f64;
        if params.triangulate {
            let neighbours = self.best_covisible(id, crate::map::MAPPING_NEIGHBOURS);
            report.counts.triangulated =
                self.triangulate(id, &neighbours, camera, scale_factor, params.sensor);
        }
        if params.fuse_points {
            (report.counts.fused, report.counts.observations_added) =
                self.fuse(id, camera, scale_factor, params.orb.levels);
        }
        self.connect(id);
        let ba = params.local_ba_keyframes;
        report.adjusted = ba > 1 && self.local_bundle_adjustment(camera, ba, params.sensor);
        self.cull_keyframes(id, scale_factor);
        report.ms = t.elapsed().as_secs_f64() * 1e3;
        report
    }
}

/// Loop corrections that are ready merged, local mapping of keyframe
/// `id`, then loop closing: the one job both the mapping thread and inline
/// mapping run.
pub(crate) fn map_keyframe(
    map: &mut Map,
    id: usize,
    camera: &Camera,
    params: &SlamParams,
    vocabulary: &Vocabulary,
    loops: &mut LoopClosing,
) -> MappingReport {
    let t = std::time::Instant::now();
    let mut merged = loops.merge_ready(map);
    let mut report = map.process_keyframe(id, camera, params, vocabulary);
    merged.extend(loops.after_keyframe(map, id));
    report.note_loops(merged);
    report.ms = t.elapsed().as_secs_f64() * 1e3;
    report
}

impl MappingReport {
    /// Adds the loop closer's reports; a closed loop moved keyframes.
    pub(crate) fn note_loops(&mut self, reports: Vec<crate::loop_closing::LoopReport>) {
        self.adjusted |= reports.iter().any(|r| r.closed.is_some());
        self.loops.extend(reports);
    }
}

enum Job {
    Keyframe {
        map: Map,
        keyframe: usize,
        /// Hand a copy of the mapped map to the checkpoint writer.
        checkpoint: Option<CheckpointSender>,
        /// Leave a snapshot of the mapped map for the outside.
        snapshot: Option<SnapshotRequest>,
    },
    /// Finish loop closing and merge what it found.
    Flush(Map),
}

impl Job {
    fn into_map(self) -> Map {
        match self {
            Job::Keyframe { map, .. } | Job::Flush(map) => map,
        }
    }
}

/// The local-mapping thread and its two channels.
pub struct LocalMapper {
    jobs: Option<Sender<Job>>,
    done: Receiver<(Map, MappingReport)>,
    worker: Option<JoinHandle<()>>,
}

impl LocalMapper {
    /// Starts the thread (named `local-mapping`), which maps with `params`
    /// and indexes keyframes with `vocabulary`.
    pub fn spawn(
        camera: Camera,
        params: SlamParams,
        vocabulary: Arc<Vocabulary>,
    ) -> std::io::Result<Self> {
        let (jobs, inbox) = channel::<Job>();
        let (outbox, done) = channel();
        let worker = std::thread::Builder::new()
            .name("local-mapping".into())
            .spawn(move || {
                let mut loops = LoopClosing::new(&params, camera, true);
                for job in inbox {
                    let (map, report) = match job {
                        Job::Keyframe {
                            mut map,
                            keyframe,
                            checkpoint,
                            snapshot,
                        } => {
                            let report = map_keyframe(
                                &mut map,
                                keyframe,
                                &camera,
                                &params,
                                &vocabulary,
                                &mut loops,
                            );
                            if let Some(to_writer) = checkpoint {
                                to_writer.offer(&map);
                            }
                            if let Some(request) = snapshot {
                                request.fulfil(&map, keyframe, &report);
                            }
                            (map, report)
                        }
                        Job::Flush(mut map) => {
                            let t = std::time::Instant::now();
                            let mut report = MappingReport::default();
                            report.note_loops(loops.flush(&mut map));
                            report.ms = t.elapsed().as_secs_f64() * 1e3;
                            (map, report)
                        }
                    };
                    if outbox.send((map, report)).is_err() {
                        break;
                    }
                }
            })?;
        Ok(Self {
            jobs: Some(jobs),
            done,
            worker: Some(worker),
        })
    }

    /// Hands `map` over for keyframe `keyframe` (and, with `checkpoint`,
    /// for a checkpoint copy once mapped; with `snapshot`, for a snapshot);
    /// gives it back if the thread is gone.
    pub fn submit(
        &self,
        map: Map,
        keyframe: usize,
        checkpoint: Option<CheckpointSender>,
        snapshot: Option<SnapshotRequest>,
    ) -> Result<(), Map> {
        match &self.jobs {
            Some(jobs) => jobs
                .send(Job::Keyframe {
                    map,
                    keyframe,
                    checkpoint,
                    snapshot,
                })
                .map_err(|e| e.0.into_map()),
            None => Err(map),
        }
    }

    /// Hands `map` over for loop closing to finish (what it is working on
    /// and what waits) and merge; gives it back if the thread is gone.
    pub fn flush(&self, map: Map) -> Result<(), Map> {
        match &self.jobs {
            Some(jobs) => jobs.send(Job::Flush(map)).map_err(|e| e.0.into_map()),
            None => Err(map),
        }
    }

    /// Waits for the map of the last submitted job. None if the thread
    /// died (a panic in mapping): that map is lost.
    pub fn collect(&self) -> Option<(Map, MappingReport)> {
        self.done.recv().ok()
    }
}

impl Drop for LocalMapper {
    fn drop(&mut self) {
        // Closing the job channel ends the thread's loop.
        self.jobs.take();
        if let Some(worker) = self.worker.take() {
            let _ = worker.join();
        }
    }
}
