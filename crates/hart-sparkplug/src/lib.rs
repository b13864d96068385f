//! # hart-sparkplug
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
//! messages out. [`run`] connects it to a broker with `rumqttc`. Topics, metric names
//! and a walk-through with mosquitto are in docs/mqtt.md.

pub mod client;
pub mod command;
pub mod config;
pub mod driver;
pub mod edge;
pub mod metrics;
pub mod proto;

pub use client::{run, Backfill, Handle, Status, BACKFILL_LOW_WATER, BACKFILL_PAGE};
pub use config::{default_edge_node, Broker, MqttConfig, DEFAULT_BACKLOG, DEFAULT_GROUP};
pub use edge::{EdgeNode, Message, Output, Sample, Settings, WriteRequest};

/// Why the publisher could not start.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Error {
    /// A setting is wrong (the message says which and how).
    Config(String),
    /// A file (password, CA) could not be read or used.
    File(std::path::PathBuf, String),
}

impl std::fmt::Display for Error {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Error::Config(m) => f.write_str(m),
            Error::File(p, m) => write!(f, "{}: {m}", p.display()),
        }
    }
}

impl std::error::Error for Error {}
