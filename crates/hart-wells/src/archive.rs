//! The archive: what the PC and the handheld keep. Minutes per well with where they
//! came from, the cursor of each source (the last minute stored from it, sent as the
//! first acknowledgement of the next transfer), the handheld's handed-over mark per
//! well (it serves the PC as a station), calibration tables waiting for a visit, and
//! a log of pulls and station status.
//!
//! The requester side of command 144 ([`Collector`]) and of command 160
//! ([`CalibrationSender`]) are here too: sans-IO, a request out, a reply in.

use std::path::{Path, PathBuf};

use rusqlite::{params, Connection, OptionalExtension};

use crate::calibration::{Sensor, Table};
use crate::proto::{
    transfer_request, Batch, DecodeError, Message, Record, SegmentReply, SegmentRequest, Station,
    StationStatus, CALIBRATION, TABLE_IN_FORCE, TRANSFER,
};
use crate::store::{
    add_count, get_count, get_meta, load_table, open_db, record_from_row, save_table, transfer_in,
    Durability, StoreError,
};

/// Where records came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Via {
    /// Straight from the well's concentrator.
    Concentrator,
    /// Through the handheld.
    Handheld,
}

impl Via {
    /// `concentrator` or `handheld`.
    pub fn name(self) -> &'static str {
        match self {
            Via::Concentrator => "concentrator",
            Via::Handheld => "handheld",
        }
    }

    /// The source that `station` is.
    pub fn of(station: Station) -> Self {
        if station.role() == crate::proto::Role::Handheld {
            Via::Handheld
        } else {
            Via::Concentrator
        }
    }
}

const SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS meta(key TEXT PRIMARY KEY, value INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS minutes(
    well INTEGER NOT NULL, minute INTEGER NOT NULL, valid INTEGER NOT NULL,
    t_raw INTEGER NOT NULL, l_raw INTEGER NOT NULL, ls_raw INTEGER NOT NULL,
    temperature REAL, level REAL, via TEXT NOT NULL, received INTEGER NOT NULL,
    PRIMARY KEY(well, minute)) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS cursors(
    source TEXT NOT NULL, well INTEGER NOT NULL, last_minute INTEGER NOT NULL,
    PRIMARY KEY(source, well));
CREATE TABLE IF NOT EXISTS pending_calibration(
    well INTEGER NOT NULL, sensor TEXT NOT NULL, segment INTEGER NOT NULL,
    raw_from INTEGER NOT NULL, raw_to INTEGER NOT NULL,
    a0 REAL NOT NULL, a1 REAL NOT NULL, a2 REAL NOT NULL,
    PRIMARY KEY(well, sensor, segment));
CREATE TABLE IF NOT EXISTS pulls(
    at INTEGER NOT NULL, well INTEGER NOT NULL, via TEXT NOT NULL, outcome TEXT NOT NULL,
    records INTEGER NOT NULL, batches INTEGER NOT NULL, detail TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS status(
    well INTEGER NOT NULL, at INTEGER NOT NULL, summary INTEGER NOT NULL,
    stored INTEGER NOT NULL, unsent INTEGER NOT NULL, fill_permille INTEGER NOT NULL,
    dropped_unsent INTEGER NOT NULL, sensors TEXT NOT NULL);
";

/// What storing one batch did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Stored {
    /// Minutes new to the archive.
    pub new: u32,
    /// Minutes the archive had already (a protocol error if it ever happens: the
    /// acknowledgements are there to prevent it).
    pub duplicated: u32,
}

/// One pull, for the log and the report.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PullLog {
    /// When (minute).
    pub at: u32,
    /// The well.
    pub well: u8,
    /// From where.
    pub via: Via,
    /// `ok`, or what went wrong in a word (`unreachable`, `cut`, `refused`).
    pub outcome: String,
    /// Minutes received.
    pub records: u32,
    /// Batches received.
    pub batches: u32,
    /// Details for people.
    pub detail: String,
}

/// The PC's or the handheld's archive.
pub struct Archive {
    conn: Connection,
    path: PathBuf,
}

