//! The concentrator's store: SQLite in WAL mode, one transaction per poll, a ring of
//! minutes that never drops data not handed over while there is room.

use std::fmt;
use std::path::{Path, PathBuf};

use rusqlite::{params, Connection, OptionalExtension, Transaction};

use crate::calibration::{Segment, Sensor, Table};
use crate::proto::{Batch, Record, SensorStatus, StationStatus, BATCH_RECORDS};

/// How hard the store works to survive power loss.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Durability {
    /// Every commit is on disk before it returns (`synchronous=FULL`): a power cut
    /// loses at most the poll in progress.
    Full,
    /// Commits survive the process being killed, not necessarily the machine losing
    /// power (`synchronous=NORMAL`): for simulation.
    Process,
}

/// A store that could not be opened or written.
#[derive(Debug)]
pub struct StoreError {
    /// The file.
    pub path: PathBuf,
    /// What happened.
    pub what: String,
}

impl fmt::Display for StoreError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "store {}: {}", self.path.display(), self.what)
    }
}

impl std::error::Error for StoreError {}

/// Opens an SQLite file for one of the network's stores: WAL, the durability asked,
/// a busy timeout (another process reading it, such as a report, does not fail a
/// poll).
pub(crate) fn open_db(path: &Path, durability: Durability) -> Result<Connection, StoreError> {
    let err = |e: rusqlite::Error| {
        StoreError {
        path: path.to_path_buf(),
        what: format!("{e}; check that the file is an SQLite database this program wrote and that the directory is writable"),
    }
    };
    let c = Connection::open(path).map_err(err)?;
    c.busy_timeout(std::time::Duration::from_secs(5))
        .map_err(err)?;
    let mode: String = c
        .query_row("PRAGMA journal_mode=WAL", [], |r| r.get(0))
        .map_err(err)?;
    if mode != "wal" && path != Path::new(":memory:") {
        return Err(StoreError {
            path: path.to_path_buf(),
            what: format!("cannot use write-ahead logging (journal mode {mode}); put the store on a local file system"),
        });
    }
    c.execute_batch(match durability {
        Durability::Full => "PRAGMA synchronous=FULL",
        Durability::Process => "PRAGMA synchronous=NORMAL",
    })
    .map_err(err)?;
    Ok(c)
}

/// What a database file of the network is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Kind {
    /// A concentrator's store.
    Store = 1,
    /// The PC's or the handheld's archive.
    Archive = 2,
}

impl Kind {
    fn name(self) -> &'static str {
        match self {
            Kind::Store => "a concentrator's store (--store of wells concentrator)",
            Kind::Archive => "an archive (--db of wells pc, --store of wells handheld)",
        }
    }

    fn minutes_columns(self) -> usize {
        match self {
            Kind::Store => 7,
            Kind::Archive => 10,
        }
    }
}

/// Makes sure the file at `path` is a `kind` file, or new: a concentrator's store
/// opened as the PC's archive (or the other way round) would be damaged by the other
/// program's writes. Marks a new file with its kind.
pub(crate) fn claim(c: &Connection, path: &Path, kind: Kind) -> Result<(), StoreError> {
    let err = |what: String| StoreError {
        path: path.to_path_buf(),
        what,
    };
    let sql = |e: rusqlite::Error| err(e.to_string());
    let tables: Vec<String> = c
        .prepare("SELECT name FROM sqlite_master WHERE type='table'")
        .and_then(|mut st| {
            st.query_map([], |r| r.get(0))?
                .collect::<Result<Vec<String>, _>>()
        })
        .map_err(sql)?;
    let has = |t: &str| tables.iter().any(|x| x == t);
    if has("meta") {
        let found: Option<i64> = get_meta(c, "kind").map_err(sql)?;
        match found {
            Some(k) if k == kind as i64 => return Ok(()),
            Some(k) => {
                let other = if k == Kind::Store as i64 {
                    Kind::Store
                } else {
                    Kind::Archive
                };
                return Err(err(format!(
                    "this file is {}, not {}; check the file name",
                    other.name(),
                    kind.name()
                )));
            }
            None => {}
        }
    }
    if has("minutes") {
        let cols: usize = c
            .query_row(
                "SELECT count(*) FROM pragma_table_info('minutes')",
                [],
                |r| r.get(0),
            )
            .map_err(sql)?;
        if cols != kind.minutes_columns() {
            return Err(err(format!(
                "this file's minutes are not laid out as in {}; check the file name",
                kind.name()
            )));
        }
    } else if !tables.is_empty() && !has("meta") {
        return Err(err(
            "this SQLite file belongs to another program; give a new file or one this program wrote"
                .into(),
        ));
    }
    Ok(())
}

