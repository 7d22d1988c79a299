//! The Sparkplug B 3.0 edge-node conformance test: the specification's edge-node assertions
//! that can be observed from outside the node, each checked by its assertion id (the
//! `tck-id-...` of the specification's AsciiDoc, chapters 2 to 6), with a PASS or FAIL line
//! per id; the test fails if any fails or was not exercised.
//!
//! Two observers, both in this process: a Sparkplug host (an MQTT client on spBv1.0/#,
//! decoding with the crate's payload types) and a wire tap between the edge node and the
//! broker (rumqttd) that reads every MQTT packet the node sends: its CONNECT (clean session,
//! the will's topic, QoS, retain and payload), SUBSCRIBE filters and QoS, each PUBLISH's QoS and
//! retain flag, DISCONNECT, and the connection's end. What a host sees of QoS and retain
//! depends on its broker (rumqttd gives every message the subscription's QoS and clears
//! retain); the tap sees what the node sent.
//!
//! The edge node runs as a "process": its own tokio runtime over a store file. Killing it drops
//! the runtime, and with it the MQTT connection, without a DISCONNECT, as `kill -9` does; the
//! broker then delivers the NDEATH will. Restarting it opens the same store file in a new
//! runtime: the bdSeq goes on from what the store kept.
//!
//! The scenario: the primary host's STATE is offline (retained) when the node starts; an online
//! STATE older than it; the online STATE; DCMD by name and by alias; NCMD rebirth by name; an
//! NDATA; a reload that removes a drive (DDEATH); an offline STATE older than the online one;
//! the host offline; the host online again; kill; restart.

mod mqtt_support;

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use drivebus_gateway::config::SparkplugConfig;
use drivebus_gateway::sparkplug::payload::{self, Metric, Payload, Value};
use drivebus_gateway::{Gateway, GatewayConfig};
use mqtt_support::{rumqttd, Msg, Subscriber, PATIENCE};
use prost::Message;
use rumqttc::QoS;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

