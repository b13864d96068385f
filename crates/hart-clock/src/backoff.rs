//! One reconnect policy for everything that holds a connection or a port open for a
//! long time (the gateway's loops, its Modbus RTU slave, the MQTT clients of the
//! Sparkplug B publisher and the ingest, the historian's writer): after a failure,
//! wait, then try again, each wait twice the last up to a ceiling, and back to the
//! first after a success. `hart_host::reconnect` re-exports it.

use std::time::{Duration, Instant};

/// Waits between attempts to open a failed port again.
#[derive(Debug, Clone)]
pub struct Backoff {
    first: Duration,
    max: Duration,
    next: Duration,
    /// No attempt before this.
    until: Option<Instant>,
    /// Failures since the last success.
    failures: u32,
}

impl Backoff {
    /// Waits of `first`, doubling up to `max`.
    pub fn new(first: Duration, max: Duration) -> Self {
        Backoff {
            first,
            max: max.max(first),
            next: first,
            until: None,
            failures: 0,
        }
    }

    /// The gateway's loops and serial front ends: 1 s, doubling up to 30 s.
    pub fn ports() -> Self {
        Self::new(Duration::from_secs(1), Duration::from_secs(30))
    }

    /// A failure at `now`: how long until the next attempt.
    pub fn failed(&mut self, now: Instant) -> Duration {
        let wait = self.next;
        self.until = Some(now + wait);
        self.next = (self.next * 2).min(self.max);
        self.failures = self.failures.saturating_add(1);
        wait
    }

    /// Whether an attempt may be made at `now`.
    pub fn ready(&self, now: Instant) -> bool {
        self.until.is_none_or(|t| now >= t)
    }

    /// How long until an attempt may be made.
    pub fn wait(&self, now: Instant) -> Duration {
        self.until
            .map_or(Duration::ZERO, |t| t.saturating_duration_since(now))
    }

    /// Failures since the last success.
    pub fn failures(&self) -> u32 {
        self.failures
    }

    /// A success: the next failure waits `first` again.
    pub fn reset(&mut self) {
        self.next = self.first;
        self.until = None;
        self.failures = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn waits_double_up_to_the_ceiling_and_start_over_after_a_success() {
        let mut b = Backoff::new(Duration::from_secs(1), Duration::from_secs(5));
        let t = Instant::now();
        assert!(b.ready(t));
        let waits: Vec<u64> = (0..5).map(|_| b.failed(t).as_secs()).collect();
        assert_eq!(waits, [1, 2, 4, 5, 5]);
        assert!(!b.ready(t + Duration::from_secs(4)));
        assert!(b.ready(t + Duration::from_secs(5)));
        assert_eq!(b.failures(), 5);
        b.reset();
        assert_eq!(b.failed(t).as_secs(), 1);
    }
}
