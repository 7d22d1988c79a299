//! The Sparkplug B payload (`org.eclipse.tahu.protobuf.Payload`, proto2), written out with
//! prost's derive macros: the messages and fields an edge node sends and reads, with the
//! schema's field numbers, so no protoc is needed at build time. Fields this edge node never
//! uses (metadata, data sets, templates, extensions) are left out: prost skips them when they
//! come in, as protobuf does for unknown fields.

use prost::Message;

/// A Sparkplug B payload.
#[derive(Clone, PartialEq, Message)]
pub struct Payload {
    /// When the message was made, unix ms.
    #[prost(uint64, optional, tag = "1")]
    pub timestamp: Option<u64>,
    /// The metrics.
    #[prost(message, repeated, tag = "2")]
    pub metrics: Vec<Metric>,
    /// The message's sequence number, 0..=255 (none in NDEATH).
    #[prost(uint64, optional, tag = "3")]
    pub seq: Option<u64>,
    /// Unused here.
    #[prost(string, optional, tag = "4")]
    pub uuid: Option<String>,
    /// Unused here.
    #[prost(bytes = "vec", optional, tag = "5")]
    pub body: Option<Vec<u8>>,
}

/// One metric of a payload.
#[derive(Clone, PartialEq, Message)]
pub struct Metric {
    /// Its name (in births; data messages use the alias).
    #[prost(string, optional, tag = "1")]
    pub name: Option<String>,
    /// Its alias, unique across the edge node and its devices.
    #[prost(uint64, optional, tag = "2")]
    pub alias: Option<u64>,
    /// When the value was read, unix ms.
    #[prost(uint64, optional, tag = "3")]
    pub timestamp: Option<u64>,
    /// Its [`DataType`] (in births and commands).
    #[prost(uint32, optional, tag = "4")]
    pub datatype: Option<u32>,
    /// Set on values sent late from the store-and-forward queue.
    #[prost(bool, optional, tag = "5")]
    pub is_historical: Option<bool>,
    /// Unused here.
    #[prost(bool, optional, tag = "6")]
    pub is_transient: Option<bool>,
    /// No value known.
    #[prost(bool, optional, tag = "7")]
    pub is_null: Option<bool>,
    /// Properties (the engineering unit).
    #[prost(message, optional, tag = "9")]
    pub properties: Option<PropertySet>,
    /// The value.
    #[prost(oneof = "Value", tags = "10, 11, 12, 13, 14, 15, 16")]
    pub value: Option<Value>,
}

/// A metric's value.
#[derive(Clone, PartialEq, prost::Oneof)]
pub enum Value {
    /// Int8, Int16, Int32, UInt8, UInt16, UInt32.
    #[prost(uint32, tag = "10")]
    Int(u32),
    /// Int64, UInt64, DateTime.
    #[prost(uint64, tag = "11")]
    Long(u64),
    /// Float.
    #[prost(float, tag = "12")]
    Float(f32),
    /// Double.
    #[prost(double, tag = "13")]
    Double(f64),
    /// Boolean.
    #[prost(bool, tag = "14")]
    Boolean(bool),
    /// String, Text, UUID.
    #[prost(string, tag = "15")]
    String(String),
    /// Bytes, File.
    #[prost(bytes = "vec", tag = "16")]
    Bytes(Vec<u8>),
}

/// Properties of a metric: keys and values in the same order.
#[derive(Clone, PartialEq, Message)]
pub struct PropertySet {
    /// The keys.
    #[prost(string, repeated, tag = "1")]
    pub keys: Vec<String>,
    /// The values.
    #[prost(message, repeated, tag = "2")]
    pub values: Vec<PropertyValue>,
}

/// A property's value.
#[derive(Clone, PartialEq, Message)]
pub struct PropertyValue {
    /// Its [`DataType`].
    #[prost(uint32, optional, tag = "1")]
    pub r#type: Option<u32>,
    /// No value.
    #[prost(bool, optional, tag = "2")]
    pub is_null: Option<bool>,
    /// The value.
    #[prost(oneof = "PropertyValueKind", tags = "3, 4, 5, 6, 7, 8")]
    pub value: Option<PropertyValueKind>,
}