/// The edge-node assertions checked, in the specification's words made short: (id, text).
const ASSERTIONS: &[(&str, &str)] = &[
    // Chapter 2, principles.
    ("principles-birth-certificates-order", "birth certificates are the first MQTT messages an edge node publishes"),
    ("principles-persistence-clean-session-311", "MQTT 3.1.1: the edge node's CONNECT sets Clean Session true"),
    // Chapter 4, topics.
    ("topic-structure", "namespace/group_id/message_type/edge_node_id/[device_id]"),
    ("topic-structure-namespace-a", "the namespace element is spBv1.0"),
    ("topic-structure-namespace-device-id-associated-message-types", "DBIRTH, DDEATH, DDATA (and DCMD) topics carry the device_id"),
    ("topic-structure-namespace-device-id-non-associated-message-types", "NBIRTH, NDEATH, NDATA (and NCMD, STATE) topics carry no device_id"),
    ("topics-nbirth-topic", "NBIRTH topic is namespace/group_id/NBIRTH/edge_node_id"),
    ("topics-nbirth-mqtt", "NBIRTH is published with QoS 0, retain false"),
    ("topics-nbirth-seq-num", "NBIRTH has a seq of 0"),
    ("topics-nbirth-timestamp", "NBIRTH has a timestamp"),
    ("topics-nbirth-metric-reqs", "NBIRTH has every metric the edge node will ever report"),
    ("topics-nbirth-metrics", "each NBIRTH metric has a name, datatype and current value"),
    ("topics-nbirth-bdseq-included", "NBIRTH has a bdSeq metric"),
    ("topics-nbirth-bdseq-matching", "NBIRTH's bdSeq matches the bdSeq of the CONNECT's will"),
    ("topics-nbirth-bdseq-increment", "bdSeq starts at 0 and goes up by one with every new CONNECT"),
    ("topics-nbirth-rebirth-metric", "NBIRTH has 'Node Control/Rebirth', Boolean, false"),
    ("topics-ndata-topic", "NDATA topic is namespace/group_id/NDATA/edge_node_id"),
    ("topics-ndata-mqtt", "NDATA is published with QoS 0, retain false"),
    ("topics-ndata-seq-num", "NDATA's seq is one more than the previous message's, 0 after 255"),
    ("topics-ndata-timestamp", "NDATA has a timestamp"),
    ("topics-ndeath-topic", "NDEATH topic is namespace/group_id/NDEATH/edge_node_id"),
    ("topics-ndeath-payload", "NDEATH has one metric only, bdSeq"),
    ("topics-ndeath-seq", "NDEATH has no seq"),
    ("topics-dbirth-topic", "DBIRTH topic is namespace/group_id/DBIRTH/edge_node_id/device_id"),
    ("topics-dbirth-mqtt", "DBIRTH is published with QoS 0, retain false"),
    ("topics-dbirth-seq", "DBIRTH's seq is one more than the previous message's, 0 after 255"),
    ("topics-dbirth-timestamp", "DBIRTH has a timestamp"),
    ("topics-dbirth-metric-reqs", "DBIRTH has every metric the device will ever report"),
    ("topics-dbirth-metrics", "each DBIRTH metric has a name, datatype and current value"),
    ("topics-ddata-topic", "DDATA topic is namespace/group_id/DDATA/edge_node_id/device_id"),
    ("topics-ddata-mqtt", "DDATA is published with QoS 0, retain false"),
    ("topics-ddata-seq-num", "DDATA's seq is one more than the previous message's, 0 after 255"),
    ("topics-ddata-timestamp", "DDATA has a timestamp"),
    ("topics-ddata-payload", "DDATA has the device's metrics that changed since the last DBIRTH or DDATA"),
    ("topics-ddeath-topic", "DDEATH topic is namespace/group_id/DDEATH/edge_node_id/device_id"),
    ("topics-ddeath-mqtt", "DDEATH is published with QoS 0, retain false"),
    ("topics-ddeath-seq-num", "DDEATH's seq is one more than the previous message's, 0 after 255"),
    ("topics-dcmd-topic", "a DCMD on namespace/group_id/DCMD/edge_node_id/device_id reaches the device"),
    ("case-sensitivity-metric-names", "(SHOULD) no two metric names of a birth differ only in case"),
    // Chapter 5, operational behaviour.
    ("message-flow-edge-node-ncmd-subscribe", "the edge node subscribes to namespace/group_id/NCMD/edge_node_id at QoS 1"),
    ("message-flow-edge-node-birth-publish-connect", "an MQTT session is established before NBIRTH and DBIRTH"),
    ("message-flow-edge-node-birth-publish-will-message", "the edge node's CONNECT has a will"),
    ("message-flow-edge-node-birth-publish-will-message-topic", "the will's topic is spBv1.0/group_id/NDEATH/edge_node_id"),
    ("message-flow-edge-node-birth-publish-will-message-payload", "the will's payload is a Sparkplug B payload"),
    ("message-flow-edge-node-birth-publish-will-message-payload-bdSeq", "the will has bdSeq, Int64, one more than in the previous CONNECT (0 after 255)"),
    ("message-flow-edge-node-birth-publish-will-message-qos", "the will's QoS is 1"),
    ("message-flow-edge-node-birth-publish-will-message-will-retained", "the will's retain flag is false"),
    ("message-flow-edge-node-birth-publish-phid-wait", "with a primary host, NBIRTH and DBIRTH wait for its STATE saying online"),
    ("message-flow-edge-node-birth-publish-phid-wait-id", "the STATE followed is the one of the configured primary host id"),
    ("message-flow-edge-node-birth-publish-phid-wait-online", "the host counts as online only with 'online': true"),
    ("message-flow-edge-node-birth-publish-phid-wait-timestamp", "a STATE older than the previous one does not count"),
    ("message-flow-edge-node-birth-publish-nbirth-topic", "NBIRTH topic is spBv1.0/group_id/NBIRTH/edge_node_id"),
    ("message-flow-edge-node-birth-publish-nbirth-payload", "NBIRTH's payload is a Sparkplug B payload"),
    ("message-flow-edge-node-birth-publish-nbirth-payload-bdSeq", "NBIRTH has bdSeq, Int64, the value of the previous CONNECT's will"),
    ("message-flow-edge-node-birth-publish-nbirth-qos", "NBIRTH's QoS is 0"),
    ("message-flow-edge-node-birth-publish-nbirth-retained", "NBIRTH's retain flag is false"),
    ("message-flow-edge-node-birth-publish-nbirth-payload-seq", "NBIRTH has a seq between 0 and 255"),
    ("message-flow-edge-node-birth-publish-phid-offline", "the primary host's STATE offline (not older): the node publishes NDEATH, disconnects, connects again"),
    ("operational-behavior-edge-node-intentional-disconnect-ndeath", "an edge node disconnecting on purpose publishes NDEATH first"),
    ("operational-behavior-edge-node-termination-host-offline", "the primary host offline (not older than its online STATE): the node disconnects"),
    ("operational-behavior-edge-node-termination-host-offline-reconnect", "after that disconnect, it connects to the next MQTT server and starts over"),
    ("operational-behavior-edge-node-termination-host-offline-timestamp", "an offline STATE older than the online one does not disconnect the node"),
    ("message-flow-device-dcmd-subscribe", "the edge node subscribes to the device's DCMD topic at QoS 1"),
    ("message-flow-device-birth-publish-nbirth-wait", "an NBIRTH was sent in this MQTT session before any DBIRTH"),
    ("message-flow-device-birth-publish-dbirth-topic", "DBIRTH topic is spBv1.0/group_id/DBIRTH/edge_node_id/device_id"),
    ("message-flow-device-birth-publish-dbirth-match-edge-node-topic", "DBIRTH's group_id and edge_node_id are the NBIRTH's"),
    ("message-flow-device-birth-publish-dbirth-payload", "DBIRTH's payload is a Sparkplug B payload"),
    ("message-flow-device-birth-publish-dbirth-qos", "DBIRTH's QoS is 0"),
    ("message-flow-device-birth-publish-dbirth-retained", "DBIRTH's retain flag is false"),
    ("message-flow-device-birth-publish-dbirth-payload-seq", "DBIRTH's seq is one more than the previous message's"),
    ("operational-behavior-primary-application-state-with-multiple-servers-state-subs", "an edge node with a primary host subscribes to its STATE"),
    ("operational-behavior-primary-application-state-with-multiple-servers-walk", "the primary host offline: the node ends its session and moves to the next server"),
    ("operational-behavior-edge-node-birth-sequence-wait", "the birth sequence waits for an online STATE"),
    ("operational-behavior-data-publish-nbirth", "NBIRTH has every metric of the edge node published in the session"),
    ("operational-behavior-data-publish-nbirth-values", "each NBIRTH metric has its value, or is_null true and no value"),
    ("operational-behavior-data-publish-nbirth-change", "(SHOULD) NDATA only when node metrics change"),
    ("operational-behavior-data-publish-nbirth-order", "NBIRTH/NDATA keep the values of a metric in time order"),
    ("operational-behavior-data-publish-dbirth", "DBIRTH has every metric of the device published in the session"),
    ("operational-behavior-data-publish-dbirth-values", "each DBIRTH metric has its value, or is_null true and no value"),
    ("operational-behavior-data-publish-dbirth-change", "(SHOULD) DDATA only when device metrics change"),
    ("operational-behavior-data-publish-dbirth-order", "DBIRTH/DDATA keep the values of a metric in time order"),
    ("operational-behavior-data-commands-rebirth-name", "NBIRTH has a metric 'Node Control/Rebirth'"),
    ("operational-behavior-data-commands-rebirth-name-aliases", "with aliases, NBIRTH gives 'Node Control/Rebirth' no alias"),
    ("operational-behavior-data-commands-rebirth-datatype", "'Node Control/Rebirth' in NBIRTH is a Boolean"),
    ("operational-behavior-data-commands-rebirth-value", "'Node Control/Rebirth' in NBIRTH is false"),
    ("operational-behavior-data-commands-ncmd-rebirth-verb", "a rebirth request comes by NCMD"),
    ("operational-behavior-data-commands-ncmd-rebirth-name", "a rebirth request names 'Node Control/Rebirth' (the node takes it by name)"),
    ("operational-behavior-data-commands-rebirth-action-2", "a rebirth request brings the whole birth sequence, NBIRTH and the DBIRTHs"),
    ("operational-behavior-data-commands-rebirth-action-3", "the rebirth's NBIRTH has the bdSeq of the session's will"),
    ("operational-behavior-data-commands-dcmd-verb", "a device command comes by DCMD"),
    ("operational-behavior-data-commands-dcmd-metric-name", "a DCMD names a metric of the DBIRTH (the node takes it by name)"),
    // Chapter 6, payloads.
    ("payloads-timestamp-in-UTC", "the payload timestamp is UTC (ms since the epoch)"),
    ("payloads-metric-timestamp-in-UTC", "the metric timestamp is UTC (ms since the epoch)"),
    ("payloads-sequence-num-always-included", "every message of the edge node but NDEATH has a seq"),
    ("payloads-sequence-num-req-nbirth", "NBIRTH has a seq between 0 and 255"),
    ("payloads-sequence-num-incrementing", "after NBIRTH, seq goes up by one with each message, 0 after 255"),
    ("payloads-name-requirement", "every metric has a name unless it goes by alias"),
    ("payloads-alias-uniqueness", "an alias in NBIRTH or DBIRTH is unique across the edge node's metrics"),
    ("payloads-alias-birth-requirement", "NBIRTH and DBIRTH metrics have a name and an alias (not bdSeq, nor Node Control/Rebirth: 5.x)"),
    ("payloads-alias-data-cmd-requirement", "NDATA, DDATA (and DCMD) metrics have an alias and no name; a DCMD by alias reaches the device"),
    ("payloads-name-birth-data-requirement", "every metric of NBIRTH, DBIRTH, NDATA and DDATA has a timestamp"),
    ("payloads-metric-datatype-value-type", "the datatype is an unsigned 32-bit integer"),
    ("payloads-metric-datatype-value", "the datatype is one of the enumerated types, and the value is in its field"),
    ("payloads-metric-datatype-req", "every metric of NBIRTH and DBIRTH has a datatype"),
    ("payloads-metric-datatype-not-req", "(SHOULD NOT) NDATA and DDATA metrics carry no datatype"),
    ("payloads-propertyset-keys-array-size", "a property set has as many keys as values"),
    ("payloads-propertyset-values-array-size", "a property set has as many values as keys"),
    ("payloads-metric-propertyvalue-type-type", "a property value's type is an unsigned 32-bit integer"),
    ("payloads-metric-propertyvalue-type-value", "a property value's type is one of the enumerated types"),
    ("payloads-metric-propertyvalue-type-req", "property values of NBIRTH and DBIRTH have a type"),
    ("payloads-nbirth-timestamp", "NBIRTH has a payload timestamp"),
    ("payloads-nbirth-seq", "NBIRTH has a seq between 0 and 255"),
    ("payloads-nbirth-bdseq", "NBIRTH has a bdSeq metric"),
    ("payloads-nbirth-bdseq-repeat", "NBIRTH's bdSeq is the one of the previous CONNECT's will"),
    ("payloads-nbirth-rebirth-req", "NBIRTH has 'Node Control/Rebirth' = false"),
    ("payloads-nbirth-qos", "NBIRTH is published with QoS 0"),
    ("payloads-nbirth-retain", "NBIRTH is published with retain false"),
    ("payloads-dbirth-timestamp", "DBIRTH has a payload timestamp"),
    ("payloads-dbirth-seq", "DBIRTH has a seq"),
    ("payloads-dbirth-seq-inc", "DBIRTH's seq is one more than the previous message's, 0 after 255"),
    ("payloads-dbirth-order", "the DBIRTHs follow the NBIRTH before any NDATA or DDATA"),
    ("payloads-dbirth-qos", "DBIRTH is published with QoS 0"),
    ("payloads-dbirth-retain", "DBIRTH is published with retain false"),
    ("payloads-ndata-timestamp", "NDATA has a payload timestamp"),
    ("payloads-ndata-seq", "NDATA has a seq"),
    ("payloads-ndata-seq-inc", "NDATA's seq is one more than the previous message's, 0 after 255"),
    ("payloads-ndata-order", "no NDATA before the NBIRTH and all DBIRTHs"),
    ("payloads-ndata-qos", "NDATA is published with QoS 0"),
    ("payloads-ndata-retain", "NDATA is published with retain false"),
    ("payloads-ddata-timestamp", "DDATA has a payload timestamp"),
    ("payloads-ddata-seq", "DDATA has a seq"),
    ("payloads-ddata-seq-inc", "DDATA's seq is one more than the previous message's, 0 after 255"),
    ("payloads-ddata-order", "no DDATA before the NBIRTH and the device's DBIRTH"),
    ("payloads-ddata-qos", "DDATA is published with QoS 0"),
    ("payloads-ddata-retain", "DDATA is published with retain false"),
    ("payloads-ndeath-seq", "NDEATH has no seq"),
    ("payloads-ndeath-will-message", "NDEATH is the will of the CONNECT (the broker delivers it when the connection drops)"),
    ("payloads-ndeath-will-message-qos", "the NDEATH will has QoS 1"),
    ("payloads-ndeath-will-message-retain", "the NDEATH will has retain false"),
    ("payloads-ndeath-bdseq", "NDEATH's bdSeq is the one of the session's NBIRTH"),
    ("payloads-ndeath-will-message-publisher", "(SHOULD) the edge node publishes NDEATH before it disconnects on purpose"),
    ("payloads-ndeath-will-message-publisher-disconnect-mqtt311", "MQTT 3.1.1: NDEATH is published before the DISCONNECT packet"),
    ("payloads-ddeath-timestamp", "DDEATH has a payload timestamp"),
    ("payloads-ddeath-seq", "DDEATH has a seq"),
    ("payloads-ddeath-seq-inc", "DDEATH's seq is one more than the previous message's, 0 after 255"),
    ("payloads-ddeath-seq-number", "DDEATH has a seq so that the host can order it"),
];

const GROUP: &str = "conf";
const EDGE: &str = "hall-c";
const HOST_ID: &str = "scada";

// ---------------------------------------------------------------------------------------------
// The wire tap.

/// An MQTT will as the CONNECT registered it.
#[derive(Clone, Debug)]
struct Will {
    topic: String,
    payload: Vec<u8>,
    qos: u8,
    retain: bool,
}

