//! Per-stage latency from the CLOCK_MONOTONIC stamps every payload carries:
//! a summary (p50/p90/p99/max per stage) and a trace that Perfetto and
//! chrome://tracing open, with one track per process.

use serde::Serialize;
use serde_json::json;

use shared_types::stats::percentile;

use crate::outputs::FrameRow;

/// The stages of a frame's path, in path order, then the two mask workers'
/// own working time (segmenter on keyframes, propagator otherwise).
pub const STAGES: [&str; 12] = [
    "decode",
    "capture_to_route",
    "route_to_masks",
    "masks_to_track",
    "track",
    "transport_frame",
    "track_to_supervisor",
    "end_to_end",
    "segmenter",
    "propagator",
    "slam_extract",
    "slam_mapping",
];

fn span(from: u64, to: u64) -> Option<f64> {
    (from > 0 && to >= from).then(|| (to - from) as f64 / 1e6)
}

/// Milliseconds of each stage of one row (`None` where a stage did not happen).
pub fn stage_ms(r: &FrameRow) -> [Option<f64>; STAGES.len()] {
    let s = &r.stamps;
    let masks_end = if s.masks_done_ns > 0 {
        s.masks_done_ns
    } else {
        s.routed_ns
    };
    [
        span(s.capture_ns, s.published_ns),
        span(s.published_ns, s.routed_ns),
        if s.masks_done_ns > 0 {
            span(s.routed_ns, s.masks_done_ns)
        } else {
            None
        },
        span(masks_end, s.track_done_ns),
        span(s.track_start_ns, s.track_done_ns),
        span(s.published_ns, s.slam_received_ns),
        span(s.track_done_ns, r.track_received_ns),
        span(s.capture_ns, r.track_received_ns),
        // By whose masks the frame was tracked (a frame segmented behind is
        // tracked with the propagator's).
        if r.mask_source == "segmenter" {
            span(s.masks_start_ns, s.masks_done_ns)
        } else {
            None
        },
        if r.mask_source == "propagator" {
            span(s.masks_start_ns, s.masks_done_ns)
        } else {
            None
        },
        (r.extract_us > 0).then(|| r.extract_us as f64 / 1e3),
        (r.mapping_us > 0).then(|| r.mapping_us as f64 / 1e3),
    ]
}

/// One stage's latency over a run (one row of the report's latency table).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct StageSummary {
    /// The stage's name (one of `STAGES`).
    pub stage: String,
    /// How many frames had this stage.
    pub count: usize,
    /// Median, milliseconds.
    pub p50_ms: f64,
    /// 90th percentile, milliseconds.
    pub p90_ms: f64,
    /// 99th percentile, milliseconds.
    pub p99_ms: f64,
    /// The slowest frame, milliseconds.
    pub max_ms: f64,
}

/// Per-stage latency percentiles over the frames that went through each stage.
pub fn summarize(rows: &[FrameRow]) -> Vec<StageSummary> {
    let per_row: Vec<[Option<f64>; STAGES.len()]> = rows.iter().map(stage_ms).collect();
    STAGES
        .iter()
        .enumerate()
        .map(|(i, name)| {
            let mut v: Vec<f64> = per_row.iter().filter_map(|s| s[i]).collect();
            v.sort_by(f64::total_cmp);
            StageSummary {
                stage: name.to_string(),
                count: v.len(),
                p50_ms: percentile(&v, 50.0),
                p90_ms: percentile(&v, 90.0),
                p99_ms: percentile(&v, 99.0),
                max_ms: v.last().copied().unwrap_or(0.0),
            }
        })
        .collect()
}

/// A fixed-width table of the summary for the terminal and the report.
pub fn format_table(summary: &[StageSummary]) -> String {
    let mut out = format!(
        "{:<20} {:>6} {:>9} {:>9} {:>9} {:>9}\n",
        "stage", "frames", "p50 ms", "p90 ms", "p99 ms", "max ms"
    );
    for s in summary {
        out.push_str(&format!(
            "{:<20} {:>6} {:>9.3} {:>9.3} {:>9.3} {:>9.3}\n",
            s.stage, s.count, s.p50_ms, s.p90_ms, s.p99_ms, s.max_ms
        ));
    }
    out
}

