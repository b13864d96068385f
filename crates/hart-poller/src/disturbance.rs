//! A babbling loop: a device that sends garbage or burst frames without pause, or
//! answers at every polling address. The loop's task counts what its line hears and
//! asks [`Disturbance`] (plain code over counters and time passed in) whether the loop
//! is disturbed; while it is, every device on it has the quality "loop disturbed"
//! (its values may be wrong or from another device), and the loop says why on every
//! front end. It recovers by itself when the line has been quiet for a window.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// The window over which a loop's line is judged.
pub const DISTURBANCE_WINDOW: Duration = Duration::from_secs(10);

/// Damaged frames in one window, with no transaction completed, that mark a loop
/// disturbed (a device that lost a reply now and then does not come near).
pub const DAMAGED_LIMIT: u64 = 20;

/// Burst frames per second, over a window, that mark a loop disturbed. A burst device
/// leaves each master a chance between its frames: at 1200 bit/s a loop carries at
/// most about three short frames a second, however many devices burst.
pub const BURSTS_PER_SECOND_LIMIT: u64 = 5;

/// How long a device seen at two polling addresses keeps its loop disturbed (a scan
/// visits each address again only every rescan).
pub const DUPLICATE_HOLD: Duration = Duration::from_secs(60);

/// What a loop's line has heard since it started: counters that only grow.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LineCounters {
    /// Transactions that got a reply.
    pub completed: u64,
    /// Damaged frames and noise.
    pub damaged: u64,
    /// Burst frames.
    pub bursts: u64,
}

/// Whether a loop is disturbed, from its [`LineCounters`] over time.
#[derive(Debug, Default)]
pub struct Disturbance {
    samples: VecDeque<(Instant, LineCounters)>,
    duplicate: Option<(Instant, String)>,
    reason: Option<String>,
}

impl Disturbance {
    /// Records the line's counters at `now`; returns the reason the loop is disturbed,
    /// or `None` while it is not. Call it every turn or so (samples are kept one
    /// window back).
    pub fn observe(&mut self, now: Instant, counters: LineCounters) -> Option<&str> {
        if self.samples.back().is_none_or(|(t, c)| {
            *c != counters || now.saturating_duration_since(*t) >= Duration::from_millis(500)
        }) {
            self.samples.push_back((now, counters));
        }
        // Keep one sample at least a window old, to compare with.
        while self.samples.len() > 2
            && self
                .samples
                .get(1)
                .is_some_and(|(t, _)| now.saturating_duration_since(*t) >= DISTURBANCE_WINDOW)
        {
            self.samples.pop_front();
        }
        if self
            .duplicate
            .as_ref()
            .is_some_and(|(t, _)| now.saturating_duration_since(*t) >= DUPLICATE_HOLD)
        {
            self.duplicate = None;
        }
        self.reason = self
            .judge(now)
            .or_else(|| self.duplicate.clone().map(|d| d.1));
        self.reason.as_deref()
    }

    fn judge(&self, now: Instant) -> Option<String> {
        let (t0, first) = self.samples.front()?;
        let (_, last) = self.samples.back()?;
        let span = now.saturating_duration_since(*t0);
        let damaged = last.damaged.saturating_sub(first.damaged);
        let completed = last.completed.saturating_sub(first.completed);
        let bursts = last.bursts.saturating_sub(first.bursts);
        let secs = span.as_secs().max(1);
        // A disturbance is judged on a whole window, or on counts so high that part
        // of one says it (a flood).
        let whole = span >= DISTURBANCE_WINDOW;
        if (whole || damaged >= 5 * DAMAGED_LIMIT) && damaged >= DAMAGED_LIMIT && completed == 0 {
            return Some(format!(
                "garbage on the line: {damaged} damaged frames in {secs} s and no reply; a \
                 device or the wiring is babbling (disconnect devices one by one to find it)"
            ));
        }
        let limit = BURSTS_PER_SECOND_LIMIT * DISTURBANCE_WINDOW.as_secs();
        if (whole && bursts > limit) || bursts > 5 * limit {
            return Some(format!(
                "burst frames without pause: {bursts} in {secs} s; a device bursts faster \
                 than a loop carries (check its burst settings, commands 108-109)"
            ));
        }
        None
    }