/// A packet the edge node sent (MQTT 3.1.1), or the end of its connection.
#[derive(Clone, Debug)]
enum Packet {
    Connect {
        clean: bool,
        will: Option<Will>,
    },
    Subscribe(Vec<(String, u8)>),
    Publish {
        topic: String,
        qos: u8,
        retain: bool,
        payload: Vec<u8>,
    },
    Disconnect,
    /// The node closed its side of the connection.
    Closed,
    Other,
}

/// A packet and the connection (numbered from 0 in order of arrival) it came on.
#[derive(Clone, Debug)]
struct Wire {
    conn: usize,
    packet: Packet,
}

fn string_at(b: &[u8], at: usize) -> (String, usize) {
    let (bytes, next) = bytes_at(b, at);
    (String::from_utf8_lossy(&bytes).into_owned(), next)
}

fn bytes_at(b: &[u8], at: usize) -> (Vec<u8>, usize) {
    let n = u16::from_be_bytes([b[at], b[at + 1]]) as usize;
    (b[at + 2..at + 2 + n].to_vec(), at + 2 + n)
}

/// One whole packet from the front of `buf` and its length, or `None` until it is complete.
fn parse_packet(buf: &[u8]) -> Option<(Packet, usize)> {
    let first = *buf.first()?;
    let (mut len, mut shift, mut i) = (0usize, 0, 1);
    loop {
        let b = *buf.get(i)?;
        len |= ((b & 0x7f) as usize) << shift;
        shift += 7;
        i += 1;
        if b & 0x80 == 0 {
            break;
        }
    }
    let body = buf.get(i..i + len)?;
    let packet = match first >> 4 {
        1 => {
            let (_protocol, at) = string_at(body, 0);
            let flags = body[at + 1];
            let (_client_id, at) = string_at(body, at + 4);
            let will = (flags & 0x04 != 0).then(|| {
                let (topic, at) = string_at(body, at);
                let (payload, _) = bytes_at(body, at);
                Will { topic, payload, qos: (flags >> 3) & 3, retain: flags & 0x20 != 0 }
            });
            Packet::Connect { clean: flags & 0x02 != 0, will }
        }
        3 => {
            let qos = (first >> 1) & 3;
            let (topic, mut at) = string_at(body, 0);
            if qos > 0 {
                at += 2;
            }
            Packet::Publish { topic, qos, retain: first & 1 == 1, payload: body[at..].to_vec() }
        }
        8 => {
            let (mut filters, mut at) = (Vec::new(), 2);
            while at < body.len() {
                let (filter, next) = string_at(body, at);
                filters.push((filter, body[next]));
                at = next + 1;
            }
            Packet::Subscribe(filters)
        }
        14 => Packet::Disconnect,
        _ => Packet::Other,
    };
    Some((packet, i + len))
}

/// A TCP relay to the broker that logs every packet its clients send.
struct Tap {
    addr: SocketAddr,
    log: Arc<Mutex<Vec<Wire>>>,
}

impl Tap {
    async fn start(broker: SocketAddr) -> Tap {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let log: Arc<Mutex<Vec<Wire>>> = Arc::default();
        let sink = log.clone();
        tokio::spawn(async move {
            for conn in 0.. {
                let Ok((client, _)) = listener.accept().await else { return };
                let log = sink.clone();
                tokio::spawn(async move {
                    let Ok(server) = TcpStream::connect(broker).await else { return };
                    let (mut from_client, mut to_client) = client.into_split();
                    let (mut from_server, mut to_server) = server.into_split();
                    let down = tokio::spawn(async move {
                        let _ = tokio::io::copy(&mut from_server, &mut to_client).await;
                    });
                    let (mut buf, mut chunk) = (Vec::new(), vec![0u8; 16 * 1024]);
                    loop {
                        let n = match from_client.read(&mut chunk).await {
                            Ok(0) | Err(_) => break,
                            Ok(n) => n,
                        };
                        buf.extend_from_slice(&chunk[..n]);
                        while let Some((packet, used)) = parse_packet(&buf) {
                            log.lock().unwrap().push(Wire { conn, packet });
                            buf.drain(..used);
                        }
                        if to_server.write_all(&chunk[..n]).await.is_err() {
                            break;
                        }
                    }
                    log.lock().unwrap().push(Wire { conn, packet: Packet::Closed });
                    let _ = to_server.shutdown().await;
                    let _ = down.await;
                });
            }
        });
        Tap { addr, log }
    }

    fn len(&self) -> usize {
        self.log.lock().unwrap().len()
    }
}

// ---------------------------------------------------------------------------------------------
// The edge node as a process.

fn config(drives: &[(&str, u8)]) -> GatewayConfig {
    let mut s = format!(
        "name = \"{EDGE}\"\n[store]\ndisabled = true\n[[bus]]\nname = \"line-1\"\nport = \"virtual\"\n\
         protocol = \"modbus-rtu\"\nbaud = 38400\n"
    );
    for (name, address) in drives {
        s.push_str(&format!(
            "[[bus.drive]]\nname = \"{name}\"\nfamily = \"generic\"\naddress = {address}\npoll_ms = 100\n"
        ));
    }
    GatewayConfig::from_toml("plant.toml", &s).unwrap()
}

/// The gateway and its edge node on a runtime of their own.
struct EdgeProcess {
    rt: Option<tokio::runtime::Runtime>,
    gw: Arc<Gateway>,
}

impl EdgeProcess {
    fn start(db: &Path, broker: SocketAddr, drives: &[(&str, u8)]) -> EdgeProcess {
        let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
        let gw = {
            let _in = rt.enter();
            let store = drivebus_store::Store::open(db).unwrap();
            let gw = Gateway::start(config(drives), Some(store)).unwrap();
            let mut sp = SparkplugConfig::new(&format!("mqtt://{broker}"));
            sp.group_id = GROUP.into();
            sp.primary_host = Some(HOST_ID.into());
            sp.commands = true;
            drivebus_gateway::sparkplug::spawn(gw.clone(), &sp).unwrap();
            gw
        };
        EdgeProcess { rt: Some(rt), gw }
    }

    async fn reload(&self, drives: &[(&str, u8)]) {
        let (gw, cfg) = (self.gw.clone(), config(drives));
        let rt = self.rt.as_ref().unwrap();
        rt.spawn(async move { gw.reload(cfg, "test").await.map(|_| ()) }).await.unwrap().unwrap();
    }

    /// Ends the process: its tasks and sockets go, with no DISCONNECT.
    fn kill(&mut self) {
        if let Some(rt) = self.rt.take() {
            rt.shutdown_background();
        }
    }
}

impl Drop for EdgeProcess {
    fn drop(&mut self) {
        self.kill();
    }
}

// ---------------------------------------------------------------------------------------------
// The host.

fn unix_ms() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().as_millis() as u64
}

fn decoded(m: &Msg) -> Option<Payload> {
    payload::decode(&m.payload).ok()
}

/// `(kind, device)` of a topic of this edge node.
fn kind_of(topic: &str) -> Option<(&str, Option<&str>)> {
    let mut it = topic.split('/');
    let (ns, g, kind, e) = (it.next()?, it.next()?, it.next()?, it.next()?);
    (ns == "spBv1.0" && g == GROUP && e == EDGE).then_some((kind, it.next()))
}

fn host_has(log: &[Msg], from: usize, kind: &str, device: Option<&str>) -> bool {
    log[from..].iter().any(|m| kind_of(&m.topic) == Some((kind, device)))
}

/// The alias the device's last DBIRTH gave `name`.
fn born_alias(log: &[Msg], device: &str, name: &str) -> Option<u64> {
    let birth = log.iter().rev().find(|m| kind_of(&m.topic) == Some(("DBIRTH", Some(device))))?;
    decoded(birth)?.metrics.iter().find(|m| m.name.as_deref() == Some(name))?.alias
}

/// The value of the device's metric `name` in a DDATA from `from` on (aliases of its DBIRTH).
fn ddata_value(log: &[Msg], from: usize, device: &str, name: &str) -> Option<Value> {
    let alias = born_alias(log, device, name)?;
    log[from..]
        .iter()
        .filter(|m| kind_of(&m.topic) == Some(("DDATA", Some(device))))
        .filter_map(decoded)
        .flat_map(|p| p.metrics)
        .rfind(|m| m.alias == Some(alias))
        .and_then(|m| m.value)
}

fn command(metric: Metric) -> Vec<u8> {
    Payload { timestamp: Some(unix_ms()), metrics: vec![metric], ..Payload::default() }.encode_to_vec()
}

