//! The library side of `hartkit history query` and `hartkit history devices`: the
//! command line only parses its options into these.

use std::time::SystemTime;

use crate::{
    format_devices, format_points, parse_every, parse_time, Agg, Error, Format, Query, Store, Var,
};

/// Options of `hartkit history query`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct QueryArgs {
    /// The database: an SQLite file or a `postgres://` URL.
    pub db: String,
    /// The device's tag or unique ID.
    pub device: String,
    /// The variable's name (`pv`, `sv`, `tv`, `qv`, `loop_current`, `percent_range`,
    /// `device_status`).
    pub var: String,
    /// From (RFC 3339, `now`, or `-1h` style).
    pub from: String,
    /// To (excluded).
    pub to: String,
    /// Bucket width, e.g. `1m`.
    pub every: Option<String>,
    /// `mean`, `min`, `max` or `last` (with `every`).
    pub agg: String,
    /// Output format.
    pub format: Format,
}

/// Parses the options into a [`Query`], with relative times counted from `now`.
pub fn parse_query(a: &QueryArgs, now: SystemTime) -> Result<Query, Error> {
    let var: Var = a.var.parse()?;
    let from = parse_time(&a.from, now).map_err(|e| Error::Usage(format!("--from {e}")))?;
    let to = parse_time(&a.to, now).map_err(|e| Error::Usage(format!("--to {e}")))?;
    if from >= to {
        return Err(Error::Usage(format!(
            "--from {} is not before --to {}: the range is empty",
            a.from, a.to
        )));
    }
    let every = a.every.as_deref().map(parse_every).transpose()?;
    let agg: Agg = a.agg.parse()?;
    Ok(Query {
        device: a.device.clone(),
        var,
        from,
        to,
        every,
        agg,
    })
}

/// `hartkit history query`: the rows, formatted; errors with exit code 2 (usage,
/// unknown device) or 5 (database).
pub fn query_command(a: &QueryArgs, now: SystemTime) -> Result<String, (String, u8)> {
    let q = parse_query(a, now)?;
    let mut store = Store::open(&a.db, false)?;
    let points = store.query(&q)?;
    Ok(format_points(&points, a.format))
}

/// `hartkit history devices`: the stored devices, formatted.
pub fn devices_command(db: &str, format: Format) -> Result<String, (String, u8)> {
    let mut store = Store::open(db, false)?;
    Ok(format_devices(&store.devices()?, format))
}
