//! What the SLAM service shares with the ROS 2 bridge, only when
//! `[bridge] enabled`: map snapshots out (the bridge's point cloud,
//! keyframes and occupancy grid), commands in (its ROS 2 services) and their
//! replies out. A command is one small message and its reply another; the
//! map file of `save_map` is written on a thread of its own, so that
//! tracking goes on meanwhile (the map is copied first, once local mapping
//! and loop closing have handed it back).

use std::path::{Path, PathBuf};
use std::thread::JoinHandle;

use anyhow::Result;
use pipeline::runtime::ServiceContext;
use pipeline::transport::{Receiver, Sender, MAX_MAP_KEYFRAMES, MAX_MAP_POINTS};
use pipeline::views::{write_map, MapPointEntry};
use shared_types::names::Topic;
use shared_types::{read_error_text, MapHeader, SlamCommand, SlamCommandKind, SlamReply};

use crate::tracker::Tracker;

/// Longest map name `save_map` takes (the `.map` suffix included).
pub const MAX_MAP_NAME: usize = 64;

/// The file a `save_map` name stands for in `maps_dir`: a plain file name
/// (letters, digits, '-', '_', '.'; not starting with '.'), `.map` added
/// when missing. Anything that could name another folder is refused.
pub fn map_path(maps_dir: &Path, name: &str) -> Result<PathBuf, String> {
    let bad = |why: &str| Err(format!("map name \"{name}\": {why}"));
    if name.is_empty() {
        return bad("empty");
    }
    if let Some(c) = name
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.')))
    {
        return bad(&format!(
            "'{c}' is not allowed (a file name of letters, digits, '-', '_' and '.'; no folder)"
        ));
    }
    if name.starts_with('.') {
        return bad("starts with '.'");
    }
    let file = if name.ends_with(".map") {
        name.to_string()
    } else {
        format!("{name}.map")
    };
    if file.len() > MAX_MAP_NAME {
        return bad(&format!("longer than {MAX_MAP_NAME} characters"));
    }
    Ok(maps_dir.join(file))
}

/// A `save_map` in progress: its command and the writer thread.
struct Saving {
    id: u64,
    writer: JoinHandle<Result<String, String>>,
}

/// The SLAM's side of the ROS 2 bridge: map snapshots out, the bridge's
/// commands (save, reset, localization mode) in.
pub struct BridgeLink {
    map: Sender<[u8], MapHeader>,
    replies: Sender<SlamReply, ()>,
    maps_dir: PathBuf,
    /// Snapshots published by this process.
    version: u64,
    left_out_warned: bool,
    saving: Option<Saving>,
}

/// What serving the commands did that the service must know.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct Served {
    /// The map was reset: whatever waited on the old one is gone.
    pub reset: bool,
}

impl BridgeLink {
    /// The link and the commands' receiver (to wait on), when the run has
    /// a bridge.
    pub fn open(ctx: &ServiceContext) -> Result<Option<(Self, Receiver<SlamCommand, ()>)>> {
        let cfg = &ctx.config.bridge;
        if !cfg.enabled {
            return Ok(None);
        }
        let link = Self {
            map: ctx
                .transport
                .slice_sender::<MapHeader>(Topic::Map, pipeline::transport::MAX_MAP_BYTES)?,
            replies: ctx.transport.sender::<SlamReply>(Topic::SlamReplies)?,
            maps_dir: cfg.maps_dir.clone(),
            version: 0,
            left_out_warned: false,
            saving: None,
        };
        let commands = ctx.transport.receiver::<SlamCommand>(Topic::SlamCommands)?;
        Ok(Some((link, commands)))
    }

    /// A save is being written: the service should look again soon.
    pub fn busy(&self) -> bool {
        self.saving.is_some()
    }

    /// Publishes the tracker's newest map snapshot, if it took one.
    pub fn publish_map(&mut self, tracker: &mut dyn Tracker) -> Result<()> {
        let Some((stamp, snapshot)) = tracker.take_map_snapshot() else {
            return Ok(());
        };
        let keyframes: Vec<[f64; 7]> = snapshot
            .keyframes
            .iter()
            .take(MAX_MAP_KEYFRAMES)
            .map(|k| {
                let (t, q) = (k.translation.vector, k.rotation);
                [t.x, t.y, t.z, q.i, q.j, q.k, q.w]
            })
            .collect();
        let points: Vec<MapPointEntry> = snapshot
            .points
            .iter()
            .filter(|p| (p.keyframe as usize) < keyframes.len())
            .take(MAX_MAP_POINTS)
            .map(|p| MapPointEntry {
                position: [
                    p.position.x as f32,
                    p.position.y as f32,
                    p.position.z as f32,
                ],
                colour: p.colour,
                keyframe: p.keyframe,
            })
            .collect();
        let left_out = (snapshot.points.len() - points.len()) as u32;
        if left_out > 0 && !self.left_out_warned {
            self.left_out_warned = true;
            tracing::warn!(
                left_out,
                "the map is larger than a snapshot holds ({MAX_MAP_KEYFRAMES} keyframes, {MAX_MAP_POINTS} points): the ROS 2 map topics leave the rest out"
            );
        }
        self.version += 1;
        let header = MapHeader {
            version: self.version,
            stamp,
            loops: tracker.loops_closed() as u32,
            keyframes: keyframes.len() as u32,
            points: points.len() as u32,
            points_left_out: left_out,
        };
        let mut sample = self.map.loan(header.payload_len())?;
        *sample.user_header_mut() = header;
        write_map(sample.payload_mut(), &keyframes, &points);
        self.map.publish(sample)
    }

