//! Engineering unit codes (HART Common Table 2).
//!
//! Source keys and section numbers refer to the project's HART reference
//! (`hart-reference.md`, §11.1). The unit list is cross-checked between PyHART, CSU,
//! CISA, HIPPY and HF-units and is tagged `[V]` unless an entry says otherwise.
//!
//! Layout of the code space:
//! * 1–169 and 235–239: units with one meaning for every device variable;
//! * 170–219 (HART 6+): meaning depends on the device variable classification
//!   (Common Table 21); only the pressure-class codes 170–179 are known here
//!   ([`PRESSURE_CLASS_UNITS`], [`unit_in_class`]);
//! * 240–249: manufacturer specific ([`is_manufacturer_specific_unit`]); deliberately
//!   not part of [`UNITS`] because their meaning is device-specific;
//! * 250 not used, 251 none, 252 unknown, 253 special.
//!
//! Symbols are compact forms meant for tables and annotated output; they use Unicode
//! (°, ², ³, µ, Ω, ·) where that is the natural spelling.

use super::*;

/// Device variable classification code for pressure (Common Table 21).
const CLASSIFICATION_PRESSURE: u8 = 65;

/// Shorthand used to keep the table below to one line per unit.
const fn u(code: u8, name: &'static str, symbol: &'static str) -> Unit {
    Unit { code, name, symbol }
}

