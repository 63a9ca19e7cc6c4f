//! The `orb-rgbd` backend of the SLAM service: the SLAM core
//! ([`slam_core::System`]) behind the service's [`Tracker`] seam.

use std::path::PathBuf;

use pipeline::config::PipelineConfig;
use pipeline::views::MasksView;
use shared_types::TrackState;
use slam_core::io::ply::ColouredPoint;
use slam_core::io::trajectory::Trajectory;
use slam_core::local_mapping::checkpoint::CheckpointPolicy;
use slam_core::local_mapping::snapshot::MapSnapshot;
use slam_core::loop_closing::LoopClosure;
use slam_core::{MapFile, MapFileError, System};

use crate::convert;
use crate::tracker::{TrackInput, TrackOutcome, Tracker};

/// The `orb-rgbd` backend: the SLAM core (RGB-D or monocular) with its map
/// files (checkpoint, load, save).
pub struct RgbdTracker {
    system: System,
    /// The frame's depth as u16 (the shared-memory payload is bytes).
    depth: Vec<u16>,
    /// `mask_mode = "blackout"`: masked pixels are painted black instead of
    /// filtering keypoints (an ablation: the paint's edges become corners).
    blackout: bool,
    /// The painted copy of the frame in blackout mode.
    painted: Vec<u8>,
    /// The checkpoint written at stop (None in localization mode: the map
    /// does not change), and the map file asked for.
    checkpoint: Option<PathBuf>,
    save: Option<PathBuf>,
    /// Loops already handed out by `take_loops`.
    loops_reported: usize,
    /// What `reset` builds the new system from.
    config: PipelineConfig,
    files: MapFiles,
    /// Present while localization mode was switched on at run time (a
    /// restarted process stays in it); beside the checkpoint.
    localize_marker: Option<PathBuf>,
}

/// Removes `path`; a file that is not there is fine.
fn remove_if_present(path: &std::path::Path) -> std::io::Result<()> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(e),
        _ => Ok(()),
    }
}

/// The file that says "localization mode" beside the run's checkpoint.
const LOCALIZE_MARKER: &str = "localization_mode";

/// Where the map comes from and goes to.
#[derive(Debug, Clone, Default)]
pub struct MapFiles {
    /// The run's checkpoint: loaded if it exists (a restart goes on in the
    /// same world frame), written every N keyframes and at stop.
    pub checkpoint: Option<PathBuf>,
    /// A map to start in when there is no checkpoint yet.
    pub load: Option<PathBuf>,
    /// Written at stop.
    pub save: Option<PathBuf>,
    /// The last poses the previous process gave (TUM format): with the
    /// checkpoint, the motion model goes on from them.
    pub resume_poses: Option<PathBuf>,
}

impl RgbdTracker {
    /// The tracker for `config`, starting in the checkpoint when there is
    /// one, else in `files.load`, else in an empty map. A map file that
    /// cannot be used is an error naming it (never an empty map instead:
    /// that would be a new world frame).
    pub fn new(config: &PipelineConfig, files: &MapFiles) -> Result<Self, MapFileError> {
        let camera = convert::camera(&config.camera, config.source.depth_scale as f64);
        let params = convert::params(config);
        let slam = &config.services.slam;
        if let Some(c) = &files.checkpoint {
            MapFile::remove_stale_temporaries(c);
        }
        let start = files
            .checkpoint
            .as_ref()
            .filter(|p| p.exists())
            .map(|p| (p, "checkpoint"))
            .or(files.load.as_ref().map(|p| (p, "map")));
        let mut system = match start {
            Some((path, what)) => {
                let started = std::time::Instant::now();
                let file = MapFile::read_for(path, &camera, &params)?;
                // What a restart spends on the map (the rest of a restart
                // is the process start and the first frame).
                tracing::info!(
                    keyframes = file.map.live_keyframes().count(),
                    points = file.map.live_point_count(),
                    read_ms = started.elapsed().as_millis() as u64,
                    "going on in the {what} {}: the first frames relocalise",
                    path.display()
                );
                let mut system = System::with_map(params, camera, file);
                if let (Some(poses), "checkpoint") = (&files.resume_poses, what) {
                    match Trajectory::load_tum(poses) {
                        Ok(t) => system
                            .resume_motion(&t.stamps.into_iter().zip(t.poses).collect::<Vec<_>>()),
                        Err(e) => tracing::warn!("{e}: relocalising instead"),
                    }
                }
                system
            }
            None => System::new(params, camera),
        };
        let localize_marker = files
            .checkpoint
            .as_ref()
            .and_then(|c| c.parent())
            .map(|dir| dir.join(LOCALIZE_MARKER));
        let switched_on = localize_marker.as_ref().is_some_and(|m| m.exists());
        if switched_on {
            tracing::info!("localization mode (switched on before this process restarted)");
        }
        system.set_localize_only(slam.localize_only || switched_on);
        if config.bridge.enabled {
            system.enable_map_snapshots(std::time::Duration::from_secs_f64(
                config.bridge.map_period_s,
            ));
        }
        let checkpoint = files.checkpoint.clone().filter(|_| !slam.localize_only);
        if let Some(path) = &checkpoint {
            let every = slam.checkpoint_every_keyframes.unwrap_or(0) as usize;
            if every > 0 {
                system.set_checkpoint(Some(CheckpointPolicy {
                    path: path.clone(),
                    every_keyframes: every,
                }));
            }
        }
        Ok(Self {
            system,
            depth: Vec::new(),
            blackout: slam.mask_mode == "blackout",
            painted: Vec::new(),
            checkpoint,
            save: files.save.clone(),
            loops_reported: 0,
            config: config.clone(),
            files: files.clone(),
            localize_marker,
        })
    }
}

