//! The server backend: PostgreSQL, samples in a table partitioned by day.

use std::collections::{HashMap, HashSet};
use std::time::{Duration, Instant};

use postgres::error::SqlState;
use postgres::{Client, Config, NoTls};

use crate::backend::{dedup_batch, query_sql, resolve_device, RetentionOutcome};
use crate::{from_micros, micros, DeviceSummary, Error, Point, Query, Sample, SCHEMA_VERSION};

const DAY_US: i64 = 86_400_000_000;

const SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS schema_version (version integer NOT NULL);
CREATE TABLE IF NOT EXISTS devices (
    id        serial PRIMARY KEY,
    unique_id text NOT NULL UNIQUE,
    tag       text NOT NULL,
    loop      text NOT NULL
);
CREATE TABLE IF NOT EXISTS samples (
    device  integer NOT NULL,
    var     smallint NOT NULL,
    time    bigint NOT NULL,
    value   double precision,
    units   smallint,
    quality smallint NOT NULL,
    PRIMARY KEY (device, var, time) INCLUDE (value, units, quality)
) PARTITION BY RANGE (time);
";

/// The ingest's saved Sparkplug births (made when first used).
const BIRTHS_TABLE: &str =
    "CREATE TABLE IF NOT EXISTS ingest_births (topic text PRIMARY KEY, payload bytea NOT NULL)";

/// A PostgreSQL historian database.
pub struct PgStore {
    config: Config,
    url_shown: String,
    client: Client,
    ids: HashMap<String, (i32, String, String)>,
    /// Days (since 1970) whose partition exists.
    days: HashSet<i64>,
}

/// The URL without its password, for messages.
pub(crate) fn redact(url: &str) -> String {
    // postgres://user:password@host/db -> postgres://user:***@host/db
    if let Some(scheme_end) = url.find("://") {
        let rest = &url[scheme_end + 3..];
        if let Some(at) = rest.find('@') {
            let userinfo = &rest[..at];
            if let Some(colon) = userinfo.find(':') {
                return format!(
                    "{}{}:***{}",
                    &url[..scheme_end + 3],
                    &userinfo[..colon],
                    &rest[at..]
                );
            }
        }
    }
    url.to_string()
}

/// A client error as a historian error about `db`.
pub(crate) fn pg_error(db: &str, e: postgres::Error) -> Error {
    // The client's own text of a server error is only "db error": say the server's.
    let text = match e.as_db_error() {
        Some(d) => format!("{}: {}", d.severity(), d.message()),
        None => {
            let mut s = e.to_string();
            let mut src = std::error::Error::source(&e);
            while let Some(x) = src {
                s.push_str(&format!(": {x}"));
                src = x.source();
            }
            s
        }
    };
    if let Some(code) = e.code() {
        if *code == SqlState::DISK_FULL || *code == SqlState::OUT_OF_MEMORY {
            return Error::Full(format!(
                "history database {db}: the server's disk is full ({text}); free space on the server or lower [history] retention"
            ));
        }
        if *code == SqlState::ADMIN_SHUTDOWN
            || *code == SqlState::CRASH_SHUTDOWN
            || *code == SqlState::CANNOT_CONNECT_NOW
            || code.code().starts_with("08")
        {
            return Error::Gone(format!(
                "history database {db}: the server went away ({text}); check that PostgreSQL runs and is reachable"
            ));
        }
        if *code == SqlState::INVALID_PASSWORD
            || *code == SqlState::INVALID_AUTHORIZATION_SPECIFICATION
            || *code == SqlState::INVALID_CATALOG_NAME
            || *code == SqlState::INSUFFICIENT_PRIVILEGE
        {
            return Error::Io(format!(
                "history database {db}: refused ({text}); check the user, password and database name, and that the user may create tables"
            ));
        }
        if *code == SqlState::LOCK_NOT_AVAILABLE || *code == SqlState::T_R_DEADLOCK_DETECTED {
            return Error::Locked(format!("history database {db}: {text}; retrying"));
        }
        return Error::Database(format!("history database {db}: {text}"));
    }
    if e.is_closed() || e.as_db_error().is_none() {
        return Error::Gone(format!(
            "history database {db}: no connection ({text}); check that PostgreSQL runs, listens at that address and lets this host in (pg_hba.conf)"
        ));
    }
    Error::Database(format!("history database {db}: {text}"))
}

