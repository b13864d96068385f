//! The historian's benchmark (`scripts/bench-history`): samples inserted through the
//! writer as the gateway feeds it, then a one-day query of one variable at 1 s
//! resolution, as `hartkit history query` runs it.

use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use crate::cli::{query_command, QueryArgs};
use crate::{DeviceKey, Error, Format, Sample, Var, Writer, WriterConfig};

/// What the benchmark does.
#[derive(Debug, Clone)]
pub struct BenchArgs {
    /// The database (a new SQLite file, or a PostgreSQL URL of an empty database).
    pub db: String,
    /// Devices.
    pub devices: usize,
    /// Seconds of data: each device gives its 7 variables once a second.
    pub seconds: u64,
    /// Query repetitions (the median is reported).
    pub repeat: usize,
}

/// The figures.
#[derive(Debug, Clone)]
pub struct BenchReport {
    /// Samples inserted.
    pub samples: u64,
    /// Wall time of the inserts, submission to the last commit.
    pub insert: Duration,
    /// Median time of one raw one-day query of one variable (open, query, format CSV).
    pub query: Duration,
    /// Rows the query gave.
    pub rows: usize,
    /// Median time of the same day in 1-minute means (`--every 1m --agg mean`).
    pub query_mean_1m: Duration,
}

impl BenchReport {
    /// Samples per second inserted.
    pub fn rate(&self) -> f64 {
        self.samples as f64 / self.insert.as_secs_f64()
    }
}

impl std::fmt::Display for BenchReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "insert: {} samples in {:.2} s = {:.0} samples/s\nquery one day raw: {} rows in {:.1} ms (median)\nquery one day --every 1m --agg mean: {:.1} ms (median)",
            self.samples,
            self.insert.as_secs_f64(),
            self.rate(),
            self.rows,
            self.query.as_secs_f64() * 1e3,
            self.query_mean_1m.as_secs_f64() * 1e3
        )
    }
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v.get(v.len() / 2).copied().unwrap_or_default()
}

/// Runs the benchmark.
pub fn run(a: &BenchArgs) -> Result<BenchReport, Error> {
    let start = UNIX_EPOCH + Duration::from_secs(1_800_000_000 - 1_800_000_000 % 86_400);
    let keys: Vec<DeviceKey> = (0..a.devices)
        .map(|i| DeviceKey {
            unique_id: format!("26F1{:06X}", i + 1),
            tag: format!("PT-{:03}", i + 1),
            loop_name: "loop1".into(),
        })
        .collect();
    let writer = Writer::start(&a.db, WriterConfig::default())?;
    let t0 = Instant::now();
    let mut n = 0u64;
    for s in 0..a.seconds {
        let time = start + Duration::from_secs(s);
        for (i, k) in keys.iter().enumerate() {
            // One change of one device: its seven variables, as the feed gives them.
            let batch: Vec<Sample> = Var::ALL
                .iter()
                .map(|&var| Sample {
                    device: k.clone(),
                    var,
                    value: (s as f64 * 0.01 + i as f64).sin() * 100.0,
                    units: (var != Var::DeviceStatus).then_some(12),
                    quality: 0,
                    time,
                })
                .collect();
            n += batch.len() as u64;
            writer.submit_wait(batch);
        }
    }
    writer.flush()?;
    let insert = t0.elapsed();
    let stats = writer.close();
    if stats.written != n {
        return Err(Error::Database(format!(
            "the writer wrote {} of {n} samples (last error: {:?})",
            stats.written, stats.last_error
        )));
    }
    // The day queried is a past day, as a trend of yesterday is: on PostgreSQL that
    // is a vacuumed partition (the writer vacuums a day when the next begins, and
    // autovacuum would anyway); SQLite needs nothing.
    if let crate::Store::Postgres(mut pg) = crate::Store::open(&a.db, false)? {
        pg.vacuum()?;
    }
    let day_end = start + Duration::from_secs(a.seconds.min(86_400));
    let args = |every: Option<&str>| QueryArgs {
        db: a.db.clone(),
        device: keys[0].tag.clone(),
        var: "pv".into(),
        from: crate::output::rfc3339(start),
        to: crate::output::rfc3339(day_end),
        every: every.map(str::to_string),
        agg: "mean".into(),
        format: Format::Csv,
    };
    let mut times = vec![];
    let mut rows = 0;
    for _ in 0..a.repeat.max(1) {
        let t = Instant::now();
        let out =
            query_command(&args(None), SystemTime::now()).map_err(|(e, _)| Error::Database(e))?;
        times.push(t.elapsed());
        rows = out.lines().count().saturating_sub(1);
    }
    let mut times_1m = vec![];
    for _ in 0..a.repeat.max(1) {
        let t = Instant::now();
        query_command(&args(Some("1m")), SystemTime::now()).map_err(|(e, _)| Error::Database(e))?;
        times_1m.push(t.elapsed());
    }
    Ok(BenchReport {
        samples: n,
        insert,
        query: median(times),
        rows,
        query_mean_1m: median(times_1m),
    })
}
