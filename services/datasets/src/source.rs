//! Frame sources: the ordered list of frames a run plays.
//!
//! A TUM RGB-D folder is read as the benchmark's own tools do: `rgb.txt` and
//! `depth.txt` (`timestamp path` lines, `#` comments), associated by nearest
//! timestamp within a tolerance (greedy on the smallest differences, each
//! image used once, like `associate.py`). Any malformed or unsorted line is an
//! error naming the file and line: a silently skipped line would shift every
//! later frame against the ground truth.

use std::path::{Path, PathBuf};

/// One frame to play.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameEntry {
    /// Source timestamp (seconds; TUM time, or index * period for folders).
    pub timestamp: f64,
    /// The colour image.
    pub rgb: PathBuf,
    /// The depth image (16-bit PNG), where the source has depth.
    pub depth: Option<PathBuf>,
}

/// Why a frame list could not be made; each names the file and line.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SourceError {
    /// The dataset folder is missing.
    #[error("dataset folder {0} does not exist or is not a folder")]
    MissingFolder(PathBuf),
    /// A list could not be read.
    #[error("{path}: cannot read: {message}")]
    Unreadable {
        /// The list or folder.
        path: PathBuf,
        /// The system's reason.
        message: String,
    },
    /// A line of a list is malformed or out of order.
    #[error("{path} line {line}: {message}")]
    BadLine {
        /// The list.
        path: PathBuf,
        /// Its line (from 1).
        line: usize,
        /// What is wrong with it.
        message: String,
    },
    /// A list or folder has no frames to play.
    #[error("{path}: {message}")]
    Empty {
        /// The list or folder.
        path: PathBuf,
        /// What is missing.
        message: String,
    },
    /// The configured source is live: it has no list (the source kind).
    #[error("source.kind = \"{0}\" is live (a camera or an outside publisher): there is no frame list to play")]
    Live(&'static str),
}

/// A timestamped file list (`rgb.txt`, `depth.txt`).
#[derive(Debug, Clone, PartialEq)]
pub struct TimedList {
    /// (timestamp in seconds, file), in the list's order.
    pub entries: Vec<(f64, PathBuf)>,
}

/// Timestamps are seconds below this (see [`parse_timed_list`]).
const MAX_TIMESTAMP_S: f64 = 1e10;

/// Parses a TUM `timestamp path` list. Paths are relative to `base`.
pub fn parse_timed_list(
    text: &str,
    list_path: &Path,
    base: &Path,
) -> Result<TimedList, SourceError> {
    let mut entries: Vec<(f64, PathBuf)> = Vec::new();
    let mut previous_line = 0;
    // A UTF-8 byte-order mark (Windows editors) is not part of the first line.
    let text = text.trim_start_matches('\u{feff}');
    for (i, raw) in text.lines().enumerate() {
        let line_no = i + 1;
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let bad = |message: String| SourceError::BadLine {
            path: list_path.to_path_buf(),
            line: line_no,
            message,
        };
        let mut fields = line.split_whitespace();
        let (Some(ts), Some(file), None) = (fields.next(), fields.next(), fields.next()) else {
            return Err(bad(format!(
                "expected '<timestamp> <file>', found '{line}'"
            )));
        };
        let timestamp: f64 = ts
            .parse()
            .ok()
            .filter(|t: &f64| t.is_finite() && *t >= 0.0)
            .ok_or_else(|| bad(format!("'{ts}' is not a valid timestamp")))?;
        // Seconds since 1970 stay below 1e10 until the year 2286; above it
        // the list is in another unit, and f64 seconds that large lose the
        // sub-millisecond steps between frames (real time would play them
        // at once or hours apart).
        if timestamp >= MAX_TIMESTAMP_S {
            return Err(bad(format!(
                "timestamp {ts} is not in seconds (>= 1e10 s, after the year 2286: nanoseconds or \
                 microseconds? TUM lists give seconds, e.g. 1305031102.175304)"
            )));
        }
        if let Some((prev, _)) = entries.last() {
            if timestamp <= *prev {
                return Err(bad(format!(
                    "timestamp {ts} is not after line {previous_line} ({prev}); the list must be sorted by time"
                )));
            }
        }
        // Frames come from inside the dataset folder only: a list is input,
        // and `/etc/passwd` or `../../x` is not a frame of this dataset.
        let rel = Path::new(file);
        if rel.is_absolute()
            || rel
                .components()
                .any(|c| matches!(c, std::path::Component::ParentDir))
        {
            return Err(bad(format!(
                "'{file}' is outside the dataset folder (an absolute path or '..'); list files inside it (a symbolic link inside the folder may point elsewhere)"
            )));
        }
        previous_line = line_no;
        entries.push((timestamp, base.join(file)));
    }
    if entries.is_empty() {
        return Err(SourceError::Empty {
            path: list_path.to_path_buf(),
            message: "lists no frames".into(),
        });
    }
    Ok(TimedList { entries })
}

