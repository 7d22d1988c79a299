//! Captures: the frames a sniff saw, as a pcapng file Wireshark and tshark open, and the
//! captures `--read` replays (that pcapng, a classic pcap, or a hex dump).
//!
//! The writer puts each protocol on its own interface. Modbus RTU frames go as Modbus RTU over
//! UDP in raw IPv4 packets (link type `RAW`, 101): the drive's side is UDP port 502 and
//! 127.0.1.N for drive N, the master's port 1024 at 127.0.0.1, so tshark's own Modbus RTU
//! dissector takes them with `-o mbrtu.udp.port:502` and tells queries from responses by the
//! port (the addresses only carry the direction and the drive: a serial line has none). The
//! other protocols go as payload with link types `USER1`..`USER5` (148..152) in [`PROTOCOLS`]
//! order. Each packet is one frame with its time and its direction also in the packet's flags
//! (outbound: from the master; inbound: from a drive).

use std::io::{self, Write};
use std::time::Duration;

use anyhow::{bail, Result};
use drivebus_proto::Direction;

use super::analyze::PROTOCOLS;

/// The link type of `USER0`; a protocol's is this plus its index in [`PROTOCOLS`] (Modbus RTU,
/// index 0, goes as [`LINKTYPE_RAW`] instead).
pub const LINKTYPE_USER0: u16 = 147;
/// Raw IPv4: Modbus RTU over UDP.
pub const LINKTYPE_RAW: u16 = 101;
/// The UDP port of the drive's side of a Modbus RTU packet.
pub const MODBUS_PORT: u16 = 502;

/// The link type that carries `protocol`'s frames.
pub fn linktype(protocol: &str) -> Option<u16> {
    match PROTOCOLS.iter().position(|p| *p == protocol)? {
        0 => Some(LINKTYPE_RAW),
        i => Some(LINKTYPE_USER0 + i as u16),
    }
}

/// The protocol a link type of ours carries.
pub fn protocol_of(linktype: u16) -> Option<&'static str> {
    if linktype == LINKTYPE_RAW {
        return Some(PROTOCOLS[0]);
    }
    match linktype.checked_sub(LINKTYPE_USER0)? {
        0 => None,
        i => PROTOCOLS.get(i as usize).copied(),
    }
}

/// An RTU frame from `from` as an IPv4/UDP packet (see the module's doc).
fn udp_wrap(frame: &[u8], from: Direction) -> Vec<u8> {
    let unit = frame.first().copied().unwrap_or(0);
    let (master, drive) = ([127, 0, 0, 1], [127, 0, 1, unit]);
    let ((src, sport), (dst, dport)) = match from {
        Direction::Master => ((master, 1024u16), (drive, MODBUS_PORT)),
        Direction::Drive => ((drive, MODBUS_PORT), (master, 1024u16)),
    };
    let total = (20 + 8 + frame.len()) as u16;
    let mut ip = vec![0x45, 0, 0, 0, 0, 0, 0, 0, 64, 17, 0, 0];
    ip[2..4].copy_from_slice(&total.to_be_bytes());
    ip.extend_from_slice(&src);
    ip.extend_from_slice(&dst);
    let sum = ip.chunks(2).fold(0u32, |a, w| a + u16::from_be_bytes([w[0], w[1]]) as u32);
    let sum = !(((sum & 0xFFFF) + (sum >> 16)) as u16);
    ip[10..12].copy_from_slice(&sum.to_be_bytes());
    ip.extend_from_slice(&sport.to_be_bytes());
    ip.extend_from_slice(&dport.to_be_bytes());
    ip.extend_from_slice(&((8 + frame.len()) as u16).to_be_bytes());
    ip.extend_from_slice(&[0, 0]);
    ip.extend_from_slice(frame);
    ip
}

/// The RTU frame in an IPv4/UDP packet, and who sent it (the side on port 502 is the drive's).
fn udp_unwrap(packet: &[u8]) -> Option<(Direction, &[u8])> {
    let ihl = (*packet.first()? & 0x0F) as usize * 4;
    if packet[0] >> 4 != 4 || packet.get(9) != Some(&17) || packet.len() < ihl + 8 {
        return None;
    }
    let sport = u16::from_be_bytes([packet[ihl], packet[ihl + 1]]);
    let from = if sport == MODBUS_PORT { Direction::Drive } else { Direction::Master };
    Some((from, &packet[ihl + 8..]))
}

/// Writes frames as pcapng.
pub struct PcapWriter<W: Write> {
    out: W,
    interfaces: Vec<&'static str>,
}

fn pad4(n: usize) -> usize {
    n.div_ceil(4) * 4
}

fn option(buf: &mut Vec<u8>, code: u16, value: &[u8]) {
    buf.extend_from_slice(&code.to_le_bytes());
    buf.extend_from_slice(&(value.len() as u16).to_le_bytes());
    buf.extend_from_slice(value);
    buf.resize(pad4(buf.len()), 0);
}

