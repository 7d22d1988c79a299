//! A frame as a person reads it: each field in the manual's words, as text and JSON, and bytes
//! that are no frame with the reason. `drivebus decode` prints these, the sniffer's records
//! carry one per frame.

use std::fmt::Write as _;

use drivebus_drive::Family;
use drivebus_proto::describe::{CodeStyle, Raw};
use drivebus_proto::protocol::WireProtocol;
use drivebus_proto::{Codec, Deframer, Describe, Direction, Event, Target};
use serde_json::{json, Map, Value};

/// One field of a decoded frame, owned.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldReport {
    /// The manual's name.
    pub name: String,
    /// As shown in text.
    pub text: String,
    /// As a JSON value.
    pub json: Value,
}

/// What one stretch of the input turned out to be.
#[derive(Debug, Clone, PartialEq)]
pub enum Item {
    /// A frame, valid or not.
    Frame(FrameReport),
    /// Bytes outside any frame.
    Noise {
        /// Offset of the first byte.
        offset: u64,
        /// The bytes.
        bytes: Vec<u8>,
    },
}

/// A decoded (or rejected) frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameReport {
    /// Offset of its first byte in the input.
    pub offset: u64,
    /// Its bytes.
    pub bytes: Vec<u8>,
    /// Who sent it, where known.
    pub direction: Option<Direction>,
    /// Its address, where known.
    pub target: Option<Target>,
    /// Command or function code and name, where known.
    pub command: Option<(String, Value, String)>,
    /// True for a drive's refusal (exception, error reply).
    pub refusal: bool,
    /// Its fields.
    pub fields: Vec<FieldReport>,
    /// Why it is not valid.
    pub error: Option<String>,
}

impl FrameReport {
    /// The report of the bytes at `offset` that are no valid frame, and why.
    pub fn invalid(offset: u64, bytes: &[u8], direction: Option<Direction>, error: String) -> Self {
        FrameReport {
            offset,
            bytes: bytes.to_vec(),
            direction,
            target: None,
            command: None,
            refusal: false,
            fields: Vec::new(),
            error: Some(error),
        }
    }
}

/// Decodes `bytes` as a stream of frames of codec `C`.
///
/// Without `from`, a frame that reads as a request or as a reply alike (a Modbus 03 answer, an
/// FC telegram with AK 1 or F) right after a request to drive N is read as drive N's reply,
/// as on the wire: a master waits for the answer before it sends again.
pub fn decode_stream<C: Codec>(input: &[u8], from: Option<Direction>) -> Vec<Item> {
    let mut items = Vec::new();
    let mut deframer = Deframer::new(C::scanner(from));
    let mut next = 0u64;
    // The drive the last request went to, while its reply is due.
    let mut awaiting: Option<Target> = None;
    let mut on_event = |e: Event<'_>| {
        let (frame, position, error) = match e {
            Event::Frame { bytes, position } => (bytes, position, None),
            Event::Rejected { bytes, position, error } => (bytes, position, Some(error.to_string())),
        };
        if position > next {
            let noise = input.get(next as usize..position as usize).unwrap_or_default().to_vec();
            items.push(Item::Noise { offset: next, bytes: noise });
        }
        next = next.max(position + frame.len() as u64);
        if error.is_some() {
            awaiting = None;
        }
        let report = match error {
            Some(error) => FrameReport::invalid(position, frame, from, error),
            None => match reply_to::<C>(awaiting.take(), frame, from)
                .map_or_else(|| C::parse(frame, from), Ok::<_, drivebus_proto::FrameError>)
            {
                Ok(parsed) => {
                    if parsed.direction() == Direction::Master && matches!(parsed.target(), Target::Unit(_)) {
                        awaiting = Some(parsed.target());
                    }
                    describe(position, frame, &parsed)
                }
                Err(error) => FrameReport::invalid(position, frame, from, error.to_string()),
            },
        };
        items.push(Item::Frame(report));
    };
    deframer.push(input, &mut on_event);
    deframer.finish(&mut on_event);
    if (next as usize) < input.len() {
        items.push(Item::Noise { offset: next, bytes: input[next as usize..].to_vec() });
    }
    items
}