impl Tracker for RgbdTracker {
    fn name(&self) -> &str {
        "orb-rgbd"
    }

    fn track(&mut self, input: &TrackInput) -> TrackOutcome {
        let frame = input.frame;
        let (w, h) = (frame.width(), frame.height());
        self.depth.clear();
        match frame.depth {
            Some(bytes) => self.depth.extend(
                bytes
                    .chunks_exact(2)
                    .map(|b| u16::from_ne_bytes([b[0], b[1]])),
            ),
            // An image-only source: no depth anywhere (tracked as lost until
            // the monocular initialisation exists).
            None => self.depth.resize(w * h, 0),
        }
        let mut mask = input.masks.map(|m| m.labels);
        let mut rgb = frame.rgb;
        if let (true, Some(labels)) = (self.blackout, mask) {
            self.painted.clear();
            self.painted.extend_from_slice(frame.rgb);
            for (px, &l) in self.painted.chunks_exact_mut(3).zip(labels) {
                if l != 0 {
                    px.fill(0);
                }
            }
            rgb = &self.painted;
            mask = None;
        }
        let rgbd = slam_core::RgbdInput {
            rgb,
            depth: &self.depth,
            mask,
            width: w,
            height: h,
            timestamp: frame.header.source_timestamp,
        };
        let r = self.system.track_paced(&rgbd, input.keyframe, input.pace);
        let (t, q) = (r.pose_wc.translation.vector, r.pose_wc.rotation);
        TrackOutcome {
            pose: [t.x, t.y, t.z, q.i, q.j, q.k, q.w],
            state: convert::track_state(r.state),
            keyframe_inserted: r.keyframe_inserted || r.keyframe_pending,
            keyframe_pending: r.keyframe_pending,
            waiting_keyframe_inserted: r.waiting_keyframe_inserted,
            // Lost frames ask for the segmenter too: relocalising on
            // fresh masks is what a dynamic scene needs.
            next_needs_keyframe: r.next_needs_keyframe
                || convert::track_state(r.state) == TrackState::Lost,
            counts: convert::counts(&r.counts),
        }
    }

    fn complete_keyframe(&mut self, masks: Option<&MasksView>) -> bool {
        self.system.complete_keyframe(masks.map(|m| m.labels))
    }

    fn finish(&mut self) -> Result<(), String> {
        // A keyframe still waiting for its masks goes in as tracked.
        self.system.complete_keyframe(None);
        for path in self.checkpoint.iter().chain(&self.save) {
            self.system.save_map(path).map_err(|e| e.to_string())?;
            tracing::info!("map written to {}", path.display());
        }
        Ok(())
    }

    fn take_loops(&mut self) -> Vec<(f64, LoopClosure)> {
        let new: Vec<(f64, LoopClosure)> = self.system.loops()[self.loops_reported..]
            .iter()
            .map(|l| {
                let t = self
                    .system
                    .keyframe_timestamp(l.keyframe)
                    .unwrap_or(f64::NAN);
                (t, *l)
            })
            .collect();
        self.loops_reported += new.len();
        new
    }

    fn corrected_trajectory(&mut self) -> Option<slam_core::io::trajectory::Trajectory> {
        (!self.system.loops().is_empty()).then(|| self.system.trajectory())
    }

    fn take_map_snapshot(&mut self) -> Option<(f64, MapSnapshot)> {
        let snapshot = self.system.take_map_snapshot()?;
        let stamp = self
            .system
            .keyframe_timestamp(snapshot.newest_keyframe)
            .unwrap_or(0.0);
        Some((stamp, snapshot))
    }

    fn loops_closed(&self) -> usize {
        self.system.loops().len()
    }

    fn map_file(&mut self) -> Result<MapFile, String> {
        Ok(self.system.map_file())
    }

    fn reset(&mut self) -> Result<(), String> {
        // The checkpoint goes first (its writer ended, so no copy of the
        // old map comes after): a process killed from here on starts the
        // new map, never the old one.
        self.system.set_checkpoint(None);
        if let Some(c) = &self.files.checkpoint {
            remove_if_present(c)
                .map_err(|e| format!("cannot remove the checkpoint {}: {e}", c.display()))?;
        }
        self.set_localize_only(false)?;
        let files = MapFiles {
            load: None,
            resume_poses: None,
            ..self.files.clone()
        };
        let mut config = self.config.clone();
        config.services.slam.localize_only = false;
        let fresh = RgbdTracker::new(&config, &files).map_err(|e| e.to_string())?;
        *self = RgbdTracker {
            config: self.config.clone(),
            ..fresh
        };
        tracing::info!("map reset: the next frame starts a new one");
        Ok(())
    }

    fn set_localize_only(&mut self, on: bool) -> Result<(), String> {
        if let Some(marker) = &self.localize_marker {
            let written = if on {
                std::fs::write(marker, b"on\n")
            } else {
                remove_if_present(marker)
            };
            written.map_err(|e| format!("cannot record the mode in {}: {e}", marker.display()))?;
        }
        self.system.set_localize_only(on);
        tracing::info!(
            "localization mode {}",
            if on {
                "on: no keyframe or point is added"
            } else {
                "off: mapping"
            }
        );
        Ok(())
    }

    fn map_points(&mut self) -> Vec<ColouredPoint> {
        self.system
            .map()
            .live_points()
            .map(|(_, p)| ColouredPoint {
                position: p.position.into(),
                colour: p.colour,
            })
            .collect()
    }
}
