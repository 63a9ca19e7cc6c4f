//! A ROS 2 node on rmw_zenoh: the Zenoh session, the node's liveliness
//! token, and publishers that put CDR samples with rmw_zenoh's attachment.

use anyhow::{anyhow, Context, Result};
use pipeline::config::BridgeConfig;
use zenoh::handlers::{RingChannel, RingChannelHandler};
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::qos::{CongestionControl, Priority};
use zenoh::query::{Query, Queryable};
use zenoh::sample::Sample;
use zenoh::{Session, Wait};
use zenoh_ext::{AdvancedPublisher, AdvancedPublisherBuilderExt, CacheConfig};

use crate::msgs::MsgType;
use crate::rmw::{self, Durability, NodeInfo};

/// The Zenoh configuration of the node: the configured file as it is, or
/// rmw_zenoh's session defaults (a peer that connects to the router, listens
/// on localhost only, no multicast scouting) with `mode` and `connect`.
pub fn session_config(cfg: &BridgeConfig) -> Result<zenoh::Config> {
    let set = |c: &mut zenoh::Config, key: &str, value: String| {
        c.insert_json5(key, &value)
            .map_err(|e| anyhow!("Zenoh setting {key} = {value}: {e}"))
    };
    // The latched topics' cache orders samples by timestamp (rmw_zenoh's
    // own session config has it on too), whatever the file says.
    let timestamping = |c: &mut zenoh::Config| set(c, "timestamping/enabled", "true".into());
    if let Some(file) = &cfg.zenoh_config {
        let mut c = zenoh::Config::from_file(file).map_err(|e| {
            anyhow!(
                "bridge.zenoh_config {}: not a usable Zenoh configuration: {e}",
                file.display()
            )
        })?;
        timestamping(&mut c)?;
        return Ok(c);
    }
    let mut c = zenoh::Config::default();
    timestamping(&mut c)?;
    set(&mut c, "mode", format!("{:?}", cfg.mode))?;
    let endpoints: Vec<String> = cfg.connect.iter().map(|e| format!("{e:?}")).collect();
    set(
        &mut c,
        "connect/endpoints",
        format!("[{}]", endpoints.join(",")),
    )
    .with_context(|| format!("bridge.connect {:?}", cfg.connect))?;
    set(&mut c, "scouting/multicast/enabled", "false".into())?;
    if cfg.mode == "peer" {
        set(&mut c, "listen/endpoints", "[\"tcp/localhost:0\"]".into())?;
    }
    Ok(c)
}

/// Samples a subscriber queues between two looks (the bridge looks every
/// 50 ms at most).
const SUBSCRIBER_QUEUE: usize = 4096;

/// One node of the ROS 2 graph.
pub struct RosNode {
    session: Session,
    info: NodeInfo,
    next_entity: u32,
    _token: LivelinessToken,
}

impl RosNode {
    /// Opens the Zenoh session `cfg` describes and declares the node's liveliness token.
    pub fn open(cfg: &BridgeConfig) -> Result<Self> {
        let config = session_config(cfg)?;
        let session = zenoh::open(config)
            .wait()
            .map_err(|e| anyhow!("cannot open the Zenoh session ({:?}): {e}", cfg.connect))?;
        let info = NodeInfo {
            domain: cfg.domain_id,
            zid: session.zid().to_string(),
            node_id: 0,
            namespace: cfg.namespace.clone(),
            name: cfg.node_name.clone(),
        };
        let token = session
            .liveliness()
            .declare_token(info.node_token())
            .wait()
            .map_err(|e| anyhow!("cannot declare the node's liveliness token: {e}"))?;
        Ok(Self {
            session,
            info,
            next_entity: 1,
            _token: token,
        })
    }

    /// The session's Zenoh id.
    pub fn zid(&self) -> &str {
        &self.info.zid
    }

    /// Routers this session is connected to (none: no ROS 2 node can see us).
    pub fn routers(&self) -> usize {
        self.session.info().routers_zid().wait().count()
    }

