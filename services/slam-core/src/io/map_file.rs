//! The map file: everything needed to go on in a map (keyframes with their
//! poses, keypoint measurements, descriptors, depth and spare keypoints;
//! map points with position, descriptor, observers, scale range; the
//! covisibility graph, spanning tree and loop edges; the keyframe database;
//! the camera; the sensor, pyramid and depth settings the map was made
//! with).
//!
//! Layout: the magic `DSLAMMAP` and the framing of [`crate::io::framed`]
//! (version, length, CRC-32), then the payload: the
//! [`MapFile`] in postcard (a compact, stable serde format). Another
//! version, another camera, a truncated, corrupted or foreign file is an
//! error naming the file and the problem; a file that decodes is checked
//! against the map's invariants before anything uses an id from it.

use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::framed::{frame, unframe, FrameProblem};
use crate::camera::Camera;
use crate::map::Map;
use crate::params::SlamParams;

/// The first eight bytes of a map file.
pub const MAGIC: &[u8; 8] = b"DSLAMMAP";
/// Bumped whenever the payload's layout changes; older files are refused
/// with both versions named (no silent misreading).
/// (v2: the keyframe database; v3: the sensor.)
pub const VERSION: u32 = 3;

/// A temporary name beside `path`, unique per process and write (two
/// writers of one file never share a temporary).
fn temporary_path(path: &Path) -> PathBuf {
    static WRITES: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = WRITES.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(format!(".{}.{n}.tmp", std::process::id()));
    PathBuf::from(tmp)
}

/// A map and what it was made with.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MapFile {
    /// The camera the map was made with (a map is refused for another one).
    pub camera: Camera,
    /// The ORB pyramid: descriptors and scale ranges mean something only
    /// for the pyramid they were measured with.
    pub pyramid_levels: u32,
    /// The pyramid's scale between levels.
    pub pyramid_scale_factor: f32,
    /// Depth range (metres) and the near-depth limit measurements used.
    pub min_depth_m: f64,
    /// See `min_depth_m`.
    pub max_depth_m: f64,
    /// Keypoints nearer than this were measured with their depth.
    pub close_depth_m: f64,
    /// Made by a monocular system: its unit is its own, not metres.
    pub monocular: bool,
    /// Keyframes, points and the keyframe database.
    pub map: Map,
}

/// What is wrong with a map file.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MapFileProblem {
    /// Reading or writing the file failed.
    #[error("{0}")]
    Io(String),
    /// Not a map file.
    #[error("not a dynslam map file (no DSLAMMAP header)")]
    NotAMapFile,
    /// Another format version than this build reads.
    #[error("format version {found}, this build reads version {supported}")]
    Version {
        /// The file's version.
        found: u32,
        /// The version this build reads.
        supported: u32,
    },
    /// Shorter than its header promises.
    #[error("truncated: the header promises {expected} bytes of map, the file has {found}")]
    Truncated {
        /// Bytes the header promises.
        expected: u64,
        /// Bytes the file has.
        found: u64,
    },
    /// Bytes after the map.
    #[error("{0} bytes after the map (not written by dynslam, or two files joined)")]
    TrailingBytes(u64),
    /// The map does not match its checksum.
    #[error("checksum mismatch: the file is corrupted")]
    Checksum,
    /// The body could not be decoded.
    #[error("cannot decode the map: {0}")]
    Decode(String),
    /// Decoded, but its ids or observations contradict each other.
    #[error("the map is inconsistent: {0}")]
    Inconsistent(String),
    /// Made with another camera than the one given.
    #[error("made with another camera: {0}")]
    Camera(String),
    /// Made with another ORB pyramid than the one configured.
    #[error("made with another ORB pyramid: {0}")]
    Pyramid(String),
    /// Made with another sensor (RGB-D or monocular).
    #[error("made with another sensor: {0}")]
    Sensor(String),
}

/// A map file that could not be read or written, and why.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("map file {}: {problem}", path.display())]
pub struct MapFileError {
    /// The file.
    pub path: PathBuf,
    /// What is wrong.
    pub problem: MapFileProblem,
}