impl Archive {
    /// Opens (or creates) an archive.
    pub fn open(path: &Path, durability: Durability) -> Result<Self, StoreError> {
        let conn = open_db(path, durability)?;
        crate::store::claim(&conn, path, crate::store::Kind::Archive)?;
        let a = Archive {
            conn,
            path: path.to_path_buf(),
        };
        a.conn.execute_batch(SCHEMA).map_err(|e| a.err(e))?;
        crate::store::mark_kind(&a.conn, crate::store::Kind::Archive).map_err(|e| a.err(e))?;
        Ok(a)
    }

    fn err(&self, e: rusqlite::Error) -> StoreError {
        StoreError {
            path: self.path.clone(),
            what: e.to_string(),
        }
    }

    /// The last minute stored from `via` for `well` (0 none).
    pub fn cursor(&self, via: Via, well: u8) -> Result<u32, StoreError> {
        self.conn
            .query_row(
                "SELECT last_minute FROM cursors WHERE source=?1 AND well=?2",
                params![via.name(), well],
                |r| r.get(0),
            )
            .optional()
            .map(|v| v.unwrap_or(0))
            .map_err(|e| self.err(e))
    }

    /// Stores a batch from `via` for `well` and moves that source's cursor to its
    /// last minute, in one transaction.
    pub fn store_batch(
        &mut self,
        via: Via,
        well: u8,
        batch: &Batch,
        now_minute: u32,
    ) -> Result<Stored, StoreError> {
        let path = self.path.clone();
        let e = |e: rusqlite::Error| StoreError {
            path: path.clone(),
            what: e.to_string(),
        };
        let tx = self.conn.transaction().map_err(e)?;
        let mut out = Stored::default();
        {
            let mut ins = tx
                .prepare_cached(
                    "INSERT OR IGNORE INTO minutes VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10)",
                )
                .map_err(e)?;
            for r in &batch.records {
                let n = ins
                    .execute(params![
                        well,
                        r.minute,
                        r.valid,
                        r.t_raw,
                        r.l_raw,
                        r.ls_raw,
                        r.temperature.is_finite().then_some(r.temperature),
                        r.level.is_finite().then_some(r.level),
                        via.name(),
                        now_minute
                    ])
                    .map_err(e)?;
                if n == 1 {
                    out.new += 1;
                } else {
                    out.duplicated += 1;
                }
            }
        }
        if let Some(last) = batch.records.last() {
            tx.execute(
                "INSERT INTO cursors VALUES (?1, ?2, ?3) ON CONFLICT(source, well) \
                 DO UPDATE SET last_minute=max(last_minute, excluded.last_minute)",
                params![via.name(), well, last.minute],
            )
            .map_err(e)?;
        }
        if out.duplicated > 0 {
            add_count(&tx, "duplicated", out.duplicated).map_err(e)?;
        }
        tx.commit().map_err(e)?;
        Ok(out)
    }

    /// Minutes received that the archive already had, over its life.
    pub fn duplicated(&self) -> Result<u32, StoreError> {
        get_count(&self.conn, "duplicated").map_err(|e| self.err(e))
    }

    /// Answers command 144 for `well` as a station (the handheld serving the PC):
    /// the same logic as the concentrator's, with a handed-over mark per well.
    pub fn transfer(&mut self, well: u8, ack: u32, now_minute: u32) -> Result<Batch, StoreError> {
        let path = self.path.clone();
        let e = |e: rusqlite::Error| StoreError {
            path: path.clone(),
            what: e.to_string(),
        };
        let tx = self.conn.transaction().map_err(e)?;
        let b = transfer_in(
            &tx,
            ack,
            now_minute,
            "minutes",
            &format!(":{well}"),
            &[("well", well as i64)],
            None,
        )
        .map_err(e)?;
        tx.commit().map_err(e)?;
        Ok(b)
    }

