//! Averages of the stored minutes over minutes, hours, days, pentads, dekads and
//! months (docs/wells.md, "The PC: exports and plots").
//!
//! Periods are UTC. A pentad is a fifth of a month as hydrological and
//! meteorological bulletins count it: days 1-5, 6-10, 11-15, 16-20, 21-25 and 26 to
//! the end of the month (3 to 6 days). A dekad is a third of a month (the WMO
//! dekad): days 1-10, 11-20 and 21 to the end of the month (8 to 11 days). So every
//! pentad and dekad lies within one month, and months are whole numbers of them.

use std::fmt;

use chrono::{Datelike, NaiveDate};

use crate::proto::{Record, VALID_LEVEL, VALID_TEMPERATURE};

/// Minutes in an hour and in a day.
const HOUR: u32 = 60;
const DAY: u32 = 1440;

/// The length of the periods averaged over.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Every {
    /// Each stored minute on its own (no averaging).
    Minute,
    /// Clock hours, UTC.
    Hour,
    /// Days, 00:00 to 24:00 UTC.
    Day,
    /// Pentads of the month: days 1-5, 6-10, 11-15, 16-20, 21-25, 26-end.
    Pentad,
    /// Dekads of the month: days 1-10, 11-20, 21-end.
    Dekad,
    /// Calendar months.
    Month,
}

impl Every {
    /// Every period length, shortest first.
    pub const ALL: [Every; 6] = [
        Every::Minute,
        Every::Hour,
        Every::Day,
        Every::Pentad,
        Every::Dekad,
        Every::Month,
    ];

    /// Reads `minute`, `hour`, `day`, `5d`, `10d` or `month` (also `pentad` and
    /// `dekad`), as [`Every::name`] writes them.
    pub fn parse(s: &str) -> Result<Self, String> {
        Ok(match s.trim().to_ascii_lowercase().as_str() {
            "minute" => Every::Minute,
            "hour" => Every::Hour,
            "day" => Every::Day,
            "5d" | "pentad" => Every::Pentad,
            "10d" | "dekad" => Every::Dekad,
            "month" => Every::Month,
            other => {
                return Err(format!(
                    "`{other}` is not a period: use minute, hour, day, 5d (pentads of the \
                     month), 10d (dekads of the month) or month"
                ))
            }
        })
    }

    /// `minute`, `hour`, `day`, `5d`, `10d` or `month`.
    pub fn name(self) -> &'static str {
        match self {
            Every::Minute => "minute",
            Every::Hour => "hour",
            Every::Day => "day",
            Every::Pentad => "5d",
            Every::Dekad => "10d",
            Every::Month => "month",
        }
    }

    /// How the values are described in a sentence: `minute values`, `hourly means`,
    /// `daily means`, `pentad means`, `dekad means`, `monthly means`.
    pub fn describe(self) -> &'static str {
        match self {
            Every::Minute => "minute values",
            Every::Hour => "hourly means",
            Every::Day => "daily means",
            Every::Pentad => "pentad (5-day) means",
            Every::Dekad => "dekad (10-day) means",
            Every::Month => "monthly means",
        }
    }
}

impl fmt::Display for Every {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Every {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Every::parse(s)
    }
}

/// The date (UTC) of a minute (Unix time / 60).
pub(crate) fn date_of(minute: u32) -> NaiveDate {
    // 719 163 days from 0001-01-01 (day 1 of the common era) to 1970-01-01; a u32 of
    // minutes reaches the year 10136, well inside chrono's dates.
    NaiveDate::from_num_days_from_ce_opt(719_163 + (minute / DAY) as i32)
        .expect("a u32 of minutes is within chrono's dates")
}

/// The minute (Unix time / 60) at which a date starts, saturating at `u32::MAX`.
pub(crate) fn minute_of_date(d: NaiveDate) -> u32 {
    let days = i64::from(d.num_days_from_ce()) - 719_163;
    (days.max(0) * i64::from(DAY)).min(i64::from(u32::MAX)) as u32
}

