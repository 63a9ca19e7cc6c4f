//! Service names of the pipeline, all under one per-run prefix.
//!
//! Every run has a run id. It appears twice: in the iceoryx2 service names
//! (`dynslam/<run>/<topic>`) and as the file prefix of every shared-memory and
//! bookkeeping file iceoryx2 creates for the run (`dsl_<run>_`). Parallel
//! runs (tests in particular) therefore never share a service, and "nothing of
//! the run remains in /dev/shm" is a plain check for files with that prefix.

/// The topics of the pipeline (one publish-subscribe service plus one event
/// service of the same name each).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Topic {
    /// camera-reader -> everyone: `FrameHeader` + pixels.
    Frames,
    /// supervisor -> segmenter, propagator, slam: `Route`.
    Routes,
    /// segmenter, propagator -> slam, propagator, supervisor: `MasksHeader` + labels.
    Masks,
    /// slam -> supervisor, camera-reader: `Track`.
    Tracks,
    /// every service -> supervisor: `Lifecycle` (readiness handshake).
    Lifecycle,
    /// supervisor -> camera-reader: `Control`.
    Control,
    /// slam -> anyone outside the pipeline: `Pose` (the public pose stream,
    /// README "Poses out").
    Poses,
    /// slam -> bridge: `MapHeader` + keyframes and points (ROS 2 map topics).
    Map,
    /// bridge -> slam: `SlamCommand` (ROS 2 services).
    SlamCommands,
    /// slam -> bridge: `SlamReply`.
    SlamReplies,
}

impl Topic {
    /// Every topic of a run.
    pub const ALL: [Topic; 10] = [
        Topic::Frames,
        Topic::Routes,
        Topic::Masks,
        Topic::Tracks,
        Topic::Lifecycle,
        Topic::Control,
        Topic::Poses,
        Topic::Map,
        Topic::SlamCommands,
        Topic::SlamReplies,
    ];
    /// The topic's part of its iceoryx2 service name.
    pub fn as_str(self) -> &'static str {
        match self {
            Topic::Frames => "frames",
            Topic::Routes => "routes",
            Topic::Masks => "masks",
            Topic::Tracks => "tracks",
            Topic::Lifecycle => "lifecycle",
            Topic::Control => "control",
            Topic::Poses => "poses",
            Topic::Map => "map",
            Topic::SlamCommands => "slam-commands",
            Topic::SlamReplies => "slam-replies",
        }
    }
}

/// Longest accepted run id (iceoryx2 file names stay well below 255 bytes).
pub const MAX_RUN_ID_LEN: usize = 32;

/// Names of one run's services and files.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RunNames {
    run_id: String,
}

impl RunNames {
    /// A run id is 1..=32 ASCII letters, digits or '-'.
    pub fn new(run_id: &str) -> Result<Self, String> {
        if run_id.is_empty() || run_id.len() > MAX_RUN_ID_LEN {
            return Err(format!(
                "run id '{run_id}' must be 1 to {MAX_RUN_ID_LEN} characters long"
            ));
        }
        if let Some(c) = run_id
            .chars()
            .find(|c| !(c.is_ascii_alphanumeric() || *c == '-'))
        {
            return Err(format!(
                "run id '{run_id}' contains '{c}'; only ASCII letters, digits and '-' are allowed"
            ));
        }
        Ok(Self {
            run_id: run_id.to_string(),
        })
    }

    /// The run id these names are of.
    pub fn run_id(&self) -> &str {
        &self.run_id
    }

    /// iceoryx2 service name of a topic.
    pub fn service(&self, topic: Topic) -> String {
        format!("dynslam/{}/{}", self.run_id, topic.as_str())
    }

    /// File prefix of every iceoryx2 resource of this run (`/dev/shm`, `/tmp/iceoryx2`).
    pub fn file_prefix(&self) -> String {
        format!("dsl_{}_", self.run_id)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_carry_the_run_id() {
        let n = RunNames::new("abc-1").unwrap();
        assert_eq!(n.service(Topic::Frames), "dynslam/abc-1/frames");
        assert_eq!(n.file_prefix(), "dsl_abc-1_");
    }

    #[test]
    fn bad_run_ids_are_rejected_with_reason() {
        assert!(RunNames::new("").is_err());
        assert!(RunNames::new("a/b").unwrap_err().contains("'/'"));
        assert!(RunNames::new(&"x".repeat(33)).is_err());
    }
}
