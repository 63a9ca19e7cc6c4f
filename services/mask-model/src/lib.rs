//! The seam between a mask worker and its model: what a segmenter or a
//! propagator backend is asked to do ([`MaskModel`]), the error for a frame
//! no worker could take ([`Unavailable`]), and the choice of a backend by its
//! name in the configuration. No IPC: the worker loop that drives a model
//! over shared memory is `pipeline::mask_worker`; the models are in the
//! `segmentation`, `propagation` and `remote` crates.

#![deny(missing_docs)]

use std::time::Duration;

use anyhow::Result;
use pipeline_config::PipelineConfig;
use provision::InputError;
use shared_types::views::{FrameView, MasksView};
use shared_types::{Instance, ServiceKind};

/// What a mask model is asked to do. Implementations: the instance segmenter
/// backends and the propagator backends.
pub trait MaskModel {
    /// Short name for logs and reports.
    fn name(&self) -> &str;

    /// Masks for `frame`: write labels (`i + 1` for instance `i`) into the
    /// zeroed `labels` (`width*height` bytes) and return the instances.
    fn infer(&mut self, frame: &FrameView, labels: &mut [u8]) -> Result<Vec<Instance>>;

    /// [`Self::infer`] given `previous`, the newest masks published before
    /// this frame's by either worker: the segmenter keeps a weak detection
    /// that continues an object in them.
    fn infer_after(
        &mut self,
        frame: &FrameView,
        _previous: Option<&MasksView>,
        labels: &mut [u8],
    ) -> Result<Vec<Instance>> {
        self.infer(frame, labels)
    }

    /// Segmenter masks for `frame` (a keyframe): new prompts. Only the
    /// propagator uses them; `frame` is `None` when it no longer holds it.
    fn prompt(&mut self, _frame: Option<&FrameView>, _masks: &MasksView) {}

    /// A frame the segmenter is making masks for (the propagator's future
    /// prompt): keep what prompting on it will need until the masks come,
    /// however late (the frame may no longer be held then).
    fn keep(&mut self, _frame: &FrameView) {}

    /// Whether the frame just inferred asks for a segmenter run now (the
    /// propagator saw something it does not follow); asked once per frame.
    fn wants_segment(&mut self) -> bool {
        false
    }

    /// One line for the log at exit (e.g. how prompts were used).
    fn summary(&self) -> Option<String> {
        None
    }

    /// [`mask_flags`](shared_types::mask_flags) saying where the masks just made were made
    /// ([`REMOTE`](shared_types::mask_flags::REMOTE), [`FALLBACK`](shared_types::mask_flags::FALLBACK)); 0: here.
    fn origin_flags(&self) -> u32 {
        0
    }
}

/// The error a model returns when no worker could take the frame (a
/// remote segmenter with `fallback = "none"` and no worker answering): real
/// time tells the frame gone at once (the propagator carries masks),
/// lockstep lets it go unmasked; both flag it [`UNAVAILABLE`](shared_types::mask_flags::UNAVAILABLE).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct Unavailable(pub String);

/// A model that finds no objects: every frame gets an empty label image,
/// after `work` of simulated compute. It is the `none` backend, for runs where
/// masks are not wanted from a worker and for plumbing and fault tests; it is
/// not a segmentation model.
pub struct NoObjects {
    /// Simulated compute per frame.
    pub work: Duration,
}

impl MaskModel for NoObjects {
    fn name(&self) -> &str {
        "none"
    }
    fn infer(&mut self, _frame: &FrameView, _labels: &mut [u8]) -> Result<Vec<Instance>> {
        if !self.work.is_zero() {
            std::thread::sleep(self.work);
        }
        Ok(Vec::new())
    }
}

/// Builds one backend of a worker from the pipeline configuration.
pub type ModelFactory = dyn Fn(&PipelineConfig) -> Result<Box<dyn MaskModel>>;

/// Builds the model `[services.<kind>]` names; unknown names are input
/// errors that list the known ones.
pub fn model_from_config(
    kind: ServiceKind,
    config: &PipelineConfig,
    known: &[(&str, &ModelFactory)],
) -> Result<Box<dyn MaskModel>> {
    let section = kind.as_str();
    let services = &config.services;
    let (wanted, work_ms) = match kind {
        ServiceKind::Segmenter => (
            services.segmenter.backend.as_str(),
            services.segmenter.work_ms,
        ),
        _ => (
            services.propagator.backend.as_str(),
            services.propagator.work_ms,
        ),
    };
    if wanted == "none" {
        return Ok(Box::new(NoObjects {
            work: Duration::from_millis(work_ms),
        }));
    }
    for (name, make) in known {
        if *name == wanted {
            return make(config);
        }
    }
    let mut names: Vec<&str> = known.iter().map(|(n, _)| *n).collect();
    names.push("none");
    Err(InputError(format!(
        "key `services.{section}.backend`: unknown backend '{wanted}' (known: {})",
        names.join(", ")
    ))
    .into())
}