async fn state(host: &Subscriber, online: bool, timestamp: u64) {
    let body = format!(r#"{{"online": {online}, "timestamp": {timestamp}}}"#);
    host.publish(&format!("spBv1.0/STATE/{HOST_ID}"), &body, true).await;
}

async fn publish_command(host: &Subscriber, topic: String, metric: Metric) {
    host.client.publish(topic, QoS::AtMostOnce, false, command(metric)).await.unwrap();
}

/// Waits for `f` to hold, at most [`PATIENCE`]; `false` if it never did (the check then fails
/// and the scenario goes on).
async fn until(mut f: impl FnMut() -> bool) -> bool {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    while !f() {
        if tokio::time::Instant::now() > deadline {
            return false;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    true
}

/// The node's count of refused commands (`drivebus_sparkplug_commands_refused_total`).
fn refused(p: &EdgeProcess) -> u64 {
    let text = drivebus_gateway::metrics::render(&p.gw).unwrap();
    text.lines()
        .filter(|l| l.starts_with("drivebus_sparkplug_commands_refused_total{"))
        .filter_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
        .sum::<f64>() as u64
}

/// Waits until the node has handled every message sent to it so far, not a fixed time: it is
/// sent an NCMD that is no Sparkplug payload (again until it is heard, in case its
/// subscription was not yet in place), which it refuses and counts, and it handles its
/// messages in order. The Unix time (ms) then, once the clock has moved past it: whatever the
/// node did on the earlier messages (a birth, a leave) is stamped at or before it, and whatever
/// it does on the next ones after it. `None` if the node never refused the probe.
async fn handled(host: &Subscriber, p: &EdgeProcess) -> Option<u64> {
    let before = refused(p);
    let deadline = tokio::time::Instant::now() + PATIENCE;
    loop {
        let topic = format!("spBv1.0/{GROUP}/NCMD/{EDGE}");
        host.client.publish(topic, QoS::AtMostOnce, false, b"not sparkplug".to_vec()).await.unwrap();
        let resend = tokio::time::Instant::now() + Duration::from_millis(500);
        while refused(p) == before && tokio::time::Instant::now() < resend {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        if refused(p) > before {
            break;
        }
        if tokio::time::Instant::now() > deadline {
            return None;
        }
    }
    let t = unix_ms();
    while unix_ms() <= t {
        tokio::task::yield_now().await;
    }
    Some(t)
}

// ---------------------------------------------------------------------------------------------
// The scenario.

/// Where the logs stood at each step: (tap, host) lengths.
#[derive(Default, Debug)]
struct Marks {
    stale_online: usize,
    online: usize,
    by_name: (usize, usize),
    by_alias: (usize, usize),
    rebirth: usize,
    stale_offline: (usize, usize),
    offline: usize,
    back_online: (usize, usize),
    /// When the node had handled the message before each window where it must not act
    /// ([`handled`]): the retained offline STATE, the stale online STATE, the stale offline
    /// STATE, and its new session's subscription while the host is offline.
    handled: [Option<u64>; 4],
    kill: (usize, usize),
    restart: (usize, usize),
}

/// What the scenario saw: everything the node sent, everything the host received, the marks
/// and what came (or did not) at the steps.
struct Run {
    wire: Vec<Wire>,
    host: Vec<Msg>,
    marks: Marks,
    seen: BTreeMap<&'static str, bool>,
    t0: u64,
    t1: u64,
}

async fn scenario() -> Run {
    let broker = rumqttd().await;
    let tap = Tap::start(broker).await;
    let host = Subscriber::start(broker, "conformance-host", "spBv1.0/#").await;
    let hlen = || host.log.lock().unwrap().len();
    let dir = std::env::temp_dir().join(format!("drivebus-spb-conformance-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let db: PathBuf = dir.join("edge.db");
    let _ = std::fs::remove_file(&db);
    let t0 = unix_ms();
    let mut seen = BTreeMap::new();
    let mut m = Marks::default();
    let stamp = t0;
    let wire_has =
        |tap: &Tap, from: usize, f: &dyn Fn(&Wire) -> bool| tap.log.lock().unwrap()[from..].iter().any(f);
    let nbirth = |w: &Wire| matches!(&w.packet, Packet::Publish { topic, .. } if kind_of(topic) == Some(("NBIRTH", None)));

    // The host is offline (retained) when the node starts.
    state(&host, false, stamp).await;
    let mut p1 = EdgeProcess::start(&db, tap.addr, &[("d1", 1), ("d2", 2)]);
    let state_topic = format!("spBv1.0/STATE/{HOST_ID}");
    let ok = until(|| {
        wire_has(
            &tap,
            0,
            &|w| matches!(&w.packet, Packet::Subscribe(f) if f.iter().any(|(t, _)| *t == state_topic)),
        )
    })
    .await;
    seen.insert("subscribed to STATE", ok);
    m.handled[0] = handled(&host, &p1).await;
    // Online, but older than the offline STATE.
    m.stale_online = tap.len();
    state(&host, true, stamp - 1).await;
    m.handled[1] = handled(&host, &p1).await;
    m.online = tap.len();
    state(&host, true, stamp + 1).await;
    let births = |from: usize| {
        let log = host.log.lock().unwrap();
        host_has(&log, from, "NBIRTH", None)
            && ["d1", "d2"].iter().all(|d| host_has(&log, from, "DBIRTH", Some(d)))
    };
    seen.insert("births after online", until(|| births(0)).await);

    // DCMD by name, then by alias.
    m.by_name = (tap.len(), hlen());
    let setpoint = Metric {
        name: Some("Setpoint".into()),
        datatype: Some(10),
        value: Some(Value::Double(30.0)),
        ..Metric::default()
    };
    publish_command(&host, format!("spBv1.0/{GROUP}/DCMD/{EDGE}/d1"), setpoint).await;
    let from = m.by_name.1;
    let ok =
        until(|| ddata_value(&host.log.lock().unwrap(), from, "d1", "Setpoint") == Some(Value::Double(30.0)))
            .await;
    seen.insert("DCMD by name", ok);
    m.by_alias = (tap.len(), hlen());
    let alias = born_alias(&host.log.lock().unwrap(), "d1", "Command/Run");
    let run = Metric { alias, datatype: Some(11), value: Some(Value::Boolean(true)), ..Metric::default() };
    publish_command(&host, format!("spBv1.0/{GROUP}/DCMD/{EDGE}/d1"), run).await;
    let from = m.by_alias.1;
    let ok = alias.is_some()
        && until(|| {
            ddata_value(&host.log.lock().unwrap(), from, "d1", "Running") == Some(Value::Boolean(true))
        })
        .await;
    seen.insert("DCMD by alias", ok);

    // NCMD rebirth by name.
    m.rebirth = tap.len();
    let from = hlen();
    let rebirth = Metric {
        name: Some("Node Control/Rebirth".into()),
        datatype: Some(11),
        value: Some(Value::Boolean(true)),
        ..Metric::default()
    };
    publish_command(&host, format!("spBv1.0/{GROUP}/NCMD/{EDGE}"), rebirth).await;
    seen.insert("rebirth", until(|| births(from)).await);
    // Bus statistics (every 10 s).
    seen.insert("NDATA", until(|| host_has(&host.log.lock().unwrap(), from, "NDATA", None)).await);

    // A reload removes d2: its DDEATH.
    p1.reload(&[("d1", 1)]).await;
    seen.insert("DDEATH", until(|| host_has(&host.log.lock().unwrap(), 0, "DDEATH", Some("d2"))).await);

    // Offline, but older than the online STATE: nothing happens.
    m.stale_offline.0 = tap.len();
    state(&host, false, stamp).await;
    m.handled[2] = handled(&host, &p1).await;
    m.stale_offline.1 = tap.len();

    // The host goes offline: NDEATH, disconnect, a new session that waits.
    m.offline = tap.len();
    state(&host, false, stamp + 2).await;
    let offline = m.offline;
    let ok = until(|| {
        let log = tap.log.lock().unwrap();
        let conns: BTreeSet<usize> = log[offline..]
            .iter()
            .filter(|w| matches!(&w.packet, Packet::Subscribe(f) if f.iter().any(|(t, _)| *t == state_topic)))
            .map(|w| w.conn)
            .collect();
        log[offline..].iter().any(|w| matches!(w.packet, Packet::Disconnect)) && !conns.is_empty()
    })
    .await;
    seen.insert("left and connected again", ok);
    m.handled[3] = handled(&host, &p1).await;
    m.back_online = (tap.len(), hlen());
    state(&host, true, stamp + 3).await;
    let (back, from) = m.back_online;
    seen.insert("births after the host is back", until(|| wire_has(&tap, back, &nbirth)).await);
    seen.insert(
        "d1 born again",
        until(|| host_has(&host.log.lock().unwrap(), from, "DBIRTH", Some("d1"))).await,
    );

    // Kill: the broker delivers the will.
    m.kill = (tap.len(), hlen());
    p1.kill();
    let from = m.kill.1;
    seen.insert("the will", until(|| host_has(&host.log.lock().unwrap(), from, "NDEATH", None)).await);
    let closed = m.kill.0;
    seen.insert(
        "killed connection closed",
        until(|| wire_has(&tap, closed, &|w| matches!(w.packet, Packet::Closed))).await,
    );

    // Restart over the same store.
    m.restart = (tap.len(), hlen());
    let mut p2 = EdgeProcess::start(&db, tap.addr, &[("d1", 1)]);
    let (restart, from) = m.restart;
    seen.insert("births after the restart", until(|| wire_has(&tap, restart, &nbirth)).await);
    seen.insert(
        "d1 born after the restart",
        until(|| host_has(&host.log.lock().unwrap(), from, "DBIRTH", Some("d1"))).await,
    );
    p2.kill();
    let t1 = unix_ms();
    let run = Run {
        wire: tap.log.lock().unwrap().clone(),
        host: host.log.lock().unwrap().clone(),
        marks: m,
        seen,
        t0,
        t1,
    };
    let _ = std::fs::remove_dir_all(&dir);
    run
}

// ---------------------------------------------------------------------------------------------
// The checks.

/// Failures per assertion id, and every id checked.
#[derive(Default)]
struct Verdicts {
    checked: BTreeSet<&'static str>,
    failed: BTreeMap<&'static str, Vec<String>>,
}

impl Verdicts {
    fn check(&mut self, ids: &[&'static str], ok: bool, why: impl Fn() -> String) {
        for id in ids {
            self.checked.insert(id);
            if !ok {
                let list = self.failed.entry(id).or_default();
                if list.len() < 3 {
                    list.push(why());
                }
            }
        }
    }
}

/// A message the node published, decoded.
struct Pub {
    at: usize,
    conn: usize,
    topic: String,
    kind: String,
    device: Option<String>,
    qos: u8,
    retain: bool,
    payload: Option<Payload>,
}

const REBIRTH: &str = "Node Control/Rebirth";
const INT64: u32 = 4;
const BOOLEAN: u32 = 11;

fn bd_seq(p: &Payload) -> Option<(&Metric, u64)> {
    let m = p.metrics.iter().find(|m| m.name.as_deref() == Some("bdSeq"))?;
    match m.value {
        Some(Value::Long(v)) => Some((m, v)),
        _ => None,
    }
}

/// The protobuf field a Sparkplug datatype's value goes in.
fn value_fits(datatype: u32, v: &Value) -> bool {
    matches!(
        (datatype, v),
        (1..=3 | 5..=7, Value::Int(_))
            | (4 | 8 | 13, Value::Long(_))
            | (9, Value::Float(_))
            | (10, Value::Double(_))
            | (11, Value::Boolean(_))
            | (12 | 14 | 15, Value::String(_))
            | (17 | 18, Value::Bytes(_))
    )
}

fn evaluate(run: &Run) -> Verdicts {
    let mut v = Verdicts::default();
    let ts_ok = |t: Option<u64>| t.is_some_and(|t| t + 5_000 >= run.t0 && t <= run.t1 + 5_000);
    let node_topic = |kind: &str| format!("spBv1.0/{GROUP}/{kind}/{EDGE}");

    // The node's connections: their CONNECT (will) and what they published.
    let mut wills: BTreeMap<usize, Option<Will>> = BTreeMap::new();
    let mut pubs: Vec<Pub> = Vec::new();
    let mut subscriptions: BTreeMap<usize, Vec<(String, u8)>> = BTreeMap::new();
    let mut first_packet: BTreeMap<usize, bool> = BTreeMap::new();
    for (at, w) in run.wire.iter().enumerate() {
        first_packet.entry(w.conn).or_insert(matches!(w.packet, Packet::Connect { .. }));
        match &w.packet {
            Packet::Connect { clean, will } => {
                v.check(&["principles-persistence-clean-session-311"], *clean, || {
                    format!("connection {}", w.conn)
                });
                wills.insert(w.conn, will.clone());
            }
            Packet::Subscribe(f) => subscriptions.entry(w.conn).or_default().extend(f.iter().cloned()),
            Packet::Publish { topic, qos, retain, payload: bytes } => {
                let (kind, device) = match kind_of(topic) {
                    Some((k, d)) => (k.to_string(), d.map(str::to_string)),
                    None => (String::new(), None),
                };
                pubs.push(Pub {
                    at,
                    conn: w.conn,
                    topic: topic.clone(),
                    kind,
                    device,
                    qos: *qos,
                    retain: *retain,
                    payload: payload::decode(bytes).ok(),
                });
            }
            _ => {}
        }
    }
    let will_bd = |conn: usize| -> Option<u64> {
        let w = wills.get(&conn)?.as_ref()?;
        bd_seq(&payload::decode(&w.payload).ok()?).map(|(_, b)| b)
    };

    // CONNECT: the will.
    let mut previous: Option<u64> = None;
    for (conn, will) in &wills {
        let ids = ["message-flow-edge-node-birth-publish-will-message", "payloads-ndeath-will-message"];
        v.check(&ids, will.is_some(), || format!("connection {conn}: no will"));
        let Some(w) = will else { continue };
        v.check(
            &["message-flow-edge-node-birth-publish-will-message-topic", "topics-ndeath-topic"],
            w.topic == node_topic("NDEATH"),
            || w.topic.clone(),
        );
        v.check(
            &["message-flow-edge-node-birth-publish-will-message-qos", "payloads-ndeath-will-message-qos"],
            w.qos == 1,
            || format!("QoS {}", w.qos),
        );
        v.check(
            &[
                "message-flow-edge-node-birth-publish-will-message-will-retained",
                "payloads-ndeath-will-message-retain",
            ],
            !w.retain,
            || "retained".into(),
        );
        let p = payload::decode(&w.payload).ok();
        v.check(&["message-flow-edge-node-birth-publish-will-message-payload"], p.is_some(), || {
            "not a Sparkplug payload".into()
        });
        let Some(p) = p else { continue };
        v.check(&["topics-ndeath-payload"], p.metrics.len() == 1 && bd_seq(&p).is_some(), || {
            format!("{:?}", p.metrics)
        });
        v.check(&["topics-ndeath-seq", "payloads-ndeath-seq"], p.seq.is_none(), || {
            format!("will seq {:?}", p.seq)
        });
        let bd = bd_seq(&p);
        let want = previous.map_or(0, |b| (b + 1) % 256);
        v.check(
            &["message-flow-edge-node-birth-publish-will-message-payload-bdSeq"],
            bd.is_some_and(|(m, b)| m.datatype == Some(INT64) && b == want),
            || {
                format!(
                    "connection {conn}: bdSeq {:?}, datatype {:?}, want {want} Int64",
                    bd.map(|x| x.1),
                    bd.and_then(|x| x.0.datatype)
                )
            },
        );
        v.check(&["topics-nbirth-bdseq-increment"], bd.is_some_and(|(_, b)| b == want), || {
            format!("connection {conn}: bdSeq {:?}, want {want}", bd.map(|x| x.1))
        });
        previous = bd.map(|x| x.1);
    }

    // SUBSCRIBE.
    for (conn, subs) in &subscriptions {
        let ncmd = node_topic("NCMD");
        v.check(
            &["message-flow-edge-node-ncmd-subscribe"],
            subs.iter().any(|(t, q)| *t == ncmd && *q == 1),
            || format!("connection {conn}: {subs:?}"),
        );
        let dcmd = format!("spBv1.0/{GROUP}/DCMD/{EDGE}/d1");
        let matches = |f: &str| {
            f == dcmd
                || f.strip_suffix('+')
                    .is_some_and(|p| dcmd.strip_prefix(p).is_some_and(|rest| !rest.contains('/')))
                || f.strip_suffix('#').is_some_and(|p| dcmd.starts_with(p))
        };
        v.check(
            &["message-flow-device-dcmd-subscribe"],
            subs.iter().any(|(t, q)| matches(t) && *q == 1),
            || format!("connection {conn}: {subs:?}"),
        );
        let state: Vec<&String> = subs.iter().map(|(t, _)| t).filter(|t| t.contains("STATE")).collect();
        v.check(
            &["operational-behavior-primary-application-state-with-multiple-servers-state-subs"],
            !state.is_empty(),
            || format!("connection {conn}: {subs:?}"),
        );
        v.check(
            &["message-flow-edge-node-birth-publish-phid-wait-id"],
            state.iter().all(|t| **t == format!("spBv1.0/STATE/{HOST_ID}")),
            || format!("{state:?}"),
        );
    }

    // Every publish, in order, per connection.
    let mut seq: HashMap<usize, Option<u64>> = HashMap::new();
    let mut births: HashMap<usize, bool> = HashMap::new();
    let mut born_devices: HashMap<usize, BTreeSet<String>> = HashMap::new();
    let mut aliases: HashMap<usize, HashMap<u64, (Option<String>, String)>> = HashMap::new();
    let mut last_value: HashMap<(usize, u64), Option<Value>> = HashMap::new();
    // After each NBIRTH: whether a data message came yet.
    let mut data_since_nbirth: HashMap<usize, bool> = HashMap::new();
    // Devices that had a DDEATH in the connection: born again later, as a drive back online is.
    let mut died: HashMap<usize, BTreeSet<String>> = HashMap::new();
    let mut first_pub: BTreeSet<usize> = BTreeSet::new();
    for p in &pubs {
        let k = p.kind.as_str();
        let levels = p.topic.split('/').count();
        v.check(&["topic-structure-namespace-a"], p.topic.starts_with("spBv1.0/"), || p.topic.clone());
        v.check(&["topic-structure"], kind_of(&p.topic).is_some() && (levels == 4 || levels == 5), || {
            p.topic.clone()
        });
        if matches!(k, "DBIRTH" | "DDATA" | "DDEATH") {
            v.check(&["topic-structure-namespace-device-id-associated-message-types"], levels == 5, || {
                p.topic.clone()
            });
        }
        if matches!(k, "NBIRTH" | "NDATA" | "NDEATH") {
            v.check(
                &["topic-structure-namespace-device-id-non-associated-message-types"],
                levels == 4,
                || p.topic.clone(),
            );
        }
        if first_pub.insert(p.conn) {
            v.check(&["principles-birth-certificates-order"], k == "NBIRTH", || {
                format!("connection {} began with {k}", p.conn)
            });
            v.check(
                &["message-flow-edge-node-birth-publish-connect"],
                first_packet.get(&p.conn) == Some(&true),
                || format!("connection {}", p.conn),
            );
        }
        let qos0 = p.qos == 0;
        let unretained = !p.retain;
        let why = || format!("{} QoS {} retain {}", p.topic, p.qos, p.retain);
        match k {
            "NBIRTH" => {
                v.check(&["topics-nbirth-mqtt"], qos0 && unretained, why);
                v.check(
                    &["payloads-nbirth-qos", "message-flow-edge-node-birth-publish-nbirth-qos"],
                    qos0,
                    why,
                );
                v.check(
                    &["payloads-nbirth-retain", "message-flow-edge-node-birth-publish-nbirth-retained"],
                    unretained,
                    why,
                );
                v.check(
                    &["topics-nbirth-topic", "message-flow-edge-node-birth-publish-nbirth-topic"],
                    p.topic == node_topic("NBIRTH"),
                    || p.topic.clone(),
                );
                v.check(
                    &["message-flow-edge-node-birth-publish-nbirth-payload"],
                    p.payload.is_some(),
                    || "not a Sparkplug payload".into(),
                );
            }
            "DBIRTH" => {
                v.check(&["topics-dbirth-mqtt"], qos0 && unretained, why);
                v.check(&["payloads-dbirth-qos", "message-flow-device-birth-publish-dbirth-qos"], qos0, why);
                v.check(
                    &["payloads-dbirth-retain", "message-flow-device-birth-publish-dbirth-retained"],
                    unretained,
                    why,
                );
                let want = format!("spBv1.0/{GROUP}/DBIRTH/{EDGE}/{}", p.device.as_deref().unwrap_or("?"));
                v.check(
                    &[
                        "topics-dbirth-topic",
                        "message-flow-device-birth-publish-dbirth-topic",
                        "message-flow-device-birth-publish-dbirth-match-edge-node-topic",
                    ],
                    p.topic == want && p.device.is_some(),
                    || p.topic.clone(),
                );
                v.check(&["message-flow-device-birth-publish-dbirth-payload"], p.payload.is_some(), || {
                    "not a Sparkplug payload".into()
                });
                v.check(
                    &["message-flow-device-birth-publish-nbirth-wait"],
                    births.get(&p.conn) == Some(&true),
                    || format!("{} before an NBIRTH in its session", p.topic),
                );
            }
            "NDATA" => {
                v.check(&["topics-ndata-mqtt"], qos0 && unretained, why);
                v.check(&["payloads-ndata-qos"], qos0, why);
                v.check(&["payloads-ndata-retain"], unretained, why);
                v.check(&["topics-ndata-topic"], p.topic == node_topic("NDATA"), || p.topic.clone());
                v.check(&["payloads-ndata-order"], births.get(&p.conn) == Some(&true), || {
                    "NDATA before NBIRTH".into()
                });
            }
            "DDATA" => {
                v.check(&["topics-ddata-mqtt"], qos0 && unretained, why);
                v.check(&["payloads-ddata-qos"], qos0, why);
                v.check(&["payloads-ddata-retain"], unretained, why);
                v.check(
                    &["topics-ddata-topic"],
                    levels == 5 && p.topic.starts_with(&format!("spBv1.0/{GROUP}/DDATA/{EDGE}/")),
                    || p.topic.clone(),
                );
                let born = p
                    .device
                    .as_ref()
                    .is_some_and(|d| born_devices.get(&p.conn).is_some_and(|b| b.contains(d)));
                v.check(&["payloads-ddata-order"], births.get(&p.conn) == Some(&true) && born, || {
                    format!("{} before its births", p.topic)
                });
            }
            "DDEATH" => {
                v.check(&["topics-ddeath-mqtt"], qos0 && unretained, why);
                v.check(
                    &["topics-ddeath-topic"],
                    levels == 5 && p.topic.starts_with(&format!("spBv1.0/{GROUP}/DDEATH/{EDGE}/")),
                    || p.topic.clone(),
                );
                if let Some(d) = &p.device {
                    born_devices.entry(p.conn).or_default().remove(d);
                    died.entry(p.conn).or_default().insert(d.clone());
                }
            }
            "NDEATH" => {
                v.check(&["topics-ndeath-topic"], p.topic == node_topic("NDEATH"), || p.topic.clone());
            }
            _ => {}
        }
        let Some(pl) = &p.payload else { continue };
        // seq.
        let seq_ids: &[&'static str] = match k {
            "DBIRTH" => &[
                "topics-dbirth-seq",
                "payloads-dbirth-seq",
                "payloads-dbirth-seq-inc",
                "message-flow-device-birth-publish-dbirth-payload-seq",
            ],
            "NDATA" => &["topics-ndata-seq-num", "payloads-ndata-seq", "payloads-ndata-seq-inc"],
            "DDATA" => &["topics-ddata-seq-num", "payloads-ddata-seq", "payloads-ddata-seq-inc"],
            "DDEATH" => &[
                "topics-ddeath-seq-num",
                "payloads-ddeath-seq",
                "payloads-ddeath-seq-inc",
                "payloads-ddeath-seq-number",
            ],
            _ => &[],
        };
        if k == "NDEATH" {
            v.check(&["topics-ndeath-seq", "payloads-ndeath-seq"], pl.seq.is_none(), || {
                format!("NDEATH seq {:?}", pl.seq)
            });
            v.check(&["topics-ndeath-payload"], pl.metrics.len() == 1 && bd_seq(pl).is_some(), || {
                format!("{:?}", pl.metrics)
            });
        } else {
            v.check(&["payloads-sequence-num-always-included"], pl.seq.is_some(), || {
                format!("{} without seq", p.topic)
            });
        }
        if k == "NBIRTH" {
            v.check(&["topics-nbirth-seq-num"], pl.seq == Some(0), || format!("seq {:?}", pl.seq));
            v.check(
                &[
                    "payloads-nbirth-seq",
                    "payloads-sequence-num-req-nbirth",
                    "message-flow-edge-node-birth-publish-nbirth-payload-seq",
                ],
                pl.seq.is_some_and(|s| s <= 255),
                || format!("seq {:?}", pl.seq),
            );
            seq.insert(p.conn, pl.seq);
        } else if !seq_ids.is_empty() {
            let want = seq.get(&p.conn).copied().flatten().map(|s| (s + 1) % 256);
            let ok = pl.seq.is_some() && pl.seq == want;
            v.check(seq_ids, ok, || format!("{}: seq {:?} where {want:?}", p.topic, pl.seq));
            v.check(&["payloads-sequence-num-incrementing"], ok, || {
                format!("{}: seq {:?} where {want:?}", p.topic, pl.seq)
            });
            seq.insert(p.conn, pl.seq);
        }
        // Payload and metric timestamps.
        if matches!(k, "NBIRTH" | "DBIRTH" | "NDATA" | "DDATA" | "DDEATH") {
            let ids: &[&'static str] = match k {
                "NBIRTH" => &["topics-nbirth-timestamp", "payloads-nbirth-timestamp"],
                "DBIRTH" => &["topics-dbirth-timestamp", "payloads-dbirth-timestamp"],
                "NDATA" => &["topics-ndata-timestamp", "payloads-ndata-timestamp"],
                "DDATA" => &["topics-ddata-timestamp", "payloads-ddata-timestamp"],
                _ => &["payloads-ddeath-timestamp"],
            };
            v.check(ids, pl.timestamp.is_some(), || format!("{} without a timestamp", p.topic));
            v.check(&["payloads-timestamp-in-UTC"], ts_ok(pl.timestamp), || {
                format!("{}: {:?}", p.topic, pl.timestamp)
            });
        }
        if matches!(k, "NBIRTH" | "DBIRTH" | "NDATA" | "DDATA") {
            for m in &pl.metrics {
                v.check(&["payloads-name-birth-data-requirement"], m.timestamp.is_some(), || {
                    format!("{}: {m:?}", p.topic)
                });
                v.check(&["payloads-metric-timestamp-in-UTC"], ts_ok(m.timestamp), || {
                    format!("{}: {m:?}", p.topic)
                });
                v.check(&["payloads-name-requirement"], m.name.is_some() || m.alias.is_some(), || {
                    format!("{}: {m:?}", p.topic)
                });
            }
            // Values of one metric in time order.
            let mut times: HashMap<(Option<String>, Option<u64>), u64> = HashMap::new();
            let order = if k.starts_with('N') {
                "operational-behavior-data-publish-nbirth-order"
            } else {
                "operational-behavior-data-publish-dbirth-order"
            };
            for m in pl.metrics.iter().filter(|m| m.is_historical != Some(true)) {
                let t = m.timestamp.unwrap_or(0);
                let earlier = times.insert((m.name.clone(), m.alias), t);
                v.check(&[order], earlier.map_or(true, |e| e <= t), || format!("{}: {m:?}", p.topic));
            }
        }
        let dev = p.device.clone();
        match k {
            "NBIRTH" | "DBIRTH" => {
                if k == "NBIRTH" {
                    births.insert(p.conn, true);
                    born_devices.insert(p.conn, BTreeSet::new());
                    aliases.insert(p.conn, HashMap::new());
                    data_since_nbirth.insert(p.conn, false);
                    let bd = bd_seq(pl);
                    v.check(&["topics-nbirth-bdseq-included", "payloads-nbirth-bdseq"], bd.is_some(), || {
                        "no bdSeq".into()
                    });
                    let will = will_bd(p.conn);
                    let same = bd.is_some_and(|(_, b)| Some(b) == will);
                    v.check(&["topics-nbirth-bdseq-matching", "payloads-nbirth-bdseq-repeat"], same, || {
                        format!("bdSeq {:?}, will {will:?}", bd.map(|x| x.1))
                    });
                    v.check(
                        &["message-flow-edge-node-birth-publish-nbirth-payload-bdSeq"],
                        same && bd.is_some_and(|(m, _)| m.datatype == Some(INT64)),
                        || {
                            format!(
                                "bdSeq {:?} datatype {:?}, will {will:?}",
                                bd.map(|x| x.1),
                                bd.and_then(|x| x.0.datatype)
                            )
                        },
                    );
                    let rebirth = pl.metrics.iter().find(|m| m.name.as_deref() == Some(REBIRTH));
                    let good = rebirth.is_some_and(|m| {
                        m.datatype == Some(BOOLEAN) && m.value == Some(Value::Boolean(false))
                    });
                    v.check(&["topics-nbirth-rebirth-metric", "payloads-nbirth-rebirth-req"], good, || {
                        format!("{rebirth:?}")
                    });
                    v.check(&["operational-behavior-data-commands-rebirth-name"], rebirth.is_some(), || {
                        "missing".into()
                    });
                    v.check(
                        &["operational-behavior-data-commands-rebirth-datatype"],
                        rebirth.is_some_and(|m| m.datatype == Some(BOOLEAN)),
                        || format!("{rebirth:?}"),
                    );
                    v.check(
                        &["operational-behavior-data-commands-rebirth-value"],
                        rebirth.is_some_and(|m| m.value == Some(Value::Boolean(false))),
                        || format!("{rebirth:?}"),
                    );
                    v.check(
                        &["operational-behavior-data-commands-rebirth-name-aliases"],
                        rebirth.is_some_and(|m| m.alias.is_none()),
                        || format!("alias {:?}", rebirth.and_then(|m| m.alias)),
                    );
                } else {
                    if let Some(d) = &dev {
                        born_devices.entry(p.conn).or_default().insert(d.clone());
                    }
                    let back = dev.as_ref().is_some_and(|d| died.get(&p.conn).is_some_and(|x| x.contains(d)));
                    v.check(
                        &["payloads-dbirth-order"],
                        data_since_nbirth.get(&p.conn) == Some(&false) || back,
                        || format!("{} after data", p.topic),
                    );
                }
                let (m_ids, v_ids): (&[&'static str], &[&'static str]) = if k == "NBIRTH" {
                    (&["topics-nbirth-metrics"], &["operational-behavior-data-publish-nbirth-values"])
                } else {
                    (&["topics-dbirth-metrics"], &["operational-behavior-data-publish-dbirth-values"])
                };
                let mut lower = BTreeSet::new();
                for m in &pl.metrics {
                    let name = m.name.clone().unwrap_or_default();
                    let valued = (m.value.is_some() && m.is_null != Some(true))
                        || (m.value.is_none() && m.is_null == Some(true));
                    v.check(m_ids, m.name.is_some() && m.datatype.is_some() && valued, || {
                        format!("{}: {m:?}", p.topic)
                    });
                    v.check(v_ids, valued, || format!("{}: {m:?}", p.topic));
                    v.check(
                        &["payloads-metric-datatype-req", "payloads-metric-datatype-value-type"],
                        m.datatype.is_some(),
                        || format!("{}: {m:?}", p.topic),
                    );
                    let dt = m.datatype.unwrap_or(0);
                    v.check(
                        &["payloads-metric-datatype-value"],
                        (1..=19).contains(&dt) && m.value.as_ref().map_or(true, |x| value_fits(dt, x)),
                        || format!("{}: {m:?}", p.topic),
                    );
                    let exempt = name == "bdSeq" || name == REBIRTH;
                    if !exempt {
                        v.check(
                            &["payloads-alias-birth-requirement"],
                            m.name.is_some() && m.alias.is_some(),
                            || format!("{}: {name} without an alias", p.topic),
                        );
                    }
                    v.check(&["case-sensitivity-metric-names"], lower.insert(name.to_lowercase()), || {
                        format!("{}: {name}", p.topic)
                    });
                    if let Some(props) = &m.properties {
                        let same = props.keys.len() == props.values.len();
                        v.check(
                            &[
                                "payloads-propertyset-keys-array-size",
                                "payloads-propertyset-values-array-size",
                            ],
                            same,
                            || format!("{props:?}"),
                        );
                        for pv in &props.values {
                            v.check(
                                &[
                                    "payloads-metric-propertyvalue-type-req",
                                    "payloads-metric-propertyvalue-type-type",
                                ],
                                pv.r#type.is_some(),
                                || format!("{pv:?}"),
                            );
                            v.check(
                                &["payloads-metric-propertyvalue-type-value"],
                                pv.r#type.is_some_and(|t| (1..=20).contains(&t)),
                                || format!("{pv:?}"),
                            );
                        }
                    }
                    if let Some(a) = m.alias {
                        let owner = (dev.clone(), name.clone());
                        let before = aliases.entry(p.conn).or_default().insert(a, owner.clone());
                        v.check(
                            &["payloads-alias-uniqueness"],
                            before.as_ref().map_or(true, |b| *b == owner),
                            || format!("alias {a}: {before:?} and {owner:?}"),
                        );
                        last_value.insert((p.conn, a), m.value.clone());
                    }
                }
            }
            "NDATA" | "DDATA" => {
                data_since_nbirth.insert(p.conn, true);
                let (req, all, change): (&[&'static str], &[&'static str], &'static str) = if k == "NDATA" {
                    (
                        &["topics-nbirth-metric-reqs"],
                        &["operational-behavior-data-publish-nbirth"],
                        "operational-behavior-data-publish-nbirth-change",
                    )
                } else {
                    (
                        &["topics-dbirth-metric-reqs"],
                        &["operational-behavior-data-publish-dbirth"],
                        "operational-behavior-data-publish-dbirth-change",
                    )
                };
                let mut changed = false;
                for m in &pl.metrics {
                    v.check(
                        &["payloads-alias-data-cmd-requirement"],
                        m.alias.is_some() && m.name.is_none(),
                        || format!("{}: {m:?}", p.topic),
                    );
                    v.check(&["payloads-metric-datatype-not-req"], m.datatype.is_none(), || {
                        format!("{}: {m:?}", p.topic)
                    });
                    let owner = m.alias.and_then(|a| aliases.get(&p.conn).and_then(|x| x.get(&a)).cloned());
                    let born = owner.as_ref().is_some_and(|(d, _)| *d == dev);
                    v.check(req, born, || format!("{}: alias {:?} not born for it", p.topic, m.alias));
                    v.check(all, born, || format!("{}: alias {:?} not born for it", p.topic, m.alias));
                    if let Some(a) = m.alias.filter(|_| m.is_historical != Some(true)) {
                        let before = last_value.insert((p.conn, a), m.value.clone());
                        let new = before.as_ref() != Some(&m.value);
                        changed |= new;
                        if k == "DDATA" {
                            v.check(&["topics-ddata-payload", change], new, || {
                                format!("{}: alias {a} unchanged {:?}", p.topic, m.value)
                            });
                        }
                    }
                }
                if k == "NDATA" {
                    v.check(&[change], changed, || "NDATA without a change".into());
                }
            }
            _ => {}
        }
    }

    // The scenario's steps.
    let m = &run.marks;
    let pubs_in = |from: usize, to: usize, kind: &str| {
        pubs.iter().filter(|p| p.at >= from && p.at < to && p.kind == kind).count()
    };
    // Whether the node published `kind` (from the wire's `from` on) stamped at or before the
    // time it had handled a message (`m.handled`): what it did on that message or an earlier
    // one, however late it reached the wire. `true` when the probe was never handled.
    let made_by = |kind: &str, from: usize, handled: Option<u64>| {
        let Some(t) = handled else { return true };
        pubs.iter()
            .filter(|p| p.kind == kind && p.at >= from)
            .any(|p| p.payload.as_ref().and_then(|x| x.timestamp).map_or(true, |ts| ts <= t))
    };
    let first_conn_births = pubs.iter().find(|p| p.kind == "NBIRTH").map(|p| p.at);
    let waited = run.seen["subscribed to STATE"] && run.seen["births after online"];
    v.check(
        &["message-flow-edge-node-birth-publish-phid-wait-online"],
        waited && pubs_in(0, m.stale_online, "NBIRTH") == 0 && !made_by("NBIRTH", 0, m.handled[0]),
        || "NBIRTH while the retained STATE said offline".into(),
    );
    v.check(
        &["message-flow-edge-node-birth-publish-phid-wait-timestamp"],
        waited && pubs_in(m.stale_online, m.online, "NBIRTH") == 0 && !made_by("NBIRTH", 0, m.handled[1]),
        || "NBIRTH on an online STATE older than the offline one".into(),
    );
    let ids = [
        "message-flow-edge-node-birth-publish-phid-wait",
        "operational-behavior-edge-node-birth-sequence-wait",
    ];
    v.check(&ids, waited && first_conn_births.is_some_and(|at| at >= m.online), || {
        format!("first NBIRTH at {first_conn_births:?}, online STATE at {}", m.online)
    });
    v.check(
        &ids,
        run.seen["births after the host is back"]
            && pubs_in(m.offline, m.back_online.0, "NBIRTH") == 0
            && !made_by("NBIRTH", m.offline, m.handled[3]),
        || "NBIRTH in the new session before the host was back".into(),
    );

    v.check(
        &[
            "operational-behavior-data-commands-dcmd-metric-name",
            "operational-behavior-data-commands-dcmd-verb",
            "topics-dcmd-topic",
        ],
        run.seen["DCMD by name"],
        || "Setpoint by name never showed in DDATA".into(),
    );
    v.check(&["payloads-alias-data-cmd-requirement"], run.seen["DCMD by alias"], || {
        "Command/Run by alias never showed in DDATA".into()
    });

    let rebirth_conn = pubs.iter().rfind(|p| p.at < m.rebirth).map(|p| p.conn);
    let reborn = pubs.iter().find(|p| p.at >= m.rebirth && p.kind == "NBIRTH");
    let ids = [
        "operational-behavior-data-commands-rebirth-action-2",
        "operational-behavior-data-commands-ncmd-rebirth-verb",
        "operational-behavior-data-commands-ncmd-rebirth-name",
    ];
    v.check(&ids, run.seen["rebirth"] && reborn.is_some_and(|p| Some(p.conn) == rebirth_conn), || {
        "no NBIRTH and DBIRTHs in the same session after NCMD".into()
    });
    let bd = reborn.and_then(|p| bd_seq(p.payload.as_ref()?)).map(|x| x.1);
    v.check(
        &["operational-behavior-data-commands-rebirth-action-3"],
        bd.is_some() && bd == reborn.and_then(|p| will_bd(p.conn)),
        || format!("rebirth bdSeq {bd:?}"),
    );
    v.check(&["topics-ndata-topic"], run.seen["NDATA"], || "no NDATA".into());
    v.check(&["topics-ddeath-topic"], run.seen["DDEATH"], || "no DDEATH for a removed drive".into());

    // An offline STATE older than the online one: the session goes on.
    let (a, b) = m.stale_offline;
    let disturbed = run.wire[a..b]
        .iter()
        .any(|w| matches!(w.packet, Packet::Disconnect | Packet::Closed | Packet::Connect { .. }))
        || pubs_in(a, b, "NDEATH") > 0
        || made_by("NDEATH", a, m.handled[2]);
    v.check(&["operational-behavior-edge-node-termination-host-offline-timestamp"], !disturbed, || {
        "the node left on an old offline STATE".into()
    });

    // The host offline: NDEATH, DISCONNECT, a new CONNECT.
    let active = pubs.iter().rfind(|p| p.at < m.offline).map(|p| p.conn);
    let after: Vec<&Wire> = run.wire[m.offline..m.back_online.0.max(m.offline)].iter().collect();
    let death = after.iter().position(|w| {
        Some(w.conn) == active
            && matches!(&w.packet, Packet::Publish { topic, .. } if *topic == node_topic("NDEATH"))
    });
    let disconnect =
        after.iter().position(|w| Some(w.conn) == active && matches!(w.packet, Packet::Disconnect));
    let closed = after.iter().position(|w| Some(w.conn) == active && matches!(w.packet, Packet::Closed));
    let reconnect =
        after.iter().position(|w| Some(w.conn) != active && matches!(w.packet, Packet::Connect { .. }));
    let death_bd = death.and_then(|i| match &after[i].packet {
        Packet::Publish { payload: b, .. } => payload::decode(b).ok().and_then(|p| bd_seq(&p).map(|x| x.1)),
        _ => None,
    });
    let why = || {
        format!("after the offline STATE: NDEATH {death:?} (bdSeq {death_bd:?}), DISCONNECT {disconnect:?}, closed {closed:?}, new CONNECT {reconnect:?}")
    };
    let left = death.is_some() && disconnect.is_some() && death < disconnect;
    v.check(
        &["message-flow-edge-node-birth-publish-phid-offline"],
        left && reconnect.is_some() && death_bd.is_some() && death_bd == active.and_then(will_bd),
        why,
    );
    v.check(
        &["operational-behavior-edge-node-termination-host-offline"],
        disconnect.is_some() || closed.is_some(),
        why,
    );
    v.check(
        &[
            "operational-behavior-edge-node-termination-host-offline-reconnect",
            "operational-behavior-primary-application-state-with-multiple-servers-walk",
        ],
        reconnect.is_some() && run.seen["left and connected again"] && run.seen["d1 born again"],
        why,
    );
    v.check(
        &[
            "operational-behavior-edge-node-intentional-disconnect-ndeath",
            "payloads-ndeath-will-message-publisher",
            "payloads-ndeath-will-message-publisher-disconnect-mqtt311",
        ],
        left,
        why,
    );
    // One NDEATH only: the broker must not add the will to the node's own.
    let (h0, h1) = (m.by_name.1, m.kill.1);
    let deaths = run.host[h0..h1].iter().filter(|x| kind_of(&x.topic) == Some(("NDEATH", None))).count();
    v.check(&["message-flow-edge-node-birth-publish-phid-offline"], deaths == 1, || {
        format!("the host saw {deaths} NDEATH while the host was offline")
    });

    // Kill: the broker delivers the will, with the session's bdSeq.
    let killed = pubs.iter().rfind(|p| p.at < m.kill.0).map(|p| p.conn);
    let will = run.host[m.kill.1..].iter().find(|x| kind_of(&x.topic) == Some(("NDEATH", None)));
    let will_p = will.and_then(decoded);
    let last_birth_bd = pubs
        .iter()
        .rfind(|p| p.at < m.kill.0 && p.kind == "NBIRTH")
        .and_then(|p| bd_seq(p.payload.as_ref()?).map(|x| x.1));
    let no_disconnect = !run.wire[m.kill.0..]
        .iter()
        .any(|w| Some(w.conn) == killed && matches!(w.packet, Packet::Disconnect));
    v.check(
        &["payloads-ndeath-will-message"],
        run.seen["the will"] && run.seen["killed connection closed"] && no_disconnect,
        || "no NDEATH delivered after the kill".into(),
    );
    let will_bd_seen = will_p.as_ref().and_then(bd_seq).map(|x| x.1);
    v.check(&["payloads-ndeath-bdseq"], will_bd_seen.is_some() && will_bd_seen == last_birth_bd, || {
        format!("NDEATH bdSeq {will_bd_seen:?}, NBIRTH {last_birth_bd:?}")
    });
    v.check(&["topics-ndeath-payload"], will_p.as_ref().is_some_and(|p| p.metrics.len() == 1), || {
        format!("{will_p:?}")
    });

    // Restart: the next bdSeq, from the store.
    let restarted = pubs
        .iter()
        .find(|p| p.at >= m.restart.0 && p.kind == "NBIRTH")
        .and_then(|p| bd_seq(p.payload.as_ref()?).map(|x| x.1));
    let want = last_birth_bd.map(|b| (b + 1) % 256);
    v.check(
        &["topics-nbirth-bdseq-increment"],
        run.seen["births after the restart"]
            && run.seen["d1 born after the restart"]
            && restarted.is_some()
            && restarted == want,
        || format!("after the restart bdSeq {restarted:?}, want {want:?}"),
    );
    v
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_edge_node_holds_the_specification_s_edge_node_assertions() {
    let run = scenario().await;
    let verdicts = evaluate(&run);
    let known: BTreeSet<&str> = ASSERTIONS.iter().map(|(id, _)| *id).collect();
    let mut bad = Vec::new();
    println!("Sparkplug B 3.0 edge-node assertions ({}):", ASSERTIONS.len());
    for (id, text) in ASSERTIONS {
        let verdict = if !verdicts.checked.contains(id) {
            bad.push(*id);
            "NOT CHECKED".to_string()
        } else if let Some(why) = verdicts.failed.get(id) {
            bad.push(*id);
            format!("FAIL ({})", why.join("; "))
        } else {
            "PASS".to_string()
        };
        println!("  {id}: {verdict} -- {text}");
    }
    let stray: Vec<&&str> = verdicts.checked.iter().filter(|id| !known.contains(*id)).collect();
    assert!(stray.is_empty(), "checked but not in the table: {stray:?}");
    let steps: Vec<_> = run.seen.iter().filter(|(_, ok)| !**ok).map(|(s, _)| s).collect();
    println!("scenario steps not seen: {steps:?}");
    assert!(
        bad.is_empty(),
        "{} of {} assertions failed or were not checked: {bad:?}",
        bad.len(),
        ASSERTIONS.len()
    );
}
