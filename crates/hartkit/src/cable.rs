//! `hartkit loop cable`: the longest cable for a network by the RC rule, and with
//! `--simulate` from the signal (the network on the analog loop, [`hart_sim::cable`]).

use std::fmt::Write as _;
use std::io::IsTerminal;
use std::path::PathBuf;

use hart_modem::cable::{self, CableParams, CLASSIC_TABLE};
use hart_sim::cable::{CableCell, CableSetup};
use serde_json::json;

use crate::sim::LoopArgs;

/// Frame error rate a cable may cause: 99.9 % of frames decoded.
pub const MAX_FER: f64 = 0.001;

/// What `hartkit loop cable` was asked.
#[derive(Debug, Clone)]
pub struct CableOptions {
    /// Cable capacitance, pF/m (one cell), or `None` with `table`.
    pub pf_per_m: Option<f64>,
    /// Devices on the loop.
    pub devices: u32,
    /// The whole classic table.
    pub table: bool,
    /// Find the lengths from the signal too.
    pub simulate: bool,
    /// Transactions per confirming measurement.
    pub transactions: usize,
    /// Resolution of the search, m.
    pub resolution_m: f64,
    /// Every measurement as CSV.
    pub csv: Option<PathBuf>,
    /// Extra measurements around each cell's edge.
    pub sweep: usize,
    /// Print JSON.
    pub json: bool,
    /// Seed of the noise.
    pub seed: u64,
    /// The loop.
    pub analog: LoopArgs,
}

fn setup(o: &CableOptions, pf: f64, devices: u8) -> Result<CableSetup, String> {
    let mut model = o.analog.model(0.0)?;
    model.cable_pf_per_m = pf;
    Ok(CableSetup {
        model,
        options: o.analog.options(o.seed)?,
        devices,
        transactions: o.transactions,
    })
}

fn rule_params(o: &CableOptions) -> Result<CableParams, String> {
    let m = o.analog.model(0.0)?;
    Ok(CableParams {
        loop_resistance_ohm: m.loop_resistance_ohm,
        cable_ohm_per_m: m.cable_ohm_per_m,
        device_capacitance_pf: m.device_capacitance_pf,
        fixed_capacitance_pf: m.fixed_capacitance_pf,
        ..CableParams::default()
    })
}

