//! `hartkit sim bench`: run the deterministic line simulation and report.

use std::io::Write;

use hart_link::TimingProfile;
use hart_sim::{SimConfig, SimReport};
use serde_json::json;

use crate::hex;

/// Parses `fsk`, `rs485:BAUD`, `psk` or `infrared`.
pub fn parse_phy(s: &str) -> Result<TimingProfile, String> {
    match s {
        "fsk" => Ok(TimingProfile::fsk()),
        "psk" => Ok(TimingProfile::psk()),
        "infrared" | "ir" => Ok(TimingProfile::infrared()),
        _ => {
            if let Some(b) = s.strip_prefix("rs485:") {
                let baud: u32 = b.parse().map_err(|_| {
                    format!("--phy {s}: baud rate must be a number, e.g. rs485:19200")
                })?;
                if !(300..=1_000_000).contains(&baud) {
                    return Err(format!("--phy {s}: baud rate must be 300..1000000"));
                }
                Ok(TimingProfile::rs485(baud))
            } else if s == "rs485" {
                Ok(TimingProfile::rs485(1200))
            } else {
                Err(format!(
                    "--phy {s}: expected fsk, rs485:BAUD, psk or infrared"
                ))
            }
        }
    }
}

/// The `--json` object.
pub fn report_json(cfg: &SimConfig, r: &SimReport, wall_seconds: f64) -> serde_json::Value {
    json!({
        "virtual_seconds": r.virtual_seconds,
        "wall_seconds": wall_seconds,
        "transactions": { "primary": r.transactions_primary, "secondary": r.transactions_secondary },
        "burst_frames": r.burst_frames,
        "failed": r.failed,
        "retries": r.retries,
        "collisions": r.collisions,
        "wrong_data": r.wrong_data,
        "line_utilization": r.line_utilization,
        "theoretical_transactions_per_s": r.theoretical_transactions_per_s,
        "efficiency": r.efficiency,
        "phy": cfg.profile.name,
        "baud": cfg.profile.baud,
        "devices": cfg.devices,
        "devices_found": r.devices_found,
        "burst_mean_period_s": r.burst_mean_period_s,
        "burst_alternates": r.burst_alternates,
        "seed": cfg.seed,
    })
}

/// Writes the trace: one JSON object per transmission.
pub fn write_trace(r: &SimReport, out: &mut impl Write) -> std::io::Result<()> {
    for t in &r.trace {
        let line = json!({
            "t0_us": t.t0_us,
            "t1_us": t.t1_us,
            "src": t.src.to_string(),
            "hex": hex::compact(&t.bytes),
            "collided": t.collided,
        });
        writeln!(out, "{line}")?;
    }
    Ok(())
}

/// The human-readable summary.
pub fn report_text(cfg: &SimConfig, r: &SimReport, wall_seconds: f64) -> String {
    let total = r.transactions_primary + r.transactions_secondary;
    let mut s = String::new();
    s.push_str(&format!(
        "simulated {:.1} s of a {}-device {} line ({} bit/s) in {:.3} s wall ({:.0}× real time)\n",
        r.virtual_seconds,
        cfg.devices,
        cfg.profile.name,
        cfg.profile.baud,
        wall_seconds,
        r.virtual_seconds / wall_seconds.max(1e-9)
    ));
    s.push_str(&format!("devices found          {}\n", r.devices_found));
    s.push_str(&format!(
        "transactions           {} primary, {} secondary ({:.2}/s)\n",
        r.transactions_primary,
        r.transactions_secondary,
        total as f64 / r.virtual_seconds.max(1e-9)
    ));
    if r.burst_frames > 0 {
        s.push_str(&format!(
            "burst frames           {} (mean period {:.3} s, master bits {})\n",
            r.burst_frames,
            r.burst_mean_period_s,
            if r.burst_alternates {
                "alternate"
            } else {
                "DO NOT alternate"
            }
        ));
    }
    s.push_str(&format!(
        "failed / retries       {} / {}\n",
        r.failed, r.retries
    ));
    s.push_str(&format!("collisions             {}\n", r.collisions));
    s.push_str(&format!("wrong data accepted    {}\n", r.wrong_data));
    s.push_str(&format!(
        "line utilization       {:.1} %\n",
        100.0 * r.line_utilization
    ));
    s.push_str(&format!(
        "theoretical ceiling    {:.3} transactions/s\n",
        r.theoretical_transactions_per_s
    ));
    s.push_str(&format!("efficiency             {:.4}", r.efficiency));
    s
}