impl MapFile {
    /// A map with the camera and settings it was made with.
    pub fn new(camera: Camera, params: &SlamParams, map: Map) -> Self {
        Self {
            camera,
            pyramid_levels: params.orb.levels as u32,
            pyramid_scale_factor: params.orb.scale_factor,
            min_depth_m: params.min_depth_m,
            max_depth_m: params.max_depth_m,
            close_depth_m: params.close_depth_m,
            monocular: params.is_monocular(),
            map,
        }
    }

    /// The file's bytes.
    pub fn encode(&self) -> Result<Vec<u8>, MapFileProblem> {
        let payload =
            postcard::to_stdvec(self).map_err(|e| MapFileProblem::Decode(e.to_string()))?;
        Ok(frame(MAGIC, VERSION, &payload))
    }

    /// A map file from its bytes, checked.
    pub fn decode(bytes: &[u8]) -> Result<Self, MapFileProblem> {
        let (payload, _) = unframe(bytes, MAGIC, VERSION).map_err(|p| match p {
            FrameProblem::Foreign => MapFileProblem::NotAMapFile,
            FrameProblem::Version { found, supported } => {
                MapFileProblem::Version { found, supported }
            }
            FrameProblem::Truncated { expected, found } => {
                MapFileProblem::Truncated { expected, found }
            }
            FrameProblem::TrailingBytes(n) => MapFileProblem::TrailingBytes(n),
            FrameProblem::Checksum => MapFileProblem::Checksum,
        })?;
        let file: MapFile =
            postcard::from_bytes(payload).map_err(|e| MapFileProblem::Decode(e.to_string()))?;
        file.map
            .check_invariants()
            .map_err(MapFileProblem::Inconsistent)?;
        Ok(file)
    }

    /// Reads and checks the map file at `path`.
    pub fn read(path: &Path) -> Result<Self, MapFileError> {
        let named = |problem| MapFileError {
            path: path.to_path_buf(),
            problem,
        };
        let bytes = std::fs::read(path).map_err(|e| named(MapFileProblem::Io(e.to_string())))?;
        Self::decode(&bytes).map_err(named)
    }

    /// Reads the map file at `path` and checks that it can be tracked in
    /// with `camera` and `params` ([`MapFile::check_compatible`]).
    pub fn read_for(
        path: &Path,
        camera: &Camera,
        params: &SlamParams,
    ) -> Result<Self, MapFileError> {
        let file = Self::read(path)?;
        file.check_compatible(camera, params)
            .map_err(|problem| MapFileError {
                path: path.to_path_buf(),
                problem,
            })?;
        Ok(file)
    }

