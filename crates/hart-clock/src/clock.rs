//! The one clock: every turn of the polling engine's loop tasks, every time stamp in
//! its image and every change it publishes takes its "now" from one [`Clock`], handed
//! to the engine when it starts. The gateway runs on the system's clock; the tests run
//! on tokio's clock with time paused, where hours of polling pass in milliseconds and
//! every step is repeatable.

use std::time::{Duration, Instant, SystemTime};

/// Where a task reads the time. Cheap to copy.
#[derive(Debug, Clone, Copy)]
pub struct Clock {
    kind: Kind,
}

#[derive(Debug, Clone, Copy)]
enum Kind {
    /// The system's monotonic and wall clocks.
    System,
    /// tokio's clock (virtual when the runtime's time is paused), with the wall clock
    /// counted from `wall` at `start`.
    Tokio {
        start: tokio::time::Instant,
        wall: SystemTime,
    },
}

impl Default for Clock {
    fn default() -> Self {
        Clock::system()
    }
}

impl Clock {
    /// The system's clocks: what a running gateway uses.
    pub fn system() -> Clock {
        Clock { kind: Kind::System }
    }

    /// tokio's clock, which stands still and jumps when the runtime's time is paused
    /// (`tokio::time::pause`, `#[tokio::test(start_paused = true)]`); wall-clock time
    /// starts at `wall` now and moves with it.
    pub fn tokio(wall: SystemTime) -> Clock {
        Clock {
            kind: Kind::Tokio {
                start: tokio::time::Instant::now(),
                wall,
            },
        }
    }

    /// The monotonic time now.
    pub fn now(&self) -> Instant {
        match self.kind {
            Kind::System => Instant::now(),
            Kind::Tokio { .. } => tokio::time::Instant::now().into_std(),
        }
    }

    /// The wall-clock time now (time stamps of values and changes).
    pub fn wall(&self) -> SystemTime {
        match self.kind {
            Kind::System => SystemTime::now(),
            Kind::Tokio { start, wall } => wall + start.elapsed(),
        }
    }

    /// The wall-clock time of the monotonic instant `at` (which must be from this
    /// clock): for time stamps taken as instants.
    pub fn wall_at(&self, at: Instant) -> SystemTime {
        let now = self.now();
        let wall = self.wall();
        if at <= now {
            wall.checked_sub(now - at).unwrap_or(wall)
        } else {
            wall + (at - now)
        }
    }

    /// The time from now until `at` (an instant of this clock), zero when it is past.
    pub fn until(&self, at: Instant) -> Duration {
        at.saturating_duration_since(self.now())
    }

    /// The time elapsed since `since` (an instant of this clock), never negative.
    pub fn since(&self, since: Instant) -> Duration {
        self.now().saturating_duration_since(since)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn the_tokio_clock_follows_paused_time() {
        let wall = SystemTime::UNIX_EPOCH + Duration::from_secs(1_800_000_000);
        let c = Clock::tokio(wall);
        let t0 = c.now();
        tokio::time::sleep(Duration::from_secs(3600)).await;
        assert_eq!(c.since(t0), Duration::from_secs(3600));
        assert_eq!(c.wall(), wall + Duration::from_secs(3600));
        assert_eq!(c.wall_at(t0), wall);
    }

    #[test]
    fn the_system_clock_moves() {
        let c = Clock::system();
        let t0 = c.now();
        assert!(c.now() >= t0);
        assert!(c.wall() > SystemTime::UNIX_EPOCH);
    }
}
