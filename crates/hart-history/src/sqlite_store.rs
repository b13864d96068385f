//! The embedded backend: one SQLite file in WAL mode.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use rusqlite::{params, Connection, ErrorCode, OpenFlags, OptionalExtension};

use crate::backend::{query_sql, resolve_device, RetentionOutcome};
use crate::{from_micros, micros, DeviceSummary, Error, Point, Query, Sample, SCHEMA_VERSION};

const DAY_US: i64 = 86_400_000_000;
/// Rows deleted per retention statement: small enough that a writer waiting for the
/// lock is not held up long.
const DELETE_CHUNK: i64 = 20_000;

const SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS schema_version (version INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS devices (
    id        INTEGER PRIMARY KEY,
    unique_id TEXT NOT NULL UNIQUE,
    tag       TEXT NOT NULL,
    loop      TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS samples (
    device  INTEGER NOT NULL REFERENCES devices(id),
    var     INTEGER NOT NULL,
    time    INTEGER NOT NULL,
    value   REAL,
    units   INTEGER,
    quality INTEGER NOT NULL,
    PRIMARY KEY (device, var, time)
) WITHOUT ROWID;
";

/// The ingest's saved Sparkplug births (made when first used).
const BIRTHS_TABLE: &str =
    "CREATE TABLE IF NOT EXISTS ingest_births (topic TEXT PRIMARY KEY, payload BLOB NOT NULL)";

/// An SQLite historian file.
pub struct SqliteStore {
    path: PathBuf,
    conn: Connection,
    /// Device ids by unique ID, with the tag and loop stored.
    ids: HashMap<String, (i64, String, String)>,
    /// The file opened and its write-ahead log, as (device, inode): a file removed or
    /// replaced under the connection is noticed ([`SqliteStore::file_lost`]).
    opened: Option<(u64, u64)>,
    wal: Option<(u64, u64)>,
    /// The connection was let go of ([`SqliteStore::release`]): every write fails
    /// (asking for a reconnection) until [`SqliteStore::reconnect`].
    released: bool,
}

/// The (device, inode) of `path`, if it exists.
fn identity(path: &Path) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(path).ok().map(|m| (m.dev(), m.ino()))
}

fn wal_path(path: &Path) -> PathBuf {
    let mut p = path.as_os_str().to_owned();
    p.push("-wal");
    PathBuf::from(p)
}

/// A rusqlite error as a historian error about `path`.
pub(crate) fn sqlite_error(path: &Path, e: rusqlite::Error) -> Error {
    let p = path.display();
    match e.sqlite_error_code() {
        Some(ErrorCode::DatabaseBusy | ErrorCode::DatabaseLocked) => Error::Locked(format!(
            "history database {p} is locked by another program ({e}); check for another process holding it (an sqlite3 shell, a backup, a second gateway)"
        )),
        Some(ErrorCode::DiskFull) => Error::Full(format!(
            "history database {p}: the disk is full ({e}); free space on its file system or lower [history] retention / max_size"
        )),
        Some(ErrorCode::NotADatabase | ErrorCode::DatabaseCorrupt) => Error::Corrupt(format!(
            "history database {p} is not an SQLite database or is damaged ({e}); move it aside (it is left as it is) and start with a new file, or check the path"
        )),
        Some(ErrorCode::ReadOnly) => Error::ReadOnly(format!(
            "history database {p} may not be written ({e}); check the permissions of the file, its -wal and -shm files and its folder"
        )),
        Some(ErrorCode::CannotOpen | ErrorCode::PermissionDenied | ErrorCode::SystemIoFailure) => Error::Io(format!(
            "history database {p} could not be opened or read ({e}); check that the path exists and may be read and written"
        )),
        _ => Error::Database(format!("history database {p}: {e}")),
    }
}

impl SqliteStore {
    /// Opens `path` (creating it with `create`), sets WAL mode and `synchronous =
    /// NORMAL`, and creates or checks the schema.
    pub fn open(path: &Path, create: bool) -> Result<SqliteStore, Error> {
        if !create && !path.exists() {
            return Err(Error::Io(format!(
                "history database {}: no such file; check the path (the gateway creates it with --history)",
                path.display()
            )));
        }
        let conn = Self::connect(path, create)?;
        let mut s = SqliteStore {
            path: path.to_path_buf(),
            conn,
            ids: HashMap::new(),
            opened: identity(path),
            wal: None,
            released: false,
        };
        s.migrate(create)?;
        s.wal = identity(&wal_path(path));
        Ok(s)
    }

    /// What happened to the file or its write-ahead log if either is no longer the
    /// one this connection has open: `None` while they are. (SQLite keeps writing to
    /// files unlinked under it, into space no one can open again.)
    pub fn file_lost(&mut self) -> Option<String> {
        let now = identity(&self.path);
        match (self.opened, now) {
            (Some(_), None) => return Some("was removed".into()),
            (Some(a), Some(b)) if a != b => return Some("was replaced by another file".into()),
            _ => {}
        }
        let wal = identity(&wal_path(&self.path));
        match (self.wal, wal) {
            (Some(_), None) => Some("lost its write-ahead log (-wal file removed)".into()),
            (Some(a), Some(b)) if a != b => {
                Some("had its write-ahead log (-wal file) replaced".into())
            }
            (None, Some(b)) => {
                // Created since the file was opened: the log this connection uses.
                self.wal = Some(b);
                None
            }
            _ => None,
        }
    }

    fn connect(path: &Path, create: bool) -> Result<Connection, Error> {
        let e = |e| sqlite_error(path, e);
        let mut flags = OpenFlags::SQLITE_OPEN_READ_WRITE | OpenFlags::SQLITE_OPEN_NO_MUTEX;
        if create {
            flags |= OpenFlags::SQLITE_OPEN_CREATE;
        }
        let conn = Connection::open_with_flags(path, flags).map_err(e)?;
        // Waits this long for another connection's lock before failing (the writer
        // then keeps its batch and tries again).
        conn.busy_timeout(std::time::Duration::from_millis(500))
            .map_err(e)?;
        let mode: String = conn
            .query_row("PRAGMA journal_mode = WAL", [], |r| r.get(0))
            .map_err(e)?;
        if !mode.eq_ignore_ascii_case("wal") {
            return Err(Error::Database(format!(
                "history database {}: WAL mode could not be set (journal mode stays {mode}); check that the file system supports shared memory (not a network share)",
                path.display()
            )));
        }
        conn.execute_batch(
            "PRAGMA synchronous = NORMAL; PRAGMA journal_size_limit = 67108864; PRAGMA foreign_keys = OFF;",
        )
        .map_err(e)?;
        conn.set_prepared_statement_cache_capacity(32);
        Ok(conn)
    }

    /// Creates the tables (with `create`) and checks the schema version.
    fn migrate(&mut self, create: bool) -> Result<(), Error> {
        let path = self.path.clone();
        let e = |e| sqlite_error(&path, e);
        let tx = self.conn.transaction().map_err(e)?;
        if create {
            tx.execute_batch(SCHEMA).map_err(e)?;
        } else {
            let n: i64 = tx
                .query_row(
                    "SELECT count(*) FROM sqlite_master WHERE type = 'table' AND name IN ('schema_version', 'devices', 'samples')",
                    [],
                    |r| r.get(0),
                )
                .map_err(e)?;
            if n != 3 {
                return Err(Error::Schema(format!(
                    "{} is an SQLite database but not a hartkit history (no schema_version, devices and samples tables); check the path",
                    path.display()
                )));
            }
        }
        let v: Option<i64> = tx
            .query_row("SELECT max(version) FROM schema_version", [], |r| r.get(0))
            .map_err(e)?;
        match v {
            None => {
                tx.execute(
                    "INSERT INTO schema_version (version) VALUES (?1)",
                    [SCHEMA_VERSION],
                )
                .map_err(e)?;
            }
            Some(v) if v > SCHEMA_VERSION => {
                return Err(Error::Schema(format!(
                    "history database {} has schema version {v}, newer than this hartkit's {SCHEMA_VERSION}; use a newer hartkit or another file",
                    path.display()
                )))
            }
            Some(_) => {}
        }
        tx.commit().map_err(e)
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Opens the file again. The old connection is closed first: SQLite shares one
    /// index of the write-ahead log between the connections of a process, and one
    /// left open on a lost log makes every new one fail.
    pub fn reconnect(&mut self) -> Result<(), Error> {
        self.ids.clear();
        self.close();
        self.conn = Self::connect(&self.path, true)?;
        self.released = false;
        self.opened = identity(&self.path);
        self.migrate(true)?;
        self.wal = identity(&wal_path(&self.path));
        Ok(())
    }

    /// Lets go of a file found lost ([`SqliteStore::file_lost`]): when the write-ahead
    /// log at the path is still this connection's, it is written into the file this
    /// connection has open (the one moved or removed) and emptied, so that a file put
    /// at the path (a restored backup) is not overwritten by the old log's pages when
    /// it is opened; then the connection is closed. Writes fail until
    /// [`SqliteStore::reconnect`].
    pub fn release(&mut self) {
        if self.wal.is_some() && identity(&wal_path(&self.path)) == self.wal {
            let _ = self
                .conn
                .query_row("PRAGMA wal_checkpoint(TRUNCATE)", [], |_| Ok(()));
        }
        self.close();
    }

    fn close(&mut self) {
        if self.released {
            return;
        }
        if let Ok(spare) = Connection::open_in_memory() {
            let old = std::mem::replace(&mut self.conn, spare);
            let _ = old.close();
            self.released = true;
        }
    }

    /// An error for a write after [`SqliteStore::release`] (one that asks for a
    /// reconnection).
    fn released_error(&self) -> Error {
        Error::Io(format!(
            "history database {}: closed after the file was lost; opening it again",
            self.path.display()
        ))
    }

    /// Before a write outside the writer (the ingest's births): a file found lost is
    /// let go of and opened anew at the path, logged.
    fn current(&mut self) -> Result<(), Error> {
        if let Some(lost) = self.file_lost() {
            tracing::error!(
                "history: {} {lost}: opening a new file there",
                self.path.display()
            );
            self.release();
        }
        if self.released {
            self.reconnect()?;
        }
        Ok(())
    }

    /// Writes a batch in one transaction with prepared statements.
    pub fn insert(&mut self, samples: &[Sample]) -> Result<(), Error> {
        if self.released {
            return Err(self.released_error());
        }
        let r = self.insert_inner(samples);
        if r.is_err() {
            // Ids learned in the rolled-back transaction may not exist.
            self.ids.clear();
        }
        r.map_err(|e| sqlite_error(&self.path, e))
    }

    fn insert_inner(&mut self, samples: &[Sample]) -> rusqlite::Result<()> {
        let tx = self.conn.transaction()?;
        {
            let mut dev = tx.prepare_cached(
                "INSERT INTO devices (unique_id, tag, loop) VALUES (?1, ?2, ?3) \
                 ON CONFLICT (unique_id) DO UPDATE SET tag = excluded.tag, loop = excluded.loop \
                 RETURNING id",
            )?;
            let mut ins = tx.prepare_cached(
                "INSERT OR REPLACE INTO samples (device, var, time, value, units, quality) \
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
            )?;
            for s in samples {
                let k = &s.device;
                let id = match self.ids.get(&k.unique_id) {
                    Some((id, tag, lp)) if *tag == k.tag && *lp == k.loop_name => *id,
                    _ => {
                        let id: i64 =
                            dev.query_row(params![k.unique_id, k.tag, k.loop_name], |r| r.get(0))?;
                        self.ids.insert(
                            k.unique_id.clone(),
                            (id, k.tag.clone(), k.loop_name.clone()),
                        );
                        id
                    }
                };
                let value = (!s.value.is_nan()).then_some(s.value);
                ins.execute(params![
                    id,
                    s.var.code(),
                    micros(s.time),
                    value,
                    s.units,
                    s.quality
                ])?;
            }
        }
        tx.commit()
    }

    /// Every device with its sample times and count.
    /// Saves Sparkplug births by topic (the ingest's, [`crate::Store::save_births`]).
    pub fn save_births(&mut self, births: &[(String, Vec<u8>)]) -> Result<(), Error> {
        self.current()?;
        let e = |e| sqlite_error(&self.path, e);
        let tx = self.conn.transaction().map_err(e)?;
        tx.execute(BIRTHS_TABLE, []).map_err(e)?;
        for (topic, payload) in births {
            tx.execute(
                "INSERT OR REPLACE INTO ingest_births (topic, payload) VALUES (?1, ?2)",
                rusqlite::params![topic, payload],
            )
            .map_err(e)?;
        }
        tx.commit().map_err(e)
    }

    /// The saved births, by topic.
    pub fn births(&mut self) -> Result<Vec<(String, Vec<u8>)>, Error> {
        let e = |e| sqlite_error(&self.path, e);
        self.conn.execute(BIRTHS_TABLE, []).map_err(e)?;
        let mut st = self
            .conn
            .prepare("SELECT topic, payload FROM ingest_births ORDER BY topic")
            .map_err(e)?;
        let rows = st
            .query_map([], |r| Ok((r.get(0)?, r.get(1)?)))
            .map_err(e)?
            .collect::<Result<Vec<_>, _>>()
            .map_err(e)?;
        Ok(rows)
    }

    pub fn devices(&mut self) -> Result<Vec<DeviceSummary>, Error> {
        let e = |e| sqlite_error(&self.path, e);
        let mut st = self
            .conn
            .prepare(
                "SELECT d.unique_id, d.tag, d.loop, min(s.time), max(s.time), count(s.time) \
                 FROM devices d LEFT JOIN samples s ON s.device = d.id \
                 GROUP BY d.id ORDER BY d.loop, d.tag, d.unique_id",
            )
            .map_err(e)?;
        let rows = st
            .query_map([], |r| {
                Ok(DeviceSummary {
                    unique_id: r.get(0)?,
                    tag: r.get(1)?,
                    loop_name: r.get(2)?,
                    first: r.get::<_, Option<i64>>(3)?.map(from_micros),
                    last: r.get::<_, Option<i64>>(4)?.map(from_micros),
                    samples: r.get::<_, i64>(5)?.max(0) as u64,
                })
            })
            .map_err(e)?;
        rows.collect::<Result<_, _>>().map_err(e)
    }

    /// One variable of one device.
    pub fn query(&mut self, q: &Query) -> Result<Vec<Point>, Error> {
        let path = self.path.clone();
        let e = |e| sqlite_error(&path, e);
        let wanted = q.device.trim();
        let found = {
            let mut st = self
                .conn
                .prepare("SELECT id, unique_id, tag, loop FROM devices WHERE upper(unique_id) = upper(?1) OR tag = ?1")
                .map_err(e)?;
            let rows = st
                .query_map([wanted], |r| {
                    Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?))
                })
                .map_err(e)?;
            rows.collect::<Result<Vec<_>, _>>().map_err(e)?
        };
        let id = resolve_device(wanted, &path.display().to_string(), found)?;
        let sql = query_sql(q).replace('$', "?");
        let mut st = self.conn.prepare(&sql).map_err(e)?;
        let (from, to) = (micros(q.from), micros(q.to));
        let map = |r: &rusqlite::Row| {
            Ok(Point {
                time: from_micros(r.get(0)?),
                value: r.get(1)?,
                units: r
                    .get::<_, Option<i64>>(2)?
                    .and_then(|u| u8::try_from(u).ok()),
                quality: u8::try_from(r.get::<_, i64>(3)?).unwrap_or(u8::MAX),
            })
        };
        let rows = match q.every {
            None => st.query_map(params![id, q.var.code(), from, to], map),
            Some(every) => {
                let e = i64::try_from(every.as_micros()).unwrap_or(i64::MAX);
                st.query_map(params![id, q.var.code(), from, to, e], map)
            }
        }
        .map_err(e)?;
        rows.collect::<Result<_, _>>().map_err(e)
    }

    /// The bytes the data take (pages in use; the file itself does not shrink, freed
    /// pages are reused).
    pub fn used_bytes(&self) -> Result<u64, Error> {
        let e = |e| sqlite_error(&self.path, e);
        let get = |p: &str| -> Result<i64, Error> {
            self.conn
                .query_row(&format!("PRAGMA {p}"), [], |r| r.get(0))
                .map_err(e)
        };
        let used = (get("page_count")? - get("freelist_count")?).max(0) * get("page_size")?;
        Ok(used as u64)
    }

    fn series(&self) -> rusqlite::Result<Vec<(i64, i16)>> {
        let mut st = self.conn.prepare_cached("SELECT id FROM devices")?;
        let ids = st
            .query_map([], |r| r.get::<_, i64>(0))?
            .collect::<rusqlite::Result<Vec<_>>>()?;
        Ok(ids
            .into_iter()
            .flat_map(|id| crate::Var::ALL.map(|v| (id, v.code())))
            .collect())
    }

    /// Deletes the samples of every series before `cutoff`, in chunks; `false` when
    /// the deadline came first.
    fn delete_before(
        &mut self,
        cutoff: i64,
        deadline: Instant,
        deleted: &mut u64,
    ) -> rusqlite::Result<bool> {
        for (dev, var) in self.series()? {
            loop {
                let bound: Option<i64> = self
                    .conn
                    .prepare_cached(
                        "SELECT time FROM samples WHERE device = ?1 AND var = ?2 AND time < ?3 \
                         ORDER BY time LIMIT 1 OFFSET ?4",
                    )?
                    .query_row(params![dev, var, cutoff, DELETE_CHUNK], |r| r.get(0))
                    .optional()?;
                let n = self
                    .conn
                    .prepare_cached(
                        "DELETE FROM samples WHERE device = ?1 AND var = ?2 AND time < ?3",
                    )?
                    .execute(params![dev, var, bound.unwrap_or(cutoff)])?;
                *deleted += n as u64;
                if Instant::now() >= deadline {
                    return Ok(false);
                }
                if bound.is_none() {
                    break;
                }
            }
        }
        Ok(true)
    }

    /// The oldest and newest sample times, by an index look-up per series.
    fn bounds(&self) -> rusqlite::Result<Option<(i64, i64)>> {
        let mut b: Option<(i64, i64)> = None;
        for (dev, var) in self.series()? {
            let t: (Option<i64>, Option<i64>) = self
                .conn
                .prepare_cached(
                    "SELECT min(time), max(time) FROM samples WHERE device = ?1 AND var = ?2",
                )?
                .query_row(params![dev, var], |r| Ok((r.get(0)?, r.get(1)?)))?;
            if let (Some(lo), Some(hi)) = t {
                b = Some(match b {
                    Some((a, z)) => (a.min(lo), z.max(hi)),
                    None => (lo, hi),
                });
            }
        }
        Ok(b)
    }

    /// Retention by age (`cutoff`, µs) and by size.
    pub fn retention(
        &mut self,
        cutoff: Option<i64>,
        max_size: Option<u64>,
        deadline: Instant,
    ) -> Result<RetentionOutcome, Error> {
        if self.released {
            return Err(self.released_error());
        }
        let path = self.path.clone();
        let e = |e| sqlite_error(&path, e);
        let mut out = RetentionOutcome::default();
        if let Some(c) = cutoff {
            if !self
                .delete_before(c, deadline, &mut out.deleted)
                .map_err(e)?
            {
                return Ok(out);
            }
        }
        if let Some(max) = max_size {
            while self.used_bytes()? > max {
                let Some((oldest, newest)) = self.bounds().map_err(e)? else {
                    break;
                };
                let day_end = crate::bucket_start(oldest, DAY_US) + DAY_US;
                let newest_day = Some(crate::bucket_start(newest, DAY_US));
                if newest_day.is_some_and(|d| day_end > d) {
                    // Only today's data are left: never delete the day being written.
                    tracing::warn!(
                        "history: {} holds more than max_size ({max} bytes) with one day of data; raise max_size",
                        path.display()
                    );
                    break;
                }
                if !self
                    .delete_before(day_end, deadline, &mut out.deleted)
                    .map_err(e)?
                {
                    return Ok(out);
                }
            }
        }
        out.done = true;
        Ok(out)
    }

    /// Sets the most pages the file may have (tests: a full disk without filling one).
    #[doc(hidden)]
    pub fn set_max_page_count(&self, pages: u32) -> Result<(), Error> {
        self.conn
            .query_row(&format!("PRAGMA max_page_count = {pages}"), [], |_| Ok(()))
            .map_err(|e| sqlite_error(&self.path, e))
    }
}
