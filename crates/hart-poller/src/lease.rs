//! Loop tests as leases: a fixed loop current (command 40) is held by the engine for
//! its device, never left behind by the front end that asked for it.
//!
//! A device in fixed current mode drives a constant 4-20 mA signal whatever it
//! measures: a control system reading that loop sees a false value until the mode is
//! left. So every fixed current the engine sees accepted, whichever path it took (a
//! typed write from Modbus, OPC UA, PROFIBUS, Sparkplug or the web dashboard, or a
//! client's command 40 passed through HART-IP), becomes a [`Lease`] that its loop's
//! task ends by sending command 40 with 0 mA:
//!
//! * when it expires: the limit the front end asked for, or the engine's
//!   [`DEFAULT_LIMIT`] (`--loop-test-limit`);
//! * when the engine stops (`Engine::stop`, which `hartkit serve` runs on SIGTERM and
//!   Ctrl-C);
//! * when its holder goes, if it asked so (a PROFIBUS master whose watchdog expired, a
//!   Sparkplug primary host gone offline): `Engine::release_held_by`.
//!
//! A release the device does not confirm is tried again ([`retry_after`]) until it
//! does, and shown as failing on every front end in the meantime (the image's
//! [`LoopTest`]). A request the device refuses changes no lease; a new fixed current
//! accepted replaces the old lease; a command 40 with 0 accepted (any path) ends it.
//!
//! [`Leases`] is the state of one loop, plain code over time passed in; the loop's
//! task does the I/O.

use std::collections::BTreeMap;
use std::time::{Duration, Instant, SystemTime};

/// How long a loop test lasts when its front end does not say (`--loop-test-limit`).
pub const DEFAULT_LIMIT: Duration = Duration::from_secs(600);

/// The first retry of a release the device did not confirm comes this soon; each
/// next one waits twice as long, up to [`MAX_RETRY`].
pub const FIRST_RETRY: Duration = Duration::from_secs(1);

/// The longest wait between two tries of a release.
pub const MAX_RETRY: Duration = Duration::from_secs(30);

/// The wait before try `attempts + 1` of a release after `attempts` failed ones.
pub fn retry_after(attempts: u32) -> Duration {
    FIRST_RETRY
        .saturating_mul(1u32 << attempts.saturating_sub(1).min(5))
        .min(MAX_RETRY)
}

/// What a front end asks of the lease its fixed current starts.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct LeaseTerms {
    /// How long the loop test may last; `None`: the engine's limit. A longer time than
    /// the engine's limit is cut to it.
    pub limit: Option<Duration>,
    /// Released when this holder goes (`Engine::release_held_by` with the same key):
    /// a PROFIBUS station, a Sparkplug primary host. `None`: only at the limit or at
    /// the engine's stop.
    pub holder: Option<String>,
    /// Who asked, in words, for the log and the front ends (`web session 3`,
    /// `modbus-tcp 10.0.0.5:50211`).
    pub by: String,
}

/// Why a lease is being released.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReleaseReason {
    /// Its time ran out.
    Expired,
    /// The engine stops.
    Stopping,
    /// Its holder went.
    HolderGone,
}

impl ReleaseReason {
    /// In words, for the log and the audit.
    pub fn describe(self) -> &'static str {
        match self {
            ReleaseReason::Expired => "loop test limit reached",
            ReleaseReason::Stopping => "gateway stopping",
            ReleaseReason::HolderGone => "its front end's client went",
        }
    }
}

/// Where a lease is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// The loop test runs until its expiry.
    Held,
    /// Being released: the next try is due at `next_try`; `attempts` tries failed.
    Releasing {
        /// Why.
        reason: ReleaseReason,
        /// Tries the device did not confirm.
        attempts: u32,
        /// When the next try is due.
        next_try: Instant,
    },
}

/// One device's loop test.
#[derive(Debug, Clone, PartialEq)]
pub struct Lease {
    /// The fixed current the device confirmed, mA.
    pub current: f32,
    /// When it was confirmed.
    pub granted: Instant,
    /// When it ends.
    pub expires: Instant,
    /// What the front end asked.
    pub terms: LeaseTerms,
    /// Held, or being released.
    pub phase: Phase,
}

impl Lease {
    /// Tries of its release the device did not confirm.
    pub fn failed_releases(&self) -> u32 {
        match self.phase {
            Phase::Held => 0,
            Phase::Releasing { attempts, .. } => attempts,
        }
    }

