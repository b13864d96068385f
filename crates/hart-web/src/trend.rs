//! The trends: each device's PV and loop current kept in memory for a window (an
//! hour by default), or read from the historian when one runs.

use std::collections::{HashMap, VecDeque};
use std::time::{Duration, SystemTime};

use hart_poller::Change;

/// One point of a device's trend.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrendPoint {
    /// When.
    pub time: SystemTime,
    /// PV (`None`: no value, or not usable).
    pub pv: Option<f64>,
    /// Loop current, mA.
    pub current: Option<f64>,
}

/// Every device's recent PV and loop current, at most one point a second each.
#[derive(Debug)]
pub struct MemoryTrend {
    window: Duration,
    spacing: Duration,
    devices: HashMap<usize, VecDeque<TrendPoint>>,
    /// PV units code of each device's last point.
    units: HashMap<usize, u8>,
}

impl MemoryTrend {
    /// Keeps `window` of each device (at most 3600 points: one a second for an hour,
    /// fewer for longer windows).
    pub fn new(window: Duration) -> Self {
        MemoryTrend {
            window,
            spacing: (window / 3600).max(Duration::from_secs(1)),
            devices: HashMap::new(),
            units: HashMap::new(),
        }
    }

    /// How much is kept.
    pub fn window(&self) -> Duration {
        self.window
    }

    /// Takes a change of the image.
    pub fn record(&mut self, c: &Change) {
        let d = &c.device;
        let usable = c.quality.usable();
        let pv = d.variables[0]
            .filter(|v| usable && v.value.is_finite())
            .map(|v| f64::from(v.value));
        let current = d
            .loop_current
            .filter(|v| usable && v.is_finite())
            .map(f64::from);
        if let Some(v) = d.variables[0] {
            self.units.insert(d.position, v.units);
        }
        self.push(
            d.position,
            TrendPoint {
                time: c.at,
                pv,
                current,
            },
        );
    }

    /// Adds a point of device `position` (dropped if it comes sooner than the
    /// spacing after the last one, unless the last had no value).
    pub fn push(&mut self, position: usize, p: TrendPoint) {
        let q = self.devices.entry(position).or_default();
        if let Some(last) = q.back() {
            let soon = p
                .time
                .duration_since(last.time)
                .map_or(true, |d| d < self.spacing);
            if soon && (last.pv.is_some() == p.pv.is_some()) {
                return;
            }
        }
        q.push_back(p);
        while q
            .front()
            .is_some_and(|f| p.time.duration_since(f.time).is_ok_and(|d| d > self.window))
        {
            q.pop_front();
        }
    }

    /// The points of device `position` from `from` on.
    pub fn since(&self, position: usize, from: SystemTime) -> Vec<TrendPoint> {
        self.devices.get(&position).map_or(vec![], |q| {
            q.iter().filter(|p| p.time >= from).copied().collect()
        })
    }

    /// The PV units code of device `position`'s last value.
    pub fn units(&self, position: usize) -> Option<u8> {
        self.units.get(&position).copied()
    }
}

/// Parses a trend window: `90s`, `15m`, `1h`, `2d` (humantime's forms), from 10
/// seconds to 31 days.
pub fn parse_window(text: &str) -> Result<Duration, String> {
    let d = humantime::parse_duration(text.trim())
        .map_err(|e| format!("window {text:?}: {e}; give a duration such as 15m, 1h or 1d"))?;
    if d < Duration::from_secs(10) || d > Duration::from_secs(31 * 86_400) {
        return Err(format!(
            "window {text:?}: give at least 10 s and at most 31 days"
        ));
    }
    Ok(d)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(s: u64) -> SystemTime {
        SystemTime::UNIX_EPOCH + Duration::from_secs(1_800_000_000 + s)
    }

    #[test]
    fn keeps_a_window_one_point_a_second() {
        let mut t = MemoryTrend::new(Duration::from_secs(60));
        for ms in (0..120_000).step_by(100) {
            t.push(
                0,
                TrendPoint {
                    time: at(0) + Duration::from_millis(ms),
                    pv: Some(ms as f64),
                    current: None,
                },
            );
        }
        let all = t.since(0, at(0));
        assert!(all.len() <= 62, "{}", all.len());
        assert!(all.first().unwrap().time >= at(59));
        assert!(t.since(1, at(0)).is_empty());
    }

    #[test]
    fn a_gap_is_kept_at_once() {
        let mut t = MemoryTrend::new(Duration::from_secs(60));
        let p = |s, pv| TrendPoint {
            time: at(0) + Duration::from_millis(s),
            pv,
            current: None,
        };
        t.push(0, p(0, Some(1.0)));
        t.push(0, p(100, None));
        t.push(0, p(200, Some(2.0)));
        assert_eq!(t.since(0, at(0)).len(), 3);
    }

    #[test]
    fn windows() {
        assert_eq!(parse_window("1h"), Ok(Duration::from_secs(3600)));
        assert_eq!(parse_window(" 15m "), Ok(Duration::from_secs(900)));
        assert!(parse_window("1s").is_err());
        assert!(parse_window("100d").is_err());
        assert!(parse_window("soon").is_err());
    }
}