/// The first day of the month after `d`'s.
fn next_month(d: NaiveDate) -> NaiveDate {
    let (y, m) = if d.month() == 12 {
        (d.year() + 1, 1)
    } else {
        (d.year(), d.month() + 1)
    };
    NaiveDate::from_ymd_opt(y, m, 1).expect("the first of a month exists")
}

/// The period of `every` that holds `minute` (Unix time / 60): its first minute
/// and the first minute after it (`start <= minute < end`; the last period a `u32`
/// can name ends at `u32::MAX`, which is then included).
pub fn period_of(minute: u32, every: Every) -> (u32, u32) {
    let fixed = |len: u32| {
        let start = minute - minute % len;
        (start, start.saturating_add(len))
    };
    match every {
        Every::Minute => (minute, minute.saturating_add(1)),
        Every::Hour => fixed(HOUR),
        Every::Day => fixed(DAY),
        Every::Pentad | Every::Dekad | Every::Month => {
            let d = date_of(minute);
            let (len, parts) = match every {
                Every::Pentad => (5, 6),
                Every::Dekad => (10, 3),
                _ => (31, 1),
            };
            // The last part of the month takes the days left over.
            let part = ((d.day() - 1) / len).min(parts - 1);
            let first = d.with_day(part * len + 1).expect("a day 1-26 exists");
            let end = if part == parts - 1 {
                next_month(d)
            } else {
                first + chrono::Duration::days(i64::from(len))
            };
            (minute_of_date(first), minute_of_date(end))
        }
    }
}

/// The averages of one period.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Average {
    /// The period's first minute (Unix time / 60).
    pub start: u32,
    /// The first minute after the period.
    pub end: u32,
    /// Mean water temperature, °C, of the valid minutes; `None` if there are none.
    pub temperature: Option<f64>,
    /// Mean water level, m, of the valid minutes; `None` if there are none.
    pub level: Option<f64>,
    /// Minutes with a valid water temperature.
    pub temperature_n: u32,
    /// Minutes with a valid level.
    pub level_n: u32,
    /// Lowest valid water temperature, °C.
    pub temperature_min: Option<f64>,
    /// Highest valid water temperature, °C.
    pub temperature_max: Option<f64>,
    /// Lowest valid level, m.
    pub level_min: Option<f64>,
    /// Highest valid level, m.
    pub level_max: Option<f64>,
}

/// A running mean of one quantity: the sum of the differences from the first value
/// (so the sum does not grow with the values' size) with Neumaier's compensation,
/// and the extremes.
#[derive(Debug, Clone, Copy, Default)]
struct Mean {
    n: u32,
    first: f64,
    sum: f64,
    compensation: f64,
    min: f64,
    max: f64,
}

impl Mean {
    fn add(&mut self, x: f64) {
        if self.n == 0 {
            self.first = x;
            self.min = x;
            self.max = x;
        } else {
            self.min = self.min.min(x);
            self.max = self.max.max(x);
        }
        self.n += 1;
        let d = x - self.first;
        let t = self.sum + d;
        self.compensation += if self.sum.abs() >= d.abs() {
            (self.sum - t) + d
        } else {
            (d - t) + self.sum
        };
        self.sum = t;
    }

    /// Mean, minimum, maximum.
    fn get(&self) -> (Option<f64>, Option<f64>, Option<f64>) {
        if self.n == 0 {
            return (None, None, None);
        }
        let mean = self.first + (self.sum + self.compensation) / f64::from(self.n);
        // Rounding cannot move a mean outside its values' range.
        let mean = mean.clamp(self.min, self.max);
        (Some(mean), Some(self.min), Some(self.max))
    }
}

/// One period being summed.
struct Acc {
    start: u32,
    end: u32,
    temperature: Mean,
    level: Mean,
}

impl Acc {
    fn new((start, end): (u32, u32)) -> Self {
        Acc {
            start,
            end,
            temperature: Mean::default(),
            level: Mean::default(),
        }
    }

    fn add(&mut self, r: &Record) {
        if r.valid & VALID_TEMPERATURE != 0 && r.temperature.is_finite() {
            self.temperature.add(r.temperature);
        }
        if r.valid & VALID_LEVEL != 0 && r.level.is_finite() {
            self.level.add(r.level);
        }
    }