    /// When its loop's task must act next.
    pub fn deadline(&self) -> Instant {
        match self.phase {
            Phase::Held => self.expires,
            Phase::Releasing { next_try, .. } => next_try,
        }
    }
}

/// A running loop test as every front end shows it (in the device's image).
#[derive(Debug, Clone, PartialEq)]
pub struct LoopTest {
    /// The fixed current, mA.
    pub current: f32,
    /// Wall-clock time at which it is released.
    pub release_at: SystemTime,
    /// Who asked for it.
    pub by: String,
    /// Tries of its release the device did not confirm: above 0, the device is still
    /// fixed after the gateway tried to release it (an alarm).
    pub failed_releases: u32,
}

/// The leases of one loop, by image position.
#[derive(Debug, Clone)]
pub struct Leases {
    limit: Duration,
    leases: BTreeMap<usize, Lease>,
}

impl Leases {
    /// No lease; fixed currents last `limit` at most.
    pub fn new(limit: Duration) -> Self {
        Leases {
            limit,
            leases: BTreeMap::new(),
        }
    }

    /// The lease of the device at `position`.
    pub fn get(&self, position: usize) -> Option<&Lease> {
        self.leases.get(&position)
    }

    /// Every lease.
    pub fn iter(&self) -> impl Iterator<Item = (usize, &Lease)> {
        self.leases.iter().map(|(p, l)| (*p, l))
    }

    /// No lease held.
    pub fn is_empty(&self) -> bool {
        self.leases.is_empty()
    }

    /// The device at `position` confirmed a fixed current of `current` mA (not 0):
    /// a new lease, replacing any one it had.
    pub fn granted(&mut self, position: usize, current: f32, terms: LeaseTerms, now: Instant) {
        let limit = terms.limit.unwrap_or(self.limit).min(self.limit);
        self.leases.insert(
            position,
            Lease {
                current,
                granted: now,
                expires: now + limit,
                terms,
                phase: Phase::Held,
            },
        );
    }

    /// The device at `position` confirmed it left fixed current mode (command 40 with
    /// 0 accepted, whoever sent it): its lease ends.
    pub fn released(&mut self, position: usize) -> Option<Lease> {
        self.leases.remove(&position)
    }

    /// The device at `position` was found not in fixed current mode when its release
    /// was due (it was reset or power-cycled): nothing to release.
    pub fn forget(&mut self, position: usize) -> Option<Lease> {
        self.leases.remove(&position)
    }

    /// A release of the device at `position` was tried and not confirmed: tried again
    /// after [`retry_after`]. Returns the failed tries so far.
    pub fn release_failed(&mut self, position: usize, now: Instant) -> u32 {
        let Some(l) = self.leases.get_mut(&position) else {
            return 0;
        };
        let (reason, attempts) = match l.phase {
            Phase::Held => (ReleaseReason::Expired, 1),
            Phase::Releasing {
                reason, attempts, ..
            } => (reason, attempts.saturating_add(1)),
        };
        l.phase = Phase::Releasing {
            reason,
            attempts,
            next_try: now + retry_after(attempts),
        };
        attempts
    }

    /// The leases held by `holder` are released now.
    pub fn holder_gone(&mut self, holder: &str, now: Instant) -> usize {
        self.release_where(now, ReleaseReason::HolderGone, |l| {
            l.terms.holder.as_deref() == Some(holder)
        })
    }

    /// Every lease is released now (the engine stops).
    pub fn release_all(&mut self, now: Instant) -> usize {
        self.release_where(now, ReleaseReason::Stopping, |_| true)
    }

    fn release_where(
        &mut self,
        now: Instant,
        reason: ReleaseReason,
        which: impl Fn(&Lease) -> bool,
    ) -> usize {
        let mut n = 0;
        for l in self.leases.values_mut().filter(|l| which(l)) {
            let attempts = l.failed_releases();
            l.phase = Phase::Releasing {
                reason,
                attempts,
                next_try: now,
            };
            n += 1;
        }
        n
    }

    /// The device whose release is due at `now`, if any, and why.
    pub fn due(&self, now: Instant) -> Option<(usize, ReleaseReason)> {
        self.leases
            .iter()
            .filter(|(_, l)| l.deadline() <= now)
            .min_by_key(|(_, l)| l.deadline())
            .map(|(p, l)| {
                (
                    *p,
                    match l.phase {
                        Phase::Held => ReleaseReason::Expired,
                        Phase::Releasing { reason, .. } => reason,
                    },
                )
            })
    }