/// Marks the file with its kind (after its tables are made).
pub(crate) fn mark_kind(c: &Connection, kind: Kind) -> rusqlite::Result<()> {
    if get_meta(c, "kind")?.is_none() {
        set_meta(c, "kind", kind as i64)?;
    }
    Ok(())
}

/// What one poll's commit did.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct PollOutcome {
    /// Minutes stored for the first time.
    pub new_minutes: u32,
    /// Which they were.
    pub new_list: Vec<u32>,
    /// Minutes that gained a quantity missing before.
    pub completed: u32,
    /// Handed-over minutes removed to make room.
    pub evicted: u32,
    /// Minutes not handed over removed because nothing else was left to remove.
    pub dropped_unsent: u32,
    /// New minutes at or before the handed-over mark, not kept: the clock is behind
    /// the data (it was set back).
    pub behind_clock: u32,
}

/// The concentrator's store.
pub struct Store {
    conn: Connection,
    path: PathBuf,
    capacity: u32,
    /// Minutes stored (counted once at open, then kept by the commits: only this
    /// store's owner writes it).
    rows: u32,
}

const SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS meta(key TEXT PRIMARY KEY, value INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS minutes(
    minute INTEGER PRIMARY KEY, valid INTEGER NOT NULL,
    t_raw INTEGER NOT NULL, l_raw INTEGER NOT NULL, ls_raw INTEGER NOT NULL,
    temperature REAL, level REAL);
CREATE TABLE IF NOT EXISTS calibration(
    sensor TEXT NOT NULL, segment INTEGER NOT NULL, raw_from INTEGER NOT NULL,
    raw_to INTEGER NOT NULL, a0 REAL NOT NULL, a1 REAL NOT NULL, a2 REAL NOT NULL,
    PRIMARY KEY(sensor, segment));
CREATE TABLE IF NOT EXISTS sensors(
    address INTEGER PRIMARY KEY, kind TEXT NOT NULL, state INTEGER NOT NULL,
    last_good INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS events(at INTEGER NOT NULL, severity TEXT NOT NULL, text TEXT NOT NULL);
";

/// Minutes in a day.
pub const DAY_MINUTES: u32 = 1440;

fn nan_null(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

pub(crate) fn record_from_row(r: &rusqlite::Row<'_>, at: usize) -> rusqlite::Result<Record> {
    Ok(Record {
        minute: r.get(at)?,
        valid: r.get(at + 1)?,
        t_raw: r.get(at + 2)?,
        l_raw: r.get(at + 3)?,
        ls_raw: r.get(at + 4)?,
        temperature: r.get::<_, Option<f64>>(at + 5)?.unwrap_or(f64::NAN),
        level: r.get::<_, Option<f64>>(at + 6)?.unwrap_or(f64::NAN),
    })
}

impl Store {
    /// Opens (or creates) the store of `well` with room for `capacity` minutes (at
    /// least 7 days).
    pub fn open(
        path: &Path,
        well: u8,
        capacity: u32,
        durability: Durability,
    ) -> Result<Self, StoreError> {
        let conn = open_db(path, durability)?;
        claim(&conn, path, Kind::Store)?;
        let mut s = Store {
            conn,
            path: path.to_path_buf(),
            capacity: capacity.max(7 * DAY_MINUTES),
            rows: 0,
        };
        s.conn.execute_batch(SCHEMA).map_err(|e| s.err(e))?;
        mark_kind(&s.conn, Kind::Store).map_err(|e| s.err(e))?;
        s.rows = s
            .conn
            .query_row("SELECT count(*) FROM minutes", [], |r| r.get(0))
            .map_err(|e| s.err(e))?;
        match s.meta("well")? {
            None => s.set_meta("well", well as i64)?,
            Some(w) if w != well as i64 => {
                return Err(StoreError {
                    path: path.to_path_buf(),
                    what: format!(
                    "this store belongs to well {w}, not well {well}; give each well its own file"
                ),
                })
            }
            Some(_) => {}
        }
        Ok(s)
    }

    fn err(&self, e: rusqlite::Error) -> StoreError {
        StoreError {
            path: self.path.clone(),
            what: e.to_string(),
        }
    }

    fn meta(&self, key: &str) -> Result<Option<i64>, StoreError> {
        self.conn
            .query_row("SELECT value FROM meta WHERE key=?1", [key], |r| r.get(0))
            .optional()
            .map_err(|e| self.err(e))
    }

    fn set_meta(&self, key: &str, v: i64) -> Result<(), StoreError> {
        set_meta(&self.conn, key, v).map_err(|e| self.err(e))
    }

    /// Room, in minutes.
    pub fn capacity(&self) -> u32 {
        self.capacity
    }

    /// A parameter changed online (command 161), if one was.
    pub fn parameter(&self, key: &str) -> Result<Option<i64>, StoreError> {
        self.meta(&format!("param:{key}"))
    }

    /// Keeps a parameter changed online, so a restart keeps it.
    pub fn set_parameter(&self, key: &str, v: i64) -> Result<(), StoreError> {
        self.set_meta(&format!("param:{key}"), v)
    }

    /// The handed-over mark: every minute up to it has been handed over.
    pub fn handed_over(&self) -> Result<u32, StoreError> {
        get_count(&self.conn, "handed_over").map_err(|e| self.err(e))
    }

    /// Minutes stored, minutes not handed over, the newest minute.
    pub fn counts(&self) -> Result<(u32, u32, u32), StoreError> {
        let ho = self.handed_over()?;
        let (unsent, newest) = self
            .conn
            .query_row(
                "SELECT count(*), (SELECT coalesce(max(minute), 0) FROM minutes) FROM minutes WHERE minute > ?1",
                [ho],
                |r| Ok((r.get(0)?, r.get(1)?)),
            )
            .map_err(|e| self.err(e))?;
        Ok((self.rows, unsent, newest))
    }

    /// Minutes dropped before they were handed over, over the store's life.
    pub fn dropped_unsent(&self) -> Result<u32, StoreError> {
        get_count(&self.conn, "dropped_unsent").map_err(|e| self.err(e))
    }

    /// The record of `minute`, if stored.
    pub fn get(&self, minute: u32) -> Result<Option<Record>, StoreError> {
        self.conn
            .query_row(
                "SELECT minute, valid, t_raw, l_raw, ls_raw, temperature, level FROM minutes WHERE minute=?1",
                [minute],
                |r| record_from_row(r, 0),
            )
            .optional()
            .map_err(|e| self.err(e))
    }

    /// Records with minutes in `from..=to`, oldest first.
    pub fn range(&self, from: u32, to: u32) -> Result<Vec<Record>, StoreError> {
        let mut st = self
            .conn
            .prepare_cached(
                "SELECT minute, valid, t_raw, l_raw, ls_raw, temperature, level FROM minutes \
                 WHERE minute BETWEEN ?1 AND ?2 ORDER BY minute",
            )
            .map_err(|e| self.err(e))?;
        let rows = st
            .query_map([from, to], |r| record_from_row(r, 0))
            .map_err(|e| self.err(e))?;
        rows.collect::<Result<Vec<_>, _>>().map_err(|e| self.err(e))
    }

    /// Stores one poll in one transaction: each record's minute if new; a minute not
    /// yet handed over gains the quantities it lacked; then the ring is kept within
    /// its capacity, and the sensors' states are written.
    pub fn commit_poll(
        &mut self,
        records: &[Record],
        sensors: &[SensorStatus],
        now_minute: u32,
    ) -> Result<PollOutcome, StoreError> {
        let path = self.path.clone();
        let capacity = self.capacity;
        let e = |e: rusqlite::Error| StoreError {
            path: path.clone(),
            what: e.to_string(),
        };
        let tx = self.conn.transaction().map_err(e)?;
        let mut out = PollOutcome::default();
        let ho = get_count(&tx, "handed_over").map_err(e)?;
        let sent = get_count(&tx, "sent_upto").map_err(e)?;
        let mut resend_from = sent;
        for r in records.iter().filter(|r| r.valid != 0) {
            if r.minute <= ho {
                // A minute at or before what has been handed over is new only if the
                // clock went back: it could never be handed over, so it is not kept.
                let known: bool = tx
                    .query_row(
                        "SELECT EXISTS(SELECT 1 FROM minutes WHERE minute=?1)",
                        [r.minute],
                        |x| x.get(0),
                    )
                    .map_err(e)?;
                if !known {
                    out.behind_clock += 1;
                }
                continue;
            }
            let old: Option<u8> = tx
                .query_row(
                    "SELECT valid FROM minutes WHERE minute=?1",
                    [r.minute],
                    |x| x.get(0),
                )
                .optional()
                .map_err(e)?;
            match old {
                None => {
                    if r.minute <= sent {
                        // A minute filled in below what was sent already (a hole
                        // filled late): send again from just before it, so it is not
                        // passed over (the requester counts the repeats).
                        resend_from = resend_from.min(r.minute - 1);
                    }
                    tx.execute(
                        "INSERT INTO minutes VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
                        params![
                            r.minute,
                            r.valid,
                            r.t_raw,
                            r.l_raw,
                            r.ls_raw,
                            nan_null(r.temperature),
                            nan_null(r.level)
                        ],
                    )
                    .map_err(e)?;
                    out.new_minutes += 1;
                    out.new_list.push(r.minute);
                }
                Some(v) if r.minute > sent && r.valid & !v != 0 => {
                    let gain = r.valid & !v;
                    if gain & crate::proto::VALID_TEMPERATURE != 0 {
                        tx.execute(
                            "UPDATE minutes SET t_raw=?2, temperature=?3 WHERE minute=?1",
                            params![r.minute, r.t_raw, nan_null(r.temperature)],
                        )
                        .map_err(e)?;
                    }
                    if gain & crate::proto::VALID_LEVEL != 0 {
                        tx.execute(
                            "UPDATE minutes SET l_raw=?2, level=?3 WHERE minute=?1",
                            params![r.minute, r.l_raw, nan_null(r.level)],
                        )
                        .map_err(e)?;
                    }
                    if gain & crate::proto::VALID_LEVEL_SENSOR_TEMPERATURE != 0 {
                        tx.execute(
                            "UPDATE minutes SET ls_raw=?2 WHERE minute=?1",
                            params![r.minute, r.ls_raw],
                        )
                        .map_err(e)?;
                    }
                    tx.execute(
                        "UPDATE minutes SET valid=?2 WHERE minute=?1",
                        params![r.minute, v | r.valid],
                    )
                    .map_err(e)?;
                    out.completed += 1;
                }
                Some(_) => {}
            }
        }
        let count = self.rows + out.new_minutes;
        if count > capacity {
            let excess = count - capacity;
            out.evicted = tx
                .execute(
                    "DELETE FROM minutes WHERE minute IN \
                     (SELECT minute FROM minutes WHERE minute <= ?1 ORDER BY minute LIMIT ?2)",
                    params![ho, excess],
                )
                .map_err(e)? as u32;
            let left = excess - out.evicted;
            if left > 0 {
                out.dropped_unsent = tx
                    .execute(
                        "DELETE FROM minutes WHERE minute IN \
                         (SELECT minute FROM minutes ORDER BY minute LIMIT ?1)",
                        [left],
                    )
                    .map_err(e)? as u32;
                let total = add_count(&tx, "dropped_unsent", out.dropped_unsent).map_err(e)?;
                tx.execute(
                    "INSERT INTO events VALUES (?1, 'error', ?2)",
                    params![
                        now_minute,
                        format!(
                            "store full: {} minutes dropped before they were handed over ({total} in all); \
                             collect the data (handheld or telephone) or give the store more room",
                            out.dropped_unsent
                        )
                    ],
                )
                .map_err(e)?;
            }
        }
        for s in sensors {
            tx.execute(
                "INSERT OR REPLACE INTO sensors VALUES (?1, ?2, ?3, ?4)",
                params![s.address, s.kind.name(), s.state, s.last_good],
            )
            .map_err(e)?;
        }
        if resend_from < sent {
            set_meta(&tx, "sent_upto", resend_from as i64).map_err(e)?;
        }
        if out.behind_clock > 0 {
            tx.execute(
                "INSERT INTO events VALUES (?1, 'error', ?2)",
                params![
                    now_minute,
                    format!(
                        "{} minutes are dated at or before the data already handed over (minute {ho}): \
                         the clock is behind; they are not kept. Check the clock",
                        out.behind_clock
                    )
                ],
            )
            .map_err(e)?;
        }
        tx.commit().map_err(e)?;
        self.rows = count - out.evicted - out.dropped_unsent;
        Ok(out)
    }

    /// Answers command 144: moves the handed-over mark to `ack` (never backwards,
    /// never past what has been sent) and returns the next batch after the mark, in
    /// one transaction. A minute goes out once it can no longer change: complete
    /// (`full`: the valid bits of every quantity the concentrator's sensors give), or
    /// older than the sensors' three minutes; the batch stops before the first minute
    /// still waiting.
    pub fn transfer(&mut self, ack: u32, now_minute: u32, full: u8) -> Result<Batch, StoreError> {
        let path = self.path.clone();
        let e = |e: rusqlite::Error| StoreError {
            path: path.clone(),
            what: e.to_string(),
        };
        let tx = self.conn.transaction().map_err(e)?;
        let batch = transfer_in(&tx, ack, now_minute, "minutes", "", &[], Some(full)).map_err(e)?;
        tx.commit().map_err(e)?;
        Ok(batch)
    }

    /// The sensors' states as last stored.
    pub fn sensors(&self) -> Result<Vec<SensorStatus>, StoreError> {
        let mut st = self
            .conn
            .prepare("SELECT address, kind, state, last_good FROM sensors ORDER BY address")
            .map_err(|e| self.err(e))?;
        let rows = st
            .query_map([], |r| {
                let kind: String = r.get(1)?;
                Ok(SensorStatus {
                    address: r.get(0)?,
                    kind: Sensor::from_name(&kind).unwrap_or(Sensor::Temperature),
                    state: r.get(2)?,
                    last_good: r.get(3)?,
                })
            })
            .map_err(|e| self.err(e))?;
        rows.collect::<Result<Vec<_>, _>>().map_err(|e| self.err(e))
    }

    /// The status command 14 reports (the summary is left to the caller's sensors).
    pub fn status(
        &self,
        clock: u32,
        sensors: Vec<SensorStatus>,
    ) -> Result<StationStatus, StoreError> {
        let (stored, unsent, _) = self.counts()?;
        let dropped = self.dropped_unsent()?;
        let faulty = sensors.iter().any(|s| s.state != 0);
        Ok(StationStatus {
            summary: if dropped > 0 {
                2
            } else if faulty {
                1
            } else {
                0
            },
            clock,
            stored,
            unsent,
            fill_permille: ((stored as u64 * 1000) / self.capacity.max(1) as u64).min(1000) as u16,
            dropped_unsent: dropped,
            sensors,
        })
    }

    /// When the last transfer happened (minute) and how many minutes it has handed
    /// over in all.
    pub fn last_transfer(&self) -> Result<Option<(u32, u32)>, StoreError> {
        let at = self.meta("last_transfer_at")?;
        let n = self.meta("transferred")?.unwrap_or(0);
        Ok(at.map(|a| (a as u32, n as u32)))
    }

    /// The calibration table stored for `sensor`, if one was downloaded.
    pub fn calibration(&self, sensor: Sensor) -> Result<Option<Table>, StoreError> {
        load_table(&self.conn, "calibration", "", sensor).map_err(|e| self.err(e))
    }

    /// Puts `table` in force for `sensor` (one transaction: the old table stays if
    /// anything fails).
    pub fn set_calibration(&mut self, sensor: Sensor, table: &Table) -> Result<(), StoreError> {
        let path = self.path.clone();
        let e = |e: rusqlite::Error| StoreError {
            path: path.clone(),
            what: e.to_string(),
        };
        let tx = self.conn.transaction().map_err(e)?;
        save_table(&tx, "calibration", "", &[], sensor, table).map_err(e)?;
        tx.commit().map_err(e)
    }

    /// Writes an event to the store's log.
    pub fn event(&self, minute: u32, severity: &str, text: &str) -> Result<(), StoreError> {
        self.conn
            .execute(
                "INSERT INTO events VALUES (?1, ?2, ?3)",
                params![minute, severity, text],
            )
            .map(|_| ())
            .map_err(|e| self.err(e))
    }

    /// The newest events, newest first.
    pub fn events(&self, n: usize) -> Result<Vec<(u32, String, String)>, StoreError> {
        let mut st = self
            .conn
            .prepare("SELECT at, severity, text FROM events ORDER BY rowid DESC LIMIT ?1")
            .map_err(|e| self.err(e))?;
        let rows = st
            .query_map([n as i64], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)))
            .map_err(|e| self.err(e))?;
        rows.collect::<Result<Vec<_>, _>>().map_err(|e| self.err(e))
    }
}

pub(crate) fn get_meta(c: &Connection, key: &str) -> rusqlite::Result<Option<i64>> {
    c.query_row("SELECT value FROM meta WHERE key=?1", [key], |r| r.get(0))
        .optional()
}

/// A mark or a count kept in `meta` (a minute, minutes dropped): 0 when not set; a
/// value outside 0..=u32::MAX (a damaged file) is an error, never wrapped into a mark
/// that would hide or drop minutes.
pub(crate) fn get_count(c: &Connection, key: &str) -> rusqlite::Result<u32> {
    let v = get_meta(c, key)?.unwrap_or(0);
    u32::try_from(v).map_err(|_| rusqlite::Error::IntegralValueOutOfRange(0, v))
}

/// Adds `n` to the count `key` in `meta` (saturating); the new total.
pub(crate) fn add_count(c: &Connection, key: &str, n: u32) -> rusqlite::Result<i64> {
    let total = get_meta(c, key)?.unwrap_or(0).saturating_add(i64::from(n));
    set_meta(c, key, total)?;
    Ok(total)
}

pub(crate) fn set_meta(c: &Connection, key: &str, v: i64) -> rusqlite::Result<()> {
    c.execute(
        "INSERT OR REPLACE INTO meta VALUES (?1, ?2)",
        params![key, v],
    )
    .map(|_| ())
}

/// The command-144 logic on any table of records: `table` with an optional `scope`
/// condition (e.g. `well=?`) and its parameters; the mark lives in `meta` under
/// `handed_over{scope_key}`, the last minute sent under `sent_upto{scope_key}`. With
/// `settle` (the concentrator), minutes that may still change are held back (see
/// [`Store::transfer`]).
pub(crate) fn transfer_in(
    tx: &Transaction<'_>,
    ack: u32,
    now_minute: u32,
    table: &str,
    scope_key: &str,
    scope: &[(&str, i64)],
    settle: Option<u8>,
) -> rusqlite::Result<Batch> {
    let where_scope: String = scope.iter().map(|(c, v)| format!(" AND {c}={v}")).collect();
    let key = format!("handed_over{scope_key}");
    let sent_key = format!("sent_upto{scope_key}");
    let mark = get_count(tx, &key)?;
    let sent = get_count(tx, &sent_key)?;
    // An acknowledgement counts up to what has been sent, never beyond (a requester's
    // cursor ahead of this station's data moves nothing it has not had).
    let new_mark = mark.max(ack.min(sent));
    if new_mark != mark {
        let before: u32 = tx.query_row(
            &format!(
                "SELECT count(*) FROM {table} WHERE minute > ?1 AND minute <= ?2{where_scope}"
            ),
            params![mark, new_mark],
            |r| r.get(0),
        )?;
        set_meta(tx, &key, new_mark as i64)?;
        add_count(tx, &format!("transferred{scope_key}"), before)?;
        set_meta(
            tx,
            &format!("last_transfer_at{scope_key}"),
            now_minute as i64,
        )?;
    }
    // The first minute that may still change, when settling.
    let limit: u32 = match settle {
        None => u32::MAX,
        Some(full) => tx
            .query_row(
                &format!(
                    "SELECT min(minute) FROM {table} WHERE minute > ?1 AND minute > ?2 \
                     AND (valid & ?3) != ?3{where_scope}"
                ),
                params![new_mark, now_minute.saturating_sub(4), full],
                |r| r.get::<_, Option<u32>>(0),
            )?
            .unwrap_or(u32::MAX),
    };
    let mut st = tx.prepare_cached(&format!(
        "SELECT minute, valid, t_raw, l_raw, ls_raw, temperature, level FROM {table} \
         WHERE minute > ?1 AND minute < ?3{where_scope} ORDER BY minute LIMIT ?2"
    ))?;
    let records = st
        .query_map(params![new_mark, BATCH_RECORDS as i64, limit], |r| {
            record_from_row(r, 0)
        })?
        .collect::<Result<Vec<_>, _>>()?;
    let after = records.last().map_or(new_mark, |r| r.minute);
    if after > sent {
        set_meta(tx, &sent_key, after as i64)?;
    }
    let remaining: u32 = tx.query_row(
        &format!("SELECT count(*) FROM {table} WHERE minute > ?1 AND minute < ?2{where_scope}"),
        params![after, limit],
        |r| r.get(0),
    )?;
    Ok(Batch { remaining, records })
}

pub(crate) fn load_table(
    c: &Connection,
    table: &str,
    where_scope: &str,
    sensor: Sensor,
) -> rusqlite::Result<Option<Table>> {
    let mut st = c.prepare(&format!(
        "SELECT raw_from, raw_to, a0, a1, a2 FROM {table} WHERE sensor=?1{where_scope} ORDER BY segment"
    ))?;
    let segs = st
        .query_map([sensor.name()], |r| {
            Ok(Segment {
                raw_from: r.get(0)?,
                raw_to: r.get(1)?,
                a0: r.get(2)?,
                a1: r.get(3)?,
                a2: r.get(4)?,
            })
        })?
        .collect::<Result<Vec<_>, _>>()?;
    if segs.is_empty() {
        return Ok(None);
    }
    Ok(Table::new(segs).ok())
}

pub(crate) fn save_table(
    c: &Connection,
    table: &str,
    scope_cols: &str,
    scope: &[i64],
    sensor: Sensor,
    t: &Table,
) -> rusqlite::Result<()> {
    let where_scope: String = scope_cols
        .split(',')
        .filter(|s| !s.is_empty())
        .zip(scope)
        .map(|(c, v)| format!(" AND {c}={v}"))
        .collect();
    c.execute(
        &format!("DELETE FROM {table} WHERE sensor=?1{where_scope}"),
        [sensor.name()],
    )?;
    let cols = if scope_cols.is_empty() {
        String::new()
    } else {
        format!("{scope_cols}, ")
    };
    let vals: String = scope.iter().map(|v| format!("{v}, ")).collect();
    for (i, s) in t.segments().iter().enumerate() {
        c.execute(
            &format!(
                "INSERT INTO {table} ({cols}sensor, segment, raw_from, raw_to, a0, a1, a2) \
                 VALUES ({vals}?1, ?2, ?3, ?4, ?5, ?6, ?7)"
            ),
            params![
                sensor.name(),
                i as i64 + 1,
                s.raw_from,
                s.raw_to,
                s.a0,
                s.a1,
                s.a2
            ],
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::proto::NO_VALUE;

    fn rec(minute: u32, valid: u8) -> Record {
        Record {
            minute,
            valid,
            t_raw: if valid & 1 != 0 { 100 } else { NO_VALUE },
            l_raw: if valid & 2 != 0 { 200 } else { NO_VALUE },
            ls_raw: NO_VALUE,
            temperature: if valid & 1 != 0 { 15.0 } else { f64::NAN },
            level: if valid & 2 != 0 { 10.0 } else { f64::NAN },
        }
    }

    fn store(dir: &tempfile::TempDir) -> Store {
        Store::open(&dir.path().join("c.db"), 1, 0, Durability::Process).unwrap()
    }

    #[test]
    fn a_minute_is_stored_once_and_completed_until_handed_over() {
        let d = tempfile::tempdir().unwrap();
        let mut s = store(&d);
        let o = s.commit_poll(&[rec(10, 1), rec(11, 3)], &[], 12).unwrap();
        assert_eq!(o.new_minutes, 2);
        let o = s.commit_poll(&[rec(10, 3), rec(11, 3)], &[], 12).unwrap();
        assert_eq!((o.new_minutes, o.completed), (0, 1));
        assert_eq!(s.get(10).unwrap().unwrap().valid, 3);
        // Once handed over, a minute does not change.
        let b = s.transfer(0, 100, 3).unwrap();
        assert_eq!(b.records.len(), 2);
        let b = s.transfer(11, 100, 3).unwrap();
        assert!(b.records.is_empty());
        s.commit_poll(&[rec(12, 1)], &[], 13).unwrap();
        let o = s.commit_poll(&[rec(11, 7), rec(12, 3)], &[], 13).unwrap();
        assert_eq!(o.completed, 1);
        assert_eq!(s.get(11).unwrap().unwrap().valid, 3);
    }

    #[test]
    fn transfer_acks_move_forward_only_and_not_past_the_newest() {
        let d = tempfile::tempdir().unwrap();
        let mut s = store(&d);
        let recs: Vec<_> = (100..130).map(|m| rec(m, 3)).collect();
        s.commit_poll(&recs, &[], 200).unwrap();
        let b = s.transfer(0, 200, 3).unwrap();
        assert_eq!((b.records.len(), b.remaining), (11, 19));
        // Repeating the same request (the reply was lost) gives the same batch.
        assert_eq!(s.transfer(0, 200, 3).unwrap(), b);
        let b2 = s.transfer(110, 200, 3).unwrap();
        assert_eq!(b2.records[0].minute, 111);
        // An older ack does not move the mark back.
        assert_eq!(s.transfer(50, 200, 3).unwrap(), b2);
        // An ack from the future counts only up to what was sent.
        let b3 = s.transfer(5000, 200, 3).unwrap();
        assert_eq!(s.handed_over().unwrap(), 121);
        assert_eq!(b3.records[0].minute, 122);
        assert_eq!(b3.remaining, 0);
        let b4 = s.transfer(129, 200, 3).unwrap();
        assert!(b4.records.is_empty());
        assert_eq!(s.handed_over().unwrap(), 129);
    }

    #[test]
    fn the_ring_drops_handed_over_minutes_first_and_unsent_ones_loudly() {
        let d = tempfile::tempdir().unwrap();
        let mut s = store(&d);
        let cap = s.capacity();
        let recs: Vec<_> = (1..=cap).map(|m| rec(m, 3)).collect();
        s.commit_poll(&recs, &[], cap).unwrap();
        // Hand over the first 99 minutes (nine batches acknowledged).
        let mut ack = 0;
        for _ in 0..10 {
            ack = s
                .transfer(ack, cap + 10, 3)
                .unwrap()
                .records
                .last()
                .unwrap()
                .minute;
        }
        let ho = s.handed_over().unwrap();
        assert_eq!(ho, 99);
        let o = s
            .commit_poll(&[rec(cap + 1, 3), rec(cap + 2, 3)], &[], cap + 2)
            .unwrap();
        assert_eq!((o.evicted, o.dropped_unsent), (2, 0));
        // Everything handed over is gone: the next ones are unsent.
        let more: Vec<_> = (cap + 3..cap + 103).map(|m| rec(m, 3)).collect();
        let o = s.commit_poll(&more, &[], cap + 103).unwrap();
        assert_eq!((o.evicted, o.dropped_unsent), (ho - 2, 100 - (ho - 2)));
        assert_eq!(s.dropped_unsent().unwrap(), 100 - (ho - 2));
        assert!(s.events(1).unwrap()[0].2.contains("store full"));
    }

    #[test]
    fn minutes_that_may_still_change_wait() {
        let d = tempfile::tempdir().unwrap();
        let mut s = store(&d);
        // At minute 110: 100-104 complete, 105 lacks the level (its sensor may still
        // give it), 106 complete.
        let mut recs: Vec<_> = (100..105).map(|m| rec(m, 3)).collect();
        recs.push(rec(105, 1));
        recs.push(rec(106, 3));
        s.commit_poll(&recs, &[], 107).unwrap();
        let b = s.transfer(0, 107, 3).unwrap();
        assert_eq!(
            b.records.iter().map(|r| r.minute).collect::<Vec<_>>(),
            (100..105).collect::<Vec<_>>()
        );
        assert_eq!(b.remaining, 0);
        // The level arrives: 105 and 106 go.
        s.commit_poll(&[rec(105, 3)], &[], 108).unwrap();
        let b = s.transfer(104, 108, 3).unwrap();
        assert_eq!(
            b.records.iter().map(|r| r.minute).collect::<Vec<_>>(),
            vec![105, 106]
        );
        assert_eq!(b.records[0].valid, 3);
        // A minute that stays incomplete goes once it is older than the sensors' memory.
        s.commit_poll(&[rec(107, 1)], &[], 109).unwrap();
        assert!(s.transfer(106, 109, 3).unwrap().records.is_empty());
        assert_eq!(s.transfer(106, 112, 3).unwrap().records[0].minute, 107);
    }

    #[test]
    fn a_clock_set_back_does_not_make_minutes_nobody_can_collect() {
        let d = tempfile::tempdir().unwrap();
        let mut s = store(&d);
        let recs: Vec<_> = (100..120).map(|m| rec(m, 3)).collect();
        s.commit_poll(&recs, &[], 121).unwrap();
        s.transfer(0, 130, 3).unwrap();
        s.transfer(110, 130, 3).unwrap();
        let o = s.commit_poll(&[rec(50, 3), rec(51, 3)], &[], 53).unwrap();
        assert_eq!((o.new_minutes, o.behind_clock), (0, 2));
        assert!(s.events(1).unwrap()[0].2.contains("clock is behind"));
    }

    #[test]
    fn a_hole_filled_below_what_was_sent_is_sent_again() {
        let d = tempfile::tempdir().unwrap();
        let mut s = store(&d);
        let recs: Vec<_> = (100..110)
            .filter(|m| *m != 104)
            .map(|m| rec(m, 3))
            .collect();
        s.commit_poll(&recs, &[], 120).unwrap();
        let b = s.transfer(0, 120, 3).unwrap();
        assert_eq!(b.records.last().unwrap().minute, 109);
        s.commit_poll(&[rec(104, 3)], &[], 121).unwrap();
        let b = s.transfer(109, 121, 3).unwrap();
        assert_eq!(b.records[0].minute, 104, "{b:?}");
    }

    /// A damaged mark (a negative or oversized value in `meta`) is an error that names
    /// it, not a wrapped mark that would drop every new minute as "behind the clock" or
    /// hand nothing over.
    #[test]
    fn a_damaged_mark_is_an_error_not_a_wrapped_minute() {
        let d = tempfile::tempdir().unwrap();
        let mut s = store(&d);
        set_meta(&s.conn, "handed_over", -1).unwrap();
        let e = s.handed_over().unwrap_err();
        assert!(e.to_string().contains("out of range"), "{e}");
        assert!(s.transfer(0, 100, 0x03).is_err());
        set_meta(&s.conn, "handed_over", 0).unwrap();
        assert_eq!(s.handed_over().unwrap(), 0);
        set_meta(&s.conn, "dropped_unsent", i64::MAX).unwrap();
        assert!(s.dropped_unsent().is_err());
    }

    #[test]
    fn a_store_is_not_an_archive() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("pc.db");
        drop(crate::archive::Archive::open(&p, Durability::Process).unwrap());
        let e = Store::open(&p, 1, 0, Durability::Process).err().unwrap();
        assert!(e.to_string().contains("is an archive"), "{e}");
        drop(store(&d));
        let e = crate::archive::Archive::open(&d.path().join("c.db"), Durability::Process)
            .err()
            .unwrap();
        assert!(e.to_string().contains("is a concentrator's store"), "{e}");
        // Another program's database.
        let other = d.path().join("other.db");
        let c = rusqlite::Connection::open(&other).unwrap();
        c.execute_batch("CREATE TABLE things(a)").unwrap();
        drop(c);
        let e = Store::open(&other, 1, 0, Durability::Process)
            .err()
            .unwrap();
        assert!(e.to_string().contains("another program"), "{e}");
    }

    #[test]
    fn a_store_is_for_one_well() {
        let d = tempfile::tempdir().unwrap();
        drop(store(&d));
        let e = Store::open(&d.path().join("c.db"), 2, 0, Durability::Process)
            .err()
            .unwrap();
        assert!(e.to_string().contains("belongs to well 1"), "{e}");
    }
}