/// `YYYYMMDD` of day `day` since 1970 (UTC).
fn day_name(day: i64) -> String {
    let t = from_micros(day * DAY_US);
    let s = humantime::format_rfc3339_seconds(t).to_string();
    s.get(0..10).unwrap_or("0000-00-00").replace('-', "")
}

/// The longest a statement of the historian may run on the server (a batch insert,
/// a query, a day's drop) before the server ends it: a blocked server or a lock held
/// elsewhere then fails the batch (retried) instead of holding the writer.
pub const STATEMENT_TIMEOUT: Duration = Duration::from_secs(60);

impl PgStore {
    /// Connects to `url` (5 s connect timeout unless the URL sets one) and creates or
    /// checks the schema.
    pub fn open(url: &str, create: bool) -> Result<PgStore, Error> {
        let shown = redact(url);
        let mut config: Config = url.parse().map_err(|e| {
            Error::Usage(format!(
                "--history {shown}: not a PostgreSQL URL ({e}); use postgres://USER[:PASSWORD]@HOST[:PORT]/DATABASE"
            ))
        })?;
        if config.get_connect_timeout().is_none() {
            config.connect_timeout(Duration::from_secs(5));
        }
        // A partitioned server is noticed, not waited on for ever: TCP keep-alives
        // (idle 30 s, the kernel's probes after), and a statement that runs longer than
        // STATEMENT_TIMEOUT is ended by the server (the URL's own options win).
        config.keepalives(true);
        config.keepalives_idle(Duration::from_secs(30));
        if config.get_options().is_none() {
            config.options(&format!(
                "-c statement_timeout={}",
                STATEMENT_TIMEOUT.as_millis()
            ));
        }
        let client = config.connect(NoTls).map_err(|e| pg_error(&shown, e))?;
        let mut s = PgStore {
            config,
            url_shown: shown,
            client,
            ids: HashMap::new(),
            days: HashSet::new(),
        };
        s.migrate(create)?;
        Ok(s)
    }

    /// Creates the tables (with `create`) and checks the schema version.
    fn migrate(&mut self, create: bool) -> Result<(), Error> {
        let shown = self.url_shown.clone();
        let e = |e| pg_error(&shown, e);
        if !create {
            let n: i64 = self
                .client
                .query_one(
                    "SELECT count(*) FROM pg_tables WHERE tablename IN ('schema_version', 'devices', 'samples') AND schemaname = ANY (current_schemas(false))",
                    &[],
                )
                .map_err(e)?
                .get(0);
            if n != 3 {
                return Err(Error::Schema(format!(
                    "{shown} holds no hartkit history (no schema_version, devices and samples tables); check the database name"
                )));
            }
            let v: Option<i32> = self
                .client
                .query_one("SELECT max(version) FROM schema_version", &[])
                .map_err(e)?
                .get(0);
            return match v {
                Some(v) if i64::from(v) > SCHEMA_VERSION => Err(Error::Schema(format!(
                    "history database {shown} has schema version {v}, newer than this hartkit's {SCHEMA_VERSION}; use a newer hartkit"
                ))),
                _ => Ok(()),
            };
        }
        let mut tx = self.client.transaction().map_err(e)?;
        // One creator at a time (two gateways starting together).
        tx.execute("SELECT pg_advisory_xact_lock(7236551)", &[])
            .map_err(e)?;
        tx.batch_execute(SCHEMA).map_err(e)?;
        let v: Option<i32> = tx
            .query_one("SELECT max(version) FROM schema_version", &[])
            .map_err(e)?
            .get(0);
        match v {
            None => {
                tx.execute(
                    "INSERT INTO schema_version (version) VALUES ($1)",
                    &[&(SCHEMA_VERSION as i32)],
                )
                .map_err(e)?;
            }
            Some(v) if i64::from(v) > SCHEMA_VERSION => {
                return Err(Error::Schema(format!(
                    "history database {shown} has schema version {v}, newer than this hartkit's {SCHEMA_VERSION}; use a newer hartkit or another database"
                )))
            }
            Some(_) => {}
        }
        tx.commit().map_err(e)
    }

