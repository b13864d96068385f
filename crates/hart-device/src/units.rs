//! Unit conversion for the unit families a device lets a host switch between
//! (commands 35, 44, 53, 104): pressure and temperature; other codes only convert to
//! themselves.

/// Pressure units: code and pascals per unit.
const PRESSURE: &[(u8, f64)] = &[
    (1, 248.84),     // inH2O @ 68 °F
    (2, 3386.38),    // inHg @ 0 °C
    (3, 2986.08),    // ftH2O @ 68 °F
    (4, 9.7890),     // mmH2O @ 68 °F
    (5, 133.322),    // mmHg @ 0 °C
    (6, 6894.757),   // psi
    (7, 100_000.0),  // bar
    (8, 100.0),      // mbar
    (9, 98.0665),    // g/cm²
    (10, 98_066.5),  // kg/cm²
    (11, 1.0),       // Pa
    (12, 1000.0),    // kPa
    (13, 133.322),   // torr
    (14, 101_325.0), // atm
    (145, 248.84),   // inH2O @ 60 °F
    (237, 1.0e6),    // MPa
    (238, 249.089),  // inH2O @ 4 °C
    (239, 9.80665),  // mmH2O @ 4 °C
];

fn to_kelvin(v: f64, code: u8) -> Option<f64> {
    Some(match code {
        32 => v + 273.15,
        33 => (v - 32.0) * 5.0 / 9.0 + 273.15,
        34 => v * 5.0 / 9.0,
        35 => v,
        _ => return None,
    })
}

fn from_kelvin(k: f64, code: u8) -> Option<f64> {
    Some(match code {
        32 => k - 273.15,
        33 => (k - 273.15) * 9.0 / 5.0 + 32.0,
        34 => k * 9.0 / 5.0,
        35 => k,
        _ => return None,
    })
}

/// Converts `value` from unit `from` to unit `to`; `None` when they are not of the same
/// family (or the family is not convertible).
pub fn convert(value: f32, from: u8, to: u8) -> Option<f32> {
    if from == to {
        return Some(value);
    }
    let v = f64::from(value);
    let p = |c: u8| {
        PRESSURE
            .iter()
            .find(|(code, _)| *code == c)
            .map(|(_, f)| *f)
    };
    if let (Some(a), Some(b)) = (p(from), p(to)) {
        return Some((v * a / b) as f32);
    }
    if let Some(k) = to_kelvin(v, from) {
        return from_kelvin(k, to).map(|x| x as f32);
    }
    None
}

/// Converts a difference (span, trigger window) rather than an absolute value.
pub fn convert_span(value: f32, from: u8, to: u8) -> Option<f32> {
    if from == to {
        return Some(value);
    }
    let zero = convert(0.0, from, to)?;
    convert(value, from, to).map(|x| x - zero)
}

/// True when `code` can stand for the same quantity as `units` (same family).
pub fn compatible(units: u8, code: u8) -> bool {
    convert(1.0, units, code).is_some()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pressure_and_temperature() {
        assert!((convert(1.0, 7, 12).unwrap() - 100.0).abs() < 1e-4);
        assert!((convert(100.0, 12, 6).unwrap() - 14.5038).abs() < 1e-3);
        assert!((convert(100.0, 32, 33).unwrap() - 212.0).abs() < 1e-3);
        assert!((convert_span(10.0, 32, 33).unwrap() - 18.0).abs() < 1e-3);
        assert!(convert(1.0, 32, 12).is_none());
        assert_eq!(convert(5.0, 57, 57), Some(5.0));
        assert!(!compatible(57, 39));
    }
}
