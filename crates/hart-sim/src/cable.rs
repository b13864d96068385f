//! How long a cable a network tolerates, found from the signal: the analog medium
//! ([`crate::Medium::Analog`]) run at a cable length, the frame error rate measured,
//! and the length searched for where it crosses a limit.
//!
//! The traffic is what a host makes of a multidrop loop: the primary master reads
//! command 3 from each device in turn with short frames, at the pace the data link
//! allows (retries included). A frame counts as decoded when its addressee decoded it
//! intact: the device a request is for, the master a reply is for.

use hart_modem::cable::{max_cable_length_m, CableParams};

use crate::{run_schedule, LineOptions, LoopModel, Medium, ScheduledRequest, SimConfig};

/// One measurement: the network at one cable length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CablePoint {
    /// Cable length, m.
    pub length_m: f64,
    /// Frames sent to an existing station.
    pub frames: u64,
    /// Of which the addressee decoded intact.
    pub heard: u64,
}

impl CablePoint {
    /// Frame error rate.
    pub fn fer(&self) -> f64 {
        if self.frames == 0 {
            1.0
        } else {
            1.0 - self.heard as f64 / self.frames as f64
        }
    }
}

/// What to measure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CableSetup {
    /// The loop; its cable length is what varies, `devices` is set from `devices`.
    pub model: LoopModel,
    /// Sample rate, levels, noise.
    pub options: LineOptions,
    /// Devices on the loop (polling addresses 1..=N).
    pub devices: u8,
    /// Transactions per measurement (each is at least two frames).
    pub transactions: usize,
}

/// Runs the network at `length_m` of cable.
pub fn measure(setup: &CableSetup, length_m: f64) -> CablePoint {
    let mut model = setup.model;
    model.cable_length_m = length_m;
    let devices = setup.devices.clamp(1, 63);
    let schedule: Vec<ScheduledRequest> = (0..setup.transactions)
        .map(|k| ScheduledRequest {
            at: 0,
            device: (k % usize::from(devices)) as u8 + 1,
            command: 3,
            long_frame: false,
        })
        .collect();
    // Long enough for every transaction to use all its retries.
    let duration = (setup.transactions as u64 + 1) * 2_000_000;
    let cfg = SimConfig {
        devices,
        duration,
        medium: Medium::Analog {
            model,
            options: setup.options,
        },
        ..SimConfig::default()
    };
    let r = run_schedule(&cfg, &schedule, &[]);
    CablePoint {
        length_m,
        frames: r.frames_sent,
        heard: r.frames_heard,
    }
}

/// The RC rule's length for this setup: [`max_cable_length_m`] with the loop's own
/// resistances and capacitances.
pub fn rule_length_m(setup: &CableSetup) -> f64 {
    let m = &setup.model;
    let p = CableParams {
        loop_resistance_ohm: m.loop_resistance_ohm,
        cable_ohm_per_m: m.cable_ohm_per_m,
        device_capacitance_pf: m.device_capacitance_pf,
        fixed_capacitance_pf: m.fixed_capacitance_pf,
        ..CableParams::default()
    };
    max_cable_length_m(m.cable_pf_per_m, u32::from(setup.devices), &p)
}

/// The result of a search.
#[derive(Debug, Clone, PartialEq)]
pub struct CableLimit {
    /// Longest length found with a frame error rate within the limit, m (0 when even
    /// the shortest fails).
    pub length_m: f64,
    /// Every measurement made, in order of length.
    pub points: Vec<CablePoint>,
}