    /// A subscriber to every type on `topic` (the type is checked per
    /// sample: a sample of another type is the network's mistake to count).
    pub fn subscriber(&self, topic: &str) -> Result<TopicSubscriber> {
        let fq = rmw::resolve(&self.info.namespace, topic);
        let key = format!("{}/{}/**", self.info.domain, fq.trim_start_matches('/'));
        let subscriber = self
            .session
            .declare_subscriber(key.clone())
            // Never blocks Zenoh: a flood drops the oldest samples.
            .with(RingChannel::new(SUBSCRIBER_QUEUE))
            .wait()
            .map_err(|e| anyhow!("cannot subscribe to {fq} ({key}): {e}"))?;
        let depth = fq.trim_start_matches('/').split('/').count() + 1;
        Ok(TopicSubscriber {
            topic: fq,
            depth,
            subscriber,
        })
    }

    /// A publisher on `topic` (resolved under the node's namespace).
    pub fn publisher(
        &mut self,
        topic: &str,
        ty: MsgType,
        durability: Durability,
        depth: u32,
        priority: Priority,
    ) -> Result<RosPublisher> {
        let fq = rmw::resolve(&self.info.namespace, topic);
        let key = rmw::topic_key(self.info.domain, &fq, &ty);
        let entity = self.next_entity;
        self.next_entity += 1;
        let token_key =
            self.info
                .publisher_token(entity, &fq, &ty, &rmw::qos_token(durability, depth));
        let builder = self
            .session
            .declare_publisher(key.clone())
            // rmw_zenoh: a keep-last publisher drops rather than blocks.
            .congestion_control(CongestionControl::Drop)
            // Zenoh queues each priority apart: poses are never dropped
            // behind a queue of images.
            .priority(priority);
        let publisher = match durability {
            Durability::Volatile => builder.wait().map(Sender::Plain),
            // rmw_zenoh's transient local: the last `depth` samples stay in
            // a cache that a late subscriber queries (zenoh-ext's advanced
            // publisher, as rmw_zenoh declares it).
            Durability::TransientLocal => builder
                .cache(CacheConfig::default().max_samples(depth as usize))
                .publisher_detection()
                .wait()
                .map(Sender::Cached),
        }
        .map_err(|e| anyhow!("cannot declare the publisher of {fq} ({key}): {e}"))?;
        let token = self
            .session
            .liveliness()
            .declare_token(token_key.clone())
            .wait()
            .map_err(|e| anyhow!("cannot declare the liveliness token of {fq}: {e}"))?;
        Ok(RosPublisher {
            topic: fq,
            gid: rmw::gid(&token_key),
            sequence_number: 0,
            publisher,
            _token: token,
        })
    }
}

impl RosNode {
    /// A service server on `name` (resolved under the node's namespace):
    /// rmw_zenoh's clients query the service's key expression and take the
    /// reply as the response.
    pub fn service(&mut self, name: &str, ty: MsgType) -> Result<RosService> {
        let fq = rmw::resolve(&self.info.namespace, name);
        let key = rmw::topic_key(self.info.domain, &fq, &ty);
        let entity = self.next_entity;
        self.next_entity += 1;
        let qos = rmw::qos_token(Durability::Volatile, SERVICE_QUEUE as u32);
        let token_key = self.info.service_token(entity, &fq, &ty, &qos);
        let queryable = self
            .session
            .declare_queryable(key.clone())
            // rmw_zenoh's clients ask complete queryables only.
            .complete(true)
            .with(RingChannel::new(SERVICE_QUEUE))
            .wait()
            .map_err(|e| anyhow!("cannot declare the service {fq} ({key}): {e}"))?;
        let token = self
            .session
            .liveliness()
            .declare_token(token_key)
            .wait()
            .map_err(|e| anyhow!("cannot declare the liveliness token of {fq}: {e}"))?;
        Ok(RosService {
            name: fq,
            key,
            queryable,
            _token: token,
        })
    }
}

