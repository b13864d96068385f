//! # hart-sparkplug-edge
//!
//! The MQTT Sparkplug B front end of hartkit's gateway: an edge node that publishes
//! every HART device of the polling engine as a Sparkplug device (DBIRTH with every
//! metric, DDATA on change by alias, DDEATH when it stops answering), keeps samples
//! while the broker or the primary host application is away and sends them
//! afterwards marked historical, answers `Node Control/Rebirth`, and carries DCMD
//! writes to the devices through the engine's one write path (allow-list, read-only,
//! audit).
//!
//! The protocol logic is the sans-IO [`edge::EdgeNode`]: events and time in,
//! messages out. [`run`] connects it to a broker through hart-sparkplug's MQTT client
//! module. The codec, the metric table and the settings are hart-sparkplug's (its
//! modules are re-exported here). Topics, metric names and a walk-through with
//! mosquitto are in docs/mqtt.md.

pub mod client;
pub mod edge;
pub mod image;

pub use client::{run, Backfill, Handle, Status, BACKFILL_LOW_WATER, BACKFILL_PAGE};
pub use edge::{EdgeNode, Message, Output, Sample, Settings, WriteRequest};
pub use hart_sparkplug::{command, config, driver, metrics, mqtt, proto};
pub use hart_sparkplug::{
    default_edge_node, Broker, Error, MqttConfig, DEFAULT_BACKLOG, DEFAULT_GROUP,
};