    /// When the next release is due.
    pub fn next_deadline(&self) -> Option<Instant> {
        self.leases.values().map(Lease::deadline).min()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn terms(holder: Option<&str>) -> LeaseTerms {
        LeaseTerms {
            holder: holder.map(str::to_string),
            by: "test".into(),
            ..Default::default()
        }
    }

    #[test]
    fn a_lease_expires_at_its_limit_cut_to_the_engines() {
        let t0 = Instant::now();
        let mut l = Leases::new(Duration::from_secs(600));
        l.granted(
            3,
            12.0,
            LeaseTerms {
                limit: Some(Duration::from_secs(3600)),
                ..terms(None)
            },
            t0,
        );
        assert_eq!(l.due(t0 + Duration::from_secs(599)), None);
        assert_eq!(
            l.due(t0 + Duration::from_secs(600)),
            Some((3, ReleaseReason::Expired))
        );
    }

    #[test]
    fn a_failed_release_is_retried_slower_and_slower() {
        let t0 = Instant::now();
        let mut l = Leases::new(Duration::from_secs(60));
        l.granted(0, 5.0, terms(None), t0);
        let t = t0 + Duration::from_secs(60);
        assert_eq!(l.release_failed(0, t), 1);
        assert_eq!(l.due(t), None);
        assert_eq!(
            l.due(t + Duration::from_secs(1)),
            Some((0, ReleaseReason::Expired))
        );
        assert_eq!(retry_after(2), Duration::from_secs(2));
        assert_eq!(retry_after(3), Duration::from_secs(4));
        assert_eq!(retry_after(40), MAX_RETRY);
    }

    #[test]
    fn holders_and_stop() {
        let t0 = Instant::now();
        let mut l = Leases::new(Duration::from_secs(600));
        l.granted(0, 5.0, terms(Some("profibus:3")), t0);
        l.granted(1, 6.0, terms(None), t0);
        assert_eq!(l.holder_gone("profibus:4", t0), 0);
        assert_eq!(l.holder_gone("profibus:3", t0), 1);
        assert_eq!(l.due(t0), Some((0, ReleaseReason::HolderGone)));
        l.released(0);
        assert_eq!(l.due(t0), None);
        assert_eq!(l.release_all(t0), 1);
        assert_eq!(l.due(t0), Some((1, ReleaseReason::Stopping)));
    }

    #[derive(Debug, Clone)]
    enum Step {
        Grant(usize, u64),
        Refused,
        Released(usize),
        Fail(usize),
        HolderGone,
        Wait(u64),
    }

    fn step() -> impl Strategy<Value = Step> {
        prop_oneof![
            (0usize..4, 1u64..1000).prop_map(|(p, s)| Step::Grant(p, s)),
            Just(Step::Refused),
            (0usize..4).prop_map(Step::Released),
            (0usize..4).prop_map(Step::Fail),
            Just(Step::HolderGone),
            (0u64..2000).prop_map(Step::Wait),
        ]
    }

    proptest! {
        /// Whatever happens, a device whose last confirmed fixed current was not
        /// released keeps a lease, and every lease comes due by its limit (plus the
        /// retry wait once its release failed): nothing is left fixed for good.
        #[test]
        fn every_fixed_current_is_released_in_time(steps in prop::collection::vec(step(), 0..60)) {
            let limit = Duration::from_secs(600);
            let t0 = Instant::now();
            let mut now = t0;
            let mut l = Leases::new(limit);
            let mut fixed = [false; 4];
            for s in steps {
                match s {
                    Step::Grant(p, secs) => {
                        let t = LeaseTerms { limit: Some(Duration::from_secs(secs)), ..terms(Some("h")) };
                        l.granted(p, 4.0, t, now);
                        fixed[p] = true;
                    }
                    // A refused request changes nothing.
                    Step::Refused => {}
                    Step::Released(p) => { l.released(p); fixed[p] = false; }
                    Step::Fail(p) => { l.release_failed(p, now); }
                    Step::HolderGone => { l.holder_gone("h", now); }
                    Step::Wait(s) => now += Duration::from_secs(s),
                }
                for (p, f) in fixed.iter().enumerate() {
                    prop_assert_eq!(*f, l.get(p).is_some());
                }
                for (_, lease) in l.iter() {
                    let bound = lease.granted + limit + MAX_RETRY;
                    prop_assert!(lease.deadline() <= bound.max(now + MAX_RETRY));
                }
            }
            // Driven by its task, every lease ends: due now or within the retry wait.
            now += limit + MAX_RETRY;
            while let Some((p, _)) = l.due(now) {
                l.released(p);
            }
            prop_assert!(l.is_empty());
        }
    }
}