    fn finish(self) -> Average {
        let (temperature, temperature_min, temperature_max) = self.temperature.get();
        let (level, level_min, level_max) = self.level.get();
        Average {
            start: self.start,
            end: self.end,
            temperature,
            level,
            temperature_n: self.temperature.n,
            level_n: self.level.n,
            temperature_min,
            temperature_max,
            level_min,
            level_max,
        }
    }
}

/// The averages of `records` over the periods of `every`, oldest first.
///
/// Only valid values count (the record's valid bit set and the value finite). A
/// period without any record is left out; a period with records but no valid value
/// of a quantity has `None` (and a count of 0) for it. The records are expected in
/// time order, as [`crate::archive::Archive::range`] gives them; records out of
/// order are still put in their periods, at the cost of sorting the periods.
pub fn averages<I: IntoIterator<Item = Record>>(records: I, every: Every) -> Vec<Average> {
    let mut out: Vec<Average> = Vec::new();
    let mut cur: Option<Acc> = None;
    let mut sorted = true;
    let mut extra: Vec<Acc> = Vec::new();
    for r in records {
        match &mut cur {
            Some(a) if a.start <= r.minute && (r.minute < a.end || a.end == u32::MAX) => a.add(&r),
            _ => {
                let mut a = Acc::new(period_of(r.minute, every));
                a.add(&r);
                if let Some(done) = cur.replace(a) {
                    if cur.as_ref().is_some_and(|c| c.start < done.start) {
                        sorted = false;
                    }
                    if sorted {
                        out.push(done.finish());
                    } else {
                        extra.push(done);
                    }
                }
            }
        }
    }
    if let Some(a) = cur {
        if sorted {
            out.push(a.finish());
        } else {
            extra.push(a);
        }
    }
    if sorted {
        return out;
    }
    merge_unsorted(out, extra)
}

