//! Map checkpoints written while the system runs: every N keyframes local
//! mapping copies the mapped map (on its thread, off the frame path) and a
//! writer thread encodes it and replaces the checkpoint file atomically
//! (temporary file, fsync, rename). A copy that arrives while the writer is
//! still busy with the previous one is not taken: the next one will be.
//! The map of the first keyframe is written at once, so that a restart
//! always finds the world frame it must go on in.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc::{sync_channel, SyncSender};
use std::sync::Arc;
use std::thread::JoinHandle;

use crate::camera::Camera;
use crate::io::map_file::MapFile;
use crate::map::Map;
use crate::params::SlamParams;

/// Where and how often.
#[derive(Debug, Clone)]
pub struct CheckpointPolicy {
    pub path: PathBuf,
    /// A checkpoint after every this many inserted keyframes (at least 1).
    pub every_keyframes: usize,
}

/// What the writer has done, for whoever reports on it.
#[derive(Debug, Default)]
pub struct CheckpointStats {
    pub written: AtomicUsize,
    pub failed: AtomicUsize,
    /// Copies not taken because the writer was busy.
    pub skipped: AtomicUsize,
}

/// Hands map copies to the writer thread.
#[derive(Clone)]
pub struct CheckpointSender {
    to_writer: SyncSender<Map>,
    busy: Arc<AtomicBool>,
    stats: Arc<CheckpointStats>,
}

impl CheckpointSender {
    /// Copies `map` for the writer unless it is still busy.
    pub fn offer(&self, map: &Map) {
        if self.busy.swap(true, Ordering::AcqRel) {
            self.stats.skipped.fetch_add(1, Ordering::Relaxed);
            return;
        }
        if self.to_writer.try_send(map.clone()).is_err() {
            self.busy.store(false, Ordering::Release);
        }
    }
}

/// The checkpoint writer thread.
pub struct Checkpointer {
    path: PathBuf,
    camera: Camera,
    params: SlamParams,
    every_keyframes: usize,
    sender: Option<CheckpointSender>,
    stats: Arc<CheckpointStats>,
    worker: Option<JoinHandle<()>>,
}

impl Checkpointer {
    pub fn spawn(
        policy: CheckpointPolicy,
        camera: Camera,
        params: SlamParams,
    ) -> std::io::Result<Self> {
        let (to_writer, inbox) = sync_channel::<Map>(1);
        let busy = Arc::new(AtomicBool::new(false));
        let stats = Arc::new(CheckpointStats::default());
        let (writer_busy, writer_stats) = (busy.clone(), stats.clone());
        let path = policy.path.clone();
        let worker = std::thread::Builder::new()
            .name("map-checkpoint".into())
            .spawn(move || {
                for map in inbox {
                    let keyframes = map.live_keyframes().count();
                    match MapFile::new(camera, &params, map).write(&path) {
                        Ok(()) => {
                            writer_stats.written.fetch_add(1, Ordering::Relaxed);
                            tracing::debug!(
                                keyframes,
                                "map checkpoint written to {}",
                                path.display()
                            );
                        }
                        Err(e) => {
                            writer_stats.failed.fetch_add(1, Ordering::Relaxed);
                            tracing::warn!("map checkpoint not written: {e}");
                        }
                    }
                    writer_busy.store(false, Ordering::Release);
                }
            })?;
        Ok(Self {
            path: policy.path,
            camera,
            params,
            every_keyframes: policy.every_keyframes.max(1),
            sender: Some(CheckpointSender {
                to_writer,
                busy,
                stats: stats.clone(),
            }),
            stats,
            worker: Some(worker),
        })
    }

    /// Writes `map` now, on the caller's thread (the first keyframe's map:
    /// small, and from then on a restart always finds a checkpoint).
    pub fn write_now(&self, map: &Map) {
        match MapFile::new(self.camera, &self.params, map.clone()).write(&self.path) {
            Ok(()) => {
                self.stats.written.fetch_add(1, Ordering::Relaxed);
            }
            Err(e) => {
                self.stats.failed.fetch_add(1, Ordering::Relaxed);
                tracing::warn!("map checkpoint not written: {e}");
            }
        }
    }

    pub fn every_keyframes(&self) -> usize {
        self.every_keyframes
    }

    pub fn sender(&self) -> CheckpointSender {
        self.sender.clone().expect("the sender lives until drop")
    }

    pub fn stats(&self) -> &CheckpointStats {
        &self.stats
    }
}

impl Drop for Checkpointer {
    /// Lets the writer finish the copy it holds (a checkpoint is never left
    /// half written: the rename is atomic anyway).
    fn drop(&mut self) {
        self.sender.take();
        if let Some(worker) = self.worker.take() {
            let _ = worker.join();
        }
    }
}
