//! A simulated sensor: its signal, its 100 readings a minute and their clipped mean,
//! its faults, and its answers to commands 1 and 14 (sans-IO: a request and the time
//! in, a reply out).
//!
//! The signal is a deterministic function of time plus noise seeded by the sensor's
//! seed and the minute, so a sensor computes any minute when it is asked, the same
//! every time, and a sensor that starts has its last three minutes at once.

use std::collections::VecDeque;

use hart_rng::Rng;

use crate::calibration::{sensor_counts, Sensor, MAX_COUNT};
use crate::proto::{
    Diagnosis, Groups, Message, Station, DIAGNOSTICS, NO_VALUE, RC_NOT_IMPLEMENTED, READ_VALUES,
    STATUS_ABNORMAL, STATUS_NORMAL,
};
use crate::Millis;

/// Readings a sensor takes in a minute.
pub const READINGS_PER_MINUTE: usize = 100;

/// A fault the simulated sensor has (its self-diagnosis finds it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Fault {
    /// None.
    #[default]
    None,
    /// The sensing element: no values.
    Element,
    /// The analog-to-digital converter: no values.
    Adc,
    /// Power supply or watchdog resets: the sensor restarts every few minutes and
    /// loses the minutes it had.
    Power,
}

impl Fault {
    /// Parses `none`, `element`, `adc`, `power`.
    pub fn from_name(s: &str) -> Option<Self> {
        Some(match s {
            "none" => Fault::None,
            "element" => Fault::Element,
            "adc" => Fault::Adc,
            "power" => Fault::Power,
            _ => return None,
        })
    }

    /// What the sensor's self-diagnosis reports.
    pub fn diagnosis(self) -> Diagnosis {
        match self {
            Fault::None => Diagnosis::Healthy,
            Fault::Element => Diagnosis::Element,
            Fault::Adc => Diagnosis::Adc,
            Fault::Power => Diagnosis::Power,
        }
    }
}

/// What a simulated sensor is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorConfig {
    /// Its address on the bus (1-15).
    pub address: u8,
    /// What it measures.
    pub kind: Sensor,
    /// Its fault.
    pub fault: Fault,
    /// Seed of its noise and of its place (each well's water is a little different).
    pub seed: u64,
}

/// A simulated sensor.
pub struct SimSensor {
    cfg: SensorConfig,
    /// Minute values computed recently: (minute, value).
    cache: VecDeque<(u32, Option<[u32; 2]>)>,
    /// This sensor's offsets from the nominal water (°C, m).
    offset: f64,
    phase: f64,
    /// Requests answered.
    pub answered: u64,
}

/// Seconds from the Unix epoch to 2026-01-01, where the slow drifts start.
const DRIFT_EPOCH: f64 = 1_767_225_600.0;

