//! iceoryx2 transport of the pipeline.
//!
//! A *topic* is an iceoryx2 publish-subscribe service plus an event service of
//! the same name: a sender writes a sample into shared memory, sends it and
//! then notifies; a receiver's listener wakes the process's WaitSet, which
//! then drains every receiver. Nobody polls.
//!
//! Every run has its own iceoryx2 file prefix (see `shared_types::names`), so
//! parallel runs never meet and a run's leftovers are easy to find and remove.
//! The quality-of-service settings of every topic live in [`qos`] only: all
//! processes open a service with identical settings.

use std::fmt::Debug;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{anyhow, Context, Result};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
pub use iceoryx2::sample::Sample;
pub use iceoryx2::sample_mut::SampleMut;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;
use shared_types::names::{RunNames, Topic};

/// The iceoryx2 service flavour of the pipeline: inter-process, shared memory.
pub type Svc = ipc::Service;

/// Per-topic quality of service.
#[derive(Debug, Clone, Copy)]
pub struct Qos {
    /// Samples a subscriber queues before the oldest is overwritten.
    pub buffer: usize,
    /// Samples a subscriber may hold at once (workers keep a few frames).
    pub borrowed: usize,
    /// Samples a subscriber that connects late still gets.
    pub history: usize,
}

/// The quality of service of each topic. Queues overflow by dropping the
/// oldest sample ("newest wins" in real-time mode); lockstep never has more
/// than one frame in flight, so nothing is lost there.
pub fn qos(topic: Topic) -> Qos {
    match topic {
        Topic::Frames => Qos {
            buffer: 4,
            borrowed: 4,
            history: 0,
        },
        // SLAM holds up to 3 sets (a frame segmented behind can have two,
        // and the next frame's may arrive before it is tracked).
        Topic::Masks => Qos {
            buffer: 4,
            borrowed: 4,
            history: 0,
        },
        Topic::Routes | Topic::Tracks => Qos {
            buffer: 64,
            borrowed: 2,
            history: 0,
        },
        // The public pose stream: a subscriber started with the run (or
        // after a hiccup) still gets the poses of its first moments.
        Topic::Poses => Qos {
            buffer: 64,
            borrowed: 2,
            history: 16,
        },
        Topic::Lifecycle | Topic::Control | Topic::SlamCommands | Topic::SlamReplies => Qos {
            buffer: 16,
            borrowed: 2,
            history: 0,
        },
        // Only the newest map matters; a restarted bridge gets it at once.
        Topic::Map => Qos {
            buffer: 1,
            borrowed: 1,
            history: 1,
        },
    }
}

/// Room of a map snapshot sample (the bridge's map topics): the points
/// beyond it are left out (and counted).
pub const MAX_MAP_KEYFRAMES: usize = 4096;
/// Points a map snapshot sample has room for.
pub const MAX_MAP_POINTS: usize = 100_000;
/// Bytes of a map snapshot sample's payload.
pub const MAX_MAP_BYTES: usize = MAX_MAP_KEYFRAMES * shared_types::MAP_KEYFRAME_BYTES
    + MAX_MAP_POINTS * shared_types::MAP_POINT_BYTES;

/// Upper bounds per service; restarts briefly leave a dead process's ports
/// registered until the dead-node cleanup runs, hence the margin.
const MAX_PUBLISHERS: usize = 8;
const MAX_SUBSCRIBERS: usize = 8;
const MAX_NODES: usize = 24;

/// Services that publish masks (the segmenter and the propagator).
const MASK_PUBLISHERS: u64 = 2;

/// Bytes of shared memory the run's frame and mask queues reserve: each
/// publisher's segment holds a sample per place a subscriber can queue or
/// borrow one, plus its history and its loan (measured: 65 samples of
/// 640x480 RGB-D, 99.9 MB). The segments are sparse: pages are used as
/// frames fill them, up to all of it on a long run.
pub fn reserved_shm_bytes(max_frame_bytes: usize, max_mask_bytes: usize) -> u64 {
    let samples = |t: Topic| {
        let q = qos(t);
        (MAX_SUBSCRIBERS * (q.buffer + q.borrowed) + q.history + 1) as u64
    };
    samples(Topic::Frames) * max_frame_bytes as u64
        + MASK_PUBLISHERS * samples(Topic::Masks) * max_mask_bytes as u64
}

