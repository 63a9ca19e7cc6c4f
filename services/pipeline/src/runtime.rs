//! What every service binary does around its own work: common arguments,
//! logging, the readiness handshake and exit codes the supervisor reads.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Result;
use shared_types::names::{RunNames, Topic};
use shared_types::{Lifecycle, ServiceKind};

use crate::clock::now_ns;
use crate::config::PipelineConfig;
use crate::transport::{Sender, Transport};

/// Exit codes shared by all services.
pub mod exit_code {
    /// Clean end (SIGTERM, end of stream).
    pub const OK: u8 = 0;
    /// Unexpected runtime failure: the supervisor restarts the service.
    pub const RUNTIME: u8 = 1;
    /// Bad input or configuration that a restart cannot fix (missing dataset,
    /// malformed rgb.txt, missing model): the supervisor does not restart the
    /// service and reports the message.
    pub const INPUT: u8 = 2;
}

/// Arguments the supervisor passes to every service.
#[derive(Debug, Clone, clap::Args)]
pub struct ServiceArgs {
    /// Run id: selects the run's iceoryx2 services and shared-memory files.
    #[arg(long)]
    pub run_id: String,
    /// Pipeline configuration (the copy in the run folder).
    #[arg(long)]
    pub config: PathBuf,
}

/// An error caused by input a restart cannot fix; exits with
/// [`exit_code::INPUT`].
pub use provision::InputError;

/// Everything a service needs after the common start-up.
pub struct ServiceContext {
    /// Which service this process is.
    pub kind: ServiceKind,
    /// The run's names (its iceoryx2 services and files).
    pub names: RunNames,
    /// The run's configuration (the run folder's copy).
    pub config: PipelineConfig,
    /// This process's iceoryx2 node.
    pub transport: Transport,
    /// Lives as long as the service: iceoryx2 discards a dropped publisher's
    /// undelivered samples, so a Ready sent from a short-lived sender could
    /// vanish before the supervisor reads it.
    lifecycle: Sender<Lifecycle, ()>,
}

impl ServiceContext {
    /// Tells the supervisor that every port of this service is open.
    pub fn announce_ready(&self) -> Result<()> {
        self.lifecycle.send(Lifecycle {
            service: self.kind as u32,
            pid: std::process::id(),
            ready_ns: now_ns(),
        })
    }
}

/// Installs the `tracing` subscriber (stderr, `RUST_LOG` or `info`), with the
/// service name on every line so that interleaved child logs stay readable.
pub fn init_logging() {
    init_logging_with("info");
}

/// [`init_logging`] with another filter where `RUST_LOG` is unset (a
/// binary that quiets a library's own warnings; `run_service` then keeps
/// the subscriber installed first).
pub fn init_logging_with(default_filter: &str) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_filter));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_target(false)
        .try_init();
}

/// Runs a service: logging, config, transport, then `body`; maps the result
/// to the exit code the supervisor understands.
pub fn run_service(
    kind: ServiceKind,
    args: &ServiceArgs,
    body: impl FnOnce(ServiceContext) -> Result<()>,
) -> ExitCode {
    run_service_body(kind, args, Box::new(body))
}

/// [`run_service`] behind a boxed body, so that its config parsing and
/// transport setup (generic code of toml, serde and iceoryx2) are compiled
/// once here rather than again in every service binary.
fn run_service_body(
    kind: ServiceKind,
    args: &ServiceArgs,
    body: Box<dyn FnOnce(ServiceContext) -> Result<()> + '_>,
) -> ExitCode {
    init_logging();
    let span = tracing::info_span!("service", name = kind.as_str());
    let _enter = span.enter();
    let result = (|| {
        let names = RunNames::new(&args.run_id).map_err(InputError)?;
        let config = PipelineConfig::load(&args.config).map_err(|e| InputError(e.to_string()))?;
        let transport = Transport::open(&names, kind.as_str())?;
        let lifecycle = transport.sender::<Lifecycle>(Topic::Lifecycle)?;
        body(ServiceContext {
            kind,
            names,
            config,
            transport,
            lifecycle,
        })
    })();
    match result {
        Ok(()) => ExitCode::from(exit_code::OK),
        Err(e) => {
            let code = if e.downcast_ref::<InputError>().is_some() {
                exit_code::INPUT
            } else {
                exit_code::RUNTIME
            };
            tracing::error!("{} failed: {e:#}", kind.as_str());
            ExitCode::from(code)
        }
    }
}