    /// Answers the commands that came, and a save that finished.
    pub fn serve(
        &mut self,
        commands: &Receiver<SlamCommand, ()>,
        tracker: &mut dyn Tracker,
    ) -> Result<Served> {
        let mut served = Served::default();
        if self.saving.as_ref().is_some_and(|s| s.writer.is_finished()) {
            self.answer_save()?;
        }
        commands.clear_wakeups();
        while let Some(c) = commands.next()? {
            let name = read_error_text(&c.name);
            let result = match SlamCommandKind::from_u32(c.kind) {
                Some(SlamCommandKind::SaveMap) => match self.start_save(c.id, &name, tracker) {
                    Ok(()) => continue, // answered when written
                    Err(e) => Err(e),
                },
                Some(SlamCommandKind::Reset) => tracker.reset().map(|()| {
                    served.reset = true;
                    "map reset: the next frame starts a new one".to_string()
                }),
                Some(SlamCommandKind::SetLocalizationMode) => {
                    let on = c.flag != 0;
                    tracker.set_localize_only(on).map(|()| {
                        if on {
                            "localization mode on: tracking in the map, adding nothing".into()
                        } else {
                            "localization mode off: mapping".into()
                        }
                    })
                }
                None => Err(format!("unknown command {}", c.kind)),
            };
            match &result {
                Ok(m) => tracing::info!("command {}: {m}", c.id),
                Err(e) => tracing::warn!("command {} refused: {e}", c.id),
            }
            self.reply(c.id, result)?;
        }
        Ok(served)
    }

    fn start_save(&mut self, id: u64, name: &str, tracker: &mut dyn Tracker) -> Result<(), String> {
        if self.saving.is_some() {
            return Err("a map is being saved already; try again when it is done".into());
        }
        let path = map_path(&self.maps_dir, name)?;
        let file = tracker.map_file()?;
        std::fs::create_dir_all(&self.maps_dir)
            .map_err(|e| format!("cannot create {}: {e}", self.maps_dir.display()))?;
        let keyframes = file.map.live_keyframes().count();
        let points = file.map.live_point_count();
        let writer = std::thread::Builder::new()
            .name("map-save".into())
            .spawn(move || {
                file.write(&path)
                    .map(|()| {
                        let m = format!(
                            "map saved to {} ({keyframes} keyframes, {points} points)",
                            path.display()
                        );
                        tracing::info!("{m}");
                        m
                    })
                    .map_err(|e| e.to_string())
            })
            .map_err(|e| format!("cannot start the map writer: {e}"))?;
        self.saving = Some(Saving { id, writer });
        Ok(())
    }

    fn reply(&self, id: u64, result: Result<String, String>) -> Result<()> {
        self.replies.send(SlamReply::new(id, result))
    }

    /// Waits for the save in progress, if any, and answers its command.
    fn answer_save(&mut self) -> Result<()> {
        let Some(s) = self.saving.take() else {
            return Ok(());
        };
        let result = s
            .writer
            .join()
            .unwrap_or_else(|_| Err("the map writer panicked".into()));
        self.reply(s.id, result)
    }

    /// At stop: a save in progress is finished and answered.
    pub fn finish(&mut self) -> Result<()> {
        self.answer_save()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn map_names_stay_in_the_maps_folder() {
        let dir = Path::new("maps");
        assert_eq!(map_path(dir, "office").unwrap(), dir.join("office.map"));
        assert_eq!(
            map_path(dir, "floor-2_b.map").unwrap(),
            dir.join("floor-2_b.map")
        );
        for bad in [
            "",
            "../evil",
            "/etc/passwd",
            "a/b",
            ".hidden",
            "..",
            "x y",
            "é",
        ] {
            let e = map_path(dir, bad).unwrap_err();
            assert!(e.contains("map name"), "{bad}: {e}");
        }
        assert!(map_path(dir, &"a".repeat(61))
            .unwrap_err()
            .contains("longer"));
    }
}
