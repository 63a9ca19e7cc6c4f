//! The other machine's end: answers a run's frames with its model's masks.
//!
//! One query at a time, newest first: queries that waited while the model
//! worked on another are answered "superseded" (the robot has given up on
//! them or moved on). A request that is not a valid frame of this run is
//! answered with an error and counted, never a crash.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{anyhow, Result};
use pipeline::mask_worker::MaskModel;
use shared_types::{MaskSource, MasksHeader};
use zenoh::query::Query;
use zenoh::{Session, Wait};

use crate::session::{frames_key, workers_key};
use crate::wire::{decode_request, encode_masks, encode_reply, Outcome};

/// What a worker did.
#[derive(Debug, Default, Clone)]
pub struct ServeStats {
    /// Frames answered with masks.
    pub answered: u64,
    /// Frames the model failed on.
    pub failed: u64,
    /// Requests refused (not a frame of this run, malformed, hostile).
    pub refused: u64,
    /// Requests passed over for a newer one.
    pub superseded: u64,
}

/// Serves run `run` with `model` until `stop` is set.
pub fn serve(
    session: &Session,
    run: &str,
    model: &mut dyn MaskModel,
    stop: &AtomicBool,
) -> Result<ServeStats> {
    let key = frames_key(run);
    let queryable = session
        .declare_queryable(&key)
        .wait()
        .map_err(|e| anyhow!("cannot serve {key}: {e}"))?;
    // Declared after the queryable: a robot that sees the token can ask.
    let token_key = format!("{}/{}", workers_key(run), session.zid());
    let _token = session
        .liveliness()
        .declare_token(&token_key)
        .wait()
        .map_err(|e| anyhow!("cannot declare {token_key}: {e}"))?;
    tracing::info!(
        "serving run '{run}' with model '{}' on {key} (worker {token_key})",
        model.name()
    );
    let mut stats = ServeStats::default();
    while !stop.load(Ordering::Relaxed) {
        let Some(mut query) = queryable
            .recv_timeout(Duration::from_millis(200))
            .map_err(|e| anyhow!("the queryable closed: {e}"))?
        else {
            continue;
        };
        // Newest first: the ones that waited are stale.
        while let Ok(Some(newer)) = queryable.try_recv() {
            stats.superseded += 1;
            let _ = query.reply_err("superseded by a newer frame").wait();
            query = newer;
        }
        answer(&query, run, model, &mut stats);
    }
    Ok(stats)
}

fn answer(query: &Query, run: &str, model: &mut dyn MaskModel, stats: &mut ServeStats) {
    let bytes = query
        .payload()
        .map(|p| p.to_bytes().into_owned())
        .unwrap_or_default();
    let frame = match decode_request(&bytes, run) {
        Ok(f) => f,
        Err(e) => {
            stats.refused += 1;
            if stats.refused <= 10 {
                tracing::warn!("refused a request ({} so far): {e:#}", stats.refused);
            }
            let _ = query.reply_err(format!("refused: {e:#}")).wait();
            return;
        }
    };
    let seq = frame.header.seq;
    let (w, h) = (frame.header.width, frame.header.height);
    let mut labels = vec![0u8; w as usize * h as usize];
    let start = Instant::now();
    let result = frame.view().and_then(|view| {
        let previous = frame.previous_view();
        model.infer_after(&view, previous.as_ref(), &mut labels)
    });
    let inference_ns = start.elapsed().as_nanos() as u64;
    let outcome = match result {
        Ok(instances) => {
            let mut header = MasksHeader {
                seq,
                source: MaskSource::Segmenter as u32,
                width: w,
                height: h,
                ..Default::default()
            };
            let n = header.set_instances(&instances);
            // Labels past the instances kept name nothing.
            labels
                .iter_mut()
                .filter(|l| **l as usize > n)
                .for_each(|l| *l = 0);
            match encode_masks(&header, &labels) {
                Ok(masks) => {
                    stats.answered += 1;
                    Outcome::Masks {
                        inference_ns,
                        masks,
                    }
                }
                Err(e) => Outcome::Failed(format!("{e:#}")),
            }
        }
        Err(e) => {
            stats.failed += 1;
            tracing::error!(seq, "{} failed: {e:#}", model.name());
            Outcome::Failed(format!("{e:#}"))
        }
    };
    tracing::debug!(seq, ms = inference_ns as f64 / 1e6, "answered");
    match encode_reply(run, seq, outcome) {
        Ok(reply) => {
            if let Err(e) = query.reply(query.key_expr().clone(), reply).wait() {
                tracing::warn!(seq, "cannot send the masks: {e}");
            }
        }
        Err(e) => tracing::error!(seq, "{e:#}"),
    }
}
