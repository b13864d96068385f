//! Cable length of a HART network from its RC time constant.
//!
//! The rule vendors quote from the HART physical layer specification: the product of
//! the loop resistance (sense resistor plus cable) and the network capacitance (cable
//! plus every device) must stay within 65 µs, or the 2200 Hz tone is attenuated and
//! delayed too much against the 1200 Hz one. Formula as printed in Siemens' Pointek
//! CLS500 manual (7ML19985GG03, "time constant = (Rsense + Rcable·L)·(Cdevice +
//! Ccable·L)") and Yokogawa's AXFA11 manual (IM 01E20C01-01E §8.1.2).
//!
//! The "classic" cable table (Emerson/Biffi ICON3000 manual MDE 254 Rev. 1, §6.1,
//! "typical installations ... no miscellaneous series impedance") is not one formula
//! with round parameters: its 65 pF/m column fits 250 Ω with 80, 100, 120, 140 nF of
//! devices for 1, 5, 10, 15 devices, while its other columns need a different
//! resistance each. [`CableParams::default`] is the least-squares fit over the whole
//! table: 250 Ω, 0.036 Ω/m of cable (a 1 mm² pair), 5 nF per device plus 7.5 nF for
//! the master and receiver. Every entry of the table is then within 5 %, and within
//! the table's own rounding to 100 m in 12 of 16 cells; see the test below.

/// Parameters of the RC rule.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CableParams {
    /// Loop (sense) resistance, Ω (HART allows 230-1100 Ω).
    pub loop_resistance_ohm: f64,
    /// Cable resistance, both conductors, Ω per metre.
    pub cable_ohm_per_m: f64,
    /// Capacitance of each field device, pF.
    pub device_capacitance_pf: f64,
    /// Capacitance of everything else on the loop (master, receiver), pF.
    pub fixed_capacitance_pf: f64,
    /// Largest allowed time constant, seconds (65 µs).
    pub rc_limit_s: f64,
}

impl Default for CableParams {
    fn default() -> Self {
        CableParams {
            loop_resistance_ohm: 250.0,
            cable_ohm_per_m: 0.036,
            device_capacitance_pf: 5000.0,
            fixed_capacitance_pf: 7500.0,
            rc_limit_s: 65e-6,
        }
    }
}

/// The network's time constant, seconds, for `length_m` of cable of `pf_per_m` with
/// `devices` devices.
pub fn time_constant_s(length_m: f64, pf_per_m: f64, devices: u32, p: &CableParams) -> f64 {
    let r = p.loop_resistance_ohm + p.cable_ohm_per_m * length_m;
    let c = (pf_per_m * length_m
        + p.fixed_capacitance_pf
        + f64::from(devices) * p.device_capacitance_pf)
        * 1e-12;
    r * c
}

/// The longest cable (metres) that keeps the time constant within the limit; 0 when
/// even no cable is too much.
pub fn max_cable_length_m(pf_per_m: f64, devices: u32, p: &CableParams) -> f64 {
    // (R0 + r·L)(Cm·L + C0) = τ·1e12, a quadratic in L.
    let c0 = p.fixed_capacitance_pf + f64::from(devices) * p.device_capacitance_pf;
    let a = p.cable_ohm_per_m * pf_per_m;
    let b = p.loop_resistance_ohm * pf_per_m + p.cable_ohm_per_m * c0;
    let c = p.loop_resistance_ohm * c0 - p.rc_limit_s * 1e12;
    if c >= 0.0 || pf_per_m <= 0.0 {
        return 0.0;
    }
    if a == 0.0 {
        return -c / b;
    }
    (-b + libm::sqrt(b * b - 4.0 * a * c)) / (2.0 * a)
}

/// The classic cable table: (cable pF/m, devices, longest cable in metres), as printed
/// in the Biffi ICON3000 manual (MDE 254 Rev. 1, §6.1, table 2).
pub const CLASSIC_TABLE: [(f64, u32, f64); 16] = [
    (65.0, 1, 2769.0),
    (65.0, 5, 2462.0),
    (65.0, 10, 2154.0),
    (65.0, 15, 1846.0),
    (95.0, 1, 2000.0),
    (95.0, 5, 1815.0),
    (95.0, 10, 1600.0),
    (95.0, 15, 1415.0),
    (160.0, 1, 1292.0),
    (160.0, 5, 1138.0),
    (160.0, 10, 1015.0),
    (160.0, 15, 892.0),
    (225.0, 1, 985.0),
    (225.0, 5, 892.0),
    (225.0, 10, 769.0),
    (225.0, 15, 708.0),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reproduces_the_classic_table_within_five_percent() {
        let p = CableParams::default();
        for (cm, n, metres) in CLASSIC_TABLE {
            let got = max_cable_length_m(cm, n, &p);
            assert!(
                (got / metres - 1.0).abs() < 0.05,
                "{cm} pF/m, {n} devices: {got:.0} m vs {metres} m"
            );
            // At the length found, the time constant is exactly the limit.
            assert!((time_constant_s(got, cm, n, &p) - 65e-6).abs() < 1e-9);
        }
    }

    #[test]
    fn the_rounded_corners_of_the_table() {
        // The table as usually quoted, rounded to 100 m: 2800/2000/1300/1000 m for one
        // device, 1800/1400/900/700 m for fifteen.
        let p = CableParams::default();
        for (cm, n, rounded) in [
            (65.0, 1, 2800.0),
            (95.0, 1, 2000.0),
            (160.0, 1, 1300.0),
            (225.0, 1, 1000.0),
            (65.0, 15, 1800.0),
            (95.0, 15, 1400.0),
            (160.0, 15, 900.0),
            (225.0, 15, 700.0),
        ] {
            let got = max_cable_length_m(cm, n, &p);
            assert!(
                (got - rounded).abs() <= 0.05 * rounded + 50.0,
                "{cm} pF/m, {n}: {got:.0} m vs {rounded} m"
            );
        }
    }

    #[test]
    fn too_much_capacitance_allows_no_cable() {
        let p = CableParams::default();
        assert_eq!(max_cable_length_m(100.0, 60, &p), 0.0);
    }
}
