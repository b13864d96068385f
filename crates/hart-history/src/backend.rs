//! What the two back-ends share, and the [`Store`](crate::Store) over them answers in:
//! the schema version, a query and its answers, retention's outcome, and the SQL and
//! checks both run. Neither back-end nor the store is used here, so the uses between
//! these files point one way: store -> back-ends -> this.

use std::time::{Duration, SystemTime};

use crate::{Error, Sample, Var};

/// The schema version this hartkit writes (table `schema_version`). A database with
/// a newer one is refused rather than written wrongly.
pub const SCHEMA_VERSION: i64 = 1;

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
