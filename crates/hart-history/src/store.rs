//! The storage: one API over SQLite and PostgreSQL, with the same schema and queries.

use std::time::{Duration, Instant, SystemTime};

use crate::postgres_store::PgStore;
use crate::sqlite_store::SqliteStore;
use crate::{Error, Sample, Var};

/// The schema version this hartkit writes (table `schema_version`). A database with
/// a newer one is refused rather than written wrongly.
pub const SCHEMA_VERSION: i64 = 1;

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

/// How to aggregate the samples of a bucket.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Agg {
    /// The mean of the values.
    Mean,
    /// The smallest value.
    Min,
    /// The largest value.
    Max,
    /// The last value (the latest time in the bucket).
    Last,
}

impl std::str::FromStr for Agg {
    type Err = Error;
    fn from_str(s: &str) -> Result<Agg, Error> {
        match s.trim().to_ascii_lowercase().as_str() {
            "mean" | "avg" => Ok(Agg::Mean),
            "min" => Ok(Agg::Min),
            "max" => Ok(Agg::Max),
            "last" => Ok(Agg::Last),
            _ => Err(Error::Usage(format!(
                "--agg '{s}': use mean, min, max or last"
            ))),
        }
    }
}

impl Agg {
    /// The SQL of the value column of a bucket (`last` is read from the bucket's
    /// latest row instead).
    pub(crate) fn sql(self) -> &'static str {
        match self {
            Agg::Mean => "avg(value)",
            Agg::Min => "min(value)",
            Agg::Max => "max(value)",
            Agg::Last => "NULL",
        }
    }
}

/// A query of one variable of one device.
#[derive(Debug, Clone, PartialEq)]
pub struct Query {
    /// The device's tag (or long tag) or unique ID (hex, any case).
    pub device: String,
    /// The variable.
    pub var: Var,
    /// From this time (included).
    pub from: SystemTime,
    /// To this time (excluded).
    pub to: SystemTime,
    /// Bucket width; `None` gives every stored sample.
    pub every: Option<Duration>,
    /// How a bucket's samples become one value.
    pub agg: Agg,
}

/// One row of a query's answer: a sample, or a bucket (its start time; the units of
/// its last sample; the worst, i.e. highest, quality code of its samples).
#[derive(Debug, Clone, PartialEq)]
pub struct Point {
    /// The sample's time, or the bucket's start.
    pub time: SystemTime,
    /// The value; `None` when the device reported none (NaN).
    pub value: Option<f64>,
    /// HART units code.
    pub units: Option<u8>,
    /// Quality code (0 good).
    pub quality: u8,
}

/// A stored device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceSummary {
    /// Unique ID (10 hex digits).
    pub unique_id: String,
    /// Tag (the latest one seen).
    pub tag: String,
    /// Loop name (the latest one seen).
    pub loop_name: String,
    /// Time of its oldest sample.
    pub first: Option<SystemTime>,
    /// Time of its newest sample.
    pub last: Option<SystemTime>,
    /// How many samples are stored.
    pub samples: u64,
}

/// What a retention step did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RetentionOutcome {
    /// Samples (or, for PostgreSQL's dropped days, rows) deleted.
    pub deleted: u64,
    /// Everything due was deleted; `false` when the step ran out of its time budget.
    pub done: bool,
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

/// The samples of a batch with the same device, variable and time reduced to the last
/// one (PostgreSQL refuses to update a row twice in one statement).
pub(crate) fn dedup_batch(samples: &[Sample]) -> Vec<&Sample> {
    let mut seen = std::collections::HashSet::with_capacity(samples.len());
    let mut out: Vec<&Sample> = samples
        .iter()
        .rev()
        .filter(|s| seen.insert((&s.device.unique_id, s.var, crate::micros(s.time))))
        .collect();
    out.reverse();
    out
}

/// The SQL of a query, with `$1`..`$6` for device id, var, from, to, bucket width
/// (aggregated only). SQLite reads them as `?1`..`?6`.
pub(crate) fn query_sql(q: &Query) -> String {
    let range = "device = $1 AND var = $2 AND time >= $3 AND time < $4";
    match q.every {
        None => {
            format!("SELECT time, value, units, quality FROM samples WHERE {range} ORDER BY time")
        }
        // One pass groups the range into buckets (value, latest time, worst quality);
        // the latest row of each bucket (its units, and its value for `last`) is then
        // one primary-key look-up per bucket.
        Some(_) => {
            let value = match q.agg {
                Agg::Last => "s.value",
                _ => "b.v",
            };
            format!(
                "SELECT b.bucket, {value}, s.units, b.q FROM \
                   (SELECT time - (((time % $5) + $5) % $5) AS bucket, {agg} AS v, max(time) AS t, max(quality) AS q \
                    FROM samples WHERE {range} GROUP BY bucket) b \
                 JOIN samples s ON s.device = $1 AND s.var = $2 AND s.time = b.t \
                 ORDER BY b.bucket",
                agg = q.agg.sql()
            )
        }
    }
}

/// The message for a tag or unique ID that names no device, or several.
pub(crate) fn resolve_device(
    wanted: &str,
    db: &str,
    found: Vec<(i64, String, String, String)>,
) -> Result<i64, Error> {
    match found.len() {
        0 => Err(Error::NoSuchDevice(format!(
            "no device with tag or unique ID '{wanted}' in {db}; `hartkit history devices --db {db}` lists the stored ones"
        ))),
        1 => Ok(found[0].0),
        _ => {
            // A unique ID match wins over tags.
            let id_match: Vec<_> = found
                .iter()
                .filter(|d| d.1.eq_ignore_ascii_case(wanted.trim()))
                .collect();
            if id_match.len() == 1 {
                return Ok(id_match[0].0);
            }
            Err(Error::NoSuchDevice(format!(
                "'{wanted}' names {} devices in {db} ({}): give the unique ID instead",
                found.len(),
                found
                    .iter()
                    .map(|d| format!("{} on {}", d.1, d.3))
                    .collect::<Vec<_>>()
                    .join(", ")
            )))
        }
    }
}
