//! The JSON view of a run (`hartkit sim bench --json`, `hartkit.sim` in Python): field
//! names are a contract other tools read (docs/simulation.md). Needs the `json` feature.

use std::io::Write;

use hart_proto::hex;
use serde_json::json;

use crate::{Medium, SimConfig, SimReport};

impl SimReport {
    /// The report as the JSON object `hartkit sim bench --json` prints, with the run's
    /// configuration and the wall time it took.
    pub fn to_json(&self, cfg: &SimConfig, wall_seconds: f64) -> serde_json::Value {
        let r = self;
        let mut j = json!({
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
        });
        if let Medium::Analog { model, options } = &cfg.medium {
            let d = r.analog_disturbance.unwrap_or_default();
            j["medium"] = json!({
                "kind": "analog",
                "loop_ohm": model.loop_resistance_ohm,
                "cable_m": model.cable_length_m,
                "cable_pf_per_m": model.cable_pf_per_m,
                "cable_ohm_per_m": model.cable_ohm_per_m,
                "device_pf": model.device_capacitance_pf,
                "noise_mv": options.noise_mv_rms,
                "carrier_on_mvpp": options.carrier_on_vpp * 1e3,
                "sample_rate": options.sample_rate,
            });
            j["frames_sent"] = r.frames_sent.into();
            j["frames_heard"] = r.frames_heard.into();
            j["frame_error_rate"] = r.frame_error_rate().into();
            j["analog_disturbance_ua"] = json!({ "mean": d.mean_ua, "peak": d.peak_ua });
        } else {
            j["medium"] = json!({ "kind": "digital", "ber": cfg.ber });
        }
        j
    }

    /// Writes the trace: one JSON object per transmission (`t0_us`, `t1_us`, `src`,
    /// `hex`, `collided`), one per line.
    pub fn write_trace(&self, out: &mut impl Write) -> std::io::Result<()> {
        for t in &self.trace {
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
}