/// Reads the list `name` (e.g. `rgb.txt`) of a TUM folder.
pub fn read_list(folder: &Path, name: &str) -> Result<TimedList, SourceError> {
    let path = folder.join(name);
    let text = std::fs::read_to_string(&path).map_err(|e| SourceError::Unreadable {
        path: path.clone(),
        message: e.to_string(),
    })?;
    parse_timed_list(&text, &path, folder)
}

/// The ground-truth label images of a synthesised sequence (`masks.txt`,
/// written by `dynslam synth`), by the colour frame's timestamp.
pub struct MaskList {
    entries: Vec<(f64, PathBuf)>,
}

impl MaskList {
    /// `None` when `folder` has no `masks.txt` (not a synthesised sequence).
    pub fn open(folder: &Path) -> Result<Option<Self>, SourceError> {
        Self::open_list(folder, "masks.txt")
    }

    /// The same for another list of label images in `folder` (as
    /// masks-eval's `ignore.txt`); `None` when there is no such file.
    pub fn open_list(folder: &Path, list: &str) -> Result<Option<Self>, SourceError> {
        if !folder.join(list).is_file() {
            return Ok(None);
        }
        Ok(Some(Self {
            entries: read_list(folder, list)?.entries,
        }))
    }

    /// The mask file of the frame at `timestamp` (same stamp as rgb.txt).
    pub fn path_at(&self, timestamp: f64) -> Option<&Path> {
        let i = self.entries.partition_point(|(t, _)| *t < timestamp - 1e-5);
        self.entries
            .get(i)
            .filter(|(t, _)| (t - timestamp).abs() <= 1e-5)
            .map(|(_, p)| p.as_path())
    }

    /// The label image at `timestamp`: an error names the missing entry or
    /// the unreadable file.
    pub fn load_at(&self, timestamp: f64) -> Result<image::GrayImage, String> {
        let p = self
            .path_at(timestamp)
            .ok_or_else(|| format!("masks.txt lists no mask for frame {timestamp:.6}"))?;
        image::open(p)
            .map(|i| i.to_luma8())
            .map_err(|e| format!("{}: {e}", p.display()))
    }
}

/// `frames` played `passes` times in a row: every pass's timestamps go on
/// one (median) frame period after the previous pass's last frame, so time
/// only moves forward.
pub fn repeated(frames: Vec<FrameEntry>, passes: u32) -> Vec<FrameEntry> {
    if passes <= 1 || frames.is_empty() {
        return frames;
    }
    let mut periods: Vec<f64> = frames
        .windows(2)
        .map(|w| w[1].timestamp - w[0].timestamp)
        .collect();
    periods.sort_by(f64::total_cmp);
    let period = periods
        .get(periods.len() / 2)
        .copied()
        .unwrap_or(1.0 / 30.0);
    let span = frames[frames.len() - 1].timestamp - frames[0].timestamp + period;
    let mut out = Vec::with_capacity(frames.len() * passes as usize);
    for pass in 0..passes {
        out.extend(frames.iter().map(|f| FrameEntry {
            timestamp: f.timestamp + pass as f64 * span,
            ..f.clone()
        }));
    }
    out
}

