//! The Zenoh session of either end and the keys they meet on.

use std::path::Path;

use anyhow::{anyhow, Context, Result};
use zenoh::{Session, Wait};

/// Which worker role a key is for (the segmenter today).
pub const ROLE: &str = "segmenter";

/// Where a run's frames are asked for (the worker's queryable).
pub fn frames_key(run: &str) -> String {
    format!("dynslam/{run}/{ROLE}/frames")
}

/// The liveliness tokens of a run's workers (one per worker session).
pub fn workers_key(run: &str) -> String {
    format!("dynslam/{run}/{ROLE}/workers")
}

/// How a session is set up: a Zenoh configuration file used as it is (TLS,
/// access control), or the mode and endpoints.
#[derive(Debug, Clone)]
pub struct Endpoints<'a> {
    /// A Zenoh JSON5 file; the rest is then not applied.
    pub zenoh_config: Option<&'a Path>,
    /// "peer" or "client".
    pub mode: &'a str,
    /// Endpoints to listen on.
    pub listen: &'a [String],
    /// Endpoints to connect to.
    pub connect: &'a [String],
}

/// The largest message either end takes (a 4096x4096 PNG frame with depth
/// fits); Zenoh's own default is 1 GiB.
const MAX_MESSAGE_BYTES: u64 = 128 << 20;

/// A link silent this long is dead (its workers' tokens go with it):
/// Zenoh's default is 10 s; a robot wants its fallback sooner.
const LEASE_MS: u64 = 4000;

/// The session's configuration.
pub fn session_config(e: &Endpoints) -> Result<zenoh::Config> {
    let set = |c: &mut zenoh::Config, key: &str, value: String| {
        c.insert_json5(key, &value)
            .map_err(|err| anyhow!("Zenoh setting {key} = {value}: {err}"))
    };
    if let Some(file) = e.zenoh_config {
        return zenoh::Config::from_file(file).map_err(|err| {
            anyhow!(
                "{}: not a usable Zenoh configuration: {err}",
                file.display()
            )
        });
    }
    let mut c = zenoh::Config::default();
    set(&mut c, "mode", format!("{:?}", e.mode))?;
    let list = |v: &[String]| {
        format!(
            "[{}]",
            v.iter()
                .map(|s| format!("{s:?}"))
                .collect::<Vec<_>>()
                .join(",")
        )
    };
    set(&mut c, "connect/endpoints", list(e.connect))
        .with_context(|| format!("connect {:?}", e.connect))?;
    set(&mut c, "listen/endpoints", list(e.listen))
        .with_context(|| format!("listen {:?}", e.listen))?;
    // Only the endpoints named: nothing found by multicast on a robot's LAN.
    set(&mut c, "scouting/multicast/enabled", "false".into())?;
    // Nothing is scouted, so the open need not wait for scouted peers.
    set(
        &mut c,
        "open/return_conditions/connect_scouted",
        "false".into(),
    )?;
    set(
        &mut c,
        "transport/link/rx/max_message_size",
        MAX_MESSAGE_BYTES.to_string(),
    )?;
    set(&mut c, "transport/link/tx/lease", LEASE_MS.to_string())?;
    // A worker that comes up (or a link that comes back) is reached within
    // a second, not Zenoh's default of up to four.
    set(
        &mut c,
        "connect/retry",
        "{period_init_ms: 200, period_max_ms: 1000, period_increase_factor: 2}".into(),
    )?;
    Ok(c)
}

/// Opens the session; the error names the endpoints.
pub fn open(e: &Endpoints) -> Result<Session> {
    let config = session_config(e)?;
    zenoh::open(config).wait().map_err(|err| {
        anyhow!(
            "cannot open the Zenoh session (listen {:?}, connect {:?}{}): {err}",
            e.listen,
            e.connect,
            e.zenoh_config
                .map(|f| format!(", config {}", f.display()))
                .unwrap_or_default()
        )
    })
}
