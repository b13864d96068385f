//! `hartkit sim bench`: run the deterministic line simulation and report.

use hart_link::TimingProfile;
use hart_sim::{LineOptions, LoopModel, Medium, SimConfig, SimReport};

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

/// The loop of the analog medium, as options (`sim bench --medium analog`,
/// `loop cable --simulate`).
#[derive(clap::Args, Debug, Clone)]
pub struct LoopArgs {
    /// Analog medium: loop (sense) resistance, Ω (HART allows 230-1100).
    #[arg(long, default_value_t = 250.0, value_name = "OHM")]
    pub loop_ohm: f64,
    /// Analog medium: cable capacitance, pF per metre.
    #[arg(long, default_value_t = 100.0, value_name = "PF")]
    pub cable_pf_per_m: f64,
    /// Analog medium: cable resistance (both conductors), Ω per metre.
    #[arg(long, default_value_t = 0.036, value_name = "OHM")]
    pub cable_ohm_per_m: f64,
    /// Analog medium: capacitance of each device, pF.
    #[arg(long, default_value_t = 5000.0, value_name = "PF")]
    pub device_pf: f64,
    /// Analog medium: noise at every receiver, mV rms in the 0.5-10 kHz band.
    #[arg(long, default_value_t = 2.2, value_name = "MV")]
    pub noise_mv: f64,
    /// Analog medium: every receiver's carrier detect switches on at this level, mVpp
    /// (HART receivers must accept 120 and ignore 80).
    #[arg(long, default_value_t = 100.0, value_name = "MVPP")]
    pub carrier_mvpp: f64,
    /// Analog medium: the 4-20 mA current, mA.
    #[arg(long, default_value_t = 12.0, value_name = "MA")]
    pub analog_ma: f64,
    /// Analog medium: receiver sample rate, samples/s.
    #[arg(long, default_value_t = 9600, value_name = "HZ")]
    pub sample_rate: u32,
}

impl LoopArgs {
    /// The loop these options describe with `cable_m` of cable (devices 1; the
    /// simulation sets the count).
    pub fn model(&self, cable_m: f64) -> Result<LoopModel, String> {
        let check = |name: &str, v: f64, lo: f64, hi: f64| {
            if v.is_finite() && (lo..=hi).contains(&v) {
                Ok(v)
            } else {
                Err(format!("--{name} {v}: must be {lo} to {hi}"))
            }
        };
        Ok(LoopModel {
            loop_resistance_ohm: check("loop-ohm", self.loop_ohm, 10.0, 10_000.0)?,
            cable_length_m: check("cable-m", cable_m, 0.0, 100_000.0)?,
            cable_pf_per_m: check("cable-pf-per-m", self.cable_pf_per_m, 0.0, 10_000.0)?,
            cable_ohm_per_m: check("cable-ohm-per-m", self.cable_ohm_per_m, 0.0, 100.0)?,
            device_capacitance_pf: check("device-pf", self.device_pf, 0.0, 1e6)?,
            analog: hart_modem::channel::AnalogProfile::Constant(check(
                "analog-ma",
                self.analog_ma,
                0.0,
                25.0,
            )?),
            ..LoopModel::default()
        })
    }

    /// Sample rate, levels and noise.
    pub fn options(&self, seed: u64) -> Result<LineOptions, String> {
        if !(8000..=96_000).contains(&self.sample_rate) {
            return Err(format!(
                "--sample-rate {}: must be 8000 to 96000",
                self.sample_rate
            ));
        }
        if !(self.noise_mv.is_finite() && (0.0..=1000.0).contains(&self.noise_mv)) {
            return Err(format!("--noise-mv {}: must be 0 to 1000", self.noise_mv));
        }
        if !(self.carrier_mvpp.is_finite() && (10.0..=1000.0).contains(&self.carrier_mvpp)) {
            return Err(format!(
                "--carrier-mvpp {}: must be 10 to 1000",
                self.carrier_mvpp
            ));
        }
        Ok(LineOptions {
            sample_rate: self.sample_rate,
            noise_mv_rms: self.noise_mv,
            carrier_on_vpp: self.carrier_mvpp * 1e-3,
            seed,
            ..LineOptions::default()
        })
    }

    /// The analog medium with `cable_m` of cable.
    pub fn medium(&self, cable_m: f64, seed: u64) -> Result<Medium, String> {
        Ok(Medium::Analog {
            model: self.model(cable_m)?,
            options: self.options(seed)?,
        })
    }
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
    if let Medium::Analog { model, options } = &cfg.medium {
        let d = r.analog_disturbance.unwrap_or_default();
        s.push_str(&format!(
            "\nanalog loop            {} Ω, {} m of {} pF/m cable, {} pF per device, noise {} mV rms, {} samples/s\n",
            model.loop_resistance_ohm,
            model.cable_length_m,
            model.cable_pf_per_m,
            model.device_capacitance_pf,
            options.noise_mv_rms,
            options.sample_rate
        ));
        s.push_str(&format!(
            "frames heard           {} of {} by their addressee (FER {:.4})\n",
            r.frames_heard,
            r.frames_sent,
            r.frame_error_rate()
        ));
        s.push_str(&format!(
            "4-20 mA reading moved  {:.2} µA mean, {:.2} µA peak by the digital traffic",
            d.mean_ua, d.peak_ua
        ));
    }
    s
}