/// Runs `hartkit loop cable`.
pub fn run(o: &CableOptions) -> Result<String, String> {
    if o.devices == 0 || o.devices > 63 {
        return Err(format!(
            "--devices {}: a loop has 1 to 63 devices",
            o.devices
        ));
    }
    if !(10..=100_000).contains(&o.transactions) {
        return Err(format!(
            "--transactions {}: give 10 to 100000",
            o.transactions
        ));
    }
    if o.sweep > 1000 {
        return Err(format!("--sweep {}: give at most 1000 points", o.sweep));
    }
    if !(o.resolution_m.is_finite() && o.resolution_m >= 1.0) {
        return Err(format!(
            "--resolution-m {}: give 1 m or more",
            o.resolution_m
        ));
    }
    let cells: Vec<(f64, u8)> = if o.table {
        CLASSIC_TABLE
            .iter()
            .map(|&(pf, n, _)| (pf, n as u8))
            .collect()
    } else {
        let pf = o
            .pf_per_m
            .ok_or("give --capacitance-pf-per-m for one network, or --table for the whole table")?;
        if !pf.is_finite() || pf <= 0.0 {
            return Err("--capacitance-pf-per-m must be positive and --devices 1 to 63".into());
        }
        vec![(pf, o.devices as u8)]
    };
    let p = rule_params(o)?;
    if !o.simulate {
        return Ok(rule_only(o, &cells, &p));
    }
    let base = setup(o, cells[0].0, cells[0].1)?;
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let bar = if std::io::stderr().is_terminal() && !o.json {
        indicatif::ProgressBar::new(cells.len() as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "searching the longest cable from the signal {bar:30} {pos}/{len} cells {elapsed}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let done = hart_sim::cable::table(
        &base,
        &cells,
        MAX_FER,
        o.resolution_m,
        o.sweep,
        threads,
        &|_| bar.inc(1),
    );
    bar.finish_and_clear();
    if let Some(path) = &o.csv {
        write_csv(path, &done).map_err(|e| format!("--csv {}: {e}", path.display()))?;
    }
    Ok(if o.json {
        simulated_json(o, &done, &p)
    } else {
        simulated_text(o, &done, &p)
    })
}

fn published(pf: f64, devices: u8) -> Option<f64> {
    CLASSIC_TABLE
        .iter()
        .find(|&&(cpf, n, _)| cpf == pf && n == u32::from(devices))
        .map(|&(_, _, m)| m)
}

fn rule_only(o: &CableOptions, cells: &[(f64, u8)], p: &CableParams) -> String {
    if o.json {
        let rows: Vec<_> = cells
            .iter()
            .map(|&(pf, n)| rule_json(pf, u32::from(n), p))
            .collect();
        return if o.table {
            serde_json::Value::Array(rows).to_string()
        } else {
            rows[0].to_string()
        };
    }
    if o.table {
        let mut t = String::from("pF/m  devices  rule (m)  published (m)\n");
        for &(pf, n) in cells {
            let len = cable::max_cable_length_m(pf, u32::from(n), p);
            let _ = writeln!(
                t,
                "{pf:>4}  {n:>7}  {len:>8.0}  {:>13}",
                published(pf, n).map_or("-".into(), |m| format!("{m:.0}"))
            );
        }
        t.push_str(&rule_text(p));
        return t;
    }
    let (pf, n) = cells[0];
    let len = cable::max_cable_length_m(pf, u32::from(n), p);
    let tau = cable::time_constant_s(len, pf, u32::from(n), p);
    format!(
        "{n} device(s), cable of {pf} pF/m: at most {len:.0} m (time constant {:.1} µs)\n{}",
        tau * 1e6,
        rule_text(p)
    )
}

fn rule_text(p: &CableParams) -> String {
    format!(
        "rule: (R_loop + R_cable·L)·(C_cable·L + N·C_device + C_fixed) <= {:.0} µs with R_loop {} Ω, \
         R_cable {} Ω/m, C_device {} pF, C_fixed {} pF",
        p.rc_limit_s * 1e6,
        p.loop_resistance_ohm,
        p.cable_ohm_per_m,
        p.device_capacitance_pf,
        p.fixed_capacitance_pf
    )
}

fn rule_json(pf: f64, devices: u32, p: &CableParams) -> serde_json::Value {
    let len = cable::max_cable_length_m(pf, devices, p);
    let tau = cable::time_constant_s(len, pf, devices, p);
    json!({
        "capacitance_pf_per_m": pf,
        "devices": devices,
        "max_length_m": (len * 10.0).round() / 10.0,
        "time_constant_us": (tau * 1e7).round() / 10.0,
        "loop_resistance_ohm": p.loop_resistance_ohm,
        "cable_ohm_per_m": p.cable_ohm_per_m,
        "device_capacitance_pf": p.device_capacitance_pf,
        "fixed_capacitance_pf": p.fixed_capacitance_pf,
        "rc_limit_us": p.rc_limit_s * 1e6,
    })
}

fn simulated_json(o: &CableOptions, cells: &[CableCell], p: &CableParams) -> String {
    let rows: Vec<_> = cells
        .iter()
        .map(|c| {
            let mut j = rule_json(c.pf_per_m, u32::from(c.devices), p);
            j["simulated_max_length_m"] = c.simulated.length_m.into();
            j["simulated_frames"] = c.at_rule.frames.into();
            j["simulated_fer"] = c.at_rule.fer().into();
            j["noise_mv"] = o.analog.noise_mv.into();
            j["carrier_on_mvpp"] = o.analog.carrier_mvpp.into();
            j["max_fer"] = MAX_FER.into();
            j["points"] = c
                .simulated
                .points
                .iter()
                .chain(&c.sweep)
                .map(|p| json!({"length_m": p.length_m, "frames": p.frames, "heard": p.heard}))
                .collect();
            j
        })
        .collect();
    if o.table {
        serde_json::Value::Array(rows).to_string()
    } else {
        rows[0].to_string()
    }
}

fn simulated_text(o: &CableOptions, cells: &[CableCell], p: &CableParams) -> String {
    let mut t = format!(
        "longest cable: by the RC rule, and from the signal (the network on the analog loop, \
         {} mV rms noise, carrier detect at {} mVpp, {:.1} % of frames decoded)\n",
        o.analog.noise_mv,
        o.analog.carrier_mvpp,
        100.0 * (1.0 - MAX_FER)
    );
    t.push_str("pF/m  devices  rule (m)  simulated (m)  published (m)  at the rule's length\n");
    for c in cells {
        let _ = writeln!(
            t,
            "{:>4}  {:>7}  {:>8.0}  {:>13.0}  {:>13}  {} of {} frames decoded",
            c.pf_per_m,
            c.devices,
            c.rule_m,
            c.simulated.length_m,
            published(c.pf_per_m, c.devices).map_or("-".into(), |m| format!("{m:.0}")),
            c.at_rule.heard,
            c.at_rule.frames
        );
    }
    t.push_str(&rule_text(p));
    t
}

fn write_csv(path: &std::path::Path, cells: &[CableCell]) -> std::io::Result<()> {
    let mut s = String::from("pf_per_m,devices,rule_m,length_m,frames,heard,fer\n");
    for c in cells {
        let mut all: Vec<_> = std::iter::once(&c.at_rule)
            .chain(&c.simulated.points)
            .chain(&c.sweep)
            .collect();
        all.sort_by(|a, b| a.length_m.total_cmp(&b.length_m));
        for p in all {
            let _ = writeln!(
                s,
                "{},{},{:.1},{:.1},{},{},{:.6}",
                c.pf_per_m,
                c.devices,
                c.rule_m,
                p.length_m,
                p.frames,
                p.heard,
                p.fer()
            );
        }
    }
    std::fs::write(path, s)
}