    /// Minutes of `well` not yet handed over (to the PC, for the handheld).
    pub fn unsent(&self, well: u8) -> Result<u32, StoreError> {
        let mark = get_meta(&self.conn, &format!("handed_over:{well}"))
            .map_err(|e| self.err(e))?
            .unwrap_or(0);
        self.conn
            .query_row(
                "SELECT count(*) FROM minutes WHERE well=?1 AND minute>?2",
                params![well, mark],
                |r| r.get(0),
            )
            .map_err(|e| self.err(e))
    }

    /// The wells the archive holds minutes of (a skip through the primary key: one
    /// short lookup per well, however many minutes there are).
    pub fn wells(&self) -> Result<Vec<u8>, StoreError> {
        let mut out = Vec::new();
        let mut after: i64 = -1;
        let mut st = self
            .conn
            .prepare_cached("SELECT min(well) FROM minutes WHERE well > ?1")
            .map_err(|e| self.err(e))?;
        while let Some(w) = st
            .query_row([after], |r| r.get::<_, Option<u8>>(0))
            .map_err(|e| self.err(e))?
        {
            out.push(w);
            after = w as i64;
        }
        Ok(out)
    }

    /// Whether the archive holds any minute of `well`.
    pub fn holds(&self, well: u8) -> Result<bool, StoreError> {
        self.conn
            .query_row(
                "SELECT EXISTS(SELECT 1 FROM minutes WHERE well=?1)",
                [well],
                |r| r.get(0),
            )
            .map_err(|e| self.err(e))
    }

    /// Minutes held for `well`.
    pub fn count(&self, well: u8) -> Result<u32, StoreError> {
        self.conn
            .query_row("SELECT count(*) FROM minutes WHERE well=?1", [well], |r| {
                r.get(0)
            })
            .map_err(|e| self.err(e))
    }

    /// Records of `well` with minutes in `from..=to`, oldest first.
    pub fn range(&self, well: u8, from: u32, to: u32) -> Result<Vec<Record>, StoreError> {
        let mut st = self
            .conn
            .prepare_cached(
                "SELECT minute, valid, t_raw, l_raw, ls_raw, temperature, level FROM minutes \
                 WHERE well=?1 AND minute BETWEEN ?2 AND ?3 ORDER BY minute",
            )
            .map_err(|e| self.err(e))?;
        let rows = st
            .query_map(params![well, from, to], |r| record_from_row(r, 0))
            .map_err(|e| self.err(e))?;
        rows.collect::<Result<Vec<_>, _>>().map_err(|e| self.err(e))
    }

    /// Writes a pull to the log.
    pub fn log_pull(&self, p: &PullLog) -> Result<(), StoreError> {
        self.conn
            .execute(
                "INSERT INTO pulls VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
                params![
                    p.at,
                    p.well,
                    p.via.name(),
                    p.outcome,
                    p.records,
                    p.batches,
                    p.detail
                ],
            )
            .map(|_| ())
            .map_err(|e| self.err(e))
    }

    /// The newest `n` pulls, newest first.
    pub fn pulls(&self, n: usize) -> Result<Vec<PullLog>, StoreError> {
        let mut st = self
            .conn
            .prepare(
                "SELECT at, well, via, outcome, records, batches, detail FROM pulls \
                 ORDER BY rowid DESC LIMIT ?1",
            )
            .map_err(|e| self.err(e))?;
        let rows = st
            .query_map([n as i64], |r| {
                let via: String = r.get(2)?;
                Ok(PullLog {
                    at: r.get(0)?,
                    well: r.get(1)?,
                    via: if via == "handheld" {
                        Via::Handheld
                    } else {
                        Via::Concentrator
                    },
                    outcome: r.get(3)?,
                    records: r.get(4)?,
                    batches: r.get(5)?,
                    detail: r.get(6)?,
                })
            })
            .map_err(|e| self.err(e))?;
        rows.collect::<Result<Vec<_>, _>>().map_err(|e| self.err(e))
    }

