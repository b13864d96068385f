//! Wall-clock times as counts since the Unix epoch (1970-01-01 00:00:00 UTC), and back.
//!
//! Unsigned counts take a time before the epoch as 0 and saturate at their largest
//! value; signed microseconds (the historian's database time) are negative before the
//! epoch. The reverse conversions take a count beyond what the system's time can hold
//! as the epoch itself, so a wrong time is kept where it can be seen to be wrong rather
//! than dropped or panicking.

use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// Whole seconds since the epoch (0 before it).
pub fn seconds(t: SystemTime) -> u64 {
    t.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs())
}

/// Milliseconds since the epoch (0 before it): Sparkplug B's time stamps, the web API's
/// times.
pub fn millis(t: SystemTime) -> u64 {
    t.duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_millis()).unwrap_or(u64::MAX))
}

/// Microseconds since the epoch (0 before it).
pub fn micros(t: SystemTime) -> u64 {
    t.duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_micros()).unwrap_or(u64::MAX))
}

/// Microseconds since the epoch, negative before it: the historian's database time.
pub fn signed_micros(t: SystemTime) -> i64 {
    match t.duration_since(UNIX_EPOCH) {
        Ok(d) => i64::try_from(d.as_micros()).unwrap_or(i64::MAX),
        Err(e) => i64::try_from(e.duration().as_micros())
            .map(|m| -m)
            .unwrap_or(i64::MIN),
    }
}

/// The time `ms` milliseconds after the epoch (the epoch itself when the system cannot
/// hold that time).
pub fn from_millis(ms: u64) -> SystemTime {
    UNIX_EPOCH
        .checked_add(Duration::from_millis(ms))
        .unwrap_or(UNIX_EPOCH)
}

/// The time `us` microseconds after the epoch, before it when negative (the epoch
/// itself when the system cannot hold that time).
pub fn from_signed_micros(us: i64) -> SystemTime {
    let d = Duration::from_micros(us.unsigned_abs());
    if us >= 0 {
        UNIX_EPOCH.checked_add(d)
    } else {
        UNIX_EPOCH.checked_sub(d)
    }
    .unwrap_or(UNIX_EPOCH)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_and_back() {
        let t = UNIX_EPOCH + Duration::from_micros(1_800_000_000_123_456);
        assert_eq!(seconds(t), 1_800_000_000);
        assert_eq!(millis(t), 1_800_000_000_123);
        assert_eq!(micros(t), 1_800_000_000_123_456);
        assert_eq!(signed_micros(t), 1_800_000_000_123_456);
        assert_eq!(from_signed_micros(signed_micros(t)), t);
        assert_eq!(
            from_millis(millis(t)),
            UNIX_EPOCH + Duration::from_millis(1_800_000_000_123)
        );
    }

    #[test]
    fn before_the_epoch_and_beyond_the_range() {
        let before = UNIX_EPOCH - Duration::from_micros(1_500);
        assert_eq!((seconds(before), millis(before), micros(before)), (0, 0, 0));
        assert_eq!(signed_micros(before), -1_500);
        assert_eq!(from_signed_micros(-1_500), before);
        // The farthest counts either way never panic.
        let _ = (from_millis(u64::MAX), from_signed_micros(i64::MIN));
        let _ = from_signed_micros(i64::MAX);
    }
}
