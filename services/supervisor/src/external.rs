//! Frames from a program outside the pipeline (`source.kind = "external"`,
//! README "Frames in"): the supervisor is the first to see each one and
//! checks it against the run's configuration, so that a publisher's mistake
//! becomes a recorded bad frame with its reason (routed Skip, no worker
//! touches its pixels) instead of a worker reading past a short payload.

use pipeline::config::PipelineConfig;
use shared_types::{frame_flags, FrameHeader, PixelFormat};

/// What the run has learnt about its external stream.
#[derive(Debug, Default)]
pub struct ExternalStream {
    /// Width and height of the first good frame: the stream keeps it.
    size: Option<(u32, u32)>,
    /// Frames that reached the supervisor (any kind).
    frames_seen: u64,
    /// Frames whose seq had been seen already (a restarted publisher).
    repeated: u64,
    /// Frames found unusable.
    bad: u64,
}

/// Bad external frames logged one by one before the log only counts them.
const BAD_FRAMES_LOGGED: u64 = 5;

impl ExternalStream {
    /// Frames the stream has given so far.
    pub fn frames_seen(&self) -> u64 {
        self.frames_seen
    }

    /// Notes a frame; `Err` says why it cannot be tracked (logged for the
    /// first few, all of them recorded in frames.csv). Headers without
    /// pixels (end of stream, frames the publisher itself marked bad or
    /// left out) pass as they are.
    pub fn check(
        &mut self,
        h: &FrameHeader,
        payload_len: usize,
        config: &PipelineConfig,
    ) -> Result<(), String> {
        let verdict = self.verdict(h, payload_len, config);
        if let Err(why) = &verdict {
            self.bad += 1;
            if self.bad <= BAD_FRAMES_LOGGED {
                tracing::error!("{why}");
            } else if self.bad == BAD_FRAMES_LOGGED + 1 {
                tracing::error!("more bad external frames follow; frames.csv has every reason");
            }
        }
        verdict
    }

    fn verdict(
        &mut self,
        h: &FrameHeader,
        payload_len: usize,
        config: &PipelineConfig,
    ) -> Result<(), String> {
        if self.frames_seen == 0 {
            tracing::info!(
                seq = h.seq,
                "first frame from the external publisher: {}x{}, depth {}",
                h.width,
                h.height,
                if h.has_depth != 0 { "yes" } else { "no" }
            );
        }
        self.frames_seen += 1;
        if !h.carries_pixels() {
            return Ok(());
        }
        let bad = |why: String| Err(format!("external frame {}: {why}", h.seq));
        if PixelFormat::from_u32(h.pixel_format).is_none() {
            return bad(format!(
                "pixel_format {} is not one the pipeline knows (1 = RGB8)",
                h.pixel_format
            ));
        }
        let (max_w, max_h) = (config.run.max_width, config.run.max_height);
        if h.width == 0 || h.height == 0 || h.width > max_w || h.height > max_h {
            return bad(format!(
                "{}x{} is not within run.max_width x run.max_height = {max_w}x{max_h}",
                h.width, h.height
            ));
        }
        if let Some((w, ht)) = self.size.filter(|&s| s != (h.width, h.height)) {
            return bad(format!(
                "{}x{}, but the stream started at {w}x{ht} (one size per run)",
                h.width, h.height
            ));
        }
        let need = h.rgb_len() + h.depth_len();
        if payload_len < need {
            return bad(format!(
                "payload has {payload_len} bytes, its header announces {}x{} RGB8{} = {need}",
                h.width,
                h.height,
                if h.has_depth != 0 { " + u16 depth" } else { "" }
            ));
        }
        let slam = &config.services.slam;
        if h.has_depth == 0 && slam.backend == "orb-rgbd" && !slam.is_monocular() {
            return bad(
                "no depth, and services.slam.sensor = \"rgbd\" needs it (publish depth or set sensor = \"monocular\")"
                    .into(),
            );
        }
        if h.has_depth != 0 && h.depth_scale != config.source.depth_scale {
            return bad(format!(
                "depth_scale {} differs from the config's source.depth_scale = {} (the SLAM reads depth with the config's)",
                h.depth_scale, config.source.depth_scale
            ));
        }
        if !h.source_timestamp.is_finite() {
            return bad("source_timestamp is not a finite number of seconds".into());
        }
        self.size = Some((h.width, h.height));
        Ok(())
    }

    /// A frame whose seq the run has recorded already: the publisher went
    /// back (restarted at 0?). Said once; such frames are not tracked.
    pub fn repeated(&mut self, h: &FrameHeader) {
        if h.has(frame_flags::END_OF_STREAM) {
            return;
        }
        self.repeated += 1;
        if self.repeated == 1 {
            tracing::warn!(
                seq = h.seq,
                "the external publisher sent a frame seq the run has already recorded; seqs must increase over a run (frames with old seqs are ignored)"
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> PipelineConfig {
        PipelineConfig::parse("[source]\nkind = \"external\"\n[run]\nmode = \"realtime\"\n")
            .unwrap()
    }

    fn frame(seq: u64, w: u32, h: u32, depth: bool) -> FrameHeader {
        FrameHeader {
            seq,
            width: w,
            height: h,
            has_depth: depth as u32,
            depth_scale: 5000.0,
            source_timestamp: seq as f64 / 30.0,
            ..Default::default()
        }
    }

    #[test]
    fn a_good_stream_passes_and_mistakes_are_named() {
        let cfg = config();
        let mut s = ExternalStream::default();
        let len = |f: &FrameHeader| f.rgb_len() + f.depth_len();
        let good = frame(0, 640, 480, true);
        assert_eq!(s.check(&good, len(&good), &cfg), Ok(()));
        let err = |s: &mut ExternalStream, f: FrameHeader, payload: usize| {
            s.check(&f, payload, &cfg).unwrap_err()
        };
        let short = frame(1, 640, 480, true);
        let e = err(&mut s, short, 640 * 480 * 3);
        assert!(
            e.contains("external frame 1") && e.contains("1536000"),
            "{e}"
        );
        let e = err(&mut s, frame(2, 1280, 720, true), 1280 * 720 * 5);
        assert!(e.contains("1280x720") && e.contains("run.max_width"), "{e}");
        let e = err(&mut s, frame(3, 320, 240, true), 320 * 240 * 5);
        assert!(e.contains("started at 640x480"), "{e}");
        let e = err(&mut s, frame(4, 640, 480, false), 640 * 480 * 3);
        assert!(e.contains("no depth") && e.contains("sensor"), "{e}");
        let mut scaled = frame(5, 640, 480, true);
        scaled.depth_scale = 1000.0;
        let e = err(&mut s, scaled, len(&scaled));
        assert!(e.contains("depth_scale 1000"), "{e}");
        let mut odd = frame(6, 640, 480, true);
        odd.pixel_format = 7;
        assert!(err(&mut s, odd, len(&odd)).contains("pixel_format 7"));
        let mut end = frame(7, 0, 0, false);
        end.flags = frame_flags::END_OF_STREAM;
        assert_eq!(s.check(&end, 0, &cfg), Ok(()));
        assert_eq!(s.frames_seen(), 8);
    }
}