    /// Writes the file atomically: a temporary file beside it, synced, then
    /// renamed over `path` (a reader sees the old file or the new one,
    /// never half of one, even if the writer is killed).
    pub fn write(&self, path: &Path) -> Result<(), MapFileError> {
        let named = |problem| MapFileError {
            path: path.to_path_buf(),
            problem,
        };
        let bytes = self.encode().map_err(named)?;
        let tmp = temporary_path(path);
        let written = (|| -> std::io::Result<()> {
            let mut f = std::fs::File::create(&tmp)?;
            f.write_all(&bytes)?;
            f.sync_all()?;
            std::fs::rename(&tmp, path)?;
            // The rename itself is durable once the folder is synced.
            if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
                if let Ok(d) = std::fs::File::open(dir) {
                    let _ = d.sync_all();
                }
            }
            Ok(())
        })();
        written.map_err(|e| {
            let _ = std::fs::remove_file(&tmp);
            named(MapFileProblem::Io(e.to_string()))
        })
    }

    /// Removes temporary files a killed writer of `path` left behind.
    pub fn remove_stale_temporaries(path: &Path) {
        let (Some(dir), Some(name)) = (path.parent(), path.file_name()) else {
            return;
        };
        let prefix = format!("{}.", name.to_string_lossy());
        let dir = if dir.as_os_str().is_empty() {
            Path::new(".")
        } else {
            dir
        };
        for entry in std::fs::read_dir(dir).into_iter().flatten().flatten() {
            let n = entry.file_name().to_string_lossy().into_owned();
            if n.starts_with(&prefix) && n.ends_with(".tmp") {
                let _ = std::fs::remove_file(entry.path());
            }
        }
    }

    /// The map can be tracked in with `camera` and `params`: the same
    /// intrinsics, distortion and depth scale (to 1e-6 relative), the same
    /// ORB pyramid and the same sensor (a monocular map's unit is not the
    /// metre an RGB-D system measures in, and the other way round).
    pub fn check_compatible(
        &self,
        camera: &Camera,
        params: &SlamParams,
    ) -> Result<(), MapFileProblem> {
        let a = &self.camera;
        let close = |x: f64, y: f64| (x - y).abs() <= 1e-6 * x.abs().max(y.abs()).max(1.0);
        let pairs = [
            ("fx", a.fx, camera.fx),
            ("fy", a.fy, camera.fy),
            ("cx", a.cx, camera.cx),
            ("cy", a.cy, camera.cy),
            ("depth_scale", a.depth_scale, camera.depth_scale),
        ];
        for (name, saved, now) in pairs {
            if !close(saved, now) {
                return Err(MapFileProblem::Camera(format!(
                    "{name} is {saved} in the map, {now} in this run"
                )));
            }
        }
        if !a.dist.iter().zip(&camera.dist).all(|(x, y)| close(*x, *y)) {
            return Err(MapFileProblem::Camera(format!(
                "distortion is {:?} in the map, {:?} in this run",
                a.dist, camera.dist
            )));
        }
        if self.pyramid_levels as usize != params.orb.levels
            || (self.pyramid_scale_factor - params.orb.scale_factor).abs() > 1e-6
        {
            return Err(MapFileProblem::Pyramid(format!(
                "{} levels {} apart in the map, {} levels {} apart in this run",
                self.pyramid_levels,
                self.pyramid_scale_factor,
                params.orb.levels,
                params.orb.scale_factor
            )));
        }
        if self.monocular != params.is_monocular() {
            let name = |mono: bool| if mono { "monocular" } else { "rgbd" };
            return Err(MapFileProblem::Sensor(format!(
                "{} in the map, {} in this run (services.slam.sensor)",
                name(self.monocular),
                name(params.is_monocular())
            )));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::framed::HEADER;
    use crate::map::{KeyFrame, KeyFrameObservation, MapPoint};
    use crate::rng::SplitMix64;
    use nalgebra::{Isometry3, Vector3};

    /// Two keyframes sharing ten points, built through the mutation API.
    fn small_map() -> Map {
        let mut map = Map::default();
        let m = |i: usize| KeyFrameObservation {
            u: 100.0 + i as f64,
            v: 50.0,
            ur: Some(90.0),
            info: 1.0,
            descriptor: [i as u64; 4],
            angle: 0.0,
        };
        let ids: Vec<usize> = (0..10)
            .map(|i| {
                let p = MapPoint::new(Vector3::new(i as f64, 0.0, 2.0), 0, &m(i), 2.0, [1, 2, 3]);
                map.add_point(p)
            })
            .collect();
        for k in 0..2 {
            map.add_keyframe(KeyFrame {
                pose_cw: Isometry3::translation(0.1 * k as f64, 0.0, 0.0),
                points: ids.clone(),
                measurements: (0..10).map(m).collect(),
                spare: Vec::new(),
                bounds: (0.0, 640.0, 0.0, 480.0),
                covisible: Vec::new(),
                parent: None,
                loops: Vec::new(),
                culled: false,
            });
        }
        map.connect(1);
        map.check_invariants().unwrap();
        map
    }

    fn file() -> MapFile {
        MapFile::new(Camera::tum_fr1(), &SlamParams::default(), small_map())
    }

    #[test]
    fn a_map_survives_the_round_trip_through_a_file() {
        let dir = std::env::temp_dir().join(format!("mapfile-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.map");
        file().write(&path).unwrap();
        let back = MapFile::read(&path).unwrap();
        assert_eq!(back.camera, Camera::tum_fr1());
        assert_eq!(back.map.keyframes.len(), 2);
        assert_eq!(back.map.live_point_count(), 10);
        assert_eq!(back.map.keyframes[1].covisible, vec![(0, 10)]);
        assert_eq!(back.map.points[3].descriptor, [3; 4]);
        back.check_compatible(&Camera::tum_fr1(), &SlamParams::default())
            .unwrap();
        // Nothing temporary left beside it.
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn bad_files_are_named_with_their_problem() {
        let bytes = file().encode().unwrap();
        let problem = |b: &[u8]| MapFile::decode(b).unwrap_err();
        // Truncated anywhere: the header's length says so.
        assert!(matches!(
            problem(&bytes[..bytes.len() - 7]),
            MapFileProblem::Truncated { .. }
        ));
        assert!(matches!(
            problem(&bytes[..15]),
            MapFileProblem::Truncated { .. }
        ));
        // Another version.
        let mut other = bytes.clone();
        other[8..12].copy_from_slice(&7u32.to_le_bytes());
        assert_eq!(
            problem(&other),
            MapFileProblem::Version {
                found: 7,
                supported: VERSION
            }
        );
        // A flipped byte in the payload.
        let mut flipped = bytes.clone();
        let last = flipped.len() - 3;
        flipped[last] ^= 0x40;
        assert_eq!(problem(&flipped), MapFileProblem::Checksum);
        // Something else entirely, and two files joined.
        assert_eq!(
            problem(b"ply\nformat ascii 1.0\n"),
            MapFileProblem::NotAMapFile
        );
        assert_eq!(problem(b""), MapFileProblem::NotAMapFile);
        let joined = [bytes.clone(), bytes.clone()].concat();
        assert!(matches!(problem(&joined), MapFileProblem::TrailingBytes(_)));
        // Decodes, but an id points nowhere: refused before use.
        let mut broken = file();
        broken.map.keyframes[0].points[0] = 99;
        let err = problem(&broken.encode().unwrap());
        assert!(
            matches!(&err, MapFileProblem::Inconsistent(m) if m.contains("point 99")),
            "{err}"
        );
        // The error names the file.
        let missing = Path::new("/nonexistent/x.map");
        let e = MapFile::read(missing).unwrap_err().to_string();
        assert!(e.starts_with("map file /nonexistent/x.map: "), "{e}");
    }

    #[test]
    fn another_camera_pyramid_or_sensor_is_refused() {
        let f = file();
        let mut camera = Camera::tum_fr1();
        camera.fx = 525.0;
        let e = f
            .check_compatible(&camera, &SlamParams::default())
            .unwrap_err();
        assert!(
            e.to_string()
                .contains("fx is 517.306408 in the map, 525 in this run"),
            "{e}"
        );
        let mut camera = Camera::tum_fr1();
        camera.depth_scale = 1000.0;
        assert!(matches!(
            f.check_compatible(&camera, &SlamParams::default()),
            Err(MapFileProblem::Camera(_))
        ));
        let mut params = SlamParams::default();
        params.orb.levels = 4;
        assert!(matches!(
            f.check_compatible(&Camera::tum_fr1(), &params),
            Err(MapFileProblem::Pyramid(_))
        ));
        let e = f
            .check_compatible(&Camera::tum_fr1(), &SlamParams::monocular())
            .unwrap_err();
        assert!(
            e.to_string()
                .contains("rgbd in the map, monocular in this run (services.slam.sensor)"),
            "{e}"
        );
    }

    /// Cheap fuzzing: random bytes, and a valid file with random bytes
    /// changed, truncated or extended (its checksum fixed so the decoder
    /// and the invariant check see them), never panic.
    #[test]
    fn mangled_files_give_errors_not_panics() {
        let bytes = file().encode().unwrap();
        let mut rng = SplitMix64::new(17);
        for i in 0..3000 {
            let mut b = if i % 5 == 0 {
                (0..rng.below(300)).map(|_| rng.below(256) as u8).collect()
            } else {
                bytes.clone()
            };
            for _ in 0..1 + rng.below(4) {
                if b.is_empty() {
                    break;
                }
                let at = rng.below(b.len());
                match rng.below(3) {
                    0 => b[at] = rng.below(256) as u8,
                    1 => b.truncate(at.max(HEADER)),
                    _ => b.insert(at, rng.below(256) as u8),
                }
            }
            if i % 2 == 0 && b.len() >= HEADER && &b[..8] == MAGIC {
                let payload = b[HEADER..].to_vec();
                b[12..20].copy_from_slice(&(payload.len() as u64).to_le_bytes());
                b[20..24].copy_from_slice(&crc32fast::hash(&payload).to_le_bytes());
                b[8..12].copy_from_slice(&VERSION.to_le_bytes());
            }
            let _ = MapFile::decode(&b);
        }
    }
}