/// Bytes of shared memory the map snapshots reserve (with the bridge).
pub fn reserved_map_shm_bytes() -> u64 {
    let q = qos(Topic::Map);
    (MAX_SUBSCRIBERS * (q.buffer + q.borrowed) + q.history + 1) as u64 * MAX_MAP_BYTES as u64
}

/// Free bytes of the file system at `dir` (statvfs), None if unknown.
pub fn free_bytes(dir: &Path) -> Option<u64> {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
    // SAFETY: statvfs(3) fills the zeroed struct; the path is NUL-terminated.
    unsafe {
        let mut st: libc::statvfs = std::mem::zeroed();
        (libc::statvfs(c.as_ptr(), &mut st) == 0).then(|| st.f_bavail as u64 * st.f_frsize as u64)
    }
}

/// Refuses a frame size whose queues /dev/shm cannot hold: a full tmpfs
/// shows up as SIGBUS in whichever process touches the next page, long
/// after the start.
pub fn check_shm_capacity(config: &crate::config::PipelineConfig) -> Result<()> {
    let (max_width, max_height) = (config.run.max_width, config.run.max_height);
    let map = if config.bridge.enabled {
        reserved_map_shm_bytes()
    } else {
        0
    };
    let need = reserved_shm_bytes(config.max_frame_bytes(), config.max_mask_bytes()) + map;
    let shm = Path::new("/dev/shm");
    let Some(free) = free_bytes(shm) else {
        return Ok(()); // no /dev/shm to ask (iceoryx2 then reports its own error)
    };
    if need > free {
        anyhow::bail!(
            "run.max_width x run.max_height = {max_width}x{max_height}: the frame and mask queues need {:.1} MB of shared memory, /dev/shm has {:.1} MB free; lower run.max_width/max_height to the camera's size or give /dev/shm more room (mount -o remount,size=...)",
            need as f64 / 1e6,
            free as f64 / 1e6
        );
    }
    Ok(())
}

/// The iceoryx2 configuration of one run: the default one with the run's
/// file prefix.
pub fn iceoryx_config(names: &RunNames) -> Result<Config> {
    let mut config = Config::default();
    config.global.prefix = FileName::new(names.file_prefix().as_bytes()).map_err(|e| {
        anyhow!(
            "invalid iceoryx2 file prefix {}: {e:?}",
            names.file_prefix()
        )
    })?;
    Ok(config)
}

/// One process's connection to a run: an iceoryx2 node with the run's config.
pub struct Transport {
    node: Node<Svc>,
    names: RunNames,
}

impl Transport {
    /// Creates this process's node in the run (`node_name` shows in
    /// iceoryx2's node list: the service's name).
    pub fn open(names: &RunNames, node_name: &str) -> Result<Self> {
        let config = iceoryx_config(names)?;
        let node_name = NodeName::new(node_name)
            .map_err(|e| anyhow!("invalid node name {node_name}: {e:?}"))?;
        let node = NodeBuilder::new()
            .name(&node_name)
            .config(&config)
            // Services decide themselves how to end on SIGINT/SIGTERM; the
            // WaitSets report termination requests to them.
            .signal_handling_mode(SignalHandlingMode::HandleTerminationRequests)
            .create::<Svc>()
            .map_err(|e| anyhow!("cannot create iceoryx2 node {node_name}: {e:?}"))?;
        Ok(Self {
            node,
            names: names.clone(),
        })
    }

    /// The iceoryx2 node.
    pub fn node(&self) -> &Node<Svc> {
        &self.node
    }

    /// The run's names.
    pub fn names(&self) -> &RunNames {
        &self.names
    }

    fn service_name(&self, topic: Topic) -> Result<ServiceName> {
        let name = self.names.service(topic);
        ServiceName::new(&name).map_err(|e| anyhow!("invalid service name {name}: {e:?}"))
    }