/// `frame` read as the reply of the drive `awaiting` names, where it reads as one and no
/// direction was given.
fn reply_to<C: Codec>(
    awaiting: Option<Target>,
    frame: &[u8],
    from: Option<Direction>,
) -> Option<C::Frame<'_>> {
    let drive = awaiting.filter(|_| from.is_none())?;
    C::parse(frame, Some(Direction::Drive))
        .ok()
        .filter(|reply| reply.direction() == Direction::Drive && reply.target() == drive)
}

/// The report of a parsed frame found at `offset`.
pub fn describe<F: Describe>(offset: u64, bytes: &[u8], frame: &F) -> FrameReport {
    let mut fields: Vec<FieldReport> = Vec::new();
    frame.fields(&mut |f| {
        let json = field_json(&f);
        let mut name = f.name.to_string();
        let same =
            fields.iter().filter(|x| x.name == name || x.name.starts_with(&format!("{name}["))).count();
        if same > 0 {
            name = format!("{name}[{}]", same + 1);
        }
        fields.push(FieldReport { name, text: f.to_string(), json });
    });
    let cmd = frame.command();
    let code = match cmd.style {
        CodeStyle::Letter => (format!("'{}'", cmd.code as char), json!((cmd.code as char).to_string())),
        CodeStyle::Hex => (format!("{:02X}", cmd.code), json!(cmd.code)),
    };
    FrameReport {
        offset,
        bytes: bytes.to_vec(),
        direction: Some(frame.direction()),
        target: Some(frame.target()),
        command: Some((code.0, code.1, cmd.name.to_string())),
        refusal: frame.is_refusal(),
        fields,
        error: None,
    }
}

fn field_json(f: &drivebus_proto::Field<'_>) -> Value {
    let raw = match f.raw {
        Raw::Hex { value, .. } => json!(value),
        Raw::Dec(v) => json!(v),
        Raw::Bool(b) => json!(b),
        Raw::Bytes(b) => json!(hex_string(b)),
        Raw::Text(t) => json!(String::from_utf8_lossy(t)),
    };
    let mut obj = Map::new();
    obj.insert("raw".into(), raw);
    if let Raw::Hex { value, digits } = f.raw {
        obj.insert("hex".into(), json!(format!("{:0w$X}", value, w = digits as usize)));
    }
    if let Some(q) = f.quantity {
        let rounded = format!("{:.*}", q.decimals as usize, q.value).parse::<f64>().unwrap_or(q.value);
        obj.insert("value".into(), json!(rounded));
        obj.insert("unit".into(), json!(q.unit));
    }
    if let Some(m) = f.meaning {
        obj.insert("meaning".into(), json!(m));
    }
    Value::Object(obj)
}

/// Bytes as spaced upper-case hex.
pub fn hex_string(bytes: &[u8]) -> String {
    let mut s = String::with_capacity(bytes.len() * 3);
    for (i, b) in bytes.iter().enumerate() {
        if i > 0 {
            s.push(' ');
        }
        let _ = write!(s, "{b:02X}");
    }
    s
}

fn target_text(t: Target) -> String {
    match t {
        Target::Unit(n) => format!("drive {n}"),
        Target::Broadcast => "all drives (broadcast)".into(),
        Target::Wildcard { tens, units } => {
            let d = |x: Option<u8>| x.map(|v| char::from(b'0' + v)).unwrap_or('*');
            format!("drives matching {}{} (wildcard)", d(tens), d(units))
        }
        Target::Implicit => "the drive on the line (no address)".into(),
    }
}

/// The name of a valid request frame that a drive acting as bus master broadcasts
/// ([`drivebus_drive::interdrive`]).
pub fn master_drive_broadcast(protocol: &str, f: &FrameReport) -> Option<&'static str> {
    let request = f.error.is_none() && f.direction != Some(Direction::Drive);
    request
        .then(|| drivebus_drive::interdrive::master_drive_broadcast(protocol.parse().ok()?, &f.bytes))
        .flatten()
}

