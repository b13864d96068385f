//! Times and durations of the command line, and the bucket arithmetic of aggregated
//! queries.

use std::time::{Duration, SystemTime};

use crate::Error;

const TIME_HELP: &str =
    "use RFC 3339 in UTC (2026-01-31T12:00:00Z), now, or a time before now such as -1h, -30m or -7d";

/// Parses a `--from`/`--to` time: RFC 3339 in UTC (`2026-01-31T12:00:00Z`, fractions of
/// a second allowed, a space in place of the `T`), `now`, or a time before `now` such
/// as `-1h`, `-90s`, `-1d 12h` (humantime durations).
pub fn parse_time(s: &str, now: SystemTime) -> Result<SystemTime, Error> {
    let t = s.trim();
    if t.eq_ignore_ascii_case("now") {
        return Ok(now);
    }
    if let Some(rest) = t.strip_prefix('-') {
        let d = humantime::parse_duration(rest.trim())
            .map_err(|e| Error::Usage(format!("'{s}': not a duration ({e}); {TIME_HELP}")))?;
        return now
            .checked_sub(d)
            .filter(|t| *t >= std::time::UNIX_EPOCH)
            .ok_or_else(|| Error::Usage(format!("'{s}': before 1970; {TIME_HELP}")));
    }
    humantime::parse_rfc3339_weak(t)
        .map_err(|e| Error::Usage(format!("'{s}': not a time ({e}); {TIME_HELP}")))
}

/// Parses an `--every` bucket width: a humantime duration (`1s`, `1m`, `15min`, `1h`,
/// `1d`) of at least a microsecond.
pub fn parse_every(s: &str) -> Result<Duration, Error> {
    let d = humantime::parse_duration(s.trim()).map_err(|e| {
        Error::Usage(format!(
            "--every '{s}': not a duration ({e}); use e.g. 1s, 1m, 15min, 1h or 1d"
        ))
    })?;
    if d.as_micros() == 0 || i64::try_from(d.as_micros()).is_err() {
        return Err(Error::Usage(format!(
            "--every '{s}': must be at least 1us and at most a few hundred thousand years"
        )));
    }
    Ok(d)
}

/// The start of the bucket of width `every_us` holding `time_us` (both in microseconds
/// since 1970): buckets are aligned on multiples of their width since 1970-01-01 UTC,
/// so `--every 1m` gives whole minutes and `--every 1d` whole UTC days. The SQL of
/// both backends computes the same thing as `time - (((time % e) + e) % e)`.
pub fn bucket_start(time_us: i64, every_us: i64) -> i64 {
    time_us - time_us.rem_euclid(every_us.max(1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::UNIX_EPOCH;

    fn at(s: u64) -> SystemTime {
        UNIX_EPOCH + Duration::from_secs(s)
    }

    #[test]
    fn forms() {
        let now = at(1_800_000_000);
        assert_eq!(parse_time("now", now).unwrap(), now);
        assert_eq!(parse_time("-1h", now).unwrap(), at(1_800_000_000 - 3600));
        assert_eq!(parse_time("-1d", now).unwrap(), at(1_800_000_000 - 86_400));
        assert_eq!(parse_time("1970-01-02T00:00:00Z", now).unwrap(), at(86_400));
        assert_eq!(
            parse_time("1970-01-01 00:00:01.5Z", now).unwrap(),
            UNIX_EPOCH + Duration::from_millis(1500)
        );
        for bad in [
            "",
            "yesterday",
            "-",
            "-1x",
            "2026-13-01T00:00:00Z",
            "-99999999999999d",
        ] {
            let e = parse_time(bad, now).unwrap_err();
            assert!(matches!(e, Error::Usage(_)), "{bad}: {e:?}");
            assert!(e.to_string().contains("RFC 3339"), "{e}");
        }
    }

    #[test]
    fn every() {
        assert_eq!(parse_every("1m").unwrap(), Duration::from_secs(60));
        assert!(parse_every("0s").is_err());
        assert!(parse_every("soon").is_err());
    }

    proptest::proptest! {
        /// The parser never panics, whatever it is given.
        #[test]
        fn any_text_is_safe(s in ".{0,40}", now in 0u64..4_000_000_000) {
            let _ = parse_time(&s, at(now));
            let _ = parse_every(&s);
        }

        /// A printed time parses back to itself.
        #[test]
        fn rfc3339_round_trip(us in 0i64..8_000_000_000_000_000) {
            let t = crate::from_micros(us);
            let s = humantime::format_rfc3339_micros(t).to_string();
            proptest::prop_assert_eq!(parse_time(&s, at(0)).unwrap(), t);
        }

        /// Relative times are `now` less the duration.
        #[test]
        fn relative(secs in 0u64..1_000_000_000, now in 1_000_000_000u64..4_000_000_000) {
            let t = parse_time(&format!("-{secs}s"), at(now)).unwrap();
            proptest::prop_assert_eq!(t, at(now - secs));
        }

        /// A bucket holds its time, starts on a multiple of its width, and the SQL
        /// formula gives the same start.
        #[test]
        fn buckets(t in -10_000_000_000_000_000i64..10_000_000_000_000_000, e in 1i64..1_000_000_000_000) {
            let b = bucket_start(t, e);
            proptest::prop_assert!(b <= t && t - b < e);
            proptest::prop_assert_eq!(b.rem_euclid(e), 0);
            proptest::prop_assert_eq!(b, t - (((t % e) + e) % e));
        }
    }
}
