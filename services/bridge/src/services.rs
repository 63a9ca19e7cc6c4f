//! The map services (`[bridge] services = true`), as robot engineers drive
//! slam_toolbox and rtabmap: ROS 2 services in rmw_zenoh's convention, each
//! request passed on to the SLAM as a [`SlamCommand`] and answered with the
//! SLAM's [`SlamReply`]:
//!
//! - `dynslam/save_map` (`dynslam_interfaces/srv/SaveMap`: a name; the map
//!   goes to `bridge.maps_dir`, which the SLAM never leaves for a name from
//!   the network);
//! - `dynslam/reset` (`std_srvs/srv/Trigger`): a new map from the next frame;
//! - `dynslam/set_localization_mode` (`std_srvs/srv/SetBool`).
//!
//! Every response is `success` and a `message` that says what was done or
//! why not. The SLAM answering nothing (dead, restarting) is a failed
//! response after a while, never a hung client.

use std::time::{Duration, Instant};

use anyhow::Result;
use pipeline::transport::{Receiver, Sender, Transport};
use shared_types::names::Topic;
use shared_types::{read_error_text, write_error_text, SlamCommand, SlamCommandKind, SlamReply};

use crate::msgs::{self, MsgType};
use crate::node::{RosNode, RosService, ServiceRequest};

/// How long a request waits for the SLAM: a save writes the whole map.
const SAVE_PATIENCE: Duration = Duration::from_secs(60);
const PATIENCE: Duration = Duration::from_secs(10);

struct Endpoint {
    kind: SlamCommandKind,
    service: RosService,
}

struct Pending {
    id: u64,
    endpoint: usize,
    request: ServiceRequest,
    deadline: Instant,
}

/// The map services (save, reset, localization mode): requests passed to the SLAM, its replies sent back.
pub struct MapServices {
    endpoints: Vec<Endpoint>,
    commands: Sender<SlamCommand, ()>,
    pending: Vec<Pending>,
    next_id: u64,
    /// Requests that made no sense, not yet handed to the diagnostics.
    refused: u64,
}

/// The services' names (relative: under the node's namespace) and types.
pub const SERVICES: [(&str, MsgType, SlamCommandKind); 3] = [
    ("dynslam/save_map", msgs::SAVE_MAP, SlamCommandKind::SaveMap),
    ("dynslam/reset", msgs::TRIGGER, SlamCommandKind::Reset),
    (
        "dynslam/set_localization_mode",
        msgs::SET_BOOL,
        SlamCommandKind::SetLocalizationMode,
    ),
];

impl MapServices {
    /// The services, and the receiver of the SLAM's replies (to wait on).
    pub fn open(
        node: &mut RosNode,
        transport: &Transport,
    ) -> Result<(Self, Receiver<SlamReply, ()>)> {
        let endpoints = SERVICES
            .iter()
            .map(|&(name, ty, kind)| {
                Ok(Endpoint {
                    kind,
                    service: node.service(name, ty)?,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let services = Self {
            endpoints,
            commands: transport.sender::<SlamCommand>(Topic::SlamCommands)?,
            pending: Vec::new(),
            // Ids from the clock: a restarted bridge never takes a reply
            // meant for its predecessor for one of its own.
            next_id: pipeline::clock::now_ns(),
            refused: 0,
        };
        Ok((
            services,
            transport.receiver::<SlamReply>(Topic::SlamReplies)?,
        ))
    }

    /// Passes new requests on, answers those the SLAM answered or that
    /// waited too long. Returns how many requests made no sense (for the
    /// diagnostics' count of refused messages).
    pub fn poll(&mut self, replies: &Receiver<SlamReply, ()>, now: Instant) -> Result<u64> {
        for i in 0..self.endpoints.len() {
            while let Some(request) = self.endpoints[i].service.next() {
                self.on_request(i, request, now)?;
            }
        }
        replies.clear_wakeups();
        while let Some(reply) = replies.next()? {
            if let Some(at) = self.pending.iter().position(|p| p.id == reply.id) {
                let p = self.pending.swap_remove(at);
                let message = read_error_text(&reply.message);
                self.respond(p.endpoint, p.request, reply.ok != 0, &message);
            }
        }
        let (late, waiting): (Vec<Pending>, Vec<Pending>) = std::mem::take(&mut self.pending)
            .into_iter()
            .partition(|p| now >= p.deadline);
        self.pending = waiting;
        for p in late {
            let message = "the SLAM did not answer in time (stopped or restarting?); try again";
            self.respond(p.endpoint, p.request, false, message);
        }
        Ok(std::mem::take(&mut self.refused))
    }

    fn on_request(&mut self, endpoint: usize, request: ServiceRequest, now: Instant) -> Result<()> {
        let kind = self.endpoints[endpoint].kind;
        let mut command = SlamCommand {
            id: self.next_id,
            kind: kind as u32,
            ..SlamCommand::default()
        };
        let parsed = match kind {
            SlamCommandKind::SaveMap => msgs::read_save_map_request(&request.payload).map(|name| {
                write_error_text(&mut command.name, &name);
                // A name cut to fit would save under another name.
                read_error_text(&command.name) == name
            }),
            SlamCommandKind::SetLocalizationMode => msgs::read_set_bool_request(&request.payload)
                .map(|on| {
                    command.flag = on as u32;
                    true
                }),
            SlamCommandKind::Reset => Ok(true),
        };
        match parsed {
            Ok(true) => {}
            Ok(false) => {
                self.refused += 1;
                self.respond(endpoint, request, false, "map name too long");
                return Ok(());
            }
            Err(e) => {
                self.refused += 1;
                let name = self.endpoints[endpoint].service.name.clone();
                tracing::warn!("{name}: a malformed request: {e}");
                self.respond(endpoint, request, false, &format!("malformed request: {e}"));
                return Ok(());
            }
        }
        self.next_id += 1;
        self.commands.send(command)?;
        let patience = if kind == SlamCommandKind::SaveMap {
            SAVE_PATIENCE
        } else {
            PATIENCE
        };
        self.pending.push(Pending {
            id: command.id,
            endpoint,
            request,
            deadline: now + patience,
        });
        Ok(())
    }

    fn respond(&self, endpoint: usize, request: ServiceRequest, success: bool, message: &str) {
        let service = &self.endpoints[endpoint].service;
        tracing::info!(success, "{}: {message}", service.name);
        // A client gone meanwhile is not the bridge's failure.
        if let Err(e) = service.respond(request, msgs::success_message_response(success, message)) {
            tracing::warn!("{e:#}");
        }
    }
}