/// A property's value.
#[derive(Clone, PartialEq, prost::Oneof)]
pub enum PropertyValueKind {
    /// Int8 .. UInt32.
    #[prost(uint32, tag = "3")]
    Int(u32),
    /// Int64, UInt64.
    #[prost(uint64, tag = "4")]
    Long(u64),
    /// Float.
    #[prost(float, tag = "5")]
    Float(f32),
    /// Double.
    #[prost(double, tag = "6")]
    Double(f64),
    /// Boolean.
    #[prost(bool, tag = "7")]
    Boolean(bool),
    /// String.
    #[prost(string, tag = "8")]
    String(String),
}

/// The Sparkplug B data types this edge node uses (the schema's `DataType` numbers).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u32)]
pub enum DataType {
    /// 64-bit signed integer (`bdSeq`, as the specification types it).
    Int64 = 4,
    /// 32-bit unsigned integer.
    UInt32 = 7,
    /// 64-bit unsigned integer.
    UInt64 = 8,
    /// 64-bit float.
    Double = 10,
    /// true/false.
    Boolean = 11,
    /// UTF-8 text.
    String = 12,
}

impl DataType {
    /// The schema's name of a data type number (for error messages).
    pub fn name(number: u32) -> &'static str {
        const NAMES: [&str; 20] = [
            "Unknown", "Int8", "Int16", "Int32", "Int64", "UInt8", "UInt16", "UInt32", "UInt64", "Float",
            "Double", "Boolean", "String", "DateTime", "Text", "UUID", "DataSet", "Bytes", "File",
            "Template",
        ];
        NAMES.get(number as usize).copied().unwrap_or("an unknown type")
    }

    /// This type's name.
    pub fn as_str(self) -> &'static str {
        DataType::name(self as u32)
    }
}

impl Metric {
    /// A metric with a name, alias, type and (possibly missing) value, for a birth.
    pub fn birth(name: &str, alias: u64, datatype: DataType, value: Option<Value>, time_ms: u64) -> Metric {
        Metric {
            name: Some(name.to_string()),
            alias: Some(alias),
            timestamp: Some(time_ms),
            datatype: Some(datatype as u32),
            is_null: value.is_none().then_some(true),
            value,
            ..Metric::default()
        }
    }

    /// [`Metric::birth`] without an alias: for a metric a host must find by name
    /// (`Node Control/Rebirth`).
    pub fn birth_by_name(name: &str, datatype: DataType, value: Option<Value>, time_ms: u64) -> Metric {
        Metric { alias: None, ..Metric::birth(name, 0, datatype, value, time_ms) }
    }

    /// Adds the engineering unit as the `engUnit` property.
    pub fn with_unit(mut self, unit: &str) -> Metric {
        if !unit.is_empty() {
            self.properties = Some(PropertySet {
                keys: vec!["engUnit".into()],
                values: vec![PropertyValue {
                    r#type: Some(DataType::String as u32),
                    is_null: None,
                    value: Some(PropertyValueKind::String(unit.to_string())),
                }],
            });
        }
        self
    }
}

/// Decodes a payload received from the broker; the error says why it is not one.
pub fn decode(bytes: &[u8]) -> Result<Payload, String> {
    Payload::decode(bytes).map_err(|e| format!("not a Sparkplug B payload: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bytes made by the schema's own generated code (Python protobuf on sparkplug_b.proto):
    /// seq 3, one metric "x", alias 5, datatype Float, value 1.5.
    const REFERENCE: &str = "120c0a017810052009650000c03f1803";

    fn hex(b: &[u8]) -> String {
        b.iter().map(|x| format!("{x:02x}")).collect()
    }

    #[test]
    fn matches_the_schema_s_own_encoding() {
        let p = Payload {
            seq: Some(3),
            metrics: vec![Metric {
                name: Some("x".into()),
                alias: Some(5),
                datatype: Some(9),
                value: Some(Value::Float(1.5)),
                ..Metric::default()
            }],
            ..Payload::default()
        };
        assert_eq!(hex(&p.encode_to_vec()), REFERENCE);
        let bytes: Vec<u8> = (0..REFERENCE.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&REFERENCE[i..i + 2], 16).unwrap())
            .collect();
        assert_eq!(decode(&bytes).unwrap(), p);
    }

    #[test]
    fn garbage_is_an_error_not_a_panic() {
        assert!(decode(b"\xff\xff\xff").is_err());
        assert!(decode(b"{\"online\": true}").is_err());
    }
}
