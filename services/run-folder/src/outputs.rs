//! The run folder's per-frame record, `frames.csv`.
//!
//! One row per frame, appended and flushed the moment the frame's fate is
//! known, so that a killed supervisor loses nothing: a resumed run reads the
//! rows back (dropping a half-written last line) and continues after them.
//! Every other per-frame output (trajectories, latency summary, trace) is
//! derived from these rows at the end of the run.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use serde::{Deserialize, Serialize};
use shared_types::StageStamps;
use slam_core::io::trajectory::Trajectory;

/// One row per frame of the run ([`FrameRow`]).
pub const FRAMES_CSV: &str = "frames.csv";

/// The fate of one frame.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FrameRow {
    /// The frame's sequence number in the run.
    pub seq: u64,
    /// The dataset's (or camera's) timestamp, seconds.
    pub timestamp: f64,
    /// ok, lost, relocalised, not_initialised, skipped, or dropped (real-time
    /// mode: a newer frame was tracked first).
    pub state: String,
    /// segment, propagate, segment-behind, skip, refused (an external frame
    /// that does not fit the run), or none (never routed).
    pub route: String,
    /// segmenter, propagator, none.
    pub mask_source: String,
    /// SLAM made this frame a keyframe.
    pub keyframe: bool,
    /// SLAM asked for the next frame to be segmented (the routing flag).
    pub next_keyframe: bool,
    /// Camera pose in the world, TUM order: tx ty tz qx qy qz qw.
    pub pose: [f64; 7],
    /// ORB features extracted.
    pub features: u32,
    /// Features dropped because they fell on a mask.
    pub features_masked: u32,
    /// Features dropped by the motion check.
    pub features_moving: u32,
    /// Features matched to map points that survived the pose optimisation.
    pub inliers: u32,
    /// Map points in the map after this frame.
    pub map_points: u32,
    /// Keyframes in the map after this frame.
    pub keyframes: u32,
    /// SLAM's feature extraction time (microseconds).
    pub extract_us: u32,
    /// SLAM's local mapping time after this frame (microseconds).
    pub mapping_us: u32,
    /// Tracked by following the last frame's points with optical flow (no
    /// ORB extraction: `services.slam.flow_frames`).
    pub tracked_by_flow: bool,
    /// When each stage took and handed on the frame.
    pub stamps: StageStamps,
    /// When the supervisor received the Track (end of the frame's path).
    pub track_received_ns: u64,
    /// Where those masks were made: local, remote, fallback (the local
    /// model standing in for a remote worker) or none.
    pub mask_origin: String,
    /// Free text: why a frame was skipped or dropped.
    pub note: String,
}

/// One line of `frames.csv` as written: the pose columns are empty where
/// a frame has no pose (skipped, dropped, lost, not initialised).
#[derive(Debug, Serialize, Deserialize)]
struct CsvRow {
    seq: u64,
    timestamp: f64,
    state: String,
    route: String,
    mask_source: String,
    keyframe: u8,
    next_keyframe: u8,
    tx: Option<f64>,
    ty: Option<f64>,
    tz: Option<f64>,
    qx: Option<f64>,
    qy: Option<f64>,
    qz: Option<f64>,
    qw: Option<f64>,
    features: u32,
    features_masked: u32,
    /// Absent in frames.csv of older versions (a resumed run).
    #[serde(default)]
    features_moving: u32,
    inliers: u32,
    map_points: u32,
    keyframes: u32,
    slam_extract_us: u32,
    slam_mapping_us: u32,
    capture_ns: u64,
    published_ns: u64,
    routed_ns: u64,
    masks_start_ns: u64,
    masks_done_ns: u64,
    slam_received_ns: u64,
    track_start_ns: u64,
    track_done_ns: u64,
    track_received_ns: u64,
    /// Absent in frames.csv of older versions (a resumed run).
    #[serde(default)]
    mask_origin: String,
    /// Absent in frames.csv of older versions (a resumed run).
    #[serde(default)]
    tracked_by_flow: u8,
    note: String,
}