/// Engineering units of Common Table 2 whose meaning does not depend on the device
/// variable classification, sorted by code.
///
/// Covers 1–156, 160–169, 235–239 and the generic codes 250–253. Codes 157–159 are
/// not listed by any source available to us; 240–249 are manufacturer specific and are
/// reported by [`is_manufacturer_specific_unit`] instead.
///
/// Common Table 2; sources: PyHART, CSU, CISA, HIPPY, HF-units `[V]`; code 69 `[U]` and
/// code 156 `[S CISA, HIPPY]` as noted on the entries.
pub static UNITS: &[Unit] = &[
    // Pressure.
    u(1, "inches of water at 68 °F", "inH2O@68°F"),
    u(2, "inches of mercury at 0 °C", "inHg@0°C"),
    u(3, "feet of water at 68 °F", "ftH2O@68°F"),
    u(4, "millimetres of water at 68 °F", "mmH2O@68°F"),
    u(5, "millimetres of mercury at 0 °C", "mmHg@0°C"),
    u(6, "pounds per square inch", "psi"),
    u(7, "bar", "bar"),
    u(8, "millibar", "mbar"),
    u(9, "grams per square centimetre", "g/cm²"),
    u(10, "kilograms per square centimetre", "kg/cm²"),
    u(11, "pascals", "Pa"),
    u(12, "kilopascals", "kPa"),
    u(13, "torr", "torr"),
    u(14, "atmospheres", "atm"),
    // Volumetric flow.
    u(15, "cubic feet per minute", "ft³/min"),
    u(16, "US gallons per minute", "gal/min"),
    u(17, "litres per minute", "L/min"),
    u(18, "imperial gallons per minute", "ImpGal/min"),
    u(19, "cubic metres per hour", "m³/h"),
    // Velocity.
    u(20, "feet per second", "ft/s"),
    u(21, "metres per second", "m/s"),
    // Volumetric flow.
    u(22, "US gallons per second", "gal/s"),
    u(23, "million US gallons per day", "Mgal/d"),
    u(24, "litres per second", "L/s"),
    u(25, "million litres per day", "ML/d"),
    u(26, "cubic feet per second", "ft³/s"),
    u(27, "cubic feet per day", "ft³/d"),
    u(28, "cubic metres per second", "m³/s"),
    u(29, "cubic metres per day", "m³/d"),
    u(30, "imperial gallons per hour", "ImpGal/h"),
    u(31, "imperial gallons per day", "ImpGal/d"),
    // Temperature.
    u(32, "degrees Celsius", "°C"),
    u(33, "degrees Fahrenheit", "°F"),
    u(34, "degrees Rankine", "°R"),
    u(35, "kelvin", "K"),
    // Electrical.
    u(36, "millivolts", "mV"),
    u(37, "ohms", "Ω"),
    u(38, "hertz", "Hz"),
    u(39, "milliamperes", "mA"),
    // Volume.
    u(40, "US gallons", "gal"),
    u(41, "litres", "L"),
    u(42, "imperial gallons", "ImpGal"),
    u(43, "cubic metres", "m³"),
    // Length.
    u(44, "feet", "ft"),
    u(45, "metres", "m"),
    // Volume.
    u(46, "barrels (42 US gallons)", "bbl"),
    // Length.
    u(47, "inches", "in"),
    u(48, "centimetres", "cm"),
    u(49, "millimetres", "mm"),
    // Time.
    u(50, "minutes", "min"),
    u(51, "seconds", "s"),
    u(52, "hours", "h"),
    u(53, "days", "d"),
    // Viscosity.
    u(54, "centistokes", "cSt"),
    u(55, "centipoise", "cP"),
    // Miscellaneous.
    u(56, "microsiemens", "µS"),
    u(57, "percent", "%"),
    u(58, "volts", "V"),
    u(59, "pH", "pH"),
    // Mass.
    u(60, "grams", "g"),
    u(61, "kilograms", "kg"),
    u(62, "metric tons", "t"),
    u(63, "pounds", "lb"),
    u(64, "short tons", "STon"),
    u(65, "long tons", "LTon"),
    // Conductance.
    u(66, "millisiemens per centimetre", "mS/cm"),
    u(67, "microsiemens per centimetre", "µS/cm"),
    // Force.
    u(68, "newtons", "N"),
    // Code 69 [U]: the reference's main unit list gives the newton metre, while CISA and
    // HIPPY (partly derived from CISA) call it the joule. The two have the same
    // dimension, so a value means the same quantity either way; only the label differs.
    // We keep "newton metre", the spelling of the majority of the cross-checked lists,
    // without claiming torque versus energy. Revisit when the Common Tables
    // specification (HCF_SPEC-183) can be checked.
    u(69, "newton metres", "N·m"),
    // Mass flow.
    u(70, "grams per second", "g/s"),
    u(71, "grams per minute", "g/min"),
    u(72, "grams per hour", "g/h"),
    u(73, "kilograms per second", "kg/s"),
    u(74, "kilograms per minute", "kg/min"),
    u(75, "kilograms per hour", "kg/h"),
    u(76, "kilograms per day", "kg/d"),
    u(77, "metric tons per minute", "t/min"),
    u(78, "metric tons per hour", "t/h"),
    u(79, "metric tons per day", "t/d"),
    u(80, "pounds per second", "lb/s"),
    u(81, "pounds per minute", "lb/min"),
    u(82, "pounds per hour", "lb/h"),
    u(83, "pounds per day", "lb/d"),
    u(84, "short tons per minute", "STon/min"),
    u(85, "short tons per hour", "STon/h"),
    u(86, "short tons per day", "STon/d"),
    u(87, "long tons per hour", "LTon/h"),
    u(88, "long tons per day", "LTon/d"),
    // Energy.
    u(89, "dekatherms", "Dth"),
    // Density and concentration.
    u(90, "specific gravity units", "SGU"),
    u(91, "grams per cubic centimetre", "g/cm³"),
    u(92, "kilograms per cubic metre", "kg/m³"),
    u(93, "pounds per US gallon", "lb/gal"),
    u(94, "pounds per cubic foot", "lb/ft³"),
    u(95, "grams per millilitre", "g/mL"),
    u(96, "kilograms per litre", "kg/L"),
    u(97, "grams per litre", "g/L"),
    u(98, "pounds per cubic inch", "lb/in³"),
    u(99, "short tons per cubic yard", "STon/yd³"),
    u(100, "degrees Twaddell", "°Tw"),
    u(101, "degrees Brix", "°Bx"),
    u(102, "degrees Baumé heavy", "°Bé hv"),
    u(103, "degrees Baumé light", "°Bé lt"),
    u(104, "degrees API", "°API"),
    u(105, "percent solids by weight", "%sol/wt"),
    u(106, "percent solids by volume", "%sol/vol"),
    u(107, "degrees Balling", "°Balling"),
    u(108, "proof per volume", "proof/vol"),
    u(109, "proof per mass", "proof/mass"),
    // Volume.
    u(110, "bushels", "bu"),
    u(111, "cubic yards", "yd³"),
    u(112, "cubic feet", "ft³"),
    u(113, "cubic inches", "in³"),
    // Velocity.
    u(114, "inches per second", "in/s"),
    u(115, "inches per minute", "in/min"),
    u(116, "feet per minute", "ft/min"),
    // Angular velocity.
    u(117, "degrees per second", "°/s"),
    u(118, "revolutions per second", "rev/s"),
    u(119, "revolutions per minute", "rpm"),
    // Velocity.
    u(120, "metres per hour", "m/h"),
    // Volumetric flow (gas, reference conditions).
    u(121, "normal cubic metres per hour", "Nm³/h"),
    u(122, "normal litres per hour", "NL/h"),
    u(123, "standard cubic feet per minute", "SCFM"),
    // Volume.
    u(124, "barrels liquid (31.5 US gallons)", "bbl liq"),
    // Mass.
    u(125, "ounces", "oz"),
    // Energy and power.
    u(126, "foot pound-force", "ft·lbf"),
    u(127, "kilowatts", "kW"),
    u(128, "kilowatt hours", "kWh"),
    u(129, "horsepower", "hp"),
    // Volumetric flow.
    u(130, "cubic feet per hour", "ft³/h"),
    u(131, "cubic metres per minute", "m³/min"),
    u(132, "barrels per second", "bbl/s"),
    u(133, "barrels per minute", "bbl/min"),
    u(134, "barrels per hour", "bbl/h"),
    u(135, "barrels per day", "bbl/d"),
    u(136, "US gallons per hour", "gal/h"),
    u(137, "imperial gallons per second", "ImpGal/s"),
    u(138, "litres per hour", "L/h"),
    // Concentration.
    u(139, "parts per million", "ppm"),
    // Power.
    u(140, "megacalories per hour", "Mcal/h"),
    u(141, "megajoules per hour", "MJ/h"),
    u(142, "British thermal units per hour", "BTU/h"),
    // Angle.
    u(143, "degrees (plane angle)", "°"),
    u(144, "radians", "rad"),
    // Pressure.
    u(145, "inches of water at 60 °F", "inH2O@60°F"),
    // Concentration.
    u(146, "micrograms per litre", "µg/L"),
    u(147, "micrograms per cubic metre", "µg/m³"),
    u(148, "percent consistency", "%Cs"),
    u(149, "volume percent", "vol%"),
    u(150, "percent steam quality", "%StmQual"),
    // Length.
    u(151, "feet in sixteenths", "ft16ths"),
    // Specific volume.
    u(152, "cubic feet per pound", "ft³/lb"),
    // Capacitance.
    u(153, "picofarads", "pF"),
    // Concentration.
    u(154, "millilitres per litre", "mL/L"),
    u(155, "microlitres per litre", "µL/L"),
    // Code 156 [S]: listed only by CISA and HIPPY (HIPPY partly derives from the others);
    // kept so that devices using it decode with a name.
    u(156, "decibels", "dB"),
    // Concentration.
    u(160, "percent Plato", "%Plato"),
    u(161, "percent of lower explosive level", "%LEL"),
    // Energy.
    u(162, "megacalories", "Mcal"),
    // Resistance.
    u(163, "kilohms", "kΩ"),
    // Energy.
    u(164, "megajoules", "MJ"),
    u(165, "British thermal units", "BTU"),
    // Volume (reference conditions).
    u(166, "normal cubic metres", "Nm³"),
    u(167, "normal litres", "NL"),
    u(168, "standard cubic feet", "SCF"),
    // Concentration.
    u(169, "parts per billion", "ppb"),
    // Codes 235–239 (late additions placed just below the manufacturer-specific block).
    u(235, "US gallons per day", "gal/d"),
    u(236, "hectolitres", "hL"),
    u(237, "megapascals", "MPa"),
    u(238, "inches of water at 4 °C", "inH2O@4°C"),
    u(239, "millimetres of water at 4 °C", "mmH2O@4°C"),
    // Generic codes shared by most Common Tables. Their "symbol" repeats the name so that
    // no symbol is empty; display code may prefer to print nothing for 250/251.
    u(250, "not used", "not used"),
    u(251, "none", "none"),
    u(252, "unknown", "unknown"),
    u(253, "special", "special"),
];

