//! The run as ROS 2 topics (`bridge publish`): the run's pose stream,
//! Tracks, masks and map (iceoryx2) out as ROS 2 topics over Zenoh, the
//! map services in. Off the frame path: tracking never waits for it and
//! goes on when it dies.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::Result;
use pipeline::config::BridgeConfig;
use pipeline::runtime::ServiceContext;
use pipeline::service_loop::{self, Drain, Event, Flow, Service};
use pipeline::transport::{attach, waitset, Receiver, Sample, Svc};
use shared_types::names::Topic;
use shared_types::{MapHeader, MasksHeader, Pose, SlamReply, Track};

use crate::node::{RosNode, TopicSubscriber};
use crate::outputs::Outputs;
use crate::services::MapServices;

/// How long the bridge sleeps at most between its periodic publications.
const TICK: Duration = Duration::from_millis(50);
/// A node with no router for this long tells the user (once).
const ROUTER_WARNING_AFTER: Duration = Duration::from_secs(3);

type MasksSample = Sample<Svc, [u8], MasksHeader>;
type MapSample = Sample<Svc, [u8], MapHeader>;

/// Publishes the run until stopped; `run_dir`: the run folder (the
/// supervisor's status.json for the diagnostics, the bridge's own record).
pub fn serve(ctx: ServiceContext, run_dir: &Path) -> Result<()> {
    let cfg = &ctx.config.bridge;
    let poses = ctx.transport.receiver::<Pose>(Topic::Poses)?;
    let tracks = ctx.transport.receiver::<Track>(Topic::Tracks)?;
    // Only with mask_image: the label images are read in shared memory.
    let masks = if cfg.mask_image {
        Some(ctx.transport.slice_receiver::<MasksHeader>(Topic::Masks)?)
    } else {
        None
    };
    // The map as local mapping leaves it (the SLAM sends it with a bridge).
    let map = ctx.transport.slice_receiver::<MapHeader>(Topic::Map)?;
    let mut node = RosNode::open(cfg)?;
    let outputs = Outputs::new(&mut node, cfg, run_dir)?;
    let (services, replies) = if cfg.services {
        Some(MapServices::open(&mut node, &ctx.transport)?).unzip()
    } else {
        (None, None)
    };
    // The robot's odom -> base arrives on tf (REP-105).
    let tf = if cfg.odom_frame.is_empty() {
        None
    } else {
        Some(node.subscriber(&cfg.tf_topic)?)
    };
    let ws = waitset()?;
    let _p = attach(&ws, &poses)?;
    let _t = attach(&ws, &tracks)?;
    let _m = masks.as_ref().map(|m| attach(&ws, m)).transpose()?;
    let _map = attach(&ws, &map)?;
    let _r = replies.as_ref().map(|r| attach(&ws, r)).transpose()?;
    ctx.announce_ready()?;
    tracing::info!(
        zid = node.zid(),
        domain = cfg.domain_id,
        namespace = %cfg.namespace,
        "ROS 2 node {} on Zenoh ({})",
        cfg.node_name,
        cfg.zenoh_config
            .as_ref()
            .map_or_else(|| format!("{} {:?}", cfg.mode, cfg.connect), |f| f.display().to_string())
    );
    service_loop::run(
        &ws,
        &mut Publish {
            cfg,
            node: &node,
            outputs,
            services,
            replies: replies.as_ref(),
            masks: masks.as_ref(),
            tracks: &tracks,
            tf: tf.as_ref(),
            poses: &poses,
            map: &map,
            started: Instant::now(),
            router_checked: false,
            drain: Drain::default(),
        },
    )
}

/// What arrives for the bridge, in the order a wake-up drains it: a frame's
/// masks before its Track, the robot's tf before the poses it places.
enum Arrival {
    Masks(MasksSample),
    Track(Track),
    Tf(String, Vec<u8>),
    Pose(Pose),
    Map(MapSample),
}

