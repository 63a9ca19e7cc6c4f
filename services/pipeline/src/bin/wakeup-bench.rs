//! Wake-up latency between two processes: how long from "the sender
//! notifies" to "the sleeping receiver runs", for the ways an iceoryx2 0.10
//! process can sleep (issue 14's question: is one semaphore event per
//! process worth leaving the WaitSet for?).
//!
//! 1. the pipeline's way: the default event (Unix datagram socket) of an
//!    `ipc::Service`, its listener attached to a WaitSet;
//! 2. the same event, the listener waited on alone (no WaitSet);
//! 3. a semaphore event (the same service with
//!    `SemaphoreShmCountingBitSet`), waited on alone: a semaphore has no
//!    file descriptor, so it cannot join a WaitSet (iceoryx2 issue 795).
//!
//! Each message is a u64 CLOCK_MONOTONIC stamp published, then notified;
//! the receiver reads it when woken. `wakeup-bench [--messages N] [--out
//! FILE]` prints p50/p99 per way, the ratios, and what they mean for the
//! pipeline (hops per frame against its end-to-end latency).

use std::fmt::Debug;
use std::io::{Read, Write};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;

use anyhow::{anyhow, bail, Context, Result};
use clap::Parser;
use iceoryx2::prelude::*;
use pipeline::clock::now_ns;
use pipeline::stats::percentile;

/// An `ipc::Service` whose events are POSIX semaphores in shared memory.
mod semaphore {
    use core::fmt::Debug;
    use iceoryx2::prelude::ZeroCopySend;
    use iceoryx2_bb_elementary_traits::testing::abandonable::Abandonable;
    use iceoryx2_cal::shm_allocator::bump_allocator::BumpAllocator;
    use iceoryx2_cal::shm_allocator::pool_allocator::PoolAllocator;
    use iceoryx2_cal::*;

    #[derive(Debug, Clone)]
    pub struct Service {}

    // The type list of iceoryx2::service::ipc::Service, the event aside.
    impl iceoryx2::service::Service for Service {
        type StaticStorage = static_storage::recommended::Ipc;
        type ConfigSerializer = serialize::recommended::Recommended;
        type PersistentDynamicStorage<T: Debug + Send + Sync + ZeroCopySend + 'static> =
            dynamic_storage::recommended::PersistentIpc<T>;
        type Bag = bag::recommended::Recommended;
        type DynamicStorage<T: Debug + Send + Sync + ZeroCopySend + 'static> =
            dynamic_storage::recommended::Ipc<T>;
        type ServiceNameHasher = hash::recommended::Recommended;
        type SharedMemory = shared_memory::recommended::Ipc<PoolAllocator>;
        type ResizableSharedMemory = resizable_shared_memory::recommended::Ipc<PoolAllocator>;
        type Connection = zero_copy_connection::recommended::Ipc;
        type Event = event::SemaphoreShmCountingBitSet;
        type Monitoring = monitoring::recommended::Ipc;
        type Reactor = reactor::recommended::Ipc;
        type ArcThreadSafetyPolicy<T: Send + Debug + Abandonable> =
            arc_sync_policy::single_threaded::SingleThreaded<T>;
        type BlackboardMgmt<KeyType: Send + Sync + Debug + ZeroCopySend + 'static> =
            dynamic_storage::recommended::Ipc<KeyType>;
        type BlackboardPayload = shared_memory::recommended::Ipc<BumpAllocator>;
        type UniqueId = iceoryx2::unique_id_generator::unique_system_id::UniqueSystemId;
    }

    impl iceoryx2::service::internal::ServiceInternal<Service> for Service {}
}

#[derive(Debug, Parser)]
#[command(about = "iceoryx2 wake-up latency: WaitSet vs a lone listener vs a semaphore event")]
struct Args {
    /// Messages per way.
    #[arg(long, default_value_t = 2000)]
    messages: usize,
    /// Where to write the figures as JSON.
    #[arg(long, default_value = "bench-results/wakeup.json")]
    out: PathBuf,
    /// Internal: run as the receiving process of this way.
    #[arg(long, hide = true)]
    receive: Option<String>,
    /// Internal: the iceoryx2 file prefix both processes use.
    #[arg(long, hide = true)]
    prefix: Option<String>,
}

/// Messages at the start of each series that warm caches and connections.
const WARMUP: usize = 100;
/// Pause between messages: the receiver is asleep when each one comes.
const PERIOD: Duration = Duration::from_millis(1);
const SERVICE: &str = "wakeup-bench";
/// Messages a subscriber queues (none is lost to a late wake-up).
const QUEUE: usize = 64;
/// The last message: the series is over.
const END: u64 = 0;

fn config(prefix: &str) -> Result<iceoryx2::config::Config> {
    let mut config = iceoryx2::config::Config::default();
    config.global.prefix =
        FileName::new(prefix.as_bytes()).map_err(|e| anyhow!("prefix {prefix}: {e:?}"))?;
    Ok(config)
}

