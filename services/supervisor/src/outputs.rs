//! The run folder's per-frame record, `frames.csv`.
//!
//! One row per frame, appended and flushed the moment the frame's fate is
//! known, so that a killed supervisor loses nothing: a resumed run reads the
//! rows back (dropping a half-written last line) and continues after them.
//! Every other per-frame output (trajectories, latency summary, trace) is
//! derived from these rows at the end of the run.

use std::fs::{File, OpenOptions};
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use shared_types::StageStamps;
use slam::trajectory::Trajectory;

pub const FRAMES_CSV: &str = "frames.csv";

const HEADER: &str = "seq,timestamp,state,route,mask_source,keyframe,next_keyframe,\
tx,ty,tz,qx,qy,qz,qw,features,features_masked,inliers,map_points,keyframes,\
slam_extract_us,slam_mapping_us,capture_ns,published_ns,routed_ns,masks_start_ns,masks_done_ns,slam_received_ns,\
track_start_ns,track_done_ns,track_received_ns,note";

/// The fate of one frame.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FrameRow {
    pub seq: u64,
    pub timestamp: f64,
    /// ok, lost, relocalised, not_initialised, skipped, or dropped (real-time
    /// mode: a newer frame was tracked first).
    pub state: String,
    /// segment, propagate, skip, or none (never routed).
    pub route: String,
    /// segmenter, propagator, none.
    pub mask_source: String,
    pub keyframe: bool,
    pub next_keyframe: bool,
    pub pose: [f64; 7],
    pub features: u32,
    pub features_masked: u32,
    pub inliers: u32,
    pub map_points: u32,
    pub keyframes: u32,
    /// SLAM's feature extraction and local mapping time (microseconds).
    pub extract_us: u32,
    pub mapping_us: u32,
    pub stamps: StageStamps,
    /// When the supervisor received the Track (end of the frame's path).
    pub track_received_ns: u64,
    /// Free text: why a frame was skipped or dropped.
    pub note: String,
}

impl FrameRow {
    pub fn to_csv(&self) -> String {
        let s = &self.stamps;
        let p = &self.pose;
        let note: String = self
            .note
            .chars()
            .map(|c| {
                if c == ',' || c == '\n' || c == '\r' {
                    ';'
                } else {
                    c
                }
            })
            .collect();
        format!(
            "{},{:.6},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            self.seq,
            self.timestamp,
            self.state,
            self.route,
            self.mask_source,
            self.keyframe as u8,
            self.next_keyframe as u8,
            p[0],
            p[1],
            p[2],
            p[3],
            p[4],
            p[5],
            p[6],
            self.features,
            self.features_masked,
            self.inliers,
            self.map_points,
            self.keyframes,
            self.extract_us,
            self.mapping_us,
            s.capture_ns,
            s.published_ns,
            s.routed_ns,
            s.masks_start_ns,
            s.masks_done_ns,
            s.slam_received_ns,
            s.track_start_ns,
            s.track_done_ns,
            self.track_received_ns,
            note
        )
    }

    pub fn from_csv(line: &str) -> Result<Self> {
        let f: Vec<&str> = line.splitn(31, ',').collect();
        if f.len() != 31 {
            bail!("expected 31 fields, found {}", f.len());
        }
        let u = |i: usize| -> Result<u64> {
            f[i].parse()
                .with_context(|| format!("field {} '{}' is not an integer", i + 1, f[i]))
        };
        let x = |i: usize| -> Result<f64> {
            f[i].parse()
                .with_context(|| format!("field {} '{}' is not a number", i + 1, f[i]))
        };
        let mut pose = [0.0; 7];
        for (k, v) in pose.iter_mut().enumerate() {
            *v = x(7 + k)?;
        }
        Ok(Self {
            seq: u(0)?,
            timestamp: x(1)?,
            state: f[2].to_string(),
            route: f[3].to_string(),
            mask_source: f[4].to_string(),
            keyframe: u(5)? != 0,
            next_keyframe: u(6)? != 0,
            pose,
            features: u(14)? as u32,
            features_masked: u(15)? as u32,
            inliers: u(16)? as u32,
            map_points: u(17)? as u32,
            keyframes: u(18)? as u32,
            extract_us: u(19)? as u32,
            mapping_us: u(20)? as u32,
            stamps: StageStamps {
                capture_ns: u(21)?,
                published_ns: u(22)?,
                routed_ns: u(23)?,
                masks_start_ns: u(24)?,
                masks_done_ns: u(25)?,
                slam_received_ns: u(26)?,
                track_start_ns: u(27)?,
                track_done_ns: u(28)?,
            },
            track_received_ns: u(29)?,
            note: f[30].to_string(),
        })
    }

    /// True when the row has a valid pose.
    pub fn is_tracked(&self) -> bool {
        matches!(self.state.as_str(), "ok" | "relocalised")
    }
}

