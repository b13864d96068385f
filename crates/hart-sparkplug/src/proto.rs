//! The Sparkplug B payload, as prost messages.
//!
//! Transcribed field for field from Eclipse Tahu's published definition,
//! `sparkplug_b/sparkplug_b.proto` (package `org.eclipse.tahu.protobuf`, proto2,
//! <https://github.com/eclipse/tahu/blob/master/sparkplug_b/sparkplug_b.proto>, the file
//! the Sparkplug 3.0.0 specification's payload chapter refers to): the same messages,
//! field numbers, scalar types and oneofs, so no `protoc` is needed to build. The
//! `extensions N to max` ranges have no prost counterpart: fields in them are skipped
//! when decoding, as protobuf does with unknown fields. The `*Extension` messages are
//! kept as empty messages.

/// Sparkplug data type codes (`Payload` comment block of the .proto; Sparkplug 3.0
/// section 6.4.16), as carried in `Metric.datatype`, `PropertyValue.type`,
/// `DataSet.types` and `Template.Parameter.type`.
pub mod datatype {
    /// Unknown placeholder.
    pub const UNKNOWN: u32 = 0;
    /// 8-bit signed integer.
    pub const INT8: u32 = 1;
    /// 16-bit signed integer.
    pub const INT16: u32 = 2;
    /// 32-bit signed integer.
    pub const INT32: u32 = 3;
    /// 64-bit signed integer.
    pub const INT64: u32 = 4;
    /// 8-bit unsigned integer.
    pub const UINT8: u32 = 5;
    /// 16-bit unsigned integer.
    pub const UINT16: u32 = 6;
    /// 32-bit unsigned integer.
    pub const UINT32: u32 = 7;
    /// 64-bit unsigned integer.
    pub const UINT64: u32 = 8;
    /// 32-bit float.
    pub const FLOAT: u32 = 9;
    /// 64-bit float.
    pub const DOUBLE: u32 = 10;
    /// Boolean.
    pub const BOOLEAN: u32 = 11;
    /// UTF-8 string.
    pub const STRING: u32 = 12;
    /// Milliseconds since the Unix epoch, in `long_value`.
    pub const DATETIME: u32 = 13;
    /// Text.
    pub const TEXT: u32 = 14;
    /// UUID, as a string.
    pub const UUID: u32 = 15;
    /// DataSet.
    pub const DATASET: u32 = 16;
    /// Bytes.
    pub const BYTES: u32 = 17;
    /// File.
    pub const FILE: u32 = 18;
    /// Template.
    pub const TEMPLATE: u32 = 19;
    /// PropertySet (property values only).
    pub const PROPERTY_SET: u32 = 20;
    /// PropertySetList (property values only).
    pub const PROPERTY_SET_LIST: u32 = 21;
}

/// `message Payload`: one Sparkplug B MQTT payload.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Payload {
    /// Time the message was sent, ms since the Unix epoch.
    #[prost(uint64, optional, tag = "1")]
    pub timestamp: Option<u64>,
    /// The metrics.
    #[prost(message, repeated, tag = "2")]
    pub metrics: Vec<payload::Metric>,
    /// Sequence number (0-255).
    #[prost(uint64, optional, tag = "3")]
    pub seq: Option<u64>,
    /// Schema UUID.
    #[prost(string, optional, tag = "4")]
    pub uuid: Option<String>,
    /// Opaque body.
    #[prost(bytes = "vec", optional, tag = "5")]
    pub body: Option<Vec<u8>>,
}

/// The messages nested in `Payload`.
pub mod payload {
    /// `message Payload.Template`.
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct Template {
        /// Template version.
        #[prost(string, optional, tag = "1")]
        pub version: Option<String>,
        /// Member metrics.
        #[prost(message, repeated, tag = "2")]
        pub metrics: Vec<Metric>,
        /// Parameters.
        #[prost(message, repeated, tag = "3")]
        pub parameters: Vec<template::Parameter>,
        /// The definition an instance refers to.
        #[prost(string, optional, tag = "4")]
        pub template_ref: Option<String>,
        /// A definition rather than an instance.
        #[prost(bool, optional, tag = "5")]
        pub is_definition: Option<bool>,
    }

    /// The messages nested in `Payload.Template`.
    pub mod template {
        /// `message Payload.Template.Parameter`.
        #[derive(Clone, PartialEq, prost::Message)]
        pub struct Parameter {
            /// Name.
            #[prost(string, optional, tag = "1")]
            pub name: Option<String>,
            /// Data type code.
            #[prost(uint32, optional, tag = "2")]
            pub r#type: Option<u32>,
            /// The value.
            #[prost(oneof = "parameter::Value", tags = "3, 4, 5, 6, 7, 8, 9")]
            pub value: Option<parameter::Value>,
        }

        /// The oneof of `Parameter`.
        pub mod parameter {
            /// `message Payload.Template.Parameter.ParameterValueExtension`.
            #[derive(Clone, PartialEq, prost::Message)]
            pub struct ParameterValueExtension {}