    /// The service builder of a topic with its quality of service applied.
    fn pubsub_builder<P, H>(
        &self,
        name: &ServiceName,
        topic: Topic,
    ) -> iceoryx2::service::builder::publish_subscribe::Builder<P, H, Svc>
    where
        P: Debug + IceoryxSend + ?Sized + 'static,
        H: Debug + ZeroCopySend,
    {
        let q = qos(topic);
        self.node
            .service_builder(name)
            .publish_subscribe::<P>()
            .user_header::<H>()
            .subscriber_max_buffer_size(q.buffer)
            .subscriber_max_borrowed_samples(q.borrowed)
            .enable_safe_overflow(true)
            .history_size(q.history)
            .max_publishers(MAX_PUBLISHERS)
            .max_subscribers(MAX_SUBSCRIBERS)
            .max_nodes(MAX_NODES)
    }

    fn typed_service<T>(&self, topic: Topic) -> Result<PubSubFactory<Svc, T, ()>>
    where
        T: Debug + ZeroCopySend + Copy + 'static,
    {
        let name = self.service_name(topic)?;
        retry_open(&name, || {
            self.pubsub_builder::<T, ()>(&name, topic)
                .open_or_create()
                .map_err(|e| format!("{e:?}"))
        })
    }

    fn slice_service<H>(&self, topic: Topic) -> Result<PubSubFactory<Svc, [u8], H>>
    where
        H: Debug + ZeroCopySend,
    {
        let name = self.service_name(topic)?;
        retry_open(&name, || {
            self.pubsub_builder::<[u8], H>(&name, topic)
                .open_or_create()
                .map_err(|e| format!("{e:?}"))
        })
    }

    fn event(
        &self,
        topic: Topic,
    ) -> Result<iceoryx2::service::port_factory::event::PortFactory<Svc>> {
        let name = self.service_name(topic)?;
        retry_open(&name, || {
            self.node
                .service_builder(&name)
                .event()
                .max_notifiers(MAX_PUBLISHERS * 2)
                .max_listeners(MAX_SUBSCRIBERS)
                .max_nodes(MAX_NODES)
                .open_or_create()
                .map_err(|e| format!("{e:?}"))
        })
    }

    /// Sender of fixed-size messages (`Route`, `Track`, ...).
    pub fn sender<T>(&self, topic: Topic) -> Result<Sender<T, ()>>
    where
        T: Debug + ZeroCopySend + Copy + 'static,
    {
        let publisher = self
            .typed_service::<T>(topic)?
            .publisher_builder()
            .max_loaned_samples(2)
            .create()
            .map_err(|e| anyhow!("cannot create publisher on {}: {e:?}", topic.as_str()))?;
        self.finish_sender(topic, publisher)
    }

    /// Sender of a header plus a byte slice of at most `max_len` bytes
    /// (frames, masks), allocated once (static strategy).
    pub fn slice_sender<H>(&self, topic: Topic, max_len: usize) -> Result<Sender<[u8], H>>
    where
        H: Debug + ZeroCopySend + Default,
    {
        let publisher = self
            .slice_service::<H>(topic)?
            .publisher_builder()
            .initial_max_slice_len(max_len)
            .allocation_strategy(AllocationStrategy::Static)
            .max_loaned_samples(1)
            .create()
            .map_err(|e| anyhow!("cannot create publisher on {}: {e:?}", topic.as_str()))?;
        self.finish_sender(topic, publisher)
    }

    fn finish_sender<P, H>(
        &self,
        topic: Topic,
        publisher: Publisher<Svc, P, H>,
    ) -> Result<Sender<P, H>>
    where
        P: Debug + IceoryxSend + ?Sized + 'static,
        H: Debug + ZeroCopySend,
    {
        let notifier = self
            .event(topic)?
            .notifier_builder()
            .create()
            .map_err(|e| anyhow!("cannot create notifier on {}: {e:?}", topic.as_str()))?;
        Ok(Sender {
            publisher,
            notifier,
            topic,
        })
    }

    /// Receiver of fixed-size messages.
    pub fn receiver<T>(&self, topic: Topic) -> Result<Receiver<T, ()>>
    where
        T: Debug + ZeroCopySend + Copy + 'static,
    {
        let service = self.typed_service::<T>(topic)?;
        self.make_receiver(topic, &service)
    }

    /// Receiver of header + byte slice samples, read in place.
    pub fn slice_receiver<H>(&self, topic: Topic) -> Result<Receiver<[u8], H>>
    where
        H: Debug + ZeroCopySend,
    {
        let service = self.slice_service::<H>(topic)?;
        self.make_receiver(topic, &service)
    }

