//! # hart-sparkplug
//!
//! Sparkplug B without the polling engine: what both hartkit's edge node
//! (hart-sparkplug-edge, the gateway's publisher) and its host application
//! (hart-ingest, the historian's subscriber) need.
//!
//! - [`proto`]: the Sparkplug B payload (protobuf through prost) and data types;
//! - [`metrics`]: the one metric table (a HART device's metrics: names, data types,
//!   aliases, units properties, and which of them the historian stores);
//! - [`command`]: NCMD and DCMD payloads decoded (untrusted bytes, typed errors);
//! - [`config`]: the `[mqtt]` settings and the broker list of a URL;
//! - [`mqtt`] and [`driver`]: the one MQTT client module (broker rotation, back-off,
//!   resubscription after a refusal, connection messages, TLS) on `rumqttc`.
//!
//! Topics, metric names and a walk-through with mosquitto are in docs/mqtt.md.

pub mod command;
pub mod config;
pub mod driver;
pub mod metrics;
pub mod mqtt;
pub mod proto;

pub use config::{default_edge_node, Broker, MqttConfig, DEFAULT_BACKLOG, DEFAULT_GROUP};

/// The Sparkplug B topic namespace.
pub const NAMESPACE: &str = "spBv1.0";

/// Milliseconds since the Unix epoch (0 before it): Sparkplug's time stamps.
pub use hart_clock::epoch::millis;

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
