//! Which device a loop polls next: a sans-IO scheduler with time passed in.
//!
//! Every device has a poll period. A device is due when its period has passed since
//! its last poll; of the devices due, the one waiting longest goes first, so when a
//! loop is too slow for the periods asked (15 devices at 1 s on a 1200 bit/s loop),
//! every device is polled in turn, none more often than another. A device that did not
//! answer is polled again after [`Schedule::retry_after`] at the soonest, so dead
//! devices do not take the line from live ones.

/// Time in microseconds since the engine started.
pub type Micros = u64;

#[derive(Debug, Clone)]
struct Entry {
    position: usize,
    period: Micros,
    due: Micros,
}

/// The poll schedule of one loop.
#[derive(Debug, Clone, Default)]
pub struct Schedule {
    entries: Vec<Entry>,
    /// Shortest wait before a device that did not answer is polled again.
    pub retry_after: Micros,
}

impl Schedule {
    /// An empty schedule; unanswered devices wait at least `retry_after` µs.
    pub fn new(retry_after: Micros) -> Self {
        Schedule {
            entries: vec![],
            retry_after,
        }
    }

    /// Adds the device at `position` (due at once), or changes its period.
    pub fn insert(&mut self, position: usize, period: Micros, now: Micros) {
        match self.entries.iter_mut().find(|e| e.position == position) {
            Some(e) => e.period = period,
            None => self.entries.push(Entry {
                position,
                period,
                due: now,
            }),
        }
    }

    /// Whether the device at `position` is scheduled.
    pub fn contains(&self, position: usize) -> bool {
        self.entries.iter().any(|e| e.position == position)
    }

    /// Devices scheduled.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether no device is scheduled.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The device to poll at `now`: of those due, the one due earliest (the first
    /// listed on a tie).
    pub fn due(&self, now: Micros) -> Option<usize> {
        self.entries
            .iter()
            .filter(|e| e.due <= now)
            .min_by_key(|e| e.due)
            .map(|e| e.position)
    }

    /// How long the most overdue device has waited past its due time at `now`.
    pub fn overdue(&self, now: Micros) -> Micros {
        self.entries
            .iter()
            .map(|e| now.saturating_sub(e.due))
            .max()
            .unwrap_or(0)
    }

    /// When the next device falls due.
    pub fn next_due(&self) -> Option<Micros> {
        self.entries.iter().map(|e| e.due).min()
    }

    /// The device at `position` was polled at `now` (`answered`: it replied).
    pub fn polled(&mut self, position: usize, now: Micros, answered: bool) {
        let retry = self.retry_after;
        if let Some(e) = self.entries.iter_mut().find(|e| e.position == position) {
            let wait = if answered {
                e.period
            } else {
                e.period.max(retry)
            };
            e.due = now.saturating_add(wait);
        }
    }

    /// Makes the device at `position` due at once (after a write, so the image shows
    /// its effect on the next turn).
    pub fn hurry(&mut self, position: usize, now: Micros) {
        if let Some(e) = self.entries.iter_mut().find(|e| e.position == position) {
            e.due = e.due.min(now);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_robin_when_the_loop_is_too_slow() {
        // Three devices at 1 s on a loop where a poll takes 0.5 s.
        let mut s = Schedule::new(5_000_000);
        for p in 0..3 {
            s.insert(p, 1_000_000, 0);
        }
        let mut now = 0;
        let mut order = vec![];
        for _ in 0..9 {
            let p = s.due(now).expect("a device is due");
            order.push(p);
            now += 500_000;
            s.polled(p, now, true);
        }
        assert_eq!(order, [0, 1, 2, 0, 1, 2, 0, 1, 2]);
    }

    #[test]
    fn a_dead_device_waits_longer() {
        let mut s = Schedule::new(5_000_000);
        s.insert(0, 1_000_000, 0);
        s.insert(1, 1_000_000, 0);
        s.polled(0, 0, false);
        s.polled(1, 0, true);
        assert_eq!(s.due(1_000_000), Some(1));
        assert_eq!(s.due(4_999_999), Some(1));
        s.polled(1, 4_999_999, true);
        assert_eq!(s.due(5_000_000), Some(0));
    }

    #[test]
    fn hurry_makes_due_now() {
        let mut s = Schedule::new(1);
        s.insert(0, 10_000_000, 0);
        s.polled(0, 0, true);
        assert_eq!(s.due(1), None);
        s.hurry(0, 1);
        assert_eq!(s.due(1), Some(0));
        assert_eq!(s.next_due(), Some(1));
    }

    proptest::proptest! {
        /// However the periods and poll times fall, no device due waits while another
        /// is polled twice: between two polls of one device, every device that was due
        /// before the first of them is polled.
        #[test]
        fn fair(periods in proptest::collection::vec(1u64..5_000_000, 1..16),
                costs in proptest::collection::vec(1u64..2_000_000, 1..64)) {
            let mut s = Schedule::new(0);
            for (p, &period) in periods.iter().enumerate() {
                s.insert(p, period, 0);
            }
            let mut now = 0;
            let mut last_poll: Vec<Option<u64>> = vec![None; periods.len()];
            let mut due_since: Vec<u64> = vec![0; periods.len()];
            for cost in costs {
                let Some(p) = s.due(now) else {
                    now = s.next_due().unwrap();
                    continue;
                };
                // Every other device due strictly before p's due time is polled first.
                for q in 0..periods.len() {
                    if q != p && due_since[q] < due_since[p] {
                        proptest::prop_assert!(due_since[q] > now,
                            "device {q} due at {} waits while {p} (due {}) is polled",
                            due_since[q], due_since[p]);
                    }
                }
                last_poll[p] = Some(now);
                now += cost;
                s.polled(p, now, true);
                due_since[p] = now + periods[p];
            }
        }
    }
}