/// Associates rgb and depth by nearest timestamp within `max_diff` seconds:
/// candidate pairs sorted by difference, taken greedily, each image once
/// (the TUM benchmark's `associate.py`). Returns pairs in time order.
pub fn associate(rgb: &TimedList, depth: &TimedList, max_diff: f64) -> Vec<FrameEntry> {
    let d = &depth.entries;
    let mut candidates: Vec<(f64, usize, usize)> = Vec::new();
    for (i, (t, _)) in rgb.entries.iter().enumerate() {
        // depth is sorted: start at the first depth stamp >= t - max_diff.
        let start = d.partition_point(|(td, _)| *td < t - max_diff);
        for (j, (td, _)) in d.iter().enumerate().skip(start) {
            let diff = (td - t).abs();
            if *td > t + max_diff {
                break;
            }
            if diff < max_diff {
                candidates.push((diff, i, j));
            }
        }
    }
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let mut rgb_used = vec![false; rgb.entries.len()];
    let mut depth_used = vec![false; d.len()];
    let mut pairs = Vec::new();
    for (_, i, j) in candidates {
        if !rgb_used[i] && !depth_used[j] {
            rgb_used[i] = true;
            depth_used[j] = true;
            pairs.push((i, j));
        }
    }
    pairs.sort();
    pairs
        .into_iter()
        .map(|(i, j)| FrameEntry {
            timestamp: rgb.entries[i].0,
            rgb: rgb.entries[i].1.clone(),
            depth: Some(d[j].1.clone()),
        })
        .collect()
}

/// Reads a TUM RGB-D folder into its associated frame list.
pub fn tum_folder(folder: &Path, max_diff: f64) -> Result<Vec<FrameEntry>, SourceError> {
    if !folder.is_dir() {
        return Err(SourceError::MissingFolder(folder.to_path_buf()));
    }
    let rgb = read_list(folder, "rgb.txt")?;
    let depth = read_list(folder, "depth.txt")?;
    let frames = associate(&rgb, &depth, max_diff);
    if frames.is_empty() {
        return Err(SourceError::Empty {
            path: folder.to_path_buf(),
            message: format!("no rgb/depth pair within {max_diff} s of each other"),
        });
    }
    Ok(frames)
}