fn block(out: &mut impl Write, kind: u32, body: &[u8]) -> io::Result<()> {
    let len = (12 + body.len()) as u32;
    out.write_all(&kind.to_le_bytes())?;
    out.write_all(&len.to_le_bytes())?;
    out.write_all(body)?;
    out.write_all(&len.to_le_bytes())
}

impl<W: Write> PcapWriter<W> {
    /// Starts a capture on `out` (writes the section header).
    pub fn new(mut out: W) -> io::Result<Self> {
        let mut body = Vec::new();
        body.extend_from_slice(&0x1A2B_3C4Du32.to_le_bytes());
        body.extend_from_slice(&1u16.to_le_bytes());
        body.extend_from_slice(&0u16.to_le_bytes());
        body.extend_from_slice(&(-1i64).to_le_bytes());
        option(&mut body, 4, b"drivebus sniff");
        option(&mut body, 0, &[]);
        block(&mut out, 0x0A0D_0D0A, &body)?;
        Ok(PcapWriter { out, interfaces: Vec::new() })
    }

    /// Writes one frame of `protocol` from `from`, read at `time` (since the Unix epoch).
    pub fn frame(
        &mut self,
        time: Duration,
        protocol: &'static str,
        from: Direction,
        bytes: &[u8],
    ) -> io::Result<()> {
        let Some(lt) = linktype(protocol) else { return Ok(()) };
        let iface = match self.interfaces.iter().position(|p| *p == protocol) {
            Some(i) => i,
            None => {
                let mut body = Vec::new();
                body.extend_from_slice(&lt.to_le_bytes());
                body.extend_from_slice(&0u16.to_le_bytes());
                body.extend_from_slice(&0u32.to_le_bytes());
                option(&mut body, 2, protocol.as_bytes());
                option(&mut body, 9, &[6]);
                option(&mut body, 0, &[]);
                block(&mut self.out, 1, &body)?;
                self.interfaces.push(protocol);
                self.interfaces.len() - 1
            }
        };
        let wrapped;
        let bytes = if lt == LINKTYPE_RAW {
            wrapped = udp_wrap(bytes, from);
            &wrapped[..]
        } else {
            bytes
        };
        let us = time.as_micros() as u64;
        let mut body = Vec::with_capacity(32 + bytes.len());
        body.extend_from_slice(&(iface as u32).to_le_bytes());
        body.extend_from_slice(&((us >> 32) as u32).to_le_bytes());
        body.extend_from_slice(&(us as u32).to_le_bytes());
        body.extend_from_slice(&(bytes.len() as u32).to_le_bytes());
        body.extend_from_slice(&(bytes.len() as u32).to_le_bytes());
        body.extend_from_slice(bytes);
        body.resize(pad4(body.len()), 0);
        let flags: u32 = match from {
            Direction::Master => 2,
            Direction::Drive => 1,
        };
        option(&mut body, 2, &flags.to_le_bytes());
        option(&mut body, 0, &[]);
        block(&mut self.out, 6, &body)
    }

    /// Flushes what was written.
    pub fn flush(&mut self) -> io::Result<()> {
        self.out.flush()
    }
}

/// One packet of a capture read back.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Packet {
    /// Its time (since the Unix epoch for pcap; the line number's for a hex dump).
    pub time: Duration,
    /// The protocol its link type says, for ours.
    pub protocol: Option<&'static str>,
    /// Who sent it, where the capture says.
    pub direction: Option<Direction>,
    /// Its bytes.
    pub bytes: Vec<u8>,
}

/// Reads a capture: pcapng, classic pcap (either byte order, µs or ns), or a hex dump (one burst
/// of bytes per line, `#` comments; the lines taken 10 ms apart, so each ends in a silence).
pub fn read(data: &[u8]) -> Result<Vec<Packet>> {
    if data.len() >= 4 && data[..4] == [0x0A, 0x0D, 0x0D, 0x0A] {
        return read_pcapng(data);
    }
    if data.len() >= 24 {
        let magic = u32::from_le_bytes([data[0], data[1], data[2], data[3]]);
        if [0xA1B2_C3D4, 0xD4C3_B2A1, 0xA1B2_3C4D, 0x4D3C_B2A1].contains(&magic) {
            return read_pcap(data);
        }
    }
    let Ok(text) = std::str::from_utf8(data) else {
        bail!("not a pcap, pcapng or hex dump: the file starts with {:02X?}", &data[..data.len().min(4)]);
    };
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let bytes = crate::hexarg::parse_hex_args(&[line.to_string()])
            .map_err(|e| anyhow::anyhow!("line {}: {e}", i + 1))?;
        out.push(Packet {
            time: Duration::from_millis(10 * i as u64),
            protocol: None,
            direction: None,
            bytes,
        });
    }
    if out.is_empty() {
        bail!("the hex dump holds no bytes: write the bytes in hex, one burst per line");
    }
    Ok(out)
}

