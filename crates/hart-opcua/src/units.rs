//! HART unit codes (Common Table 2) as OPC UA engineering units: UNECE Recommendation
//! 20 common codes, the unit system OPC UA's EUInformation uses (Part 8, 5.6.3).

use opcua::types::{EUInformation, LocalizedText, UAString};

/// The namespace of UNECE unit ids in EUInformation.
pub const UNECE_NAMESPACE: &str = "http://www.opcfoundation.org/UA/units/un/cefact";

/// HART unit codes and their UNECE common codes, where one exists without doubt.
const UNECE: &[(u8, &str)] = &[
    (6, "PS"),    // psi
    (7, "BAR"),   // bar
    (8, "MBR"),   // mbar
    (11, "PAL"),  // Pa
    (12, "KPA"),  // kPa
    (14, "ATM"),  // atm
    (19, "MQH"),  // m³/h
    (21, "MTS"),  // m/s
    (28, "MQS"),  // m³/s
    (32, "CEL"),  // °C
    (33, "FAH"),  // °F
    (35, "KEL"),  // K
    (36, "2Z"),   // mV
    (37, "OHM"),  // Ω
    (38, "HTZ"),  // Hz
    (39, "4K"),   // mA
    (41, "LTR"),  // L
    (43, "MTQ"),  // m³
    (44, "FOT"),  // ft
    (45, "MTR"),  // m
    (47, "INH"),  // in
    (48, "CMT"),  // cm
    (49, "MMT"),  // mm
    (50, "MIN"),  // min
    (51, "SEC"),  // s
    (52, "HUR"),  // h
    (53, "DAY"),  // d
    (57, "P1"),   // %
    (58, "VLT"),  // V
    (60, "GRM"),  // g
    (61, "KGM"),  // kg
    (62, "TNE"),  // t
    (63, "LBR"),  // lb
    (68, "NEW"),  // N
    (73, "KGS"),  // kg/s
    (92, "KMQ"),  // kg/m³
    (127, "KWT"), // kW
    (128, "KWH"), // kWh
    (144, "C81"), // rad
    (237, "MPA"), // MPa
];

/// The UNECE code of a HART unit code.
pub fn unece_code(hart: u8) -> Option<&'static str> {
    UNECE.iter().find(|(c, _)| *c == hart).map(|(_, u)| *u)
}

/// OPC UA's unit id of a UNECE common code: its characters, 8 bits each, first one
/// highest (Part 8, 5.6.3).
pub fn unit_id(code: &str) -> i32 {
    code.bytes().fold(0i32, |id, c| (id << 8) | i32::from(c))
}

/// The EUInformation of a HART unit code: the UNECE unit when there is one, else unit
/// id -1 with HART's symbol (the client still shows it).
pub fn eu_information(hart: u8) -> EUInformation {
    let symbol = hart_proto::tables::unit_symbol(hart).unwrap_or("");
    let description = hart_proto::tables::unit(hart).map_or("", |u| u.name);
    EUInformation {
        namespace_uri: UAString::from(UNECE_NAMESPACE),
        unit_id: unece_code(hart).map_or(-1, unit_id),
        display_name: LocalizedText::new("", symbol),
        description: LocalizedText::new("", description),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Part 8's own example: "°C" is UNECE "CEL", unit id 4408652 (0x434546).
    #[test]
    fn unit_ids() {
        assert_eq!(unit_id("CEL"), 4_408_652);
        assert_eq!(unit_id("4K"), 0x344B);
        let eu = eu_information(12);
        assert_eq!(eu.unit_id, unit_id("KPA"));
        assert_eq!(eu.display_name.text.as_ref(), "kPa");
        assert_eq!(eu_information(1).unit_id, -1);
    }
}