/// The text form of one item.
pub fn render_text(protocol: &str, index: usize, item: &Item) -> String {
    match item {
        Item::Noise { offset, bytes } => format!(
            "bytes {}..{} are not part of any {protocol} frame: {}\n",
            offset,
            offset + bytes.len() as u64,
            hex_string(bytes)
        ),
        Item::Frame(f) => {
            let mut s = format!("frame {index} at byte {}: ", f.offset);
            if let Some(err) = &f.error {
                let _ = writeln!(s, "INVALID: {err}");
                let _ = writeln!(s, "    bytes {}", hex_string(&f.bytes));
                return s;
            }
            let who = match (f.direction, f.target) {
                (Some(Direction::Master), Some(t)) => format!("master to {}", target_text(t)),
                (Some(Direction::Drive), Some(Target::Unit(n))) => format!("drive {n} to master"),
                (Some(Direction::Drive), Some(t)) => format!("{} to master", target_text(t)),
                _ => "?".into(),
            };
            let (code, _, name) = f.command.clone().unwrap_or_default();
            let _ =
                writeln!(s, "{who}: {code} {name}{}", if f.refusal { " (the drive refuses)" } else { "" });
            if let Some(note) = master_drive_broadcast(protocol, f) {
                let _ = writeln!(s, "    {note}");
            }
            for field in &f.fields {
                let _ = writeln!(s, "    {}", field.text);
            }
            s
        }
    }
}

/// The JSON form of one item (frames only; noise gets `null`).
pub fn render_json(protocol: &str, item: &Item) -> Option<Value> {
    let Item::Frame(f) = item else { return None };
    let mut o = Map::new();
    o.insert("valid".into(), json!(f.error.is_none()));
    o.insert("protocol".into(), json!(protocol));
    o.insert("offset".into(), json!(f.offset));
    o.insert("bytes".into(), json!(hex_string(&f.bytes)));
    o.insert("direction".into(), f.direction.map(|d| json!(d.as_str())).unwrap_or(Value::Null));
    let (address, broadcast, wildcard) = match f.target {
        Some(Target::Unit(n)) => (json!(n), false, None),
        Some(Target::Broadcast) => (json!(0), true, None),
        Some(Target::Wildcard { tens, units }) => {
            let d = |x: Option<u8>| x.map(|v| char::from(b'0' + v)).unwrap_or('*');
            (Value::Null, true, Some(format!("{}{}", d(tens), d(units))))
        }
        Some(Target::Implicit) | None => (Value::Null, false, None),
    };
    o.insert("address".into(), address);
    o.insert("broadcast".into(), json!(broadcast));
    if let Some(w) = wildcard {
        o.insert("wildcard".into(), json!(w));
    }
    let key = if protocol.starts_with("modbus") { "function" } else { "command" };
    match &f.command {
        Some((_, code, name)) => {
            o.insert(key.into(), code.clone());
            o.insert(format!("{key}_name"), json!(name));
        }
        None => {
            o.insert(key.into(), Value::Null);
        }
    }
    o.insert("refusal".into(), json!(f.refusal));
    if master_drive_broadcast(protocol, f).is_some() {
        o.insert("drive_master_broadcast".into(), json!(true));
    }
    let mut fields = Map::new();
    for field in &f.fields {
        fields.insert(field.name.clone(), field.json.clone());
    }
    o.insert("fields".into(), Value::Object(fields));
    if let Some(e) = &f.error {
        o.insert("error".into(), json!(e));
    }
    Some(Value::Object(o))
}

/// Decodes with the codec of `name`; Modbus registers are named from the catalog of `family`
/// (generic or toshiba), or of whichever of the two has the register when `None`.
pub fn decode_by_name(
    name: WireProtocol,
    bytes: &[u8],
    from: Option<Direction>,
    family: Option<Family>,
) -> (&'static str, Vec<Item>) {
    struct Decode<'a>(&'a [u8], Option<Direction>);
    impl drivebus_proto::protocol::CodecJob for Decode<'_> {
        type Output = Vec<Item>;
        fn run<C: Codec + 'static>(self) -> Vec<Item>
        where
            C::Scanner: Send + 'static,
        {
            decode_stream::<C>(self.0, self.1)
        }
    }
    let mut items = name.with_codec(Decode(bytes, from));
    if name.is_modbus() {
        name_registers(&mut items, family);
    }
    (name.name(), items)
}

/// Decodes `reply` as the drive's answer to `request` (one valid request): a read reply's
/// values named and scaled by the request's starting address. Only the reply's items.
pub fn decode_reply(
    name: WireProtocol,
    request: &[u8],
    reply: &[u8],
    family: Option<Family>,
) -> (&'static str, Vec<Item>) {
    let (_, mut items) = decode_by_name(name, request, Some(Direction::Master), family);
    let (protocol, answer) = decode_by_name(name, reply, Some(Direction::Drive), family);
    let asked = items.len();
    items.extend(answer);
    if name.is_modbus() {
        name_registers(&mut items, family);
    }
    (protocol, items.split_off(asked))
}

