//! What each SLAM death cost a run: the frames without a pose around it and
//! the time from the death to the next pose, from `restarts.log` (a SLAM
//! line says which frame the supervisor had seen last and when it saw the
//! death) and `frames.csv`.

use std::path::Path;

use crate::outputs::FrameRow;
use crate::run_dir::RESTARTS_FILE;

/// One SLAM death.
#[derive(Debug, Clone, PartialEq)]
pub struct SlamOutage {
    /// The first frame the supervisor had not seen when the death was seen.
    pub next_seq: u64,
    /// Frames between the dead process's last pose and its successor's
    /// first: the ones it held and the ones that came while none tracked.
    /// None when no frame was tracked after it (the stream ended).
    pub frames_without_pose: Option<u64>,
    /// From the death seen (the supervisor's watch period after the kill)
    /// to the successor's first pose reaching the supervisor, ms.
    pub death_to_pose_ms: Option<f64>,
}

/// A `restarts.log` line of a SLAM death: (next_seq, when seen in ns of
/// the monotonic clock; absent in logs written before it was recorded).
fn slam_death(line: &str) -> Option<(u64, Option<u64>)> {
    let mut words = line.split_whitespace();
    if words.next()? != "slam" {
        return None;
    }
    let value = |key: &str| {
        let mut w = line.split_whitespace().skip_while(|w| *w != key);
        w.next()?;
        w.next()?.parse::<u64>().ok()
    };
    Some((value("next_seq")?, value("at_ns")))
}

/// The SLAM deaths of the run in `run_dir`, in order, measured on `rows`
/// (its `frames.csv`).
pub fn slam_outages(run_dir: &Path, rows: &[FrameRow]) -> Vec<SlamOutage> {
    let Ok(log) = std::fs::read_to_string(run_dir.join(RESTARTS_FILE)) else {
        return Vec::new();
    };
    let mut tracked: Vec<&FrameRow> = rows.iter().filter(|r| r.is_tracked()).collect();
    tracked.sort_unstable_by_key(|r| r.seq);
    log.lines()
        .filter_map(slam_death)
        .map(|(next_seq, at_ns)| {
            // The dead process only tracked frames the supervisor had seen
            // (< next_seq); its successor never gets those (frames keep no
            // history).
            let at = tracked.partition_point(|r| r.seq < next_seq);
            let last = at.checked_sub(1).map(|i| tracked[i].seq);
            let first = tracked.get(at);
            SlamOutage {
                next_seq,
                frames_without_pose: first.map(|f| f.seq - last.map_or(0, |l| l + 1)),
                death_to_pose_ms: first.zip(at_ns).and_then(|(f, at)| {
                    (f.track_received_ns > at).then(|| (f.track_received_ns - at) as f64 / 1e6)
                }),
            }
        })
        .collect()
}

/// The report's words for `outages` (None without any).
pub fn outages_line(outages: &[SlamOutage]) -> Option<String> {
    if outages.is_empty() {
        return None;
    }
    let frames: Vec<String> = outages
        .iter()
        .map(|o| o.frames_without_pose.map_or("-".into(), |n| n.to_string()))
        .collect();
    let ms: Vec<String> = outages
        .iter()
        .map(|o| o.death_to_pose_ms.map_or("-".into(), |m| format!("{m:.0}")))
        .collect();
    Some(format!(
        "SLAM deaths: {}; frames without a pose around each (the frames the dead process held and those until its successor's first pose): {}; from the death seen to the next pose: {} ms.",
        outages.len(),
        frames.join(", "),
        ms.join(", ")
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(seq: u64, state: &str, received_ns: u64) -> FrameRow {
        FrameRow {
            seq,
            state: state.into(),
            track_received_ns: received_ns,
            ..FrameRow::default()
        }
    }

    #[test]
    fn each_slam_death_costs_the_frames_from_its_last_pose_to_its_successors_first() {
        let dir = std::env::temp_dir().join(format!("dynslam-outages-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        assert!(slam_outages(&dir, &[]).is_empty(), "no log: no outage");
        for line in [
            "slam pid 11 signal 9 (SIGKILL) next_seq 4 at_ns 1000000000",
            "segmenter pid 12 signal 9 (SIGKILL) next_seq 6 at_ns 1100000000",
            // An older log line without the time.
            "slam pid 13 signal 9 (SIGKILL) next_seq 9",
            "slam pid 14 signal 9 (SIGKILL) next_seq 12 at_ns 3000000000",
        ] {
            crate::run_dir::log_restart(&dir, line).unwrap();
        }
        let rows = [
            row(0, "ok", 1),
            row(1, "ok", 2),
            row(2, "dropped", 0), // held by the dead process
            row(3, "dropped", 0),
            row(4, "dropped", 0),
            row(5, "relocalised", 1_150_000_000),
            row(6, "ok", 1_200_000_000),
            row(7, "lost", 1_300_000_000),
            row(8, "dropped", 0),
            row(9, "ok", 2_000_000_000),
            row(10, "ok", 2_100_000_000),
            row(11, "ok", 2_200_000_000),
            row(12, "dropped", 0),
        ];
        let outages = slam_outages(&dir, &rows);
        assert_eq!(
            outages,
            [
                SlamOutage {
                    next_seq: 4,
                    frames_without_pose: Some(3),
                    death_to_pose_ms: Some(150.0),
                },
                SlamOutage {
                    next_seq: 9,
                    frames_without_pose: Some(2),
                    death_to_pose_ms: None,
                },
                SlamOutage {
                    next_seq: 12,
                    frames_without_pose: None,
                    death_to_pose_ms: None,
                },
            ]
        );
        let line = outages_line(&outages).unwrap();
        assert!(line.starts_with("SLAM deaths: 3;"), "{line}");
        assert!(line.contains(": 3, 2, -;"), "{line}");
        assert!(line.ends_with("next pose: 150, -, - ms."), "{line}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