    /// The URL without its password.
    pub fn describe(&self) -> String {
        self.url_shown.clone()
    }

    /// Connects again.
    pub fn reconnect(&mut self) -> Result<(), Error> {
        self.ids.clear();
        self.days.clear();
        self.client = self
            .config
            .connect(NoTls)
            .map_err(|e| pg_error(&self.url_shown, e))?;
        self.migrate(true)
    }

    /// Writes a batch in one transaction: the partitions of its days, its devices,
    /// then every sample in one multi-row statement (`unnest` of arrays).
    pub fn insert(&mut self, samples: &[Sample]) -> Result<(), Error> {
        let r = self.insert_inner(samples);
        if r.is_err() {
            self.ids.clear();
            self.days.clear();
        }
        r.map_err(|e| pg_error(&self.url_shown, e))
    }

    fn insert_inner(&mut self, samples: &[Sample]) -> Result<(), postgres::Error> {
        let batch = dedup_batch(samples);
        let mut tx = self.client.transaction()?;
        let mut new_days = vec![];
        for s in &batch {
            let day = micros(s.time).div_euclid(DAY_US);
            if !self.days.contains(&day) && !new_days.contains(&day) {
                new_days.push(day);
            }
        }
        for &day in &new_days {
            tx.batch_execute(&format!(
                "CREATE TABLE IF NOT EXISTS samples_{} PARTITION OF samples FOR VALUES FROM ({}) TO ({})",
                day_name(day),
                day * DAY_US,
                (day + 1) * DAY_US
            ))?;
        }
        let mut fresh = vec![];
        let mut dev_ids = Vec::with_capacity(batch.len());
        for s in &batch {
            let k = &s.device;
            let id = match self.ids.get(&k.unique_id) {
                Some((id, tag, lp)) if *tag == k.tag && *lp == k.loop_name => *id,
                _ => {
                    let id: i32 = tx
                        .query_one(
                            "INSERT INTO devices (unique_id, tag, loop) VALUES ($1, $2, $3) \
                             ON CONFLICT (unique_id) DO UPDATE SET tag = EXCLUDED.tag, loop = EXCLUDED.loop \
                             RETURNING id",
                            &[&k.unique_id, &k.tag, &k.loop_name],
                        )?
                        .get(0);
                    self.ids.insert(
                        k.unique_id.clone(),
                        (id, k.tag.clone(), k.loop_name.clone()),
                    );
                    fresh.push(k.unique_id.clone());
                    id
                }
            };
            dev_ids.push(id);
        }
        let vars: Vec<i16> = batch.iter().map(|s| s.var.code()).collect();
        let times: Vec<i64> = batch.iter().map(|s| micros(s.time)).collect();
        let values: Vec<Option<f64>> = batch
            .iter()
            .map(|s| (!s.value.is_nan()).then_some(s.value))
            .collect();
        let units: Vec<Option<i16>> = batch.iter().map(|s| s.units.map(i16::from)).collect();
        let quality: Vec<i16> = batch.iter().map(|s| i16::from(s.quality)).collect();
        tx.execute(
            "INSERT INTO samples (device, var, time, value, units, quality) \
             SELECT * FROM unnest($1::int4[], $2::int2[], $3::int8[], $4::float8[], $5::int2[], $6::int2[]) \
             ON CONFLICT (device, var, time) DO UPDATE \
             SET value = EXCLUDED.value, units = EXCLUDED.units, quality = EXCLUDED.quality",
            &[&dev_ids, &vars, &times, &values, &units, &quality],
        )?;
        tx.commit()?;
        // A day that is over is read, not written: vacuumed once, its partition is
        // all-visible and a query of it is an index-only scan of the primary key, which
        // carries the values (15 ms for a day of one variable instead of 50).
        for &day in &new_days {
            if self.days.contains(&(day - 1)) {
                let t0 = Instant::now();
                match self
                    .client
                    .batch_execute(&format!("VACUUM (ANALYZE) samples_{}", day_name(day - 1)))
                {
                    Ok(()) => tracing::info!(
                        "history: the day {} is closed: vacuumed in {} ms",
                        day_name(day - 1),
                        t0.elapsed().as_millis()
                    ),
                    Err(e) => tracing::warn!(
                        "history: could not vacuum the day {} that is over ({e}); queries of it are slower until autovacuum does",
                        day_name(day - 1)
                    ),
                }
            }
        }
        self.days.extend(new_days);
        Ok(())
    }

