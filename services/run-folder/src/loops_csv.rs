//! `loops.csv` in the run folder: one row per loop closure, appended as it
//! happens (a SLAM killed later loses none; a restarted one appends).

use std::io::Write;
use std::path::Path;

use slam_core::loop_closing::LoopClosure;

/// The header line of `loops.csv`.
pub const HEADER: &str =
    "timestamp,keyframe,matched_keyframe,inliers,confirmed,correction_m,correction_deg,fused_points,keyframes_moved,scale";

/// Appends `loops` ((timestamp of the keyframe's frame, closure)) to the CSV
/// at `path`, writing the header first if the file is new or empty.
pub fn append(path: &Path, loops: &[(f64, LoopClosure)]) -> std::io::Result<()> {
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)?;
    let mut text = String::new();
    if f.metadata()?.len() == 0 {
        text.push_str(HEADER);
        text.push('\n');
    }
    for (t, l) in loops {
        text.push_str(&format!(
            "{t:.6},{},{},{},{},{:.4},{:.3},{},{},{:.4}\n",
            l.keyframe,
            l.matched,
            l.inliers,
            l.confirmed,
            l.correction_m,
            l.correction_deg,
            l.fused,
            l.keyframes_moved,
            l.scale
        ));
    }
    f.write_all(text.as_bytes())?;
    f.sync_data()
}

/// The rows of a `loops.csv` (header left out); an absent file has none.
pub fn count_rows(path: &Path) -> std::io::Result<usize> {
    Ok(timestamps(path)?.len())
}

/// The timestamp of each row of a `loops.csv` (NaN where it is not a
/// number); an absent file has none.
pub fn timestamps(path: &Path) -> std::io::Result<Vec<f64>> {
    match std::fs::read_to_string(path) {
        Ok(text) => Ok(text
            .lines()
            .skip(1)
            .filter(|l| !l.trim().is_empty())
            .map(|l| {
                l.split(',')
                    .next()
                    .and_then(|t| t.trim().parse().ok())
                    .unwrap_or(f64::NAN)
            })
            .collect()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Vec::new()),
        Err(e) => Err(e),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_append_under_one_header() {
        let dir = std::env::temp_dir().join(format!("dynslam-loops-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("loops.csv");
        let _ = std::fs::remove_file(&path);
        assert_eq!(count_rows(&path).unwrap(), 0);
        let l = LoopClosure {
            keyframe: 45,
            matched: 0,
            inliers: 481,
            confirmed: 711,
            correction_m: 0.04,
            correction_deg: 0.57,
            fused: 481,
            keyframes_moved: 44,
            scale: 1.0,
        };
        append(&path, &[(1014.9, l)]).unwrap();
        append(&path, &[(1020.0, l), (1021.0, l)]).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(text.lines().next().unwrap(), HEADER);
        assert_eq!(text.matches("timestamp").count(), 1);
        assert!(
            text.contains("1014.900000,45,0,481,711,0.0400,0.570,481,44,1.0000"),
            "{text}"
        );
        assert_eq!(count_rows(&path).unwrap(), 3);
        assert_eq!(timestamps(&path).unwrap(), vec![1014.9, 1020.0, 1021.0]);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