    fn make_receiver<P, H>(
        &self,
        topic: Topic,
        service: &PubSubFactory<Svc, P, H>,
    ) -> Result<Receiver<P, H>>
    where
        P: Debug + IceoryxSend + ?Sized + 'static,
        H: Debug + ZeroCopySend,
    {
        let subscriber = service
            .subscriber_builder()
            .create()
            .map_err(|e| anyhow!("cannot create subscriber on {}: {e:?}", topic.as_str()))?;
        let listener = self
            .event(topic)?
            .listener_builder()
            .create()
            .map_err(|e| anyhow!("cannot create listener on {}: {e:?}", topic.as_str()))?;
        Ok(Receiver {
            subscriber,
            listener,
            topic,
        })
    }
}

/// Two processes may create the same service at the same moment; the loser
/// sees a transient error and simply opens it a moment later.
fn retry_open<T>(
    name: &ServiceName,
    mut open: impl FnMut() -> std::result::Result<T, String>,
) -> Result<T> {
    let mut last = String::new();
    for _ in 0..100 {
        match open() {
            Ok(v) => return Ok(v),
            Err(e) => last = e,
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    Err(anyhow!("cannot open iceoryx2 service {name}: {last}"))
}

/// Publishing end of a topic.
pub struct Sender<P: Debug + IceoryxSend + ?Sized + 'static, H: Debug + ZeroCopySend> {
    publisher: Publisher<Svc, P, H>,
    notifier: Notifier<Svc>,
    topic: Topic,
}

impl<P: Debug + IceoryxSend + ?Sized + 'static, H: Debug + ZeroCopySend> Sender<P, H> {
    fn wake(&self) -> Result<()> {
        self.notifier
            .notify()
            .map(|_| ())
            .map_err(|e| anyhow!("cannot notify {}: {e:?}", self.topic.as_str()))
    }
}

impl<T: Debug + ZeroCopySend + Copy + 'static> Sender<T, ()> {
    /// Writes `value` into shared memory, publishes it and wakes receivers.
    pub fn send(&self, value: T) -> Result<()> {
        self.publisher
            .send_copy(value)
            .map_err(|e| anyhow!("cannot send on {}: {e:?}", self.topic.as_str()))?;
        self.wake()
    }
}

impl<H: Debug + ZeroCopySend + Default> Sender<[u8], H> {
    /// Loans a zeroed sample of `len` bytes in shared memory: the producer
    /// writes the header and the pixels straight into it.
    pub fn loan(&self, len: usize) -> Result<SampleMut<Svc, [u8], H>> {
        self.publisher.loan_slice(len).map_err(|e| {
            anyhow!(
                "cannot loan {len} bytes on {} (max {}): {e:?}",
                self.topic.as_str(),
                self.publisher.initial_max_slice_len()
            )
        })
    }

    /// Publishes a loaned sample and wakes receivers.
    pub fn publish(&self, sample: SampleMut<Svc, [u8], H>) -> Result<()> {
        let receivers = sample
            .send()
            .map_err(|e| anyhow!("cannot send on {}: {e:?}", self.topic.as_str()))?;
        tracing::trace!(topic = self.topic.as_str(), receivers, "published");
        self.wake()
    }

    /// The largest payload a sample holds, bytes.
    pub fn max_len(&self) -> usize {
        self.publisher.initial_max_slice_len()
    }
}

/// Subscribing end of a topic; attach [`Receiver::listener`] to a WaitSet.
pub struct Receiver<P: Debug + IceoryxSend + ?Sized + 'static, H: Debug + ZeroCopySend> {
    subscriber: Subscriber<Svc, P, H>,
    listener: Listener<Svc>,
    topic: Topic,
}