/// Append-only writer of `frames.csv`.
pub struct FrameLog {
    file: File,
    path: PathBuf,
}

impl FrameLog {
    /// Opens the run's `frames.csv`, returning the rows already in it. A
    /// half-written last line (the supervisor was killed mid-write) is cut off.
    pub fn open(run_dir: &Path) -> Result<(Self, Vec<FrameRow>)> {
        let path = run_dir.join(FRAMES_CSV);
        let mut rows = Vec::new();
        if path.exists() {
            let text =
                std::fs::read(&path).with_context(|| format!("cannot read {}", path.display()))?;
            let complete = text
                .iter()
                .rposition(|&b| b == b'\n')
                .map(|i| i + 1)
                .unwrap_or(0);
            if complete < text.len() {
                tracing::warn!("{}: dropping a half-written last line", path.display());
                let f = OpenOptions::new().write(true).open(&path)?;
                f.set_len(complete as u64)?;
            }
            let reader = BufReader::new(&text[..complete]);
            for (i, line) in reader.lines().enumerate() {
                let line = line?;
                if i == 0 {
                    if line != HEADER {
                        bail!(
                            "{}: unexpected header line; not a dynslam frames file",
                            path.display()
                        );
                    }
                    continue;
                }
                rows.push(
                    FrameRow::from_csv(&line)
                        .with_context(|| format!("{} line {}", path.display(), i + 1))?,
                );
            }
        }
        let mut file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .with_context(|| format!("cannot open {}", path.display()))?;
        if std::fs::metadata(&path)?.len() == 0 {
            writeln!(file, "{HEADER}")?;
        }
        Ok((Self { file, path }, rows))
    }

    /// Appends one row with a single write, flushed to the OS at once.
    pub fn append(&mut self, row: &FrameRow) -> Result<()> {
        let line = format!("{}\n", row.to_csv());
        self.file
            .write_all(line.as_bytes())
            .with_context(|| format!("cannot write {}", self.path.display()))
    }
}

/// Writes a TUM trajectory (`timestamp tx ty tz qx qy qz qw`) of the rows
/// that pass `keep`.
pub fn write_tum(
    path: &Path,
    rows: &[FrameRow],
    keep: impl Fn(&FrameRow) -> bool,
) -> Result<usize> {
    let kept: Vec<&FrameRow> = rows.iter().filter(|r| keep(r)).collect();
    let trajectory = Trajectory {
        stamps: kept.iter().map(|r| r.timestamp).collect(),
        poses: kept.iter().map(|r| pose_of(&r.pose)).collect(),
    };
    std::fs::write(path, trajectory.to_tum())
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(kept.len())
}

/// A Track's `[tx ty tz qx qy qz qw]` as an isometry.
fn pose_of(p: &[f64; 7]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(p[0], p[1], p[2]),
        UnitQuaternion::new_unchecked(Quaternion::new(p[6], p[3], p[4], p[5])),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(seq: u64) -> FrameRow {
        FrameRow {
            seq,
            timestamp: 1305031229.5 + seq as f64,
            state: "ok".into(),
            route: "segment".into(),
            mask_source: "segmenter".into(),
            keyframe: true,
            pose: [1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0],
            stamps: StageStamps {
                capture_ns: 10,
                track_done_ns: 99,
                ..Default::default()
            },
            note: "a, b\nc".into(),
            ..Default::default()
        }
    }

    #[test]
    fn rows_round_trip_and_notes_are_sanitised() {
        let r = row(3);
        let back = FrameRow::from_csv(&r.to_csv()).unwrap();
        assert_eq!(back.note, "a; b;c");
        assert_eq!(back.stamps, r.stamps);
        assert_eq!(back.pose, r.pose);
        assert!(FrameRow::from_csv("1,2,3").is_err());
    }

    #[test]
    fn resume_reads_rows_and_cuts_a_half_written_line() {
        let dir = std::env::temp_dir().join(format!("dynslam-outputs-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let _ = std::fs::remove_file(dir.join(FRAMES_CSV));
        {
            let (mut log, rows) = FrameLog::open(&dir).unwrap();
            assert!(rows.is_empty());
            log.append(&row(0)).unwrap();
            log.append(&row(1)).unwrap();
        }
        // A kill in the middle of a write leaves a partial line.
        let mut f = OpenOptions::new()
            .append(true)
            .open(dir.join(FRAMES_CSV))
            .unwrap();
        f.write_all(b"2,1305031231.5,ok,seg").unwrap();
        drop(f);
        let (mut log, rows) = FrameLog::open(&dir).unwrap();
        assert_eq!(rows.iter().map(|r| r.seq).collect::<Vec<_>>(), vec![0, 1]);
        log.append(&row(2)).unwrap();
        let (_, rows) = FrameLog::open(&dir).unwrap();
        assert_eq!(
            rows.iter().map(|r| r.seq).collect::<Vec<_>>(),
            vec![0, 1, 2]
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}