    /// Keeps a station's status (command 14) as read at `at`.
    pub fn log_status(&self, well: u8, at: u32, s: &StationStatus) -> Result<(), StoreError> {
        let sensors: Vec<serde_json::Value> = s.sensors.iter().map(|x| x.to_json()).collect();
        self.conn
            .execute(
                "INSERT INTO status VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
                params![
                    well,
                    at,
                    s.summary,
                    s.stored,
                    s.unsent,
                    s.fill_permille,
                    s.dropped_unsent,
                    serde_json::Value::from(sensors).to_string()
                ],
            )
            .map(|_| ())
            .map_err(|e| self.err(e))
    }

    /// Keeps `table` to download to `well`'s concentrator (the handheld, on its next
    /// visit).
    pub fn set_pending_calibration(
        &mut self,
        well: u8,
        sensor: Sensor,
        table: &Table,
    ) -> Result<(), StoreError> {
        let path = self.path.clone();
        let e = |e: rusqlite::Error| StoreError {
            path: path.clone(),
            what: e.to_string(),
        };
        let tx = self.conn.transaction().map_err(e)?;
        save_table(
            &tx,
            "pending_calibration",
            "well",
            &[well as i64],
            sensor,
            table,
        )
        .map_err(e)?;
        tx.commit().map_err(e)
    }

    /// The table waiting for `well`'s concentrator, if any.
    pub fn pending_calibration(
        &self,
        well: u8,
        sensor: Sensor,
    ) -> Result<Option<Table>, StoreError> {
        load_table(
            &self.conn,
            "pending_calibration",
            &format!(" AND well={well}"),
            sensor,
        )
        .map_err(|e| self.err(e))
    }

    /// Forgets the table waiting for `well` (it has been downloaded).
    pub fn clear_pending_calibration(&self, well: u8, sensor: Sensor) -> Result<(), StoreError> {
        self.conn
            .execute(
                "DELETE FROM pending_calibration WHERE well=?1 AND sensor=?2",
                params![well, sensor.name()],
            )
            .map(|_| ())
            .map_err(|e| self.err(e))
    }
}

/// Why a transfer stopped.
#[derive(Debug)]
pub enum TransferError {
    /// The station answered with a response code other than 0.
    Refused {
        /// The station.
        station: Station,
        /// The response code.
        code: u8,
    },
    /// The reply did not decode.
    Decode(DecodeError),
    /// The archive could not store it.
    Store(StoreError),
    /// The station sent the batch it had just sent although it was acknowledged, or
    /// more batches than any store holds: it is not moving on, and the pull stops
    /// rather than asking forever (what came before is stored).
    NotMovingOn {
        /// The station.
        station: Station,
        /// Batches received in this pull.
        batches: u32,
    },
}

impl std::fmt::Display for TransferError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TransferError::Refused { station, code } => write!(
                f,
                "{station} answered response code {code} ({}){}",
                match *code {
                    2 => "invalid selection: a sensor or segment number it does not know",
                    3 => "a value out of range",
                    5 => "too few data bytes",
                    6 => "its store failed (a full disk, or the file locked by another program); see its log",
                    9 => "segments out of order: it restarted or another download came in between; send the file again",
                    10 => "calibration table refused: its log says why; the old table stays in force",
                    64 => "command not implemented",
                    _ => "refused",
                },
                if *code == 64 {
                    "; check that the address belongs to a concentrator or handheld of this network"
                } else {
                    ""
                }
            ),
            TransferError::Decode(e) => write!(f, "{e}"),
            TransferError::Store(e) => write!(f, "{e}"),
            TransferError::NotMovingOn { station, batches } => write!(
                f,
                "{station} is not moving on after {batches} batch(es): it sent an acknowledged \
                 batch again, or more than its store can hold; what came before is stored. \
                 Check its log, and that no other program answers at its address"
            ),
        }
    }
}

impl std::error::Error for TransferError {}

/// What the collector wants next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Step {
    /// Send [`Collector::request`] again (the next batch).
    More,
    /// Everything is across.
    Done,
}