    /// The same device (`unique_id`) answered at polling addresses `first` and
    /// `second` at `now`: it answers addresses that are not its own.
    pub fn duplicate(&mut self, now: Instant, unique_id: &str, first: u8, second: u8) {
        self.duplicate = Some((
            now,
            format!(
                "device {unique_id} answers at polling addresses {first} and {second}: it \
                 answers addresses not its own, so values read by address may be its"
            ),
        ));
    }

    /// Why the loop is disturbed, as of the last [`Disturbance::observe`].
    pub fn reason(&self) -> Option<&str> {
        self.reason.as_deref()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(t0: Instant, ms: u64) -> Instant {
        t0 + Duration::from_millis(ms)
    }

    #[test]
    fn a_healthy_loop_with_a_lost_reply_now_and_then_is_not_disturbed() {
        let mut d = Disturbance::default();
        let t0 = Instant::now();
        let mut c = LineCounters::default();
        for i in 0..600u64 {
            c.completed += 1;
            if i % 50 == 0 {
                c.damaged += 1;
            }
            // One burst frame every 0.5 s.
            if i % 5 == 0 {
                c.bursts += 1;
            }
            assert_eq!(d.observe(at(t0, i * 100), c), None, "at {i}");
        }
    }

    #[test]
    fn garbage_without_replies_is_a_disturbance_and_quiet_ends_it() {
        let mut d = Disturbance::default();
        let t0 = Instant::now();
        let mut c = LineCounters::default();
        let mut first = None;
        for i in 0..200u64 {
            c.damaged += 3;
            if d.observe(at(t0, i * 100), c).is_some() && first.is_none() {
                first = Some(i);
            }
        }
        let first = first.expect("disturbed");
        assert!(first <= 100, "within a window: {first}");
        assert!(d.reason().unwrap().contains("garbage"));
        // Quiet again, replies again: clear within a window.
        let mut cleared = None;
        for i in 200..400u64 {
            c.completed += 1;
            if d.observe(at(t0, i * 100), c).is_none() && cleared.is_none() {
                cleared = Some(i);
            }
        }
        let cleared = cleared.expect("recovers");
        assert!(cleared - 200 <= 110, "{cleared}");
    }

    #[test]
    fn a_burst_flood_is_seen_at_once() {
        let mut d = Disturbance::default();
        let t0 = Instant::now();
        let mut c = LineCounters::default();
        c.bursts += 300;
        d.observe(t0, LineCounters::default());
        assert!(d.observe(at(t0, 1000), c).unwrap().contains("burst"));
    }

    #[test]
    fn a_device_at_two_addresses_is_held_for_a_while() {
        let mut d = Disturbance::default();
        let t0 = Instant::now();
        d.duplicate(t0, "26F3020003", 1, 2);
        let c = LineCounters {
            completed: 10,
            ..Default::default()
        };
        assert!(d.observe(at(t0, 1000), c).unwrap().contains("1 and 2"));
        assert!(d.observe(at(t0, 59_000), c).is_some());
        assert_eq!(d.observe(at(t0, 61_000), c), None);
    }

    proptest::proptest! {
        /// Any counters at any times never panic, and a loop that hears nothing is
        /// never disturbed.
        #[test]
        fn any_counters_are_safe(steps in proptest::collection::vec((0u64..5_000, 0u64..100, 0u64..100, 0u64..100), 0..200)) {
            let mut d = Disturbance::default();
            let t0 = Instant::now();
            let (mut t, mut c) = (0u64, LineCounters::default());
            let mut quiet = Disturbance::default();
            for (dt, a, b, e) in steps {
                t += dt;
                c.completed += a;
                c.damaged += b;
                c.bursts += e;
                let _ = d.observe(at(t0, t), c);
                proptest::prop_assert!(quiet.observe(at(t0, t), LineCounters::default()).is_none());
            }
        }
    }
}