fn main() -> Result<()> {
    let args = Args::parse();
    if let Some(way) = &args.receive {
        let prefix = args.prefix.as_deref().context("--prefix")?;
        return match way.as_str() {
            "waitset" => receive_waitset(prefix, args.messages),
            "listener" => receive_alone::<ipc::Service>(prefix, args.messages),
            "semaphore" => receive_alone::<semaphore::Service>(prefix, args.messages),
            other => bail!("unknown way {other}"),
        };
    }
    let ways = [
        ("waitset", "default event, WaitSet (the pipeline)"),
        ("listener", "default event, lone listener"),
        ("semaphore", "semaphore event, lone listener"),
    ];
    let mut figures = Vec::new();
    for (way, _) in ways {
        let f = match way {
            "semaphore" => drive::<semaphore::Service>(way, args.messages)?,
            _ => drive::<ipc::Service>(way, args.messages)?,
        };
        figures.push(f);
    }
    println!(
        "wake-up latency, notify -> receiver running, {} messages each, {} ms apart",
        args.messages,
        PERIOD.as_millis()
    );
    println!("{:<40} {:>9} {:>9}", "way", "p50 us", "p99 us");
    for ((_, name), f) in ways.iter().zip(&figures) {
        println!("{name:<40} {:>9.1} {:>9.1}", f.0, f.1);
    }
    let (ws, sem) = (figures[0], figures[2]);
    // A frame's path wakes a process 5 times: supervisor (frame), mask
    // worker (route), SLAM (masks), supervisor (track), camera-reader (track).
    let hops = 5.0;
    println!(
        "semaphore / WaitSet: p50 {:.2}x, p99 {:.2}x; per frame ({hops} wake-ups on its path) the semaphore would save {:.0} us at p50",
        sem.0 / ws.0.max(1e-9),
        sem.1 / ws.1.max(1e-9),
        hops * (ws.0 - sem.0)
    );
    let json = format!(
        "{{\n  \"waitset_p50_us\": {:.3},\n  \"waitset_p99_us\": {:.3},\n  \"listener_p50_us\": {:.3},\n  \"listener_p99_us\": {:.3},\n  \"semaphore_p50_us\": {:.3},\n  \"semaphore_p99_us\": {:.3},\n  \"messages\": {}\n}}\n",
        figures[0].0, figures[0].1, figures[1].0, figures[1].1, figures[2].0, figures[2].1, args.messages
    );
    if let Some(dir) = args.out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(&args.out, json)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    println!("wrote {}", args.out.display());
    Ok(())
}

/// Sends the series to a receiver process of `way`; its (p50, p99) in us.
/// The bench's iceoryx2 files are removed afterwards, as a run's are (its
/// management file is world-writable: none may stay in /dev/shm).
fn drive<S: iceoryx2::service::Service + Debug>(way: &str, messages: usize) -> Result<(f64, f64)> {
    let prefix = format!("dsl_wakeup{}_{way}_", std::process::id());
    let figures = drive_with::<S>(way, messages, &prefix);
    match pipeline::transport::remove_prefixed_files(&prefix) {
        Ok(n) => eprintln!("{way}: removed the bench's {n} iceoryx2 files"),
        Err(e) => eprintln!("{way}: cannot remove the bench's iceoryx2 files: {e:#}"),
    }
    figures
}

/// [`drive`] with the bench's iceoryx2 `prefix`; every port and node is
/// dropped on return.
fn drive_with<S: iceoryx2::service::Service + Debug>(
    way: &str,
    messages: usize,
    prefix: &str,
) -> Result<(f64, f64)> {
    let (_node, pubsub, event) = services::<S>(prefix)?;
    let publisher = pubsub
        .publisher_builder()
        .create()
        .map_err(|e| anyhow!("publisher: {e:?}"))?;
    let notifier = event
        .notifier_builder()
        .create()
        .map_err(|e| anyhow!("notifier: {e:?}"))?;
    let mut child = Command::new(std::env::current_exe()?)
        .args(["--receive", way, "--prefix", prefix, "--messages"])
        .arg(messages.to_string())
        .stdout(Stdio::piped())
        .spawn()?;
    let mut out = child.stdout.take().context("receiver stdout")?;
    let mut ready = [0u8; 1];
    out.read_exact(&mut ready)
        .context("the receiver did not start")?;
    // Its listener has to be connected before the first notification.
    std::thread::sleep(Duration::from_millis(100));
    for _ in 0..messages + WARMUP {
        publisher
            .send_copy(now_ns())
            .map_err(|e| anyhow!("send: {e:?}"))?;
        notifier.notify().map_err(|e| anyhow!("notify: {e:?}"))?;
        std::thread::sleep(PERIOD);
    }
    publisher
        .send_copy(END)
        .map_err(|e| anyhow!("send: {e:?}"))?;
    notifier.notify().map_err(|e| anyhow!("notify: {e:?}"))?;
    let mut text = String::new();
    out.read_to_string(&mut text)?;
    if !child.wait()?.success() {
        bail!("the {way} receiver failed");
    }
    let v: Vec<f64> = text
        .split_whitespace()
        .filter_map(|t| t.parse().ok())
        .collect();
    match v[..] {
        [p50, p99] => Ok((p50, p99)),
        _ => bail!("the {way} receiver printed '{text}'"),
    }
}