            /// `oneof value`.
            #[derive(Clone, PartialEq, prost::Oneof)]
            pub enum Value {
                /// `uint32 int_value = 3`.
                #[prost(uint32, tag = "3")]
                IntValue(u32),
                /// `uint64 long_value = 4`.
                #[prost(uint64, tag = "4")]
                LongValue(u64),
                /// `float float_value = 5`.
                #[prost(float, tag = "5")]
                FloatValue(f32),
                /// `double double_value = 6`.
                #[prost(double, tag = "6")]
                DoubleValue(f64),
                /// `bool boolean_value = 7`.
                #[prost(bool, tag = "7")]
                BooleanValue(bool),
                /// `string string_value = 8`.
                #[prost(string, tag = "8")]
                StringValue(String),
                /// `ParameterValueExtension extension_value = 9`.
                #[prost(message, tag = "9")]
                ExtensionValue(ParameterValueExtension),
            }
        }
    }

    /// `message Payload.DataSet`.
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct DataSet {
        /// Columns.
        #[prost(uint64, optional, tag = "1")]
        pub num_of_columns: Option<u64>,
        /// Column names.
        #[prost(string, repeated, tag = "2")]
        pub columns: Vec<String>,
        /// Column data type codes.
        #[prost(uint32, repeated, packed = "false", tag = "3")]
        pub types: Vec<u32>,
        /// Rows.
        #[prost(message, repeated, tag = "4")]
        pub rows: Vec<data_set::Row>,
    }

    /// The messages nested in `Payload.DataSet`.
    pub mod data_set {
        /// `message Payload.DataSet.DataSetValue`.
        #[derive(Clone, PartialEq, prost::Message)]
        pub struct DataSetValue {
            /// The value.
            #[prost(oneof = "data_set_value::Value", tags = "1, 2, 3, 4, 5, 6, 7")]
            pub value: Option<data_set_value::Value>,
        }

        /// The oneof of `DataSetValue`.
        pub mod data_set_value {
            /// `message Payload.DataSet.DataSetValue.DataSetValueExtension`.
            #[derive(Clone, PartialEq, prost::Message)]
            pub struct DataSetValueExtension {}

            /// `oneof value`.
            #[derive(Clone, PartialEq, prost::Oneof)]
            pub enum Value {
                /// `uint32 int_value = 1`.
                #[prost(uint32, tag = "1")]
                IntValue(u32),
                /// `uint64 long_value = 2`.
                #[prost(uint64, tag = "2")]
                LongValue(u64),
                /// `float float_value = 3`.
                #[prost(float, tag = "3")]
                FloatValue(f32),
                /// `double double_value = 4`.
                #[prost(double, tag = "4")]
                DoubleValue(f64),
                /// `bool boolean_value = 5`.
                #[prost(bool, tag = "5")]
                BooleanValue(bool),
                /// `string string_value = 6`.
                #[prost(string, tag = "6")]
                StringValue(String),
                /// `DataSetValueExtension extension_value = 7`.
                #[prost(message, tag = "7")]
                ExtensionValue(DataSetValueExtension),
            }
        }

        /// `message Payload.DataSet.Row`.
        #[derive(Clone, PartialEq, prost::Message)]
        pub struct Row {
            /// One value per column.
            #[prost(message, repeated, tag = "1")]
            pub elements: Vec<DataSetValue>,
        }
    }

    /// `message Payload.PropertyValue`.
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct PropertyValue {
        /// Data type code.
        #[prost(uint32, optional, tag = "1")]
        pub r#type: Option<u32>,
        /// No value.
        #[prost(bool, optional, tag = "2")]
        pub is_null: Option<bool>,
        /// The value.
        #[prost(oneof = "property_value::Value", tags = "3, 4, 5, 6, 7, 8, 9, 10, 11")]
        pub value: Option<property_value::Value>,
    }

    /// The oneof of `PropertyValue`.
    pub mod property_value {
        /// `message Payload.PropertyValue.PropertyValueExtension`.
        #[derive(Clone, PartialEq, prost::Message)]
        pub struct PropertyValueExtension {}

        /// `oneof value`.
        #[derive(Clone, PartialEq, prost::Oneof)]
        pub enum Value {
            /// `uint32 int_value = 3`.
            #[prost(uint32, tag = "3")]
            IntValue(u32),
            /// `uint64 long_value = 4`.
            #[prost(uint64, tag = "4")]
            LongValue(u64),
            /// `float float_value = 5`.
            #[prost(float, tag = "5")]
            FloatValue(f32),
            /// `double double_value = 6`.
            #[prost(double, tag = "6")]
            DoubleValue(f64),
            /// `bool boolean_value = 7`.
            #[prost(bool, tag = "7")]
            BooleanValue(bool),
            /// `string string_value = 8`.
            #[prost(string, tag = "8")]
            StringValue(String),
            /// `PropertySet propertyset_value = 9`.
            #[prost(message, tag = "9")]
            PropertysetValue(super::PropertySet),
            /// `PropertySetList propertysets_value = 10`.
            #[prost(message, tag = "10")]
            PropertysetsValue(super::PropertySetList),
            /// `PropertyValueExtension extension_value = 11`.
            #[prost(message, tag = "11")]
            ExtensionValue(PropertyValueExtension),
        }
    }