/// The header line `CsvRow` writes (checked by a test).
const HEADER: &str = "seq,timestamp,state,route,mask_source,keyframe,next_keyframe,\
tx,ty,tz,qx,qy,qz,qw,features,features_masked,features_moving,inliers,map_points,keyframes,\
slam_extract_us,slam_mapping_us,capture_ns,published_ns,routed_ns,masks_start_ns,masks_done_ns,slam_received_ns,\
track_start_ns,track_done_ns,track_received_ns,mask_origin,tracked_by_flow,note";

impl From<&FrameRow> for CsvRow {
    fn from(r: &FrameRow) -> Self {
        let s = &r.stamps;
        let pose = |k: usize| r.is_tracked().then_some(r.pose[k]);
        Self {
            seq: r.seq,
            timestamp: r.timestamp,
            state: r.state.clone(),
            route: r.route.clone(),
            mask_source: r.mask_source.clone(),
            keyframe: r.keyframe as u8,
            next_keyframe: r.next_keyframe as u8,
            tx: pose(0),
            ty: pose(1),
            tz: pose(2),
            qx: pose(3),
            qy: pose(4),
            qz: pose(5),
            qw: pose(6),
            features: r.features,
            features_masked: r.features_masked,
            features_moving: r.features_moving,
            inliers: r.inliers,
            map_points: r.map_points,
            keyframes: r.keyframes,
            slam_extract_us: r.extract_us,
            slam_mapping_us: r.mapping_us,
            capture_ns: s.capture_ns,
            published_ns: s.published_ns,
            routed_ns: s.routed_ns,
            masks_start_ns: s.masks_start_ns,
            masks_done_ns: s.masks_done_ns,
            slam_received_ns: s.slam_received_ns,
            track_start_ns: s.track_start_ns,
            track_done_ns: s.track_done_ns,
            track_received_ns: r.track_received_ns,
            mask_origin: r.mask_origin.clone(),
            tracked_by_flow: r.tracked_by_flow as u8,
            // One frame, one line (a resumed run cuts a half-written last
            // line): line breaks in a note become spaces, commas are quoted.
            note: r.note.replace(['\n', '\r'], " "),
        }
    }
}

impl From<CsvRow> for FrameRow {
    fn from(c: CsvRow) -> Self {
        let p = [c.tx, c.ty, c.tz, c.qx, c.qy, c.qz, c.qw];
        Self {
            seq: c.seq,
            timestamp: c.timestamp,
            state: c.state,
            route: c.route,
            mask_source: c.mask_source,
            keyframe: c.keyframe != 0,
            next_keyframe: c.next_keyframe != 0,
            pose: p.map(|v| v.unwrap_or(0.0)),
            features: c.features,
            features_masked: c.features_masked,
            features_moving: c.features_moving,
            inliers: c.inliers,
            map_points: c.map_points,
            keyframes: c.keyframes,
            extract_us: c.slam_extract_us,
            mapping_us: c.slam_mapping_us,
            stamps: StageStamps {
                capture_ns: c.capture_ns,
                published_ns: c.published_ns,
                routed_ns: c.routed_ns,
                masks_start_ns: c.masks_start_ns,
                masks_done_ns: c.masks_done_ns,
                slam_received_ns: c.slam_received_ns,
                track_start_ns: c.track_start_ns,
                track_done_ns: c.track_done_ns,
            },
            track_received_ns: c.track_received_ns,
            mask_origin: c.mask_origin,
            tracked_by_flow: c.tracked_by_flow != 0,
            note: c.note,
        }
    }
}

impl FrameRow {
    /// The row as one CSV line (with its newline; quoted where needed).
    pub fn to_csv(&self) -> Result<String> {
        let mut w = csv::WriterBuilder::new()
            .has_headers(false)
            .from_writer(Vec::new());
        w.serialize(CsvRow::from(self))?;
        let bytes = w.into_inner().map_err(|e| anyhow::anyhow!("{e}"))?;
        Ok(String::from_utf8(bytes)?)
    }

    /// True when the row has a valid pose.
    pub fn is_tracked(&self) -> bool {
        matches!(self.state.as_str(), "ok" | "relocalised" | "turning")
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
            let (r, complete, len) = read_complete_rows(&path)?;
            if complete < len {
                tracing::warn!("{}: dropping a half-written last line", path.display());
                let f = OpenOptions::new().write(true).open(&path)?;
                f.set_len(complete as u64)?;
            }
            rows = r;
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
        let line = row.to_csv()?;
        self.file
            .write_all(line.as_bytes())
            .with_context(|| format!("cannot write {}", self.path.display()))
    }
}