/// A receiver's ports (the node kept alive with them).
struct Ports<S: iceoryx2::service::Service> {
    _node: Node<S>,
    subscriber: iceoryx2::port::subscriber::Subscriber<S, u64, ()>,
    listener: iceoryx2::port::listener::Listener<S>,
}

type Services<S> = (
    Node<S>,
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<S, u64, ()>,
    iceoryx2::service::port_factory::event::PortFactory<S>,
);

/// The bench's node, its stamp service and its event service.
fn services<S: iceoryx2::service::Service + Debug>(prefix: &str) -> Result<Services<S>> {
    let node = NodeBuilder::new()
        .config(&config(prefix)?)
        .create::<S>()
        .map_err(|e| anyhow!("node: {e:?}"))?;
    let name = ServiceName::new(SERVICE).map_err(|e| anyhow!("{e:?}"))?;
    let pubsub = node
        .service_builder(&name)
        .publish_subscribe::<u64>()
        .subscriber_max_buffer_size(QUEUE)
        .open_or_create()
        .map_err(|e| anyhow!("publish-subscribe service: {e:?}"))?;
    let event = node
        .service_builder(&name)
        .event()
        .open_or_create()
        .map_err(|e| anyhow!("event service: {e:?}"))?;
    Ok((node, pubsub, event))
}

fn open_ports<S: iceoryx2::service::Service + Debug>(prefix: &str) -> Result<Ports<S>> {
    let (node, pubsub, event) = services::<S>(prefix)?;
    let subscriber = pubsub
        .subscriber_builder()
        .buffer_size(QUEUE)
        .create()
        .map_err(|e| anyhow!("subscriber: {e:?}"))?;
    let listener = event
        .listener_builder()
        .create()
        .map_err(|e| anyhow!("listener: {e:?}"))?;
    print!("r");
    std::io::stdout().flush()?;
    Ok(Ports {
        _node: node,
        subscriber,
        listener,
    })
}

impl<S: iceoryx2::service::Service + Debug> Ports<S> {
    /// Takes what the wake-up brought: the notifications, then the stamps;
    /// whether the series is over.
    fn drain(&self, lat: &mut Vec<f64>) -> Result<bool> {
        self.listener
            .try_wait(|_| {})
            .map_err(|e| anyhow!("listener: {e:?}"))?;
        while let Some(sample) = self
            .subscriber
            .receive()
            .map_err(|e| anyhow!("receive: {e:?}"))?
        {
            if *sample == END {
                return Ok(true);
            }
            lat.push(now_ns().saturating_sub(*sample) as f64 / 1e3);
        }
        Ok(false)
    }
}

const RECEIVE_TIMEOUT: Duration = Duration::from_secs(10);

fn print_figures(lat: Vec<f64>, sent: usize) {
    if lat.len() < sent {
        eprintln!("{} of {sent} messages never arrived", sent - lat.len());
    }
    let mut lat: Vec<f64> = lat.into_iter().skip(WARMUP).collect();
    lat.sort_by(f64::total_cmp);
    println!("{} {}", percentile(&lat, 50.0), percentile(&lat, 99.0));
}

/// The listener waited on alone (the only way for a semaphore event).
fn receive_alone<S: iceoryx2::service::Service + Debug>(
    prefix: &str,
    messages: usize,
) -> Result<()> {
    let ports = open_ports::<S>(prefix)?;
    let total = messages + WARMUP;
    let mut lat = Vec::with_capacity(total);
    loop {
        let woken = ports
            .listener
            .timed_wait(|_| {}, RECEIVE_TIMEOUT)
            .map_err(|e| anyhow!("listener: {e:?}"))?;
        let before = lat.len();
        if ports.drain(&mut lat)? {
            break;
        }
        if woken == 0 && lat.len() == before {
            bail!("no message for {RECEIVE_TIMEOUT:?} ({before} received)");
        }
    }
    print_figures(lat, total);
    Ok(())
}

/// The pipeline's way: the listener wakes a WaitSet (only the default,
/// file-descriptor event can be attached to one).
fn receive_waitset(prefix: &str, messages: usize) -> Result<()> {
    let ports = open_ports::<ipc::Service>(prefix)?;
    let ws = WaitSetBuilder::new()
        .create::<ipc::Service>()
        .map_err(|e| anyhow!("WaitSet: {e:?}"))?;
    let _guard = ws
        .attach_notification(&ports.listener)
        .map_err(|e| anyhow!("attach: {e:?}"))?;
    let total = messages + WARMUP;
    let mut lat = Vec::with_capacity(total);
    loop {
        ws.wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, RECEIVE_TIMEOUT)
            .map_err(|e| anyhow!("WaitSet wait: {e:?}"))?;
        if ports.drain(&mut lat)? {
            break;
        }
    }
    print_figures(lat, total);
    Ok(())
}