/// The requester of command 144: asks `station` for batches until a batch comes
/// back empty, storing each batch (and moving the cursor) before acknowledging it.
pub struct Collector {
    station: Station,
    well: u8,
    via: Via,
    ack: u32,
    /// Batches received.
    pub batches: u32,
    /// Minutes new to the archive.
    pub new: u32,
    /// Minutes the archive had already.
    pub duplicated: u32,
    /// Records the station said remained after the last batch.
    pub remaining: u32,
    /// The last batch's data, to tell a station that repeats it.
    last_data: Vec<u8>,
}

/// More batches than a pull can need: a year of minutes at 11 a batch is under 48 000,
/// and no store holds a year.
const MAX_BATCHES: u32 = 60_000;

impl Collector {
    /// A transfer from `station` (a concentrator, or the handheld for a well), going
    /// on from the archive's cursor for that source.
    pub fn new(archive: &Archive, station: Station) -> Result<Self, StoreError> {
        let via = Via::of(station);
        let well = station.number();
        Ok(Collector {
            station,
            well,
            via,
            ack: archive.cursor(via, well)?,
            batches: 0,
            new: 0,
            duplicated: 0,
            remaining: 0,
            last_data: Vec::new(),
        })
    }

    /// The station asked.
    pub fn station(&self) -> Station {
        self.station
    }

    /// The next request: command 144 acknowledging the last batch stored.
    pub fn request(&self) -> Message {
        Message::request(self.station, TRANSFER, transfer_request(self.ack))
    }

    /// Takes the reply to [`Collector::request`]: stores the batch, and says whether
    /// to go on.
    pub fn on_reply(
        &mut self,
        reply: &Message,
        archive: &mut Archive,
        now_minute: u32,
    ) -> Result<Step, TransferError> {
        let rc = reply.response_code().unwrap_or(0);
        if rc != 0 {
            return Err(TransferError::Refused {
                station: self.station,
                code: rc,
            });
        }
        let batch = Batch::decode(&reply.data).map_err(TransferError::Decode)?;
        self.remaining = batch.remaining;
        if batch.records.is_empty() {
            return Ok(Step::Done);
        }
        // An acknowledged batch sent again, or no end in sight: a station that does
        // not move on would otherwise be asked forever.
        if reply.data == self.last_data || self.batches >= MAX_BATCHES {
            return Err(TransferError::NotMovingOn {
                station: self.station,
                batches: self.batches,
            });
        }
        self.last_data.clone_from(&reply.data);
        let s = archive
            .store_batch(self.via, self.well, &batch, now_minute)
            .map_err(TransferError::Store)?;
        self.batches += 1;
        self.new += s.new;
        self.duplicated += s.duplicated;
        if let Some(last) = batch.records.last() {
            self.ack = self.ack.max(last.minute);
        }
        Ok(Step::More)
    }
}

/// The requester of command 160: sends a table's ten segments in order.
pub struct CalibrationSender {
    station: Station,
    sensor: Sensor,
    table: Table,
    next: usize,
    mismatches: u8,
}

impl CalibrationSender {
    /// Sends `table` for `sensor` to `station`.
    pub fn new(station: Station, sensor: Sensor, table: Table) -> Self {
        CalibrationSender {
            station,
            sensor,
            table,
            next: 0,
            mismatches: 0,
        }
    }

    /// The next segment's request.
    pub fn request(&self) -> Message {
        let i = self.next.min(self.table.segments().len() - 1);
        Message::request(
            self.station,
            CALIBRATION,
            SegmentRequest {
                sensor: self.sensor,
                number: i as u8 + 1,
                segment: self.table.segments()[i],
            }
            .encode(),
        )
    }

