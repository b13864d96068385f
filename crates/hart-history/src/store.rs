//! The storage: one API over SQLite and PostgreSQL, with the same schema and queries
//! (what both share is in `backend`).

use std::time::{Duration, Instant, SystemTime};

use crate::backend::{DeviceSummary, Point, Query, RetentionOutcome};
use crate::postgres_store::PgStore;
use crate::sqlite_store::SqliteStore;
use crate::{Error, Sample};

/// Which backend a database address names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StoreKind {
    /// An SQLite file.
    Sqlite,
    /// A PostgreSQL server (`postgres://` or `postgresql://`).
    Postgres,
}

impl StoreKind {
    /// `db` for a log line: a PostgreSQL URL without its password.
    pub fn name_of(self, db: &str) -> String {
        match self {
            StoreKind::Sqlite => db.to_string(),
            StoreKind::Postgres => crate::postgres_store::redact(db),
        }
    }

    /// The backend of `db`: a `postgres://` or `postgresql://` URL, else a file path.
    pub fn of(db: &str) -> StoreKind {
        let l = db.trim_start().to_ascii_lowercase();
        if l.starts_with("postgres://") || l.starts_with("postgresql://") {
            StoreKind::Postgres
        } else {
            StoreKind::Sqlite
        }
    }
}

/// A historian database: SQLite or PostgreSQL, the same schema and queries.
pub enum Store {
    /// An SQLite file in WAL mode.
    Sqlite(Box<SqliteStore>),
    /// A PostgreSQL database with a table partitioned by day.
    Postgres(Box<PgStore>),
}

impl Store {
    /// Opens (and creates, with `create`) the database `db`: a `postgres://` /
    /// `postgresql://` URL or an SQLite file path. Creates or checks the schema.
    pub fn open(db: &str, create: bool) -> Result<Store, Error> {
        match StoreKind::of(db) {
            StoreKind::Postgres => PgStore::open(db, create).map(|s| Store::Postgres(Box::new(s))),
            StoreKind::Sqlite => SqliteStore::open(std::path::Path::new(db), create)
                .map(|s| Store::Sqlite(Box::new(s))),
        }
    }

    /// Which backend this is.
    pub fn kind(&self) -> StoreKind {
        match self {
            Store::Sqlite(_) => StoreKind::Sqlite,
            Store::Postgres(_) => StoreKind::Postgres,
        }
    }

    /// Writes `samples` in one transaction: all or none. Samples of the same device,
    /// variable and time replace each other (the last one stays).
    pub fn insert(&mut self, samples: &[Sample]) -> Result<(), Error> {
        if samples.is_empty() {
            return Ok(());
        }
        match self {
            Store::Sqlite(s) => s.insert(samples),
            Store::Postgres(s) => s.insert(samples),
        }
    }

    /// Saves the Sparkplug births (NBIRTH, DBIRTH payloads by topic) an ingest has
    /// taken in, replacing those of the same topic: after a restart, the data the
    /// broker kept for it is read against them (its metrics carry aliases only).
    pub fn save_births(&mut self, births: &[(String, Vec<u8>)]) -> Result<(), Error> {
        if births.is_empty() {
            return Ok(());
        }
        match self {
            Store::Sqlite(s) => s.save_births(births),
            Store::Postgres(s) => s.save_births(births),
        }
    }

    /// The births saved by [`Store::save_births`], by topic.
    pub fn births(&mut self) -> Result<Vec<(String, Vec<u8>)>, Error> {
        match self {
            Store::Sqlite(s) => s.births(),
            Store::Postgres(s) => s.births(),
        }
    }

    /// Every stored device with its first and last sample times and sample count.
    pub fn devices(&mut self) -> Result<Vec<DeviceSummary>, Error> {
        match self {
            Store::Sqlite(s) => s.devices(),
            Store::Postgres(s) => s.devices(),
        }
    }

    /// One variable of one device over a time range, raw or aggregated in buckets.
    pub fn query(&mut self, q: &Query) -> Result<Vec<Point>, Error> {
        match self {
            Store::Sqlite(s) => s.query(q),
            Store::Postgres(s) => s.query(q),
        }
    }

    /// Deletes samples older than `now - age` and, for SQLite, the oldest days while
    /// the data take more than `max_size` bytes; works for about `budget` at most and
    /// says whether it finished.
    pub fn retention(
        &mut self,
        now: SystemTime,
        age: Option<Duration>,
        max_size: Option<u64>,
        budget: Duration,
    ) -> Result<RetentionOutcome, Error> {
        let deadline = Instant::now() + budget;
        let cutoff = age.and_then(|a| now.checked_sub(a)).map(crate::micros);
        match self {
            Store::Sqlite(s) => s.retention(cutoff, max_size, deadline),
            Store::Postgres(s) => s.retention(cutoff, deadline),
        }
    }

    /// Opens the connection again (after the server went away or the file was
    /// replaced).
    pub fn reconnect(&mut self) -> Result<(), Error> {
        match self {
            Store::Sqlite(s) => s.reconnect(),
            Store::Postgres(s) => s.reconnect(),
        }
    }

    /// SQLite: what happened to the file (or its write-ahead log) if it is no longer
    /// the one open ("was removed", "was replaced by another file"); `None` while it
    /// is, and always for PostgreSQL.
    pub fn file_lost(&mut self) -> Option<String> {
        match self {
            Store::Sqlite(s) => s.file_lost(),
            Store::Postgres(_) => None,
        }
    }

    /// SQLite: lets go of a file found lost ([`SqliteStore::release`]); nothing for
    /// PostgreSQL.
    pub fn release(&mut self) {
        if let Store::Sqlite(s) = self {
            s.release();
        }
    }

    /// The database's address as given (a PostgreSQL URL without its password).
    pub fn describe(&self) -> String {
        match self {
            Store::Sqlite(s) => s.path().display().to_string(),
            Store::Postgres(s) => s.describe(),
        }
    }
}