    /// What autovacuum does in the background, now: every partition vacuumed and
    /// analysed, so queries of the data stored so far are index-only scans (the
    /// benchmark's "a past day").
    pub fn vacuum(&mut self) -> Result<(), Error> {
        let shown = self.url_shown.clone();
        self.client
            .batch_execute("VACUUM (ANALYZE) samples")
            .map_err(|e| pg_error(&shown, e))
    }

    /// Every device with its sample times and count.
    /// Saves Sparkplug births by topic (the ingest's, [`crate::Store::save_births`]).
    pub fn save_births(&mut self, births: &[(String, Vec<u8>)]) -> Result<(), Error> {
        let shown = self.url_shown.clone();
        let e = |e| pg_error(&shown, e);
        let mut tx = self.client.transaction().map_err(e)?;
        tx.batch_execute(BIRTHS_TABLE).map_err(e)?;
        for (topic, payload) in births {
            tx.execute(
                "INSERT INTO ingest_births (topic, payload) VALUES ($1, $2) \
                 ON CONFLICT (topic) DO UPDATE SET payload = EXCLUDED.payload",
                &[topic, payload],
            )
            .map_err(e)?;
        }
        tx.commit().map_err(e)
    }

    /// The saved births, by topic.
    pub fn births(&mut self) -> Result<Vec<(String, Vec<u8>)>, Error> {
        let shown = self.url_shown.clone();
        let e = |e| pg_error(&shown, e);
        self.client.batch_execute(BIRTHS_TABLE).map_err(e)?;
        let rows = self
            .client
            .query(
                "SELECT topic, payload FROM ingest_births ORDER BY topic",
                &[],
            )
            .map_err(e)?;
        Ok(rows.iter().map(|r| (r.get(0), r.get(1))).collect())
    }

    pub fn devices(&mut self) -> Result<Vec<DeviceSummary>, Error> {
        let shown = self.url_shown.clone();
        let rows = self
            .client
            .query(
                "SELECT d.unique_id, d.tag, d.loop, min(s.time), max(s.time), count(s.time) \
                 FROM devices d LEFT JOIN samples s ON s.device = d.id \
                 GROUP BY d.id, d.unique_id, d.tag, d.loop ORDER BY d.loop, d.tag, d.unique_id",
                &[],
            )
            .map_err(|e| pg_error(&shown, e))?;
        Ok(rows
            .iter()
            .map(|r| DeviceSummary {
                unique_id: r.get(0),
                tag: r.get(1),
                loop_name: r.get(2),
                first: r.get::<_, Option<i64>>(3).map(from_micros),
                last: r.get::<_, Option<i64>>(4).map(from_micros),
                samples: r.get::<_, i64>(5).max(0) as u64,
            })
            .collect())
    }