/// The rows of a run's `frames.csv` in frame order (the last row of a
/// frame wins); a half-written last line is left out.
pub fn read_rows(run_dir: &Path) -> Result<Vec<FrameRow>> {
    let path = run_dir.join(FRAMES_CSV);
    if !path.exists() {
        return Ok(Vec::new());
    }
    let mut rows = read_complete_rows(&path)?.0;
    rows.sort_by_key(|r| r.seq);
    rows.dedup_by(|later, earlier| {
        let same = later.seq == earlier.seq;
        if same {
            std::mem::swap(later, earlier);
        }
        same
    });
    Ok(rows)
}

/// The rows of the complete lines of `path`, the length of those lines
/// and the file's length.
fn read_complete_rows(path: &Path) -> Result<(Vec<FrameRow>, usize, usize)> {
    let text = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let complete = text
        .iter()
        .rposition(|&b| b == b'\n')
        .map(|i| i + 1)
        .unwrap_or(0);
    let mut reader = csv::ReaderBuilder::new().from_reader(&text[..complete]);
    let header: Vec<String> = reader
        .headers()
        .with_context(|| format!("cannot read {}", path.display()))?
        .iter()
        .map(String::from)
        .collect();
    if complete > 0 && header.join(",") != HEADER {
        bail!(
            "{}: unexpected header line; not a frames file of this dynslam version",
            path.display()
        );
    }
    let mut rows = Vec::new();
    for record in reader.deserialize::<CsvRow>() {
        let row = record.map_err(|e| {
            let line = e.position().map_or(0, |p| p.line());
            anyhow::anyhow!("{} line {line}: {e}", path.display())
        })?;
        rows.push(row.into());
    }
    Ok((rows, complete, text.len()))
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
            mask_origin: "remote".into(),
            keyframe: true,
            tracked_by_flow: true,
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

    fn read_back(line: &str) -> FrameRow {
        let text = format!("{HEADER}\n{line}");
        let mut reader = csv::ReaderBuilder::new().from_reader(text.as_bytes());
        let header: Vec<&str> = reader.headers().unwrap().iter().collect();
        assert_eq!(header.join(","), HEADER);
        reader
            .deserialize::<CsvRow>()
            .next()
            .unwrap()
            .unwrap()
            .into()
    }

    #[test]
    fn read_rows_orders_by_frame_and_leaves_out_a_half_written_line() {
        let dir = std::env::temp_dir().join(format!("dynslam-readrows-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let (mut log, old) = FrameLog::open(&dir).unwrap();
        assert!(old.is_empty());
        for seq in [1u64, 0, 2] {
            log.append(&row(seq)).unwrap();
        }
        let mut f = OpenOptions::new()
            .append(true)
            .open(dir.join(FRAMES_CSV))
            .unwrap();
        f.write_all(b"3,1.5,ok").unwrap();
        let rows = read_rows(&dir).unwrap();
        assert_eq!(
            rows.iter().map(|r| r.seq).collect::<Vec<_>>(),
            vec![0, 1, 2]
        );
        assert_eq!(
            (rows[1].timestamp, rows[1].pose),
            (row(1).timestamp, row(1).pose)
        );
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn rows_round_trip_with_notes_quoted_and_no_pose_left_empty() {
        let r = row(3);
        let line = r.to_csv().unwrap();
        assert!(
            line.ends_with('\n') && line.contains("\"a, b c\""),
            "{line}"
        );
        assert_eq!(line.matches('\n').count(), 1);
        let back = read_back(&line);
        assert_eq!(back.note, "a, b c");
        assert_eq!(
            back,
            FrameRow {
                note: "a, b c".into(),
                ..r
            }
        );
        let skipped = FrameRow {
            state: "skipped".into(),
            ..row(4)
        };
        let line = skipped.to_csv().unwrap();
        assert!(line.contains(",,,,,,,"), "{line}");
        assert_eq!(read_back(&line).pose, [0.0; 7]);
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
