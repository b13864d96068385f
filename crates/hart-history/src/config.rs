//! The `[history]` section of the gateway's configuration file.

use std::time::Duration;

use serde::Deserialize;

use crate::Error;

/// The `[history]` section of the gateway's TOML file; `hartkit serve --history DB`
/// is a shortcut for `db` with the other fields at their defaults.
///
/// ```toml
/// [history]
/// db = "/var/lib/hartkit/history.sqlite"   # or "postgres://user@host/db"
/// batch = "1s"            # one transaction per batch: at most this is lost on a crash
/// sample_period = "10s"   # every device's values at this period, besides every change
/// retention = "30d"       # delete samples older than this (default: keep all)
/// max_size = "1GB"        # SQLite only: delete the oldest days beyond this size
/// ```
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HistoryConfig {
    /// An SQLite file path, or a `postgres://` / `postgresql://` URL.
    pub db: String,
    /// How often the writer commits a batch (default 1 s): a crash (kill -9, power
    /// cut aside) loses at most the samples of the last batch.
    #[serde(with = "humantime_serde", default = "default_batch")]
    pub batch: Duration,
    /// A sample of every device's values at this period, besides every change
    /// (default 10 s).
    #[serde(with = "humantime_serde", default = "default_sample_period")]
    pub sample_period: Duration,
    /// Samples older than this are deleted (default: kept for ever).
    #[serde(with = "humantime_serde", default)]
    pub retention: Option<Duration>,
    /// SQLite only: beyond this size of data ("1GB", "500MB", "2GiB" or bytes), the
    /// oldest days are deleted.
    #[serde(default, deserialize_with = "de_size")]
    pub max_size: Option<u64>,
    /// A batch is committed early when it reaches this many samples (default 10 000).
    #[serde(default = "default_max_batch")]
    pub max_batch: usize,
    /// Samples kept in memory while the database cannot be written (default
    /// 1 000 000); beyond it the oldest are dropped, counted and logged.
    #[serde(default = "default_backlog")]
    pub backlog: usize,
    /// SQLite only: what the writer does when its file is removed or replaced under
    /// it (`"reopen"`, the default: a new file at the path; `"stop"`: history
    /// stops, with an error).
    #[serde(default)]
    pub on_file_lost: FileLost,
}

/// What the writer does when its SQLite file (or its write-ahead log) is removed or
/// replaced while it writes: whatever it commits then goes to a file no one can
/// open any more.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum FileLost {
    /// Create a new file at the path and write on there (logged as an error).
    #[default]
    Reopen,
    /// Stop writing: every later sample is dropped and counted, the error stays in
    /// the writer's status until the gateway is restarted.
    Stop,
}

fn default_batch() -> Duration {
    Duration::from_secs(1)
}
fn default_sample_period() -> Duration {
    Duration::from_secs(10)
}
fn default_max_batch() -> usize {
    10_000
}
fn default_backlog() -> usize {
    1_000_000
}

fn de_size<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<u64>, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Raw {
        Bytes(u64),
        Text(String),
    }
    match Option::<Raw>::deserialize(d)? {
        None => Ok(None),
        Some(Raw::Bytes(b)) => Ok(Some(b)),
        Some(Raw::Text(s)) => parse_size(&s).map(Some).map_err(serde::de::Error::custom),
    }
}

impl HistoryConfig {
    /// The defaults with this database (what `--history DB` gives).
    pub fn with_db(db: impl Into<String>) -> Self {
        HistoryConfig {
            db: db.into(),
            batch: default_batch(),
            sample_period: default_sample_period(),
            retention: None,
            max_size: None,
            max_batch: default_max_batch(),
            backlog: default_backlog(),
            on_file_lost: FileLost::default(),
        }
    }

    /// Checks the values that serde cannot: periods not zero, sizes not zero.
    pub fn validate(&self) -> Result<(), Error> {
        if self.db.trim().is_empty() {
            return Err(Error::Usage(
                "[history] db is empty: give an SQLite file path or a postgres:// URL".into(),
            ));
        }
        if self.batch.is_zero() || self.sample_period.is_zero() {
            return Err(Error::Usage(
                "[history] batch and sample_period must be longer than 0 s".into(),
            ));
        }
        if self.max_batch == 0 || self.backlog == 0 {
            return Err(Error::Usage(
                "[history] max_batch and backlog must be at least 1".into(),
            ));
        }
        if self.retention.is_some_and(|r| r.is_zero()) {
            return Err(Error::Usage(
                "[history] retention must be longer than 0 s (leave it out to keep everything)"
                    .into(),
            ));
        }
        Ok(())
    }
}

/// Parses a size: bytes (`1000000`), or a number with B, kB/KB, MB, GB, TB (powers of
/// 1000) or KiB, MiB, GiB, TiB (powers of 1024), e.g. `1GB`, `500MB`, `1.5 GiB`.
pub fn parse_size(s: &str) -> Result<u64, Error> {
    let t = s.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    let bad = || {
        Error::Usage(format!(
            "size '{s}': use bytes or a number with kB, MB, GB, TB (or KiB, MiB, GiB, TiB), e.g. 1GB"
        ))
    };
    let n: f64 = num.parse().map_err(|_| bad())?;
    let mult: f64 = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1.0,
        "k" | "kb" => 1e3,
        "m" | "mb" => 1e6,
        "g" | "gb" => 1e9,
        "t" | "tb" => 1e12,
        "kib" => 1024.0,
        "mib" => 1024.0 * 1024.0,
        "gib" => 1024.0 * 1024.0 * 1024.0,
        "tib" => 1024.0 * 1024.0 * 1024.0 * 1024.0,
        _ => return Err(bad()),
    };
    let b = n * mult;
    if !b.is_finite() || !(1.0..1.8e19).contains(&b) {
        return Err(bad());
    }
    Ok(b as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes() {
        assert_eq!(parse_size("1GB").unwrap(), 1_000_000_000);
        assert_eq!(parse_size("500 MB").unwrap(), 500_000_000);
        assert_eq!(parse_size("2GiB").unwrap(), 2 << 30);
        assert_eq!(parse_size("1.5kB").unwrap(), 1500);
        assert_eq!(parse_size("4096").unwrap(), 4096);
        for bad in ["", "GB", "1XB", "-1GB", "0", "1e400GB"] {
            assert!(parse_size(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn toml_section() {
        #[derive(Deserialize)]
        struct File {
            history: HistoryConfig,
        }
        let f: File = toml::from_str(
            "[history]\ndb = \"h.sqlite\"\nretention = \"30d\"\nmax_size = \"1GB\"\n",
        )
        .unwrap();
        let h = f.history;
        assert_eq!(h.batch, Duration::from_secs(1));
        assert_eq!(h.sample_period, Duration::from_secs(10));
        assert_eq!(h.retention, Some(Duration::from_secs(30 * 86_400)));
        assert_eq!(h.max_size, Some(1_000_000_000));
        h.validate().unwrap();
        let e = toml::from_str::<File>("[history]\ndb = \"x\"\nbatchh = \"1s\"\n")
            .err()
            .unwrap();
        assert!(e.to_string().contains("batchh"), "{e}");
        let e = toml::from_str::<File>("[history]\ndb = \"x\"\nmax_size = \"lots\"\n")
            .err()
            .unwrap();
        assert!(e.to_string().contains("1GB"), "{e}");
    }
}