/// A packet read back; Modbus RTU over UDP unwrapped (its direction from the ports).
fn packet(
    time: Duration,
    protocol: Option<&'static str>,
    direction: Option<Direction>,
    bytes: &[u8],
) -> Packet {
    if protocol == Some(PROTOCOLS[0]) {
        if let Some((from, frame)) = udp_unwrap(bytes) {
            return Packet { time, protocol, direction: direction.or(Some(from)), bytes: frame.to_vec() };
        }
    }
    Packet { time, protocol, direction, bytes: bytes.to_vec() }
}

fn read_pcap(data: &[u8]) -> Result<Vec<Packet>> {
    let le = data[0] == 0xD4 || data[0] == 0x4D;
    let nanos = data[..4] == [0x4D, 0x3C, 0xB2, 0xA1] || data[..4] == [0xA1, 0xB2, 0x3C, 0x4D];
    let u32_at = |at: usize| -> u32 {
        let b = [data[at], data[at + 1], data[at + 2], data[at + 3]];
        if le {
            u32::from_le_bytes(b)
        } else {
            u32::from_be_bytes(b)
        }
    };
    let protocol = protocol_of(u32_at(20) as u16);
    let mut out = Vec::new();
    let mut at = 24;
    while at + 16 <= data.len() {
        let (secs, frac, incl) = (u32_at(at) as u64, u32_at(at + 4) as u64, u32_at(at + 8) as usize);
        let end = at + 16 + incl;
        if end > data.len() {
            bail!(
                "the pcap is cut short: a packet at byte {at} needs {incl} bytes, {} are left",
                data.len() - at - 16
            );
        }
        let time = Duration::from_secs(secs)
            + if nanos { Duration::from_nanos(frac) } else { Duration::from_micros(frac) };
        out.push(packet(time, protocol, None, &data[at + 16..end]));
        at = end;
    }
    Ok(out)
}

fn read_pcapng(data: &[u8]) -> Result<Vec<Packet>> {
    let mut out = Vec::new();
    // (link type, ticks per second) per interface.
    let mut ifaces: Vec<(u16, u64)> = Vec::new();
    let mut le = true;
    let mut at = 0;
    while at + 12 <= data.len() {
        let raw = |at: usize| [data[at], data[at + 1], data[at + 2], data[at + 3]];
        let kind_le = u32::from_le_bytes(raw(at));
        if kind_le == 0x0A0D_0D0A {
            le = data.get(at + 8..at + 12) == Some(&[0x4D, 0x3C, 0x2B, 0x1A]);
            ifaces.clear();
        }
        let u32_at = |at: usize| if le { u32::from_le_bytes(raw(at)) } else { u32::from_be_bytes(raw(at)) };
        let u16_at = |at: usize| {
            let b = [data[at], data[at + 1]];
            if le {
                u16::from_le_bytes(b)
            } else {
                u16::from_be_bytes(b)
            }
        };
        let kind = u32_at(at);
        let len = u32_at(at + 4) as usize;
        if len < 12 || at + len > data.len() {
            bail!("the pcapng is damaged at byte {at}: a block of {len} bytes does not fit");
        }
        let body = at + 8..at + len - 4;
        match kind {
            1 => {
                let lt = u16_at(body.start);
                let mut resol = 1_000_000u64;
                let mut o = body.start + 8;
                while o + 4 <= body.end {
                    let (code, olen) = (u16_at(o), u16_at(o + 2) as usize);
                    if code == 0 {
                        break;
                    }
                    if code == 9 && olen >= 1 {
                        let v = data[o + 4];
                        resol = if v & 0x80 == 0 {
                            10u64.saturating_pow(v as u32)
                        } else {
                            1u64 << (v & 0x7F).min(63)
                        };
                    }
                    o += 4 + pad4(olen);
                }
                ifaces.push((lt, resol.max(1)));
            }
            6 => {
                let iface = u32_at(body.start) as usize;
                let ticks = ((u32_at(body.start + 4) as u64) << 32) | u32_at(body.start + 8) as u64;
                let caplen = u32_at(body.start + 12) as usize;
                let start = body.start + 20;
                if start + caplen > body.end {
                    bail!("the pcapng is damaged at byte {at}: a packet of {caplen} bytes does not fit its block");
                }
                let (lt, resol) = ifaces.get(iface).copied().unwrap_or((0, 1_000_000));
                let mut direction = None;
                let mut o = start + pad4(caplen);
                while o + 4 <= body.end {
                    let (code, olen) = (u16_at(o), u16_at(o + 2) as usize);
                    if code == 0 {
                        break;
                    }
                    if code == 2 && olen == 4 {
                        direction = match u32_at(o + 4) & 3 {
                            1 => Some(Direction::Drive),
                            2 => Some(Direction::Master),
                            _ => None,
                        };
                    }
                    o += 4 + pad4(olen);
                }
                let time = Duration::from_secs(ticks / resol)
                    + Duration::from_nanos(((ticks % resol) as u128 * 1_000_000_000 / resol as u128) as u64);
                out.push(packet(time, protocol_of(lt), direction, &data[start..start + caplen]));
            }
            _ => {}
        }
        at += len;
    }
    Ok(out)
}