    /// `message Payload.PropertySet`: parallel lists of keys and values.
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct PropertySet {
        /// Property names.
        #[prost(string, repeated, tag = "1")]
        pub keys: Vec<String>,
        /// Property values, one per key.
        #[prost(message, repeated, tag = "2")]
        pub values: Vec<PropertyValue>,
    }

    /// `message Payload.PropertySetList`.
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct PropertySetList {
        /// The sets.
        #[prost(message, repeated, tag = "1")]
        pub propertyset: Vec<PropertySet>,
    }

    /// `message Payload.MetaData`.
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct MetaData {
        /// Part of a multi-part message.
        #[prost(bool, optional, tag = "1")]
        pub is_multi_part: Option<bool>,
        /// Content (media) type.
        #[prost(string, optional, tag = "2")]
        pub content_type: Option<String>,
        /// Size.
        #[prost(uint64, optional, tag = "3")]
        pub size: Option<u64>,
        /// Sequence number of a multi-part message.
        #[prost(uint64, optional, tag = "4")]
        pub seq: Option<u64>,
        /// File name.
        #[prost(string, optional, tag = "5")]
        pub file_name: Option<String>,
        /// File type.
        #[prost(string, optional, tag = "6")]
        pub file_type: Option<String>,
        /// MD5 of the data.
        #[prost(string, optional, tag = "7")]
        pub md5: Option<String>,
        /// Free text.
        #[prost(string, optional, tag = "8")]
        pub description: Option<String>,
    }

    /// `message Payload.Metric`.
    #[derive(Clone, PartialEq, prost::Message)]
    pub struct Metric {
        /// Name (births and commands; data messages use the alias).
        #[prost(string, optional, tag = "1")]
        pub name: Option<String>,
        /// Alias, tied to the name in the birth.
        #[prost(uint64, optional, tag = "2")]
        pub alias: Option<u64>,
        /// When the value was acquired, ms since the Unix epoch.
        #[prost(uint64, optional, tag = "3")]
        pub timestamp: Option<u64>,
        /// Data type code ([`super::datatype`]).
        #[prost(uint32, optional, tag = "4")]
        pub datatype: Option<u32>,
        /// Historical: must not update the real-time value.
        #[prost(bool, optional, tag = "5")]
        pub is_historical: Option<bool>,
        /// Transient: not to be stored as a tag.
        #[prost(bool, optional, tag = "6")]
        pub is_transient: Option<bool>,
        /// No value.
        #[prost(bool, optional, tag = "7")]
        pub is_null: Option<bool>,
        /// Metadata.
        #[prost(message, optional, tag = "8")]
        pub metadata: Option<MetaData>,
        /// Properties (`engUnit`, ...).
        #[prost(message, optional, tag = "9")]
        pub properties: Option<PropertySet>,
        /// The value.
        #[prost(
            oneof = "metric::Value",
            tags = "10, 11, 12, 13, 14, 15, 16, 17, 18, 19"
        )]
        pub value: Option<metric::Value>,
    }

    /// The oneof of `Metric`.
    pub mod metric {
        /// `message Payload.Metric.MetricValueExtension`.
        #[derive(Clone, PartialEq, prost::Message)]
        pub struct MetricValueExtension {}

        /// `oneof value`.
        #[derive(Clone, PartialEq, prost::Oneof)]
        pub enum Value {
            /// `uint32 int_value = 10` (Int8..Int32, UInt8..UInt32).
            #[prost(uint32, tag = "10")]
            IntValue(u32),
            /// `uint64 long_value = 11` (Int64, UInt64, DateTime).
            #[prost(uint64, tag = "11")]
            LongValue(u64),
            /// `float float_value = 12`.
            #[prost(float, tag = "12")]
            FloatValue(f32),
            /// `double double_value = 13`.
            #[prost(double, tag = "13")]
            DoubleValue(f64),
            /// `bool boolean_value = 14`.
            #[prost(bool, tag = "14")]
            BooleanValue(bool),
            /// `string string_value = 15` (String, Text, UUID).
            #[prost(string, tag = "15")]
            StringValue(String),
            /// `bytes bytes_value = 16` (Bytes, File).
            #[prost(bytes = "vec", tag = "16")]
            BytesValue(Vec<u8>),
            /// `DataSet dataset_value = 17`.
            #[prost(message, tag = "17")]
            DatasetValue(super::DataSet),
            /// `Template template_value = 18`.
            #[prost(message, tag = "18")]
            TemplateValue(super::Template),
            /// `MetricValueExtension extension_value = 19`.
            #[prost(message, tag = "19")]
            ExtensionValue(MetricValueExtension),
        }
    }
}
