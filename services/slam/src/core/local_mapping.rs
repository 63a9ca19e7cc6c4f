//! Local mapping on its own thread. After tracking inserts a keyframe it
//! hands the whole map to this thread ([`super::map::Map::process_keyframe`])
//! and gets it back before it tracks the next frame. The next frame's
//! feature extraction, which needs no map, runs meanwhile, so mapping
//! leaves the frame path as long as it is shorter than extraction; tracking
//! waits for the rest.
//!
//! The map moves between the threads (it is never shared), so there are no
//! locks, and a run is as repeatable as with mapping done inline: every
//! keyframe's mapping is finished before the next frame is tracked.

use std::sync::mpsc::{channel, Receiver, Sender};
use std::thread::JoinHandle;

use super::camera::Camera;
use super::map::{Map, MappingReport};
use super::system::SlamParams;

struct Job {
    map: Map,
    keyframe: usize,
}

/// The local-mapping thread and its two channels.
pub struct LocalMapper {
    jobs: Option<Sender<Job>>,
    done: Receiver<(Map, MappingReport)>,
    worker: Option<JoinHandle<()>>,
}

impl LocalMapper {
    /// Starts the thread (named `local-mapping`), which maps with `params`.
    pub fn spawn(camera: Camera, params: SlamParams) -> std::io::Result<Self> {
        let (jobs, inbox) = channel::<Job>();
        let (outbox, done) = channel();
        let worker = std::thread::Builder::new()
            .name("local-mapping".into())
            .spawn(move || {
                for Job { mut map, keyframe } in inbox {
                    let report = map.process_keyframe(keyframe, &camera, &params);
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

    /// Hands `map` over for keyframe `keyframe`; gives it back if the
    /// thread is gone.
    pub fn submit(&self, map: Map, keyframe: usize) -> Result<(), Map> {
        match &self.jobs {
            Some(jobs) => jobs.send(Job { map, keyframe }).map_err(|e| e.0.map),
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