fn mix(a: u64, b: u64) -> u64 {
    let mut r = Rng::new(a ^ b.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    r.next_u64()
}

impl SimSensor {
    /// A sensor.
    pub fn new(cfg: SensorConfig) -> Self {
        let mut r = Rng::new(mix(cfg.seed, 0x5EED));
        let offset = r.uniform() - 0.5;
        let phase = r.uniform() * std::f64::consts::TAU;
        SimSensor {
            cfg,
            cache: VecDeque::with_capacity(8),
            offset,
            phase,
            answered: 0,
        }
    }

    /// Its configuration.
    pub fn config(&self) -> &SensorConfig {
        &self.cfg
    }

    /// Its station address.
    pub fn station(&self) -> Station {
        Station::sensor(self.cfg.address)
    }

    /// The true water temperature (°C) or level (m) at `t` seconds (Unix time).
    pub fn truth(&self, t: f64) -> f64 {
        let days = (t - DRIFT_EPOCH) / 86_400.0;
        match self.cfg.kind {
            // About 100 m down: 15.2 °C give or take this well, a slow warming of
            // 3 m°C a day and a faint seasonal wave.
            Sensor::Temperature => {
                15.2 + self.offset
                    + 0.003 * days
                    + 0.02 * (std::f64::consts::TAU * days / 365.25 + self.phase).sin()
            }
            // About 10 m of water above the sensor: a drift of -1 mm a day, and the
            // earth tides M2 (12.42 h, 8 mm) and O1 (25.82 h, 5 mm).
            Sensor::Level => {
                let tau = std::f64::consts::TAU;
                10.0 + self.offset - 0.001 * days
                    + 0.008 * (tau * t / 44_712.0).cos()
                    + 0.005 * (tau * t / 92_950.0 + self.phase).cos()
            }
        }
    }

    /// The level sensor's own temperature (°C).
    fn body_temperature(&self, t: f64) -> f64 {
        14.8 + self.offset + 0.2 * (std::f64::consts::TAU * t / 86_400.0).sin()
    }

    /// The 100 readings of `minute` in counts: the truth through the sensor's
    /// transfer function, with reading noise and an occasional spike.
    pub fn readings(&self, minute: u32) -> [u32; READINGS_PER_MINUTE] {
        let mut r = Rng::new(mix(self.cfg.seed, minute as u64));
        let (sigma, spike) = match self.cfg.kind {
            Sensor::Temperature => (0.002, 0.3),
            Sensor::Level => (0.0005, 0.05),
        };
        let mut out = [0u32; READINGS_PER_MINUTE];
        for (i, o) in out.iter_mut().enumerate() {
            let t = minute as f64 * 60.0 + i as f64 * 0.6;
            let mut x = self.truth(t) + sigma * r.gaussian();
            if r.next_u64() % 500 == 0 {
                x += spike * (0.2 + r.uniform()) * if r.next_u64() & 1 == 0 { 1.0 } else { -1.0 };
            }
            *o = sensor_counts(self.cfg.kind, x);
        }
        out
    }

    /// The clipped mean of `minute`'s readings (counts), and for the level sensor
    /// its own temperature; `None` when the sensor has no value for that minute (a
    /// fault, or a reset that minute or since).
    pub fn minute_value(&mut self, minute: u32, now_minute: u32) -> Option<[u32; 2]> {
        match self.cfg.fault {
            Fault::Element | Fault::Adc => return None,
            Fault::Power if (minute..=now_minute).any(|m| self.resets_at(m)) => return None,
            _ => {}
        }
        if let Some(&(_, v)) = self.cache.iter().find(|(m, _)| *m == minute) {
            return v;
        }
        let v = Some([clipped_mean(&self.readings(minute), self.limit()), {
            match self.cfg.kind {
                Sensor::Temperature => NO_VALUE,
                Sensor::Level => body_counts(self.body_temperature(minute as f64 * 60.0 + 30.0)),
            }
        }]);
        if self.cache.len() == 8 {
            self.cache.pop_front();
        }
        self.cache.push_back((minute, v));
        v
    }

    /// With a power fault, the minutes in which the sensor restarts (about one in
    /// seven, seeded).
    fn resets_at(&self, minute: u32) -> bool {
        mix(self.cfg.seed ^ 0xB00, minute as u64) % 7 == 0
    }

    /// The clipping limit in counts (0.02 °C; 5 mm).
    fn limit(&self) -> u32 {
        let (lo, hi) = self.cfg.kind.range();
        let l = match self.cfg.kind {
            Sensor::Temperature => 0.02,
            Sensor::Level => 0.005,
        };
        (l / (hi - lo) * MAX_COUNT as f64) as u32
    }

    /// The command-1 reply at `now`: the three minutes before the current one.
    pub fn groups(&mut self, now: Millis) -> Groups {
        let now_minute = (now / 60_000) as u32;
        let width = match self.cfg.kind {
            Sensor::Temperature => 1,
            Sensor::Level => 2,
        };
        let mut groups = [[NO_VALUE; 2]; 3];
        let mut complete = true;
        for (i, g) in groups.iter_mut().enumerate() {
            let m = now_minute.saturating_sub(3 - i as u32);
            match self.minute_value(m, now_minute) {
                Some(v) => *g = v,
                None => complete = false,
            }
        }
        Groups {
            status: if complete {
                STATUS_NORMAL
            } else {
                STATUS_ABNORMAL
            },
            width,
            groups,
        }
    }

    /// Answers a request addressed to this sensor (others, and replies, get nothing).
    pub fn handle(&mut self, msg: &Message, now: Millis) -> Option<Message> {
        if msg.reply || msg.station != self.station() {
            return None;
        }
        self.answered += 1;
        Some(match msg.command {
            READ_VALUES => {
                let (s, d) = self.groups(now).encode();
                Message::reply(self.station(), READ_VALUES, s, d)
            }
            DIAGNOSTICS => Message::reply(
                self.station(),
                DIAGNOSTICS,
                [DIAGNOSTICS, self.cfg.fault.diagnosis().code()],
                vec![],
            ),
            c => Message::reply(self.station(), c, [RC_NOT_IMPLEMENTED, 0], vec![]),
        })
    }
}

/// The level sensor's housekeeping temperature scale: -20 to +80 °C over the counts.
pub fn body_counts(c: f64) -> u32 {
    (((c + 20.0) / 100.0).clamp(0.0, 1.0) * MAX_COUNT as f64).round() as u32
}

/// °C of [`body_counts`].
pub fn body_celsius(counts: u32) -> f64 {
    counts as f64 / MAX_COUNT as f64 * 100.0 - 20.0
}

/// The clipped (limited-amplitude) mean: the readings within `limit` counts of their
/// median, averaged; spikes beyond it are dropped.
pub fn clipped_mean(readings: &[u32], limit: u32) -> u32 {
    if readings.is_empty() {
        return NO_VALUE;
    }
    let mut sorted = readings.to_vec();
    sorted.sort_unstable();
    let median = sorted[sorted.len() / 2] as i64;
    let (mut sum, mut n) = (0i64, 0i64);
    for &r in readings {
        if (r as i64 - median).abs() <= limit as i64 {
            sum += r as i64;
            n += 1;
        }
    }
    // The median itself is always kept, so n >= 1.
    ((sum + n / 2) / n.max(1)) as u32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::Table;

    fn sensor(kind: Sensor, fault: Fault) -> SimSensor {
        SimSensor::new(SensorConfig {
            address: if kind == Sensor::Temperature { 1 } else { 2 },
            kind,
            fault,
            seed: 7,
        })
    }

    #[test]
    fn clipped_mean_drops_spikes() {
        let mut r = vec![1000u32; 99];
        r.push(90_000);
        assert_eq!(clipped_mean(&r, 50), 1000);
        assert_eq!(clipped_mean(&[10, 20, 30], 100), 20);
    }

    #[test]
    fn minute_values_meet_the_sensors_accuracy() {
        // Through the built-in calibration, a minute's value is within the sensors'
        // accuracy of the true mean of the minute: 0.05 °C and 1 mm (the noise left
        // after averaging 100 readings is far below both).
        for kind in [Sensor::Temperature, Sensor::Level] {
            let mut s = sensor(kind, Fault::None);
            let table = Table::builtin(kind);
            for minute in (29_500_000..29_500_000 + 3000).step_by(97) {
                let v = s.minute_value(minute, minute + 1).unwrap()[0];
                let x = table.eval(v);
                let truth: f64 = (0..100)
                    .map(|i| s.truth(minute as f64 * 60.0 + i as f64 * 0.6))
                    .sum::<f64>()
                    / 100.0;
                let tol = if kind == Sensor::Temperature {
                    0.002
                } else {
                    0.0005
                };
                assert!((x - truth).abs() < tol, "{kind:?} {minute}: {x} vs {truth}");
            }
        }
    }

    #[test]
    fn answers_commands_1_and_14_and_refuses_others() {
        let now = 29_500_000u64 * 60_000 + 10_000;
        let mut s = sensor(Sensor::Level, Fault::None);
        let r = s
            .handle(
                &Message::request(Station::sensor(2), READ_VALUES, vec![]),
                now,
            )
            .unwrap();
        assert_eq!(r.status, Some([0, 0]));
        assert_eq!(r.data.len(), 18);
        let r = s
            .handle(
                &Message::request(Station::sensor(2), DIAGNOSTICS, vec![]),
                now,
            )
            .unwrap();
        assert_eq!((r.status, r.data.len()), (Some([0x0E, 0]), 0));
        let r = s
            .handle(&Message::request(Station::sensor(2), 3, vec![]), now)
            .unwrap();
        assert_eq!(r.status, Some([64, 0]));
        assert!(s
            .handle(&Message::request(Station::sensor(1), 1, vec![]), now)
            .is_none());
    }

    #[test]
    fn faults_show_in_both_commands() {
        let now = 29_500_000u64 * 60_000 + 10_000;
        for (fault, code) in [(Fault::Element, 1), (Fault::Adc, 2)] {
            let mut s = sensor(Sensor::Temperature, fault);
            let g = s.groups(now);
            assert_eq!(g.status, STATUS_ABNORMAL);
            assert!(g.groups.iter().all(|g| g[0] == NO_VALUE));
            let r = s
                .handle(
                    &Message::request(Station::sensor(1), DIAGNOSTICS, vec![]),
                    now,
                )
                .unwrap();
            assert_eq!(r.status, Some([14, code]));
        }
        // Power resets lose some minutes, not all.
        let mut s = sensor(Sensor::Temperature, Fault::Power);
        let (mut some, mut none) = (0, 0);
        for m in 0..300u64 {
            let g = s.groups((29_500_000 + m) * 60_000 + 10_000);
            for v in g.groups {
                if v[0] == NO_VALUE {
                    none += 1
                } else {
                    some += 1
                }
            }
        }
        assert!(some > 100 && none > 100, "{some} {none}");
    }
}
