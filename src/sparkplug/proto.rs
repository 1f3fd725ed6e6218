//! Sparkplug B payload messages (Eclipse Sparkplug 3.0, `org.eclipse.tahu.protobuf`),
//! written from the specification as `prost` derives: no generated code, no `protoc`.
//! Field numbers are the specification's; the parts this node never sends (data sets,
//! templates, extensions) are left out, which protobuf decoders accept (unknown fields are
//! skipped), and a host's extra fields are skipped here the same way.

/// Sparkplug B data types (`DataType` enum of the specification).
pub mod datatype {
    /// Signed 32-bit.
    pub const INT32: u32 = 3;
    /// Signed 64-bit.
    pub const INT64: u32 = 4;
    /// Unsigned 32-bit.
    pub const UINT32: u32 = 7;
    /// Unsigned 64-bit.
    pub const UINT64: u32 = 8;
    /// IEEE 754 single.
    pub const FLOAT: u32 = 9;
    /// IEEE 754 double.
    pub const DOUBLE: u32 = 10;
    /// Boolean.
    pub const BOOLEAN: u32 = 11;
    /// UTF-8 string.
    pub const STRING: u32 = 12;
}

/// `Payload`.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Payload {
    /// ms since the Unix epoch.
    #[prost(uint64, optional, tag = "1")]
    pub timestamp: Option<u64>,
    /// The metrics.
    #[prost(message, repeated, tag = "2")]
    pub metrics: Vec<Metric>,
    /// Message sequence number (0..255), absent in NDEATH.
    #[prost(uint64, optional, tag = "3")]
    pub seq: Option<u64>,
    /// Optional UUID.
    #[prost(string, optional, tag = "4")]
    pub uuid: Option<String>,
    /// Optional opaque body.
    #[prost(bytes = "vec", optional, tag = "5")]
    pub body: Option<Vec<u8>>,
}

/// `Payload.Metric`.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Metric {
    /// Name (always sent by this node; no aliases).
    #[prost(string, optional, tag = "1")]
    pub name: Option<String>,
    /// Alias.
    #[prost(uint64, optional, tag = "2")]
    pub alias: Option<u64>,
    /// ms since the Unix epoch.
    #[prost(uint64, optional, tag = "3")]
    pub timestamp: Option<u64>,
    /// [`datatype`].
    #[prost(uint32, optional, tag = "4")]
    pub datatype: Option<u32>,
    /// A value from the store-and-forward queue.
    #[prost(bool, optional, tag = "5")]
    pub is_historical: Option<bool>,
    /// Not to be stored by the host.
    #[prost(bool, optional, tag = "6")]
    pub is_transient: Option<bool>,
    /// No value.
    #[prost(bool, optional, tag = "7")]
    pub is_null: Option<bool>,
    /// Properties (engineering units and limits).
    #[prost(message, optional, tag = "9")]
    pub properties: Option<PropertySet>,
    /// The value.
    #[prost(oneof = "MetricValue", tags = "10, 11, 12, 13, 14, 15, 16")]
    pub value: Option<MetricValue>,
}

/// `Metric.value` oneof.
#[derive(Clone, PartialEq, prost::Oneof)]
pub enum MetricValue {
    /// Int8..Int32, UInt8..UInt32.
    #[prost(uint32, tag = "10")]
    IntValue(u32),
    /// Int64, UInt64, DateTime.
    #[prost(uint64, tag = "11")]
    LongValue(u64),
    /// Float.
    #[prost(float, tag = "12")]
    FloatValue(f32),
    /// Double.
    #[prost(double, tag = "13")]
    DoubleValue(f64),
    /// Boolean.
    #[prost(bool, tag = "14")]
    BooleanValue(bool),
    /// String, Text.
    #[prost(string, tag = "15")]
    StringValue(String),
    /// Bytes.
    #[prost(bytes = "vec", tag = "16")]
    BytesValue(Vec<u8>),
}

/// `Payload.PropertySet`.
#[derive(Clone, PartialEq, prost::Message)]
pub struct PropertySet {
    /// Keys.
    #[prost(string, repeated, tag = "1")]
    pub keys: Vec<String>,
    /// Values, one per key.
    #[prost(message, repeated, tag = "2")]
    pub values: Vec<PropertyValue>,
}

/// `Payload.PropertyValue`.
#[derive(Clone, PartialEq, prost::Message)]
pub struct PropertyValue {
    /// [`datatype`].
    #[prost(uint32, optional, tag = "1")]
    pub r#type: Option<u32>,
    /// No value.
    #[prost(bool, optional, tag = "2")]
    pub is_null: Option<bool>,
    /// The value.
    #[prost(oneof = "PropertyValueKind", tags = "3, 4, 5, 6, 7, 8")]
    pub value: Option<PropertyValueKind>,
}

/// `PropertyValue.value` oneof.
#[derive(Clone, PartialEq, prost::Oneof)]
pub enum PropertyValueKind {
    /// 32-bit integers.
    #[prost(uint32, tag = "3")]
    IntValue(u32),
    /// 64-bit integers.
    #[prost(uint64, tag = "4")]
    LongValue(u64),
    /// Float.
    #[prost(float, tag = "5")]
    FloatValue(f32),
    /// Double.
    #[prost(double, tag = "6")]
    DoubleValue(f64),
    /// Boolean.
    #[prost(bool, tag = "7")]
    BooleanValue(bool),
    /// String.
    #[prost(string, tag = "8")]
    StringValue(String),
}

impl PropertySet {
    /// Add a string property.
    pub fn push_str(&mut self, key: &str, v: &str) {
        self.keys.push(key.into());
        self.values.push(PropertyValue {
            r#type: Some(datatype::STRING),
            is_null: None,
            value: Some(PropertyValueKind::StringValue(v.into())),
        });
    }

    /// Add a double property.
    pub fn push_f64(&mut self, key: &str, v: f64) {
        self.keys.push(key.into());
        self.values.push(PropertyValue {
            r#type: Some(datatype::DOUBLE),
            is_null: None,
            value: Some(PropertyValueKind::DoubleValue(v)),
        });
    }

    /// The property `key`, if present.
    pub fn get(&self, key: &str) -> Option<&PropertyValue> {
        self.keys
            .iter()
            .position(|k| k == key)
            .and_then(|i| self.values.get(i))
    }
}
