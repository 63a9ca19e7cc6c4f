//! rmw_zenoh's wire conventions (ros2/rmw_zenoh `docs/design.md`), so that
//! ROS 2 nodes running `RMW_IMPLEMENTATION=rmw_zenoh_cpp` see dynslam as a
//! node of their own graph:
//!
//! - a topic's data travel on `<domain>/<topic without its leading '/'>/<DDS
//!   type name>/<RIHS01 type hash>`;
//! - each sample carries an attachment: sequence number (`i64`), source
//!   timestamp (`i64` ns) and the publisher's 16-byte gid, as zenoh's
//!   serializer writes them (little endian, the gid's length as a LEB128
//!   byte);
//! - the graph (`ros2 node list`, `ros2 topic list`) is made of liveliness
//!   tokens: `@ros2_lv/<domain>/<session zid>/<node id>/<entity id>/<NN|MP>/
//!   <enclave>/<namespace>/<node name>[/<topic>/<type>/<hash>/<qos>]`, every
//!   '/' inside a part written '%'.

use crate::msgs::MsgType;

/// The liveliness admin space of rmw_zenoh.
pub const ADMIN_SPACE: &str = "@ros2_lv";

/// A name with its '/' written '%' (a key-expression part); empty or "/"
/// is "%".
pub fn mangle(name: &str) -> String {
    if name.is_empty() || name == "/" {
        "%".into()
    } else {
        name.replace('/', "%")
    }
}

/// A topic's fully qualified name: absolute names stay, relative ones go
/// under the namespace (`odometry` in `/robot1` is `/robot1/odometry`).
pub fn resolve(namespace: &str, topic: &str) -> String {
    if topic.starts_with('/') {
        topic.to_string()
    } else if namespace.is_empty() || namespace == "/" {
        format!("/{topic}")
    } else {
        format!("{}/{topic}", namespace.trim_end_matches('/'))
    }
}

/// The data key expression of a topic.
pub fn topic_key(domain: u32, fq_topic: &str, ty: &MsgType) -> String {
    format!(
        "{domain}/{}/{}/{}",
        fq_topic.trim_start_matches('/'),
        ty.dds,
        ty.hash
    )
}

/// Reliability and durability of a publisher, as its QoS token part says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Durability {
    /// Only subscribers present now get a sample (the default).
    Volatile,
    /// Late subscribers get the last samples (`/tf_static`).
    TransientLocal,
}

/// The QoS part of a liveliness token (rmw_zenoh's `qos_to_keyexpr`): a
/// reliable, keep-last publisher; fields equal to ROS 2's default profile
/// (reliable, volatile, keep last 10, no deadline/lifespan, automatic
/// liveliness) are left empty.
pub fn qos_token(durability: Durability, depth: u32) -> String {
    let durability = match durability {
        Durability::Volatile => "",
        Durability::TransientLocal => "1",
    };
    format!(":{durability}:,{depth}:,:,:,,")
}

/// A node of the graph.
#[derive(Debug, Clone)]
pub struct NodeInfo {
    /// ROS 2 domain id.
    pub domain: u32,
    /// The Zenoh session's id, as zenoh prints it (lowercase hex).
    pub zid: String,
    /// Node id within the session.
    pub node_id: u32,
    /// The node's namespace.
    pub namespace: String,
    /// The node's name.
    pub name: String,
}

impl NodeInfo {
    fn prefix(&self, entity_id: u32, kind: &str) -> String {
        format!(
            "{ADMIN_SPACE}/{}/{}/{}/{entity_id}/{kind}/%/{}/{}",
            self.domain,
            self.zid,
            self.node_id,
            mangle(&self.namespace),
            mangle(&self.name)
        )
    }
    /// The node's own token (its entity id is the node id).
    pub fn node_token(&self) -> String {
        self.prefix(self.node_id, "NN")
    }
    /// A publisher's token.
    pub fn publisher_token(
        &self,
        entity_id: u32,
        fq_topic: &str,
        ty: &MsgType,
        qos: &str,
    ) -> String {
        self.endpoint_token(entity_id, "MP", fq_topic, ty, qos)
    }
    /// A service server's token (`ros2 service list`).
    pub fn service_token(&self, entity_id: u32, fq_name: &str, ty: &MsgType, qos: &str) -> String {
        self.endpoint_token(entity_id, "SS", fq_name, ty, qos)
    }
    fn endpoint_token(
        &self,
        entity_id: u32,
        kind: &str,
        fq_name: &str,
        ty: &MsgType,
        qos: &str,
    ) -> String {
        format!(
            "{}/{}/{}/{}/{qos}",
            self.prefix(entity_id, kind),
            mangle(fq_name),
            ty.dds,
            ty.hash
        )
    }
}