/// Process tracks of the trace.
const TRACKS: [(u32, &str); 5] = [
    (1, "camera-reader"),
    (2, "supervisor"),
    (3, "segmenter"),
    (4, "propagator"),
    (5, "slam"),
];

/// Chrome trace-event JSON: one complete event per stage per frame, on the
/// track of the process that did the work. Times are microseconds since the
/// first capture of the run.
pub fn trace_json(rows: &[FrameRow]) -> serde_json::Value {
    let t0 = rows
        .iter()
        .map(|r| r.stamps.capture_ns)
        .filter(|&t| t > 0)
        .min()
        .unwrap_or(0);
    let us = |t: u64| (t.saturating_sub(t0)) as f64 / 1e3;
    let mut events = Vec::new();
    for (pid, name) in TRACKS {
        events.push(json!({"name": "process_name", "ph": "M", "pid": pid, "tid": 0, "args": {"name": name}}));
        events.push(
            json!({"name": "thread_name", "ph": "M", "pid": pid, "tid": 0, "args": {"name": name}}),
        );
    }
    let mut complete = |pid: u32, name: &str, from: u64, to: u64, r: &FrameRow| {
        if from > 0 && to >= from {
            events.push(json!({
                "name": name, "ph": "X", "pid": pid, "tid": 0,
                "ts": us(from), "dur": (to - from) as f64 / 1e3,
                "args": {"seq": r.seq, "route": r.route, "state": r.state}
            }));
        }
    };
    for r in rows {
        let s = &r.stamps;
        complete(1, "decode", s.capture_ns, s.published_ns, r);
        complete(2, "route", s.published_ns, s.routed_ns, r);
        let worker = if r.mask_source == "segmenter" { 3 } else { 4 };
        complete(
            worker,
            r.route.as_str(),
            s.masks_start_ns,
            s.masks_done_ns,
            r,
        );
        complete(5, "track", s.track_start_ns, s.track_done_ns, r);
        complete(2, "record", s.track_done_ns, r.track_received_ns, r);
    }
    json!({"traceEvents": events, "displayTimeUnit": "ms"})
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared_types::StageStamps;

    fn row(seq: u64, base: u64) -> FrameRow {
        FrameRow {
            seq,
            route: "segment".into(),
            mask_source: "segmenter".into(),
            state: "ok".into(),
            stamps: StageStamps {
                capture_ns: base,
                published_ns: base + 10_000_000,
                routed_ns: base + 10_100_000,
                masks_start_ns: base + 10_200_000,
                masks_done_ns: base + 30_000_000,
                slam_received_ns: base + 10_050_000,
                track_start_ns: base + 30_100_000,
                track_done_ns: base + 40_000_000,
            },
            track_received_ns: base + 40_200_000,
            ..Default::default()
        }
    }

    #[test]
    fn stages_are_differences_of_stamps() {
        let s = stage_ms(&row(0, 1_000_000_000));
        assert!((s[0].unwrap() - 10.0).abs() < 1e-9);
        assert!((s[2].unwrap() - 19.9).abs() < 1e-9);
        assert!((s[5].unwrap() - 0.05).abs() < 1e-9);
        assert!((s[7].unwrap() - 40.2).abs() < 1e-9);
    }

    #[test]
    fn trace_has_one_named_track_per_process() {
        let rows: Vec<_> = (0..3)
            .map(|i| row(i, 1_000_000_000 + i * 50_000_000))
            .collect();
        let t = trace_json(&rows);
        let events = t["traceEvents"].as_array().unwrap();
        let names: Vec<_> = events
            .iter()
            .filter(|e| e["name"] == "process_name")
            .map(|e| e["args"]["name"].as_str().unwrap())
            .collect();
        assert_eq!(
            names,
            vec![
                "camera-reader",
                "supervisor",
                "segmenter",
                "propagator",
                "slam"
            ]
        );
        assert_eq!(events.iter().filter(|e| e["ph"] == "X").count(), 3 * 5);
    }
}
