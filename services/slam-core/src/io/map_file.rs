//! The map file: everything needed to go on in a map (keyframes with their
//! poses, keypoint measurements, descriptors, depth and spare keypoints;
//! map points with position, descriptor, observers, scale range; the
//! covisibility graph and spanning tree; the camera; the pyramid and depth
//! settings the map was made with).
//!
//! Layout (little-endian): the magic `DSLAMMAP`, a format version (u32), the
//! payload's length (u64) and CRC-32 (u32), then the payload: the
//! [`MapFile`] in postcard (a compact, stable serde format). Another
//! version, another camera, a truncated, corrupted or foreign file is an
//! error naming the file and the problem; a file that decodes is checked
//! against the map's invariants before anything uses an id from it.

use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::camera::Camera;
use crate::map::Map;
use crate::params::SlamParams;

pub const MAGIC: &[u8; 8] = b"DSLAMMAP";
/// Bumped whenever the payload's layout changes; older files are refused
/// with both versions named (no silent misreading).
pub const VERSION: u32 = 1;
const HEADER: usize = 8 + 4 + 8 + 4;

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
    pub camera: Camera,
    /// The ORB pyramid: descriptors and scale ranges mean something only
    /// for the pyramid they were measured with.
    pub pyramid_levels: u32,
    pub pyramid_scale_factor: f32,
    /// Depth range (metres) and the near-depth limit measurements used.
    pub min_depth_m: f64,
    pub max_depth_m: f64,
    pub close_depth_m: f64,
    pub map: Map,
}

/// What is wrong with a map file.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MapFileProblem {
    #[error("{0}")]
    Io(String),
    #[error("not a dynslam map file (no DSLAMMAP header)")]
    NotAMapFile,
    #[error("format version {found}, this build reads version {supported}")]
    Version { found: u32, supported: u32 },
    #[error("truncated: the header promises {expected} bytes of map, the file has {found}")]
    Truncated { expected: u64, found: u64 },
    #[error("{0} bytes after the map (not written by dynslam, or two files joined)")]
    TrailingBytes(u64),
    #[error("checksum mismatch: the file is corrupted")]
    Checksum,
    #[error("cannot decode the map: {0}")]
    Decode(String),
    #[error("the map is inconsistent: {0}")]
    Inconsistent(String),
    #[error("made with another camera: {0}")]
    Camera(String),
    #[error("made with another ORB pyramid: {0}")]
    Pyramid(String),
}

#[derive(Debug, thiserror::Error, PartialEq)]
#[error("map file {}: {problem}", path.display())]
pub struct MapFileError {
    pub path: PathBuf,
    pub problem: MapFileProblem,
}

impl MapFile {
    pub fn new(camera: Camera, params: &SlamParams, map: Map) -> Self {
        Self {
            camera,
            pyramid_levels: params.orb.levels as u32,
            pyramid_scale_factor: params.orb.scale_factor,
            min_depth_m: params.min_depth_m,
            max_depth_m: params.max_depth_m,
            close_depth_m: params.close_depth_m,
            map,
        }
    }

    /// The file's bytes.
    pub fn encode(&self) -> Result<Vec<u8>, MapFileProblem> {
        let payload =
            postcard::to_stdvec(self).map_err(|e| MapFileProblem::Decode(e.to_string()))?;
        let mut out = Vec::with_capacity(HEADER + payload.len());
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&VERSION.to_le_bytes());
        out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
        out.extend_from_slice(&crc32fast::hash(&payload).to_le_bytes());
        out.extend_from_slice(&payload);
        Ok(out)
    }

    /// A map file from its bytes, checked.
    pub fn decode(bytes: &[u8]) -> Result<Self, MapFileProblem> {
        if bytes.len() < MAGIC.len() || &bytes[..MAGIC.len()] != MAGIC {
            return Err(MapFileProblem::NotAMapFile);
        }
        if bytes.len() < HEADER {
            return Err(MapFileProblem::Truncated {
                expected: HEADER as u64,
                found: bytes.len() as u64,
            });
        }
        let word = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap_or_default());
        let version = word(8);
        if version != VERSION {
            return Err(MapFileProblem::Version {
                found: version,
                supported: VERSION,
            });
        }
        let length = u64::from_le_bytes(bytes[12..20].try_into().unwrap_or_default());
        let crc = word(20);
        let payload = &bytes[HEADER..];
        let found = payload.len() as u64;
        if found < length {
            return Err(MapFileProblem::Truncated {
                expected: length,
                found,
            });
        }
        if found > length {
            return Err(MapFileProblem::TrailingBytes(found - length));
        }
        if crc32fast::hash(payload) != crc {
            return Err(MapFileProblem::Checksum);
        }
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
    /// intrinsics, distortion and depth scale (to 1e-6 relative) and the
    /// same ORB pyramid.
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
        Ok(())
    }
}