/// A publisher's 16-byte gid: unique per session and entity (two FNV-1a
/// hashes of its token, which holds both).
pub fn gid(token: &str) -> [u8; 16] {
    let fnv = |seed: u64| {
        token.bytes().fold(seed, |h, b| {
            (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3)
        })
    };
    let mut g = [0u8; 16];
    g[..8].copy_from_slice(&fnv(0xcbf2_9ce4_8422_2325).to_le_bytes());
    g[8..].copy_from_slice(&fnv(0x6c62_272e_07bb_0142).to_le_bytes());
    g
}

/// The attachment of one sample.
pub fn attachment(sequence_number: i64, source_timestamp_ns: i64, gid: &[u8; 16]) -> Vec<u8> {
    let mut a = Vec::with_capacity(33);
    a.extend_from_slice(&sequence_number.to_le_bytes());
    a.extend_from_slice(&source_timestamp_ns.to_le_bytes());
    a.push(16);
    a.extend_from_slice(gid);
    a
}

/// An attachment's parts: sequence number, source timestamp, gid. None
/// when it is not rmw_zenoh's 33 bytes.
pub fn parse_attachment(a: &[u8]) -> Option<(i64, i64, [u8; 16])> {
    if a.len() != 33 || a[16] != 16 {
        return None;
    }
    let seq = i64::from_le_bytes(a[..8].try_into().ok()?);
    let ts = i64::from_le_bytes(a[8..16].try_into().ok()?);
    Some((seq, ts, a[17..33].try_into().ok()?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{ODOMETRY, STRING};

    #[test]
    fn names_resolve_and_mangle_as_rmw_zenoh() {
        assert_eq!(resolve("", "dynslam/odometry"), "/dynslam/odometry");
        assert_eq!(resolve("/robot1", "tf"), "/robot1/tf");
        assert_eq!(resolve("/robot1", "/diagnostics"), "/diagnostics");
        assert_eq!(mangle("/robot1/tf"), "%robot1%tf");
        assert_eq!(mangle(""), "%");
        assert_eq!(
            topic_key(0, "/chatter", &STRING),
            "0/chatter/std_msgs::msg::dds_::String_/RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
        );
    }

    #[test]
    fn tokens_have_rmw_zenohs_parts() {
        let node = NodeInfo {
            domain: 3,
            zid: "a1b2".into(),
            node_id: 0,
            namespace: "/robot1".into(),
            name: "dynslam".into(),
        };
        assert_eq!(
            node.node_token(),
            "@ros2_lv/3/a1b2/0/0/NN/%/%robot1/dynslam"
        );
        let qos = qos_token(Durability::Volatile, 10);
        assert_eq!(qos, "::,10:,:,:,,");
        let t = node.publisher_token(4, "/robot1/dynslam/odometry", &ODOMETRY, &qos);
        let parts: Vec<&str> = t.split('/').collect();
        assert_eq!(parts.len(), 13);
        assert_eq!(parts[5], "MP");
        assert_eq!(parts[9], "%robot1%dynslam%odometry");
        assert_eq!(parts[10], ODOMETRY.dds);
        assert_eq!(parts[11], ODOMETRY.hash);
        assert_eq!(qos_token(Durability::TransientLocal, 1), ":1:,1:,:,:,,");
    }

    #[test]
    fn attachments_are_33_bytes_and_gids_differ() {
        let g = gid("a");
        assert_ne!(g, gid("b"));
        let a = attachment(7, 1_000, &g);
        assert_eq!(a.len(), 33);
        assert_eq!(&a[..8], &7i64.to_le_bytes());
        assert_eq!(a[16], 16);
        assert_eq!(parse_attachment(&a), Some((7, 1_000, g)));
        assert_eq!(parse_attachment(&a[..32]), None);
        let mut wrong = a.clone();
        wrong[16] = 8;
        assert_eq!(parse_attachment(&wrong), None);
    }
}