/// The attachment's source timestamp: wall-clock ns, as rmw_zenoh writes it.
fn wall_clock_ns() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as i64)
        .unwrap_or(0)
}

/// Requests a service queues between two looks (more are dropped: the
/// client times out).
const SERVICE_QUEUE: usize = 16;

/// A ROS 2 service server.
pub struct RosService {
    /// The service's name.
    pub name: String,
    key: String,
    queryable: Queryable<RingChannelHandler<Query>>,
    _token: LivelinessToken,
}

/// One request: its CDR payload and what the response must carry back.
pub struct ServiceRequest {
    query: Query,
    /// The request's CDR.
    pub payload: Vec<u8>,
    /// The client's sequence number and gid (from the request's
    /// attachment; 0 and zeros when it had none).
    sequence_number: i64,
    client_gid: [u8; 16],
}

impl RosService {
    /// The next request waiting, if any.
    pub fn next(&self) -> Option<ServiceRequest> {
        let query = self.queryable.try_recv().ok()??;
        let payload = query
            .payload()
            .map(|p| p.to_bytes().into_owned())
            .unwrap_or_default();
        let (sequence_number, _, client_gid) = query
            .attachment()
            .and_then(|a| rmw::parse_attachment(&a.to_bytes()))
            .unwrap_or((0, 0, [0; 16]));
        Some(ServiceRequest {
            query,
            payload,
            sequence_number,
            client_gid,
        })
    }

    /// Answers `request` with `cdr`; the reply's attachment carries the
    /// request's sequence number and the client's gid back (rmw_zenoh
    /// matches responses to requests by them).
    pub fn respond(&self, request: ServiceRequest, cdr: Vec<u8>) -> Result<()> {
        let attachment = rmw::attachment(
            request.sequence_number,
            wall_clock_ns(),
            &request.client_gid,
        );
        request
            .query
            .reply(self.key.clone(), cdr)
            .attachment(attachment)
            .wait()
            .map_err(|e| anyhow!("cannot answer a request on {}: {e}", self.name))
    }
}

/// A ROS 2 publisher: its samples are numbered 1, 2, ... (continued from
/// `sequence_number` after a restart).
pub struct RosPublisher {
    /// The topic's name.
    pub topic: String,
    gid: [u8; 16],
    /// Sequence number of the next message.
    pub sequence_number: i64,
    publisher: Sender,
    _token: LivelinessToken,
}

enum Sender {
    Plain(Publisher<'static>),
    Cached(AdvancedPublisher<'static>),
}

impl RosPublisher {
    /// Publishes one message's CDR with the attachment rmw_zenoh expects.
    pub fn publish(&mut self, cdr: Vec<u8>) -> Result<()> {
        self.sequence_number += 1;
        let attachment = rmw::attachment(self.sequence_number, wall_clock_ns(), &self.gid);
        match &self.publisher {
            Sender::Plain(p) => p.put(cdr).attachment(attachment).wait(),
            Sender::Cached(p) => p.put(cdr).attachment(attachment).wait(),
        }
        .map_err(|e| anyhow!("cannot publish on {}: {e}", self.topic))
    }
}

/// Samples of one topic, as they came.
pub struct TopicSubscriber {
    /// The topic's name.
    pub topic: String,
    /// Key parts before the type: the domain and the topic's parts.
    depth: usize,
    subscriber: Subscriber<RingChannelHandler<Sample>>,
}

impl TopicSubscriber {
    /// The next sample that arrived: the DDS type named by its key ("" when
    /// the key has no type and hash after the topic) and its payload.
    pub fn next(&self) -> Option<(String, Vec<u8>)> {
        let sample = self.subscriber.try_recv().ok()??;
        let parts: Vec<&str> = sample.key_expr().as_str().split('/').collect();
        let dds = if parts.len() == self.depth + 2 {
            parts[self.depth].to_string()
        } else {
            String::new()
        };
        Some((dds, sample.payload().to_bytes().into_owned()))
    }
}