impl<P: Debug + IceoryxSend + ?Sized + 'static, H: Debug + ZeroCopySend> Receiver<P, H> {
    /// Wakes the WaitSet it is attached to when a sample arrives.
    pub fn listener(&self) -> &Listener<Svc> {
        &self.listener
    }

    /// This receiver, its wake-ups cleared first when a wake-up's drain is
    /// `entering` it ([`crate::service_loop::Drain`]): a sample that arrives
    /// while it is drained wakes the loop again.
    pub fn entered(&self, entering: bool) -> &Self {
        if entering {
            self.clear_wakeups();
        }
        self
    }

    /// Consumes pending wake-ups. Call before draining with `receive`, so a
    /// sample that arrives afterwards wakes the WaitSet again.
    pub fn clear_wakeups(&self) {
        let _ = self.listener.try_wait(|_| {});
    }

    /// The topic it reads.
    pub fn topic(&self) -> Topic {
        self.topic
    }

    /// True when a sample is waiting (lets a holder of borrowed samples make
    /// room only when there is something to take).
    pub fn has_samples(&self) -> Result<bool> {
        self.subscriber
            .has_samples()
            .map_err(|e| anyhow!("cannot query {}: {e:?}", self.topic.as_str()))
    }
}

impl<T: Debug + ZeroCopySend + Copy + 'static> Receiver<T, ()> {
    /// Next message, copied out (they are small).
    pub fn next(&self) -> Result<Option<T>> {
        match self.subscriber.receive() {
            Ok(Some(sample)) => Ok(Some(*sample.payload())),
            Ok(None) => Ok(None),
            Err(e) => Err(anyhow!("cannot receive on {}: {e:?}", self.topic.as_str())),
        }
    }

    /// All pending messages.
    pub fn drain(&self) -> Result<Vec<T>> {
        self.clear_wakeups();
        let mut out = Vec::new();
        while let Some(v) = self.next()? {
            out.push(v);
        }
        Ok(out)
    }
}

impl<H: Debug + ZeroCopySend> Receiver<[u8], H> {
    /// Next sample, borrowed in place from shared memory (no copy).
    pub fn next_sample(&self) -> Result<Option<Sample<Svc, [u8], H>>> {
        self.subscriber
            .receive()
            .map_err(|e| anyhow!("cannot receive on {}: {e:?}", self.topic.as_str()))
    }
}

/// Wake-up multiplexer of one service loop (the listeners of its receivers).
pub type Waiter = WaitSet<Svc>;

/// Keeps a receiver attached to a [`Waiter`]; detaches when dropped.
pub type Attachment<'w, 'a> = WaitSetGuard<'w, 'a, Svc>;

/// A WaitSet that returns on SIGINT / SIGTERM (the services end cleanly).
pub fn waitset() -> Result<Waiter> {
    WaitSetBuilder::new()
        .signal_handling_mode(SignalHandlingMode::HandleTerminationRequests)
        .create::<Svc>()
        .map_err(|e| anyhow!("cannot create WaitSet: {e:?}"))
}

/// Wakes `ws` whenever `receiver` gets a sample.
pub fn attach<'w, 'a, P, H>(
    ws: &'w Waiter,
    receiver: &'a Receiver<P, H>,
) -> Result<Attachment<'w, 'a>>
where
    P: Debug + IceoryxSend + ?Sized + 'static,
    H: Debug + ZeroCopySend,
{
    ws.attach_notification(receiver.listener()).map_err(|e| {
        anyhow!(
            "cannot attach {} to the WaitSet: {e:?}",
            receiver.topic().as_str()
        )
    })
}

/// Outcome of one [`wait`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wake {
    /// Something arrived or the timeout passed: drain the receivers.
    Work,
    /// SIGINT or SIGTERM: stop cleanly.
    Terminate,
}

/// Sleeps until a listener fires, the tick passes, or a termination signal.
pub fn wait(ws: &WaitSet<Svc>, timeout: Duration) -> Result<Wake> {
    match ws.wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, timeout) {
        Ok(WaitSetRunResult::TerminationRequest) | Ok(WaitSetRunResult::Interrupt) => {
            Ok(Wake::Terminate)
        }
        Ok(_) => Ok(Wake::Work),
        Err(e) => Err(anyhow!("WaitSet wait failed: {e:?}")),
    }
}

pub use iceoryx2::waitset::WaitSetRunResult;

/// Result of a stale-resource sweep.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct CleanupReport {
    /// Nodes of dead processes whose resources were removed.
    pub dead_nodes_removed: usize,
    /// Nodes still alive (left alone).
    pub alive_nodes: usize,
}

