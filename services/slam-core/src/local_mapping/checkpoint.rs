//! Map checkpoints written while the system runs: every N keyframes local
//! mapping copies the mapped map (on its thread, off the frame path) into a
//! one-map slot, and a writer thread encodes the newest copy and replaces
//! the checkpoint file atomically (temporary file, fsync, rename). A copy
//! that arrives while the writer is busy replaces the one waiting in the
//! slot, so the writer always goes on with the newest map (never with a
//! stale one, never with a queue). The map of the first keyframe is written
//! at once, so that a restart always finds the world frame it must go on in.

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;

use crate::camera::Camera;
use crate::io::map_file::MapFile;
use crate::map::Map;
use crate::params::SlamParams;

/// Where and how often.
#[derive(Debug, Clone)]
pub struct CheckpointPolicy {
    /// The map file the checkpoints replace (written beside it, then renamed).
    pub path: PathBuf,
    /// A checkpoint after every this many inserted keyframes (at least 1).
    pub every_keyframes: usize,
}

/// What the writer has done, for whoever reports on it.
#[derive(Debug, Default)]
pub struct CheckpointStats {
    /// Checkpoints written.
    pub written: AtomicUsize,
    /// Checkpoints that failed to write.
    pub failed: AtomicUsize,
    /// Copies replaced by a newer one before the writer got to them.
    pub superseded: AtomicUsize,
}

/// The newest copy waiting for the writer, and whether the writer should
/// stop once it is written.
#[derive(Default)]
struct Slot {
    map: Option<Map>,
    closing: bool,
}

#[derive(Default)]
struct Shared {
    slot: Mutex<Slot>,
    ready: Condvar,
    stats: CheckpointStats,
}

/// Hands map copies to the writer thread.
#[derive(Clone)]
pub struct CheckpointSender {
    shared: Arc<Shared>,
}

impl CheckpointSender {
    /// Puts a copy of `map` in the slot (replacing an unwritten older one).
    pub fn offer(&self, map: &Map) {
        let copy = map.clone();
        let Ok(mut slot) = self.shared.slot.lock() else {
            return; // the writer panicked: no more checkpoints
        };
        if slot.map.replace(copy).is_some() {
            self.shared.stats.superseded.fetch_add(1, Ordering::Relaxed);
        }
        self.shared.ready.notify_one();
    }
}

/// The checkpoint writer thread.
pub struct Checkpointer {
    path: PathBuf,
    camera: Camera,
    params: SlamParams,
    every_keyframes: usize,
    shared: Arc<Shared>,
    worker: Option<JoinHandle<()>>,
}

impl Checkpointer {
    /// Starts the writer thread, which writes with `policy` the maps it is sent.
    pub fn spawn(
        policy: CheckpointPolicy,
        camera: Camera,
        params: SlamParams,
    ) -> std::io::Result<Self> {
        let shared = Arc::new(Shared::default());
        let writer = shared.clone();
        let path = policy.path.clone();
        let worker = std::thread::Builder::new()
            .name("map-checkpoint".into())
            .spawn(move || loop {
                let map = {
                    let Ok(mut slot) = writer.slot.lock() else {
                        return;
                    };
                    loop {
                        if let Some(map) = slot.map.take() {
                            break map;
                        }
                        if slot.closing {
                            return;
                        }
                        slot = match writer.ready.wait(slot) {
                            Ok(s) => s,
                            Err(_) => return,
                        };
                    }
                };
                write(&writer.stats, &path, MapFile::new(camera, &params, map));
            })?;
        Ok(Self {
            path: policy.path,
            camera,
            params,
            every_keyframes: policy.every_keyframes.max(1),
            shared,
            worker: Some(worker),
        })
    }

    /// Writes `map` now, on the caller's thread (the first keyframe's map:
    /// small, and from then on a restart always finds a checkpoint).
    pub fn write_now(&self, map: &Map) {
        write(
            &self.shared.stats,
            &self.path,
            MapFile::new(self.camera, &self.params, map.clone()),
        );
    }

    /// A checkpoint after every this many keyframes.
    pub fn every_keyframes(&self) -> usize {
        self.every_keyframes
    }

    /// Where local mapping sends its map copies.
    pub fn sender(&self) -> CheckpointSender {
        CheckpointSender {
            shared: self.shared.clone(),
        }
    }

    /// What the writer has done so far.
    pub fn stats(&self) -> &CheckpointStats {
        &self.shared.stats
    }
}

fn write(stats: &CheckpointStats, path: &std::path::Path, file: MapFile) {
    let keyframes = file.map.live_keyframes().count();
    match file.write(path) {
        Ok(()) => {
            stats.written.fetch_add(1, Ordering::Relaxed);
            tracing::debug!(keyframes, "map checkpoint written to {}", path.display());
        }
        Err(e) => {
            stats.failed.fetch_add(1, Ordering::Relaxed);
            tracing::warn!("map checkpoint not written: {e}");
        }
    }
}

impl Drop for Checkpointer {
    /// Writes the copy still waiting, then lets the writer end (a
    /// checkpoint is never left half written: the rename is atomic anyway).
    fn drop(&mut self) {
        if let Ok(mut slot) = self.shared.slot.lock() {
            slot.closing = true;
            self.shared.ready.notify_one();
        }
        if let Some(worker) = self.worker.take() {
            let _ = worker.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_newest_copy_is_written_and_nothing_waits_at_drop() {
        let dir = std::env::temp_dir().join(format!("checkpoint-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("c.map");
        let policy = CheckpointPolicy {
            path: path.clone(),
            every_keyframes: 1,
        };
        let c = Checkpointer::spawn(policy, Camera::tum_fr1(), SlamParams::default()).unwrap();
        let sender = c.sender();
        let mut map = Map::default();
        for i in 0..20 {
            map.add_point(crate::map::MapPoint::new(
                nalgebra::Vector3::new(i as f64, 0.0, 1.0),
                0,
                &crate::map::KeyFrameObservation {
                    u: 1.0,
                    v: 1.0,
                    ur: None,
                    info: 1.0,
                    descriptor: [0; 4],
                    angle: 0.0,
                },
                1.0,
                [0; 3],
            ));
            sender.offer(&map);
        }
        let stats = (
            c.stats().written.load(Ordering::Relaxed),
            c.stats().superseded.load(Ordering::Relaxed),
        );
        drop(c);
        let back = MapFile::read(&path).unwrap();
        assert_eq!(back.map.points.len(), 20, "the newest copy is the file");
        assert!(stats.0 + stats.1 <= 20);
        std::fs::remove_dir_all(&dir).ok();
    }
}