/// The bridge's inputs and outputs.
struct Publish<'a> {
    cfg: &'a BridgeConfig,
    node: &'a RosNode,
    outputs: Outputs,
    services: Option<MapServices>,
    replies: Option<&'a Receiver<SlamReply, ()>>,
    masks: Option<&'a Receiver<[u8], MasksHeader>>,
    tracks: &'a Receiver<Track, ()>,
    tf: Option<&'a TopicSubscriber>,
    poses: &'a Receiver<Pose, ()>,
    map: &'a Receiver<[u8], MapHeader>,
    started: Instant,
    router_checked: bool,
    drain: Drain,
}

impl Publish<'_> {
    fn on_arrival(&mut self, arrival: Arrival) -> Result<()> {
        match arrival {
            Arrival::Masks(sample) => self
                .outputs
                .on_masks(sample.user_header(), sample.payload()),
            Arrival::Track(t) => {
                // Masks that came after the masks were drained, for this Track.
                if let Some(m) = self.masks {
                    while self.outputs.awaits_masks_for(&t) {
                        let Some(sample) = m.next_sample()? else {
                            break;
                        };
                        self.outputs
                            .on_masks(sample.user_header(), sample.payload());
                    }
                }
                self.outputs.on_track(&t)?;
            }
            Arrival::Tf(dds, payload) => self.outputs.on_tf_sample(&dds, &payload),
            Arrival::Pose(p) => self.outputs.on_pose(&p)?,
            Arrival::Map(sample) => self
                .outputs
                .on_map(sample.user_header(), sample.payload())?,
        }
        Ok(())
    }

    /// The map services' requests answered or timed out.
    fn serve_requests(&mut self) -> Result<()> {
        if let (Some(s), Some(replies)) = (&mut self.services, self.replies) {
            self.outputs.refused += s.poll(replies, Instant::now())?;
        }
        Ok(())
    }

    /// Once, a few seconds in: no Zenoh router reached is worth a word.
    fn check_router(&mut self) {
        if self.router_checked || self.started.elapsed() <= ROUTER_WARNING_AFTER {
            return;
        }
        self.router_checked = true;
        if self.cfg.zenoh_config.is_none() && self.node.routers() == 0 {
            tracing::warn!(
                "no Zenoh router reached at {:?} yet: ROS 2 nodes will not see dynslam until one runs (on the robot: ros2 run rmw_zenoh_cpp rmw_zenohd); the bridge keeps trying",
                self.cfg.connect
            );
        }
    }
}

impl Service for Publish<'_> {
    type Event = Arrival;

    fn patience(&self) -> Duration {
        TICK
    }

    fn woke(&mut self) {
        self.drain.restart();
    }

    fn next_event(&mut self) -> Result<Option<Arrival>> {
        let (masks, tracks, tf, poses, map) =
            (self.masks, self.tracks, self.tf, self.poses, self.map);
        self.drain.next(5, |stage, entering| {
            Ok(match stage {
                0 => match masks {
                    Some(m) => m.entered(entering).next_sample()?.map(Arrival::Masks),
                    None => None,
                },
                1 => tracks.entered(entering).next()?.map(Arrival::Track),
                // Zenoh's subscriber does not wake the WaitSet: read each time.
                2 => tf
                    .and_then(|tf| tf.next())
                    .map(|(dds, payload)| Arrival::Tf(dds, payload)),
                3 => poses.entered(entering).next()?.map(Arrival::Pose),
                _ => map.entered(entering).next_sample()?.map(Arrival::Map),
            })
        })
    }

    fn handle(&mut self, event: Event<Arrival>) -> Result<Flow> {
        match event {
            Event::Arrived(arrival) => self.on_arrival(arrival)?,
            Event::Tick => {
                self.serve_requests()?;
                self.outputs.tick(Instant::now())?;
                self.check_router();
            }
            Event::Shutdown => {
                // The supervisor stops the bridge after the SLAM: what the
                // SLAM said last goes out, the path complete.
                self.woke();
                while let Some(arrival) = self.next_event()? {
                    self.on_arrival(arrival)?;
                }
                self.serve_requests()?;
                self.outputs.finish()?;
            }
        }
        Ok(Flow::Continue)
    }
}