/// Merges period pieces that came out of order (rare: the archive gives records in
/// order). Pieces of the same period are combined by count-weighted means.
fn merge_unsorted(done: Vec<Average>, rest: Vec<Acc>) -> Vec<Average> {
    let mut all: Vec<Average> = done;
    all.extend(rest.into_iter().map(Acc::finish));
    all.sort_by_key(|a| a.start);
    let mut out: Vec<Average> = Vec::with_capacity(all.len());
    for a in all {
        match out.last_mut() {
            Some(b) if b.start == a.start => {
                let merge = |m1: Option<f64>, n1: u32, m2: Option<f64>, n2: u32| match (m1, m2) {
                    (Some(x), Some(y)) => {
                        Some((x * f64::from(n1) + y * f64::from(n2)) / f64::from(n1 + n2))
                    }
                    (x, None) => x,
                    (None, y) => y,
                };
                let lo = |x: Option<f64>, y: Option<f64>| match (x, y) {
                    (Some(x), Some(y)) => Some(x.min(y)),
                    (x, y) => x.or(y),
                };
                let hi = |x: Option<f64>, y: Option<f64>| match (x, y) {
                    (Some(x), Some(y)) => Some(x.max(y)),
                    (x, y) => x.or(y),
                };
                b.temperature = merge(
                    b.temperature,
                    b.temperature_n,
                    a.temperature,
                    a.temperature_n,
                );
                b.level = merge(b.level, b.level_n, a.level, a.level_n);
                b.temperature_n += a.temperature_n;
                b.level_n += a.level_n;
                b.temperature_min = lo(b.temperature_min, a.temperature_min);
                b.temperature_max = hi(b.temperature_max, a.temperature_max);
                b.level_min = lo(b.level_min, a.level_min);
                b.level_max = hi(b.level_max, a.level_max);
            }
            _ => out.push(a),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The minute of a UTC date and time.
    fn at(y: i32, mo: u32, d: u32, h: u32, mi: u32) -> u32 {
        minute_of_date(NaiveDate::from_ymd_opt(y, mo, d).unwrap()) + h * 60 + mi
    }

    fn day(y: i32, mo: u32, d: u32) -> u32 {
        at(y, mo, d, 0, 0)
    }

    fn rec(minute: u32, t: Option<f64>, l: Option<f64>) -> Record {
        let mut r = Record::empty(minute);
        if let Some(t) = t {
            r.valid |= VALID_TEMPERATURE;
            r.temperature = t;
            r.t_raw = 1;
        }
        if let Some(l) = l {
            r.valid |= VALID_LEVEL;
            r.level = l;
            r.l_raw = 1;
        }
        r
    }

    #[test]
    fn names_round_trip() {
        for e in Every::ALL {
            assert_eq!(Every::parse(e.name()), Ok(e));
            assert_eq!(e.name().parse::<Every>(), Ok(e));
        }
        assert_eq!(Every::parse("Pentad"), Ok(Every::Pentad));
        assert_eq!(Every::parse("dekad"), Ok(Every::Dekad));
        let e = Every::parse("week").unwrap_err();
        assert!(e.contains("week") && e.contains("10d"), "{e}");
    }

    #[test]
    fn epoch_and_simulation_start() {
        assert_eq!(day(1970, 1, 1), 0);
        // sim::START, 2026-03-01 00:00 UTC.
        assert_eq!(u64::from(day(2026, 3, 1)) * 60_000, crate::sim::START);
        assert_eq!(date_of(day(2026, 3, 1) + 1439).day(), 1);
        assert_eq!(date_of(day(2026, 3, 1) + 1440).day(), 2);
    }

    #[test]
    fn minutes_hours_days() {
        let m = at(2026, 3, 14, 15, 9);
        assert_eq!(period_of(m, Every::Minute), (m, m + 1));
        assert_eq!(
            period_of(m, Every::Hour),
            (at(2026, 3, 14, 15, 0), at(2026, 3, 14, 16, 0))
        );
        assert_eq!(
            period_of(at(2026, 3, 14, 15, 0), Every::Hour).0,
            at(2026, 3, 14, 15, 0)
        );
        assert_eq!(
            period_of(at(2026, 3, 14, 15, 59), Every::Hour).1,
            at(2026, 3, 14, 16, 0)
        );
        assert_eq!(
            period_of(m, Every::Day),
            (day(2026, 3, 14), day(2026, 3, 15))
        );
        // Across the end of a year.
        assert_eq!(
            period_of(at(2026, 12, 31, 23, 59), Every::Day),
            (day(2026, 12, 31), day(2027, 1, 1))
        );
        assert_eq!(period_of(0, Every::Day), (0, 1440));
    }

    #[test]
    fn months_including_february() {
        let month = |y, mo, d| period_of(at(y, mo, d, 12, 0), Every::Month);
        // Leap year: 29 days.
        assert_eq!(month(2024, 2, 29), (day(2024, 2, 1), day(2024, 3, 1)));
        assert_eq!(month(2024, 2, 29).1 - month(2024, 2, 29).0, 29 * 1440);
        // Not a leap year: 28 days; 1900 was not one, 2000 was.
        assert_eq!(month(2026, 2, 28), (day(2026, 2, 1), day(2026, 3, 1)));
        assert_eq!(month(2026, 2, 1).1 - month(2026, 2, 1).0, 28 * 1440);
        assert_eq!(month(2000, 2, 10).1 - month(2000, 2, 10).0, 29 * 1440);
        assert_eq!(month(2100, 2, 10).1 - month(2100, 2, 10).0, 28 * 1440);
        // December runs into the next year; 30- and 31-day months.
        assert_eq!(month(2026, 12, 31), (day(2026, 12, 1), day(2027, 1, 1)));
        assert_eq!(month(2026, 4, 30), (day(2026, 4, 1), day(2026, 5, 1)));
        assert_eq!(month(2026, 3, 31), (day(2026, 3, 1), day(2026, 4, 1)));
        // The last minute of a month and the first of the next.
        assert_eq!(
            period_of(day(2026, 4, 1) - 1, Every::Month).1,
            day(2026, 4, 1)
        );
        assert_eq!(period_of(day(2026, 4, 1), Every::Month).0, day(2026, 4, 1));
    }

    #[test]
    fn pentads() {
        let p = |y, mo, d| period_of(at(y, mo, d, 0, 0), Every::Pentad);
        for (d, first, last) in [
            (1, 1, 5),
            (5, 1, 5),
            (6, 6, 10),
            (10, 6, 10),
            (11, 11, 15),
            (16, 16, 20),
            (20, 16, 20),
            (21, 21, 25),
            (25, 21, 25),
        ] {
            assert_eq!(
                p(2026, 3, d),
                (day(2026, 3, first), day(2026, 3, last + 1)),
                "day {d}"
            );
        }
        // The sixth pentad takes the rest of the month: 6 days in a 31-day month.
        assert_eq!(p(2026, 3, 26), (day(2026, 3, 26), day(2026, 4, 1)));
        assert_eq!(p(2026, 3, 31), (day(2026, 3, 26), day(2026, 4, 1)));
        assert_eq!(p(2026, 3, 31).1 - p(2026, 3, 31).0, 6 * 1440);
        // 5 days in a 30-day month, 4 in a leap February, 3 in another February.
        assert_eq!(p(2026, 4, 30).1 - p(2026, 4, 30).0, 5 * 1440);
        assert_eq!(p(2024, 2, 29), (day(2024, 2, 26), day(2024, 3, 1)));
        assert_eq!(p(2026, 2, 28), (day(2026, 2, 26), day(2026, 3, 1)));
        assert_eq!(p(2026, 2, 26).1 - p(2026, 2, 26).0, 3 * 1440);
        // The last minute of a pentad.
        assert_eq!(
            period_of(day(2026, 3, 6) - 1, Every::Pentad),
            (day(2026, 3, 1), day(2026, 3, 6))
        );
        // December's last pentad ends with the year.
        assert_eq!(p(2026, 12, 31), (day(2026, 12, 26), day(2027, 1, 1)));
    }

    #[test]
    fn dekads() {
        let k = |y, mo, d| period_of(at(y, mo, d, 6, 30), Every::Dekad);
        assert_eq!(k(2026, 3, 1), (day(2026, 3, 1), day(2026, 3, 11)));
        assert_eq!(k(2026, 3, 10), (day(2026, 3, 1), day(2026, 3, 11)));
        assert_eq!(k(2026, 3, 11), (day(2026, 3, 11), day(2026, 3, 21)));
        assert_eq!(k(2026, 3, 20), (day(2026, 3, 11), day(2026, 3, 21)));
        // The third dekad: 11 days in a 31-day month, 10 in a 30-day one, 9 in a
        // leap February, 8 in another.
        assert_eq!(k(2026, 3, 21), (day(2026, 3, 21), day(2026, 4, 1)));
        assert_eq!(k(2026, 3, 31).1 - k(2026, 3, 31).0, 11 * 1440);
        assert_eq!(k(2026, 6, 30).1 - k(2026, 6, 30).0, 10 * 1440);
        assert_eq!(k(2024, 2, 29), (day(2024, 2, 21), day(2024, 3, 1)));
        assert_eq!(k(2024, 2, 29).1 - k(2024, 2, 29).0, 9 * 1440);
        assert_eq!(k(2026, 2, 21).1 - k(2026, 2, 21).0, 8 * 1440);
        assert_eq!(k(2026, 12, 25), (day(2026, 12, 21), day(2027, 1, 1)));
    }

    #[test]
    fn periods_tile_a_year() {
        // Consecutive periods touch, and the minutes of each map back to it.
        for e in [Every::Day, Every::Pentad, Every::Dekad, Every::Month] {
            let mut m = day(2024, 1, 1);
            let mut n = 0;
            while m < day(2025, 1, 1) {
                let (s, end) = period_of(m, e);
                assert_eq!(s, m, "{e}");
                assert!(end > s);
                assert_eq!(period_of(end - 1, e), (s, end), "{e}");
                m = end;
                n += 1;
            }
            assert_eq!(m, day(2025, 1, 1), "{e}");
            let expected = match e {
                Every::Day => 366,
                Every::Pentad => 72,
                Every::Dekad => 36,
                _ => 12,
            };
            assert_eq!(n, expected, "{e}");
        }
    }

    #[test]
    fn the_end_of_time() {
        assert_eq!(period_of(u32::MAX, Every::Minute), (u32::MAX, u32::MAX));
        let (s, e) = period_of(u32::MAX, Every::Hour);
        assert!(s < e && e == u32::MAX);
        let (s, e) = period_of(u32::MAX, Every::Month);
        assert!(s < e && e == u32::MAX);
    }

    #[test]
    fn averages_skip_invalid_values() {
        let h = at(2026, 3, 1, 0, 0);
        let records = vec![
            rec(h, Some(15.0), Some(10.0)),
            rec(h + 1, Some(15.2), None),
            rec(h + 2, None, Some(10.2)),
            // A NaN with its valid bit set does not count either.
            rec(h + 3, Some(f64::NAN), Some(10.4)),
            // The next hour: only invalid values.
            rec(h + 60, None, None),
            rec(h + 61, None, Some(9.0)),
            // Two hours later (the hour between has no record: left out).
            rec(h + 180, Some(16.0), Some(11.0)),
        ];
        let a = averages(records, Every::Hour);
        assert_eq!(a.len(), 3, "{a:?}");
        assert_eq!((a[0].start, a[0].end), (h, h + 60));
        assert_eq!(a[0].temperature_n, 2);
        assert_eq!(a[0].level_n, 3);
        assert!((a[0].temperature.unwrap() - 15.1).abs() < 1e-12);
        assert!((a[0].level.unwrap() - 10.2).abs() < 1e-12);
        assert_eq!(a[0].temperature_min, Some(15.0));
        assert_eq!(a[0].temperature_max, Some(15.2));
        assert_eq!(a[0].level_min, Some(10.0));
        assert_eq!(a[0].level_max, Some(10.4));
        assert_eq!(a[1].start, h + 60);
        assert_eq!(a[1].temperature, None);
        assert_eq!(a[1].temperature_min, None);
        assert_eq!(a[1].temperature_n, 0);
        assert_eq!(a[1].level, Some(9.0));
        assert_eq!(a[2].start, h + 180);
        assert_eq!(a[2].temperature, Some(16.0));
        // A day holds them all.
        let d = averages(
            vec![rec(h, Some(1.0), None), rec(h + 1439, Some(3.0), None)],
            Every::Day,
        );
        assert_eq!(d.len(), 1);
        assert_eq!(d[0].temperature, Some(2.0));
        assert!(averages(Vec::new(), Every::Month).is_empty());
    }

    #[test]
    fn minute_averages_are_the_values() {
        let h = at(2026, 3, 1, 0, 0);
        let a = averages(
            vec![rec(h, Some(15.2), None), rec(h + 2, None, Some(10.0))],
            Every::Minute,
        );
        assert_eq!(a.len(), 2);
        assert_eq!(
            (a[0].temperature, a[0].temperature_n, a[0].level_n),
            (Some(15.2), 1, 0)
        );
        assert_eq!(
            (a[1].start, a[1].end, a[1].level),
            (h + 2, h + 3, Some(10.0))
        );
    }

    #[test]
    fn a_month_of_minutes_keeps_its_precision() {
        // 44 640 minutes of 10 m plus a tiny tide: the mean is exact to far better
        // than the 0.1 mm the exports print.
        let start = at(2026, 3, 1, 0, 0);
        let n = 31 * 1440;
        let records: Vec<Record> = (0..n)
            .map(|i| {
                let x = 10.0 + 0.008 * (i as f64 * std::f64::consts::TAU / 745.2).cos();
                rec(start + i, Some(15.2 + 1e-7 * i as f64), Some(x))
            })
            .collect();
        let exact_t = 15.2 + 1e-7 * (n - 1) as f64 / 2.0;
        let a = averages(records.clone(), Every::Month);
        assert_eq!(a.len(), 1);
        assert_eq!(a[0].temperature_n, n);
        assert!((a[0].temperature.unwrap() - exact_t).abs() < 1e-11);
        let mean_l = records.iter().map(|r| r.level - 10.0).sum::<f64>() / n as f64 + 10.0;
        assert!((a[0].level.unwrap() - mean_l).abs() < 1e-11);
    }

    #[test]
    fn records_out_of_order_still_land_in_their_periods() {
        let h = at(2026, 3, 1, 0, 0);
        let a = averages(
            vec![
                rec(h + 60, Some(2.0), None),
                rec(h, Some(1.0), None),
                rec(h + 61, Some(4.0), None),
            ],
            Every::Hour,
        );
        assert_eq!(a.len(), 2, "{a:?}");
        assert_eq!((a[0].start, a[0].temperature), (h, Some(1.0)));
        assert_eq!(
            (a[1].start, a[1].temperature, a[1].temperature_n),
            (h + 60, Some(3.0), 2)
        );
    }

    proptest! {
        /// Records out of order give the same periods, counts and (to rounding) means.
        #[test]
        fn order_does_not_matter(
            values in prop::collection::vec((0u32..20_000, -5.0f64..5.0), 1..200),
            e in every(),
            seed in any::<u64>(),
        ) {
            let mut minutes: Vec<u32> = values.iter().map(|v| 29_000_000 + v.0 * 7).collect();
            minutes.sort_unstable();
            minutes.dedup();
            let sorted: Vec<Record> = minutes
                .iter()
                .zip(&values)
                .map(|(m, v)| rec(*m, Some(v.1), None))
                .collect();
            let mut shuffled = sorted.clone();
            let mut rng = hart_rng::Rng::new(seed);
            for i in (1..shuffled.len()).rev() {
                shuffled.swap(i, (rng.next_u64() % (i as u64 + 1)) as usize);
            }
            let a = averages(sorted, e);
            let b = averages(shuffled, e);
            prop_assert_eq!(a.len(), b.len());
            for (x, y) in a.iter().zip(&b) {
                prop_assert_eq!((x.start, x.end, x.temperature_n), (y.start, y.end, y.temperature_n));
                prop_assert!((x.temperature.unwrap() - y.temperature.unwrap()).abs() < 1e-9);
                prop_assert_eq!(x.temperature_min, y.temperature_min);
                prop_assert_eq!(x.temperature_max, y.temperature_max);
            }
        }
    }

    fn every() -> impl Strategy<Value = Every> {
        prop::sample::select(Every::ALL.to_vec())
    }

    proptest! {
        /// The counts of all periods add up to the valid values given, each period
        /// holds its records, and each mean lies between its extremes.
        #[test]
        fn counts_add_up(
            steps in prop::collection::vec((1u32..5000, 0u8..8, -50.0f64..50.0, 0.0f64..20.0), 0..400),
            e in every(),
            start in 0u32..40_000_000,
        ) {
            let mut m = start;
            let mut records = Vec::new();
            for (step, valid, t, l) in steps {
                m += step;
                let mut r = Record::empty(m);
                r.valid = valid;
                if valid & VALID_TEMPERATURE != 0 { r.temperature = t; }
                if valid & VALID_LEVEL != 0 { r.level = l; }
                records.push(r);
            }
            let n_t = records.iter().filter(|r| r.valid & VALID_TEMPERATURE != 0).count() as u32;
            let n_l = records.iter().filter(|r| r.valid & VALID_LEVEL != 0).count() as u32;
            let a = averages(records.clone(), e);
            prop_assert_eq!(a.iter().map(|x| x.temperature_n).sum::<u32>(), n_t);
            prop_assert_eq!(a.iter().map(|x| x.level_n).sum::<u32>(), n_l);
            for w in a.windows(2) {
                prop_assert!(w[0].end <= w[1].start);
            }
            for x in &a {
                prop_assert_eq!(period_of(x.start, e), (x.start, x.end));
                prop_assert!(records.iter().any(|r| r.minute >= x.start && r.minute < x.end));
                if let (Some(v), Some(lo), Some(hi)) = (x.temperature, x.temperature_min, x.temperature_max) {
                    prop_assert!(lo <= v && v <= hi);
                }
                if let (Some(v), Some(lo), Some(hi)) = (x.level, x.level_min, x.level_max) {
                    prop_assert!(lo <= v && v <= hi);
                }
                prop_assert_eq!(x.temperature.is_some(), x.temperature_n > 0);
                prop_assert_eq!(x.level.is_some(), x.level_n > 0);
            }
            for r in &records {
                let p = period_of(r.minute, e);
                prop_assert!(a.iter().any(|x| (x.start, x.end) == p));
            }
        }
    }
}