    /// One variable of one device.
    pub fn query(&mut self, q: &Query) -> Result<Vec<Point>, Error> {
        let shown = self.url_shown.clone();
        let e = |e| pg_error(&shown, e);
        let wanted = q.device.trim();
        let found: Vec<(i64, String, String, String)> = self
            .client
            .query(
                "SELECT id, unique_id, tag, loop FROM devices WHERE upper(unique_id) = upper($1) OR tag = $1",
                &[&wanted],
            )
            .map_err(e)?
            .iter()
            .map(|r| (i64::from(r.get::<_, i32>(0)), r.get(1), r.get(2), r.get(3)))
            .collect();
        let id = resolve_device(wanted, &shown, found)? as i32;
        let (from, to) = (micros(q.from), micros(q.to));
        let var = q.var.code();
        let sql = query_sql(q);
        let rows = match q.every {
            None => self.client.query(&sql, &[&id, &var, &from, &to]),
            Some(every) => {
                let e = i64::try_from(every.as_micros()).unwrap_or(i64::MAX);
                self.client.query(&sql, &[&id, &var, &from, &to, &e])
            }
        }
        .map_err(e)?;
        Ok(rows
            .iter()
            .map(|r| Point {
                time: from_micros(r.get(0)),
                value: r.get::<_, Option<f64>>(1).filter(|v| !v.is_nan()),
                units: r
                    .get::<_, Option<i16>>(2)
                    .and_then(|u| u8::try_from(u).ok()),
                quality: u8::try_from(r.get::<_, i16>(3)).unwrap_or(u8::MAX),
            })
            .collect())
    }

    /// Retention by age: drops the partitions of whole days before `cutoff`, and
    /// deletes the rest of the cutoff's day.
    pub fn retention(
        &mut self,
        cutoff: Option<i64>,
        deadline: Instant,
    ) -> Result<RetentionOutcome, Error> {
        let mut out = RetentionOutcome::default();
        let Some(cutoff) = cutoff else {
            out.done = true;
            return Ok(out);
        };
        let shown = self.url_shown.clone();
        let e = |e| pg_error(&shown, e);
        let parts: Vec<String> = self
            .client
            .query(
                "SELECT c.relname::text FROM pg_inherits i \
                 JOIN pg_class c ON c.oid = i.inhrelid JOIN pg_class p ON p.oid = i.inhparent \
                 WHERE p.relname = 'samples' AND p.relnamespace = c.relnamespace \
                 AND pg_table_is_visible(p.oid) ORDER BY 1",
                &[],
            )
            .map_err(e)?
            .iter()
            .map(|r| r.get(0))
            .collect();
        let cutoff_day = day_name(cutoff.div_euclid(DAY_US));
        for p in parts {
            let Some(day) = p.strip_prefix("samples_") else {
                continue;
            };
            // Names sort as their days do (YYYYMMDD).
            if day.len() == 8
                && day.bytes().all(|b| b.is_ascii_digit())
                && *day < *cutoff_day.as_str()
            {
                self.client
                    .batch_execute(&format!("DROP TABLE IF EXISTS {p}"))
                    .map_err(e)?;
                self.days.clear();
                out.deleted += 1;
                if Instant::now() >= deadline {
                    return Ok(out);
                }
            }
        }
        let n = self
            .client
            .execute("DELETE FROM samples WHERE time < $1", &[&cutoff])
            .map_err(e)?;
        out.deleted += n;
        out.done = true;
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names() {
        assert_eq!(day_name(0), "19700101");
        assert_eq!(day_name(20_000), "20241004");
        assert_eq!(
            redact("postgres://me:secret@db:5432/h"),
            "postgres://me:***@db:5432/h"
        );
        assert_eq!(redact("postgres://db/h"), "postgres://db/h");
    }
}