/// A folder of PNG images in file-name order, `period` seconds apart.
pub fn image_folder(folder: &Path, period: f64) -> Result<Vec<FrameEntry>, SourceError> {
    if !folder.is_dir() {
        return Err(SourceError::MissingFolder(folder.to_path_buf()));
    }
    let read = std::fs::read_dir(folder).map_err(|e| SourceError::Unreadable {
        path: folder.to_path_buf(),
        message: e.to_string(),
    })?;
    let mut files: Vec<PathBuf> = read
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")))
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(SourceError::Empty {
            path: folder.to_path_buf(),
            message: "contains no .png images".into(),
        });
    }
    Ok(files
        .into_iter()
        .enumerate()
        .map(|(i, rgb)| FrameEntry {
            timestamp: i as f64 * period,
            rgb,
            depth: None,
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn list(text: &str) -> Result<TimedList, SourceError> {
        parse_timed_list(text, Path::new("/d/rgb.txt"), Path::new("/d"))
    }

    #[test]
    fn a_repeated_sequence_keeps_time_moving_forward() {
        let frames: Vec<FrameEntry> = [10.0, 10.1, 10.2, 10.35]
            .iter()
            .map(|&t| FrameEntry {
                timestamp: t,
                rgb: PathBuf::from(format!("rgb/{t}.png")),
                depth: None,
            })
            .collect();
        assert_eq!(repeated(frames.clone(), 1), frames);
        let three = repeated(frames.clone(), 3);
        assert_eq!(three.len(), 12);
        // The median period (0.1 s) separates the passes.
        assert!(
            (three[4].timestamp - 10.45).abs() < 1e-9,
            "{}",
            three[4].timestamp
        );
        assert!((three[11].timestamp - (10.35 + 2.0 * 0.45)).abs() < 1e-9);
        assert!(three.windows(2).all(|w| w[1].timestamp > w[0].timestamp));
        assert_eq!(three[8].rgb, frames[0].rgb);
    }

    #[test]
    fn paths_outside_the_dataset_folder_are_refused_and_a_bom_is_not_a_character() {
        for file in ["/etc/passwd", "../other/rgb/1.png", "rgb/../../x.png"] {
            let err = list(&format!("1.0 rgb/a.png\n2.0 {file}\n"))
                .unwrap_err()
                .to_string();
            assert!(
                err.contains("outside the dataset folder") && err.contains("line 2"),
                "{err}"
            );
        }
        let ok = list("\u{feff}# color images\n1.0 rgb/a.png\n").unwrap();
        assert_eq!(ok.entries, vec![(1.0, PathBuf::from("/d/rgb/a.png"))]);
        let ok = list("\u{feff}1.0 rgb/a.png\n").unwrap();
        assert_eq!(ok.entries.len(), 1);
    }

    #[test]
    fn parses_comments_and_relative_paths() {
        let l =
            list("# color images\n# timestamp filename\n1.0 rgb/1.png\n\n2.5 rgb/2.png\n").unwrap();
        assert_eq!(l.entries.len(), 2);
        assert_eq!(l.entries[1], (2.5, PathBuf::from("/d/rgb/2.png")));
    }

    #[test]
    fn malformed_line_names_file_and_line() {
        let err = list("# c\n1.0 rgb/1.png\nnot-a-line\n").unwrap_err();
        assert_eq!(
            err.to_string(),
            "/d/rgb.txt line 3: expected '<timestamp> <file>', found 'not-a-line'"
        );
        let err = list("abc rgb/1.png\n").unwrap_err();
        assert!(
            err.to_string()
                .contains("line 1: 'abc' is not a valid timestamp"),
            "{err}"
        );
        let err = list("1.0 a.png extra\n").unwrap_err();
        assert!(err.to_string().contains("line 1"), "{err}");
        // Nanoseconds (a ROS bag export) are refused, seconds of today pass.
        let err = list("1.0 a.png\n1305031102175304000 b.png\n").unwrap_err();
        assert!(
            err.to_string().contains("line 2") && err.to_string().contains("not in seconds"),
            "{err}"
        );
        list("1305031102.175304 a.png\n").unwrap();
    }

    #[test]
    fn unsorted_line_names_both_lines() {
        let err = list("2.0 a.png\n3.0 b.png\n2.5 c.png\n").unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains("line 3") && msg.contains("line 2") && msg.contains("sorted"),
            "{msg}"
        );
    }

    #[test]
    fn empty_list_is_an_error() {
        assert!(matches!(
            list("# nothing\n"),
            Err(SourceError::Empty { .. })
        ));
    }

    #[test]
    fn association_is_greedy_nearest_and_one_to_one() {
        let rgb = list("1.00 r1\n1.03 r2\n1.07 r3\n2.00 r4\n").unwrap();
        let depth = list("1.01 d1\n1.02 d2\n1.071 d3\n").unwrap();
        let pairs = associate(&rgb, &depth, 0.02);
        let names: Vec<_> = pairs
            .iter()
            .map(|p| {
                (
                    p.rgb.file_name().unwrap().to_str().unwrap().to_string(),
                    p.depth
                        .as_ref()
                        .unwrap()
                        .file_name()
                        .unwrap()
                        .to_str()
                        .unwrap()
                        .to_string(),
                )
            })
            .collect();
        // r2 (1.03) pairs with d2 (1.02, diff .01) and r1 with d1; r3 with d3; r4 has none.
        assert_eq!(
            names,
            vec![
                ("r1".into(), "d1".into()),
                ("r2".into(), "d2".into()),
                ("r3".into(), "d3".into())
            ]
        );
    }

    #[test]
    fn shared_tum_sequence_associates_all_300_frames() {
        let folder = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../../shared/data/tum/rgbd_dataset_freiburg1_rpy_first300");
        let frames = tum_folder(&folder, 0.02).unwrap();
        // The dataset's own associations.txt (made by associate.py) has the same pairs.
        let reference = std::fs::read_to_string(folder.join("associations.txt")).unwrap();
        let expected: Vec<&str> = reference.lines().filter(|l| !l.starts_with('#')).collect();
        assert_eq!(frames.len(), expected.len());
        for (f, line) in frames.iter().zip(&expected) {
            let fields: Vec<&str> = line.split_whitespace().collect();
            assert!(f.rgb.ends_with(fields[1]), "{:?} vs {line}", f.rgb);
            assert!(
                f.depth.as_ref().unwrap().ends_with(fields[3]),
                "{:?} vs {line}",
                f.depth
            );
        }
    }

    #[test]
    fn random_lists_are_errors_or_lists_never_panics() {
        for text in crate::fuzz::texts(11, 3000) {
            if let Err(e) = list(&text) {
                assert!(e.to_string().starts_with("/d/rgb.txt"), "{e}");
            }
        }
    }

    #[test]
    fn missing_folder_is_named() {
        let err = tum_folder(Path::new("/no/such/folder"), 0.02).unwrap_err();
        assert_eq!(
            err.to_string(),
            "dataset folder /no/such/folder does not exist or is not a folder"
        );
    }
}
