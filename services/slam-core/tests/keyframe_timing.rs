//! When keyframes come in real time (frames dropped, keyframes waiting
//! for their segmenter masks), on the real TUM sequence (../shared).

mod common;
use common::{load, Depth};
use slam_core::{
    Camera, FrameResult, KeyframeTiming, RgbdInput, SlamParams, System, TrackingState,
};

type Frames = Vec<(f64, image::RgbImage, Depth)>;

fn track(
    sys: &mut System,
    (t, rgb, depth): &(f64, image::RgbImage, Depth),
    mask: Option<&[u8]>,
    timing: KeyframeTiming,
) -> FrameResult {
    let input = RgbdInput {
        rgb: rgb.as_raw(),
        depth: depth.as_raw(),
        mask,
        width: 640,
        height: 480,
        timestamp: *t,
    };
    sys.track_with(&input, timing)
}

/// Timestamps of the keyframes made while tracking `frames`, and of the
/// frames that relocalised.
fn keyframe_times(
    params: SlamParams,
    frames: &[&(f64, image::RgbImage, Depth)],
) -> (Vec<f64>, Vec<f64>) {
    let mut sys = System::new(params, Camera::tum_fr1());
    let (mut keyframes, mut relocalised) = (Vec::new(), Vec::new());
    for f in frames {
        let r = track(&mut sys, f, None, KeyframeTiming::Now);
        if r.keyframe_inserted {
            keyframes.push(f.0);
        }
        if r.state == TrackingState::Relocalised {
            relocalised.push(f.0);
        }
    }
    (keyframes, relocalised)
}

/// The longest time between two keyframes with no relocalisation between
/// them (keyframes wait a few frames after one, for the motion model).
fn longest_gap((keyframes, relocalised): &(Vec<f64>, Vec<f64>)) -> f64 {
    keyframes
        .windows(2)
        .filter(|w| !relocalised.iter().any(|t| (w[0]..w[1]).contains(t)))
        .map(|w| w[1] - w[0])
        .fold(0.0, f64::max)
}

#[test]
fn with_frames_dropped_keyframes_still_come_by_the_cameras_time() {
    // Every third frame of 3 s: what a busy machine tracks in real time.
    let data: Frames = load(90);
    let thinned: Vec<_> = data.iter().step_by(3).collect();
    // Keyframes for being long overdue only (no same-view exception).
    let params = SlamParams {
        same_view_m: 0.0,
        ..SlamParams::default()
    };
    let by_time = keyframe_times(params, &thinned);
    let by_frames = keyframe_times(
        SlamParams {
            max_seconds_between_keyframes: f64::INFINITY,
            ..params
        },
        &thinned,
    );
    eprintln!(
        "keyframes by time {} (longest gap {:.2} s), by frames only {} ({:.2} s)",
        by_time.0.len(),
        longest_gap(&by_time),
        by_frames.0.len(),
        longest_gap(&by_frames)
    );
    // At most the time limit plus one frame's gap (0.1 s) apart; counting
    // frames alone, 10 tracked frames are a second: half as many.
    assert!(longest_gap(&by_time) <= 0.32 + 0.11, "{by_time:?}");
    assert!(
        2 * by_time.0.len() >= 3 * by_frames.0.len(),
        "{by_time:?} {by_frames:?}"
    );
}

#[test]
fn a_keyframe_that_waited_for_its_masks_counts_the_cadence_from_its_own_frame() {
    let data: Frames = load(60);
    let mut sys = System::new(SlamParams::default(), Camera::tum_fr1());
    let mut pending_at = Vec::new();
    for (i, f) in data.iter().enumerate() {
        let r = track(&mut sys, f, None, KeyframeTiming::AfterBetterMasks);
        if r.keyframe_pending {
            pending_at.push(i);
        }
        // Its masks come 6 frames later (a segmenter at 60 fps), unless
        // tracking weakened and it went in without them.
        if pending_at.last().is_some_and(|&p| i == p + 6) && sys.keyframe_pending() {
            assert!(sys.complete_keyframe(None));
        }
    }
    eprintln!("keyframes waited at frames {pending_at:?}");
    assert!(pending_at.len() >= 4, "{pending_at:?}");
    // The next one is due 10 frames after the last one's frame (sooner when
    // tracking weakens), not 10 after its masks came (16).
    for w in pending_at.windows(2) {
        assert!(w[1] - w[0] <= 10, "{pending_at:?}");
    }
}

#[test]
fn a_keyframe_stops_waiting_for_its_masks_when_tracking_weakens_two_frames_in_a_row() {
    let data: Frames = load(40);
    let mut sys = System::new(SlamParams::default(), Camera::tum_fr1());
    // Masks hiding all but the left fifth of the image: the frames track
    // on a fraction of their usual inliers.
    let mut mostly_masked = vec![1u8; 640 * 480];
    for row in mostly_masked.chunks_mut(640) {
        row[..256].fill(0);
    }
    let mut pending = None;
    let mut results = Vec::new();
    for (i, f) in data.iter().enumerate() {
        let masked = pending.is_some_and(|p| i > p);
        let mask = masked.then_some(mostly_masked.as_slice());
        let r = track(&mut sys, f, mask, KeyframeTiming::AfterBetterMasks);
        if r.keyframe_pending && pending.is_none() {
            pending = Some(i);
            continue;
        }
        if pending.is_some() {
            results.push((r.counts.inliers, r.waiting_keyframe_inserted));
            if results.len() == 3 {
                break;
            }
        }
    }
    eprintln!("after the pending keyframe: (inliers, inserted) {results:?}");
    assert_eq!(results.len(), 3, "no keyframe waited: {pending:?}");
    // The first weak frame leaves it waiting (one weak frame may be a wrong
    // pose), the second puts it in.
    assert!(!results[0].1 && results[1].1, "{results:?}");
    assert!(!sys.keyframe_pending());
}