/// A register as the catalogs know it: one family's parameter, or several that share the
/// number (a generic Pgg.nn and a Toshiba communication number).
enum Known {
    One(Family, drivebus_drive::ParamDef),
    Several(String),
}

/// The Modbus families' catalog entries at register `address` (only `family`'s when given).
fn known_register(address: u16, family: Option<Family>) -> Option<Known> {
    let families: Vec<Family> = match family {
        Some(f) => vec![f],
        None => vec![Family::Generic, Family::Toshiba],
    };
    let mut found: Vec<(Family, drivebus_drive::ParamDef)> = families
        .into_iter()
        .filter_map(|f| {
            Some((f, drivebus_drive::Catalog::load(f).ok()?.by_number(u32::from(address))?.clone()))
        })
        .collect();
    match found.len() {
        0 => None,
        1 => found.pop().map(|(f, def)| Known::One(f, def)),
        _ => Some(Known::Several(format!(
            "{}: --drive FAMILY says which",
            found.iter().map(|(f, d)| format!("{f} {} {}", d.name, d.title)).collect::<Vec<_>>().join(" or ")
        ))),
    }
}

/// Adds what the proto tables leave out to Modbus frames: a read reply's values named and
/// scaled by its request's starting address (the frame before it, to the same drive), and
/// registers the catalogs know (generic P0.02 at 0002H, the 2000H command values).
fn name_registers(items: &mut [Item], family: Option<Family>) {
    // The drive and starting address of the last read request (03 or 04).
    let mut read: Option<(Option<Target>, u16)> = None;
    for item in items.iter_mut() {
        let Item::Frame(f) = item else {
            read = None;
            continue;
        };
        if f.error.is_some() {
            read = None;
            continue;
        }
        let function = f.command.as_ref().and_then(|(_, code, _)| code.as_u64());
        let is_read = matches!(function, Some(3 | 4));
        // A read reply's values start at its request's address.
        let mut at = match (f.direction, read.take()) {
            (Some(Direction::Drive), Some((target, start))) if is_read && target == f.target => Some(start),
            _ => None,
        };
        for field in &mut f.fields {
            let Some(raw) = field.json["raw"].as_u64().and_then(|r| u16::try_from(r).ok()) else { continue };
            match field.name.split('[').next().unwrap_or_default() {
                "starting address" | "register address" => {
                    at = Some(raw);
                    if is_read && f.direction == Some(Direction::Master) {
                        read = Some((f.target, raw));
                    }
                    if field.json.get("meaning").is_none() {
                        let meaning = match known_register(raw, family) {
                            Some(Known::One(fam, def)) => format!("{} {} ({fam})", def.name, def.title),
                            Some(Known::Several(text)) => text,
                            None => continue,
                        };
                        field.text = format!("{} ({meaning})", field.text);
                        field.json["meaning"] = json!(meaning);
                    }
                }
                "register value" => {
                    let Some(address) = at else { continue };
                    at = Some(address.wrapping_add(1));
                    if field.json.get("value").is_some() || field.json.get("meaning").is_some() {
                        continue;
                    }
                    if let Some((unit, scale, decimals)) = drivebus_proto::modbus::register_info(
                        drivebus_proto::modbus::RegisterAddress(address),
                    )
                    .and_then(|i| i.unit)
                    {
                        set_quantity(field, f64::from(raw) * scale, unit, usize::from(decimals));
                    } else if let Some(Known::One(_, def)) = known_register(address, family) {
                        if let Some(choice) = def.choice(i64::from(raw)) {
                            field.text = format!("{} ({choice})", field.text);
                            field.json["meaning"] = json!(choice);
                        } else if !def.unit.is_empty() {
                            let decimals = usize::try_from(def.scale.max(0)).unwrap_or(0);
                            set_quantity(field, def.from_raw(i64::from(raw)), &def.unit, decimals);
                        }
                    }
                }
                _ => {}
            }
        }
    }
}

/// Adds a value in a unit to a field, as the proto's own quantities show.
fn set_quantity(field: &mut FieldReport, value: f64, unit: &str, decimals: usize) {
    let shown = format!("{value:.decimals$}");
    field.text = format!("{} = {shown} {unit}", field.text);
    field.json["value"] = json!(shown.parse::<f64>().unwrap_or(value));
    field.json["unit"] = json!(unit);
}