/// Finds the longest cable at which the frame error rate stays within `max_fer`, to
/// `resolution_m`, between no cable and `ceiling_m` (doubled while the network still
/// works there). The frame error rate falls off a
/// cliff (where the far end's signal drops under carrier detect), so a bisection with
/// a fifth of the transactions finds the cliff, and the length found is then
/// confirmed with all of them, stepping back by `resolution_m` until it holds.
/// `on_point` sees every measurement as it is made.
pub fn longest_cable(
    setup: &CableSetup,
    max_fer: f64,
    ceiling_m: f64,
    resolution_m: f64,
    mut on_point: impl FnMut(&CablePoint),
) -> CableLimit {
    let coarse = CableSetup {
        transactions: (setup.transactions / 5).max(20),
        ..*setup
    };
    let mut points = vec![];
    let mut probe = |s: &CableSetup, len: f64, points: &mut Vec<CablePoint>| {
        let p = measure(s, len);
        on_point(&p);
        points.push(p);
        p.fer() <= max_fer
    };
    // The ceiling is doubled while the network still works there.
    let (mut good, mut bad) = (0.0, ceiling_m.max(resolution_m));
    for _ in 0..6 {
        if !probe(&coarse, bad, &mut points) {
            break;
        }
        good = bad;
        bad *= 2.0;
    }
    while bad - good > resolution_m {
        let mid = ((good + bad) / 2.0 / resolution_m).round() * resolution_m;
        if mid <= good || mid >= bad {
            break;
        }
        if probe(&coarse, mid, &mut points) {
            good = mid;
        } else {
            bad = mid;
        }
    }
    while !probe(setup, good, &mut points) {
        if good <= 0.0 {
            break;
        }
        good = (good - resolution_m).max(0.0);
    }
    points.sort_by(|a, b| a.length_m.total_cmp(&b.length_m));
    CableLimit {
        length_m: good,
        points,
    }
}

/// One cell of a cable table.
#[derive(Debug, Clone, PartialEq)]
pub struct CableCell {
    /// Cable capacitance, pF per metre.
    pub pf_per_m: f64,
    /// Devices on the loop.
    pub devices: u8,
    /// The RC rule's length, m.
    pub rule_m: f64,
    /// The longest cable found from the signal.
    pub simulated: CableLimit,
    /// The network at the rule's length.
    pub at_rule: CablePoint,
    /// Measurements from 80 % to 120 % of the length found, to show the edge.
    pub sweep: Vec<CablePoint>,
}

/// Measures one cell: the network at the rule's length, then the longest cable with a
/// frame error rate within `max_fer` (to `resolution_m`), then `sweep_points` lengths
/// from 80 % to 120 % of it with a fifth of the transactions.
pub fn cell(
    setup: &CableSetup,
    max_fer: f64,
    resolution_m: f64,
    sweep_points: usize,
    on_point: impl FnMut(&CablePoint),
) -> CableCell {
    let rule_m = rule_length_m(setup);
    let at_rule = measure(setup, rule_m);
    let simulated = longest_cable(setup, max_fer, 2.0 * rule_m, resolution_m, on_point);
    let coarse = CableSetup {
        transactions: (setup.transactions / 5).max(20),
        ..*setup
    };
    let sweep = (0..sweep_points)
        .map(|i| {
            let x = 0.8 + 0.4 * i as f64 / (sweep_points.max(2) - 1) as f64;
            measure(&coarse, (simulated.length_m * x).round())
        })
        .collect();
    CableCell {
        pf_per_m: setup.model.cable_pf_per_m,
        devices: setup.devices,
        rule_m,
        simulated,
        at_rule,
        sweep,
    }
}

/// Measures the cells `(pF/m, devices)` of a table ([`cell`]) on `threads` threads;
/// `on_cell` sees each as it is done. Cells come back in the order given.
#[allow(clippy::too_many_arguments)]
pub fn table(
    base: &CableSetup,
    cells: &[(f64, u8)],
    max_fer: f64,
    resolution_m: f64,
    sweep_points: usize,
    threads: usize,
    on_cell: &(dyn Fn(&CableCell) + Sync),
) -> Vec<CableCell> {
    let next = std::sync::atomic::AtomicUsize::new(0);
    let done = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..threads.clamp(1, cells.len().max(1)) {
            scope.spawn(|| loop {
                let k = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some(&(pf, devices)) = cells.get(k) else {
                    break;
                };
                let setup = CableSetup {
                    model: LoopModel {
                        cable_pf_per_m: pf,
                        ..base.model
                    },
                    devices,
                    ..*base
                };
                let c = cell(&setup, max_fer, resolution_m, sweep_points, |_| {});
                on_cell(&c);
                if let Ok(mut d) = done.lock() {
                    d.push((k, c));
                }
            });
        }
    });
    let mut out = done.into_inner().unwrap_or_default();
    out.sort_by_key(|(k, _)| *k);
    out.into_iter().map(|(_, c)| c).collect()
}
