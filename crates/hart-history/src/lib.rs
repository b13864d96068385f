//! # hart-history
//!
//! The historian's store, without the polling engine (hart-recorder feeds it the
//! engine's image changes, hart-ingest the Sparkplug B data of many gateways): a
//! [`Sample`] is one device
//! (unique ID, tag, loop), one variable (PV, SV, TV, QV, loop current, percent of
//! range, device status), a value, its units code, the image's quality and the time.
//! A [`Writer`] thread stores them in batches (one transaction per batch, every
//! second by default) in a [`Store`]: SQLite in WAL mode (embedded, the default) or
//! PostgreSQL (a table partitioned by day). The same schema and the same queries serve
//! both: [`Store::devices`] lists what is stored and [`Store::query`] reads one
//! variable of one device over a time range, raw or aggregated in SQL into buckets.
//!
//! Faults of the database (locked, full disk, corrupt file, a server gone away) never
//! stop the caller: the writer logs one line saying what failed and what to check,
//! keeps the samples in a bounded backlog in memory and retries with backoff.
//!
//! See docs/history.md for the schema, crash safety, retention and the queries.

mod backend;
mod config;
mod error;
mod output;
mod postgres_store;
mod readers;
mod sample;
mod sqlite_store;
mod store;
mod when;
mod writer;

pub mod bench;
pub mod cli;
#[doc(hidden)]
pub mod pgtest;

pub use backend::{Agg, DeviceSummary, Point, Query, SCHEMA_VERSION};
pub use config::{parse_size, FileLost, HistoryConfig};
pub use error::Error;
pub use output::{format_devices, format_points, quality_name, Format};
pub use postgres_store::PgStore;
pub use readers::{Readers, DEFAULT_READERS};
pub use sample::{
    from_micros, micros, widen, DeviceKey, Sample, Var, UNITS_MILLIAMPERES, UNITS_PERCENT,
};
pub use sqlite_store::SqliteStore;
pub use store::{Store, StoreKind};
pub use when::{bucket_start, parse_every, parse_time};
pub use writer::{Stats, Writer, WriterConfig};
