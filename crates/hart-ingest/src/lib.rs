//! # hart-ingest
//!
//! `hartkit history ingest`: a Sparkplug B host application that subscribes to a
//! group's topics on an MQTT broker (or a broker cluster) and stores every edge
//! node's device values in one historian ([`hart_history`], SQLite or PostgreSQL), so
//! that the history of many gateways lives in one place and survives the loss of any
//! of them.
//!
//! The protocol logic is the sans-IO [`decoder::Decoder`]: topic, payload and time
//! in, samples and rebirth requests out. [`run`] connects it to the broker with
//! `rumqttc` (QoS 1, persistent session, each message acknowledged once its samples
//! are committed). docs/history.md and docs/mqtt.md describe its use.

pub mod cli;
pub mod client;
pub mod decoder;

pub use client::{run, IngestConfig, Summary};
pub use decoder::{Counters, Decoder, Output, Publish, Rejected};

/// Why the ingest could not start.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Error {
    /// A setting is wrong (the message says which and how).
    Config(String),
    /// The historian could not be opened.
    History(hart_history::Error),
}

impl Error {
    /// The command line's exit code: 2 for settings, the historian's otherwise.
    pub fn exit_code(&self) -> u8 {
        match self {
            Error::Config(_) => 2,
            Error::History(e) => e.exit_code(),
        }
    }
}

impl std::fmt::Display for Error {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Error::Config(m) => f.write_str(m),
            Error::History(e) => write!(f, "history: {e}"),
        }
    }
}

impl std::error::Error for Error {}