/// iceoryx2 dead-node detection: finds the run's nodes whose process died
/// without cleaning up, and removes their ports and shared memory.
pub fn cleanup_dead_nodes(names: &RunNames) -> Result<CleanupReport> {
    let config = iceoryx_config(names)?;
    let mut report = CleanupReport::default();
    Node::<Svc>::list(&config, |state| {
        match state {
            NodeState::Dead(view) => {
                report.dead_nodes_removed += view.try_remove_stale_resources().is_ok() as usize;
            }
            NodeState::Alive(_) => report.alive_nodes += 1,
            _ => {}
        }
        CallbackProgression::Continue
    })
    .map_err(|e| anyhow!("cannot list iceoryx2 nodes: {e:?}"))?;
    Ok(report)
}

/// Folders where iceoryx2 keeps its files (shared memory, and the
/// bookkeeping under its root path).
fn resource_dirs() -> Vec<PathBuf> {
    let root = PathBuf::from(Config::default().global.root_path().to_string());
    vec![PathBuf::from("/dev/shm"), root]
}

/// Every iceoryx2 file whose name starts with `prefix` (a run's, or a
/// bench's own prefix).
pub fn prefixed_files(prefix: &str) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for dir in resource_dirs() {
        collect_prefixed(&dir, prefix, &mut out);
    }
    out.sort();
    out
}

/// Removes every iceoryx2 file whose name starts with `prefix`. Only call
/// when no process using that prefix is alive.
pub fn remove_prefixed_files(prefix: &str) -> Result<usize> {
    let files = prefixed_files(prefix);
    for f in &files {
        std::fs::remove_file(f)
            .with_context(|| format!("cannot remove stale file {}", f.display()))?;
    }
    Ok(files.len())
}

/// Every file of the run's prefix still on disk (shared memory and
/// bookkeeping files). Empty after a clean shutdown.
pub fn run_files(names: &RunNames) -> Vec<PathBuf> {
    prefixed_files(&names.file_prefix())
}

fn collect_prefixed(dir: &Path, prefix: &str, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        let is_dir = entry.file_type().map(|t| t.is_dir()).unwrap_or(false);
        if is_dir {
            collect_prefixed(&path, prefix, out);
        } else if entry.file_name().to_string_lossy().starts_with(prefix) {
            out.push(path);
        }
    }
}

/// Makes every file of the run owner-only (0600). iceoryx2 creates its
/// global management file world-writable (0666) whatever the umask; another
/// local user could overwrite it and break every later service start.
/// Returns how many files had other permissions.
pub fn make_run_files_private(names: &RunNames) -> Result<usize> {
    use std::os::unix::fs::PermissionsExt;
    let mut changed = 0;
    for f in run_files(names) {
        let Ok(meta) = std::fs::metadata(&f) else {
            continue; // gone meanwhile
        };
        if meta.permissions().mode() & 0o077 != 0 {
            std::fs::set_permissions(&f, std::fs::Permissions::from_mode(0o600))
                .with_context(|| format!("cannot make {} private", f.display()))?;
            changed += 1;
        }
    }
    Ok(changed)
}

/// Removes every file of the run's prefix. Only call when no process of the
/// run is alive (after shutdown, or before restarting a killed supervisor).
pub fn remove_run_files(names: &RunNames) -> Result<usize> {
    remove_prefixed_files(&names.file_prefix())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reservation_matches_the_measured_segments_and_a_huge_frame_is_refused() {
        // 640x480: 65 frame samples of 1.536 MB (the camera-reader's segment
        // measured 99.86 MB) and 65 mask samples per mask publisher.
        let frame = 640 * 480 * 5;
        let mask = 640 * 480;
        assert_eq!(
            reserved_shm_bytes(frame, mask),
            65 * frame as u64 + 2 * 65 * mask as u64
        );
        let free = free_bytes(Path::new("/dev/shm")).expect("/dev/shm is there");
        // A frame size whose queues are twice what is free is refused, naming the keys.
        let side = ((free as f64 / 455.0 * 2.0).sqrt() as u32).max(16);
        let mut config = crate::config::PipelineConfig::default();
        (config.run.max_width, config.run.max_height) = (side, side);
        let err = check_shm_capacity(&config).unwrap_err().to_string();
        assert!(err.contains("run.max_width x run.max_height"), "{err}");
        assert!(err.contains("/dev/shm has"), "{err}");
    }
}