    /// Takes the reply; `Done` when the station has put the table in force.
    pub fn on_reply(&mut self, reply: &Message) -> Result<Step, TransferError> {
        let rc = reply.response_code().unwrap_or(0);
        if rc != 0 {
            return Err(TransferError::Refused {
                station: self.station,
                code: rc,
            });
        }
        // A reply for another segment (a late reply to an earlier try): send this one
        // again.
        let echoed = SegmentReply::decode(&reply.data).ok();
        if !echoed
            .is_some_and(|r| r.sensor == self.sensor && usize::from(r.number) == self.next + 1)
        {
            self.mismatches += 1;
            if self.mismatches > 3 {
                return Err(TransferError::Decode(DecodeError::Field {
                    what: "command 160 reply",
                    problem:
                        "the station keeps echoing another sensor or segment than the one sent"
                            .into(),
                }));
            }
            return Ok(Step::More);
        }
        self.mismatches = 0;
        self.next += 1;
        if echoed.is_some_and(|r| r.state == TABLE_IN_FORCE) {
            return Ok(Step::Done);
        }
        if self.next >= self.table.segments().len() {
            return Err(TransferError::Decode(DecodeError::Field {
                what: "command 160 reply",
                problem: "all ten segments sent but the station did not put the table in force"
                    .into(),
            }));
        }
        Ok(Step::More)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::proto::Record;

    fn batch(minutes: std::ops::Range<u32>) -> Batch {
        Batch {
            remaining: 0,
            records: minutes.map(Record::empty).collect(),
        }
    }

    #[test]
    fn wells_cursors_and_duplicates() {
        let d = tempfile::tempdir().unwrap();
        let mut a = Archive::open(&d.path().join("a.db"), Durability::Process).unwrap();
        assert!(a.wells().unwrap().is_empty());
        let s = a
            .store_batch(Via::Concentrator, 5, &batch(10..20), 30)
            .unwrap();
        assert_eq!((s.new, s.duplicated), (10, 0));
        a.store_batch(Via::Handheld, 2, &batch(1..4), 30).unwrap();
        assert_eq!(a.wells().unwrap(), vec![2, 5]);
        assert!(a.holds(2).unwrap() && !a.holds(3).unwrap());
        // Cursors are per source: the handheld's does not move the concentrator's.
        assert_eq!(a.cursor(Via::Concentrator, 5).unwrap(), 19);
        assert_eq!(a.cursor(Via::Handheld, 5).unwrap(), 0);
        // A minute received twice is counted, not stored twice.
        let s = a.store_batch(Via::Handheld, 5, &batch(18..22), 31).unwrap();
        assert_eq!((s.new, s.duplicated), (2, 2));
        assert_eq!(a.duplicated().unwrap(), 2);
        assert_eq!(a.count(5).unwrap(), 12);
        // As a station, the handheld hands each well over with its own mark.
        let b = a.transfer(5, 0, 40).unwrap();
        assert_eq!((b.records.len(), b.remaining), (11, 1));
        let b = a.transfer(5, 20, 40).unwrap();
        assert_eq!(b.records.len(), 1);
        assert_eq!(a.unsent(5).unwrap(), 1);
        assert_eq!(a.unsent(2).unwrap(), 3);
    }

    /// A station that answers every request with the batch it has just sent (a broken
    /// peer, or another program at its address) ends the pull with an error instead
    /// of being asked forever; what it sent first is stored.
    #[test]
    fn a_station_that_repeats_an_acknowledged_batch_ends_the_pull() {
        let d = tempfile::tempdir().unwrap();
        let mut a = Archive::open(&d.path().join("a.db"), Durability::Process).unwrap();
        let station = Station::concentrator(3);
        let mut col = Collector::new(&a, station).unwrap();
        let reply = Message::reply(station, TRANSFER, [0, 0], batch(5..6).encode());
        assert_eq!(col.on_reply(&reply, &mut a, 10).unwrap(), Step::More);
        let e = col.on_reply(&reply, &mut a, 10).unwrap_err();
        assert!(
            matches!(e, TransferError::NotMovingOn { batches: 1, .. }),
            "{e}"
        );
        assert!(e.to_string().contains("not moving on"), "{e}");
        assert_eq!(a.count(3).unwrap(), 1);
        // A different batch next is progress.
        let mut col = Collector::new(&a, station).unwrap();
        for m in 6..9 {
            let r = Message::reply(station, TRANSFER, [0, 0], batch(m..m + 1).encode());
            assert_eq!(col.on_reply(&r, &mut a, 10).unwrap(), Step::More);
        }
    }
}