/// HART 6+ unit codes 170–179 as interpreted for device variables of the pressure
/// classification (Common Table 21 code 65), sorted by code.
///
/// In other classifications these codes mean different units, so they are kept out of
/// [`UNITS`]; use [`unit_in_class`] to look them up.
///
/// Common Table 2 (classification-dependent part); source: CSU only `[S]`.
pub static PRESSURE_CLASS_UNITS: &[Unit] = &[
    u(170, "centimetres of water at 4 °C", "cmH2O@4°C"),
    u(171, "metres of water at 4 °C", "mH2O@4°C"),
    u(172, "centimetres of mercury at 0 °C", "cmHg@0°C"),
    u(173, "pounds per square foot", "psf"),
    u(174, "hectopascals", "hPa"),
    u(175, "pounds per square inch absolute", "psia"),
    u(176, "kilograms per square metre", "kg/m²"),
    u(177, "feet of water at 4 °C", "ftH2O@4°C"),
    u(178, "feet of water at 60 °F", "ftH2O@60°F"),
    u(179, "metres of mercury at 0 °C", "mHg@0°C"),
];

/// Binary search in a unit slice sorted by code.
fn find(table: &'static [Unit], code: u8) -> Option<&'static Unit> {
    table
        .binary_search_by_key(&code, |e| e.code)
        .ok()
        .map(|i| &table[i])
}

/// Looks up a unit code in the context of a device variable classification
/// (Common Table 21).
///
/// For the pressure classification (65) the HART 6+ codes 170–179 resolve through
/// [`PRESSURE_CLASS_UNITS`]; everything else resolves through [`UNITS`]. Other
/// classification-dependent codes (170–219 outside the pressure class) and the
/// manufacturer-specific codes 240–249 return `None`.
///
/// Common Tables 2 and 21; sources: PyHART, CSU, CISA `[V]`; pressure extras CSU `[S]`.
pub fn unit_in_class(code: u8, classification: u8) -> Option<&'static Unit> {
    if classification == CLASSIFICATION_PRESSURE && (170..=179).contains(&code) {
        find(PRESSURE_CLASS_UNITS, code)
    } else {
        find(UNITS, code)
    }
}

/// The compact symbol of a classification-independent unit code (e.g. `"psi"` for 6),
/// or `None` for codes not in [`UNITS`].
///
/// Common Table 2; sources: PyHART, CSU, CISA, HIPPY `[V]`.
pub fn unit_symbol(code: u8) -> Option<&'static str> {
    find(UNITS, code).map(|e| e.symbol)
}

/// Whether `code` is one of the manufacturer-specific unit codes 240–249, whose
/// meaning is defined by the device's manufacturer (device description), not by HART.
///
/// Common Table 2; sources: PyHART, CSU, CISA `[V]`.
pub fn is_manufacturer_specific_unit(code: u8) -> bool {
    (240..=249).contains(&code)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check_sorted_unique(table: &[Unit]) {
        for w in table.windows(2) {
            assert!(w[0].code < w[1].code, "not sorted/unique at {}", w[1].code);
        }
        for e in table {
            assert!(!e.name.is_empty(), "empty name for {}", e.code);
            assert!(!e.symbol.is_empty(), "empty symbol for {}", e.code);
            assert_eq!(e.name.trim(), e.name);
            assert_eq!(e.symbol.trim(), e.symbol);
        }
    }

    #[test]
    fn tables_sorted_unique_named() {
        check_sorted_unique(UNITS);
        check_sorted_unique(PRESSURE_CLASS_UNITS);
    }

    #[test]
    fn size_and_coverage() {
        assert!(UNITS.len() >= 150);
        assert_eq!(PRESSURE_CLASS_UNITS.len(), 10);
        for code in (1..=156).chain(160..=169).chain(235..=239).chain(250..=253) {
            assert!(unit(code).is_some(), "missing unit {code}");
        }
        for code in (0..=0).chain(157..=159).chain(170..=234).chain(240..=249) {
            assert!(unit(code).is_none(), "unexpected unit {code}");
        }
        assert!(unit(254).is_none() && unit(255).is_none());
    }

    #[test]
    fn spot_checks() {
        assert_eq!(unit_symbol(6), Some("psi"));
        assert_eq!(unit(6).unwrap().name, "pounds per square inch");
        assert_eq!(unit_symbol(32), Some("°C"));
        assert_eq!(unit(32).unwrap().name, "degrees Celsius");
        assert_eq!(unit_symbol(39), Some("mA"));
        assert_eq!(unit_symbol(57), Some("%"));
        assert_eq!(unit(250).unwrap().name, "not used");
        assert_eq!(unit(251).unwrap().name, "none");
        assert_eq!(unit(1).unwrap().name, "inches of water at 68 °F");
        assert_eq!(unit_symbol(19), Some("m³/h"));
        assert_eq!(unit_symbol(67), Some("µS/cm"));
        assert_eq!(unit_symbol(37), Some("Ω"));
        assert_eq!(unit_symbol(69), Some("N·m"));
        assert_eq!(unit_symbol(156), Some("dB"));
        assert_eq!(unit_symbol(237), Some("MPa"));
        assert_eq!(unit_symbol(240), None);
    }

    #[test]
    fn class_dependent_lookup() {
        assert_eq!(unit_in_class(174, 65).unwrap().symbol, "hPa");
        assert_eq!(unit_in_class(175, 65).unwrap().symbol, "psia");
        assert!(unit_in_class(174, 64).is_none());
        assert!(unit_in_class(180, 65).is_none());
        assert_eq!(unit_in_class(6, 65).unwrap().symbol, "psi");
        assert_eq!(unit_in_class(32, 0).unwrap().symbol, "°C");
        // 170–179 never appear in the classification-independent table.
        for code in 170..=179 {
            assert!(unit(code).is_none());
            assert!(unit_in_class(code, 65).is_some());
        }
    }

    #[test]
    fn manufacturer_specific() {
        assert!(!is_manufacturer_specific_unit(239));
        assert!(is_manufacturer_specific_unit(240));
        assert!(is_manufacturer_specific_unit(249));
        assert!(!is_manufacturer_specific_unit(250));
        for code in 240..=249 {
            assert!(unit(code).is_none());
        }
    }
}
