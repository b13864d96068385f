//! Enumerated code tables (HART Common Tables and the device variable status fields).
//!
//! Source keys and section numbers refer to the project's HART reference
//! (`hart-reference.md`). Conventions:
//! * `entries` hold individually defined codes, sorted by code;
//! * `ranges` hold spans sharing one meaning (manufacturer specific, reserved,
//!   device specific) and the generic "no real value" codes 250 not used, 251 none,
//!   252 unknown and 253 special, kept as one-code ranges so that `entries` lists only
//!   the values a device or a user would actually select (exception: in Common Table
//!   34, 250 "not used" marks an empty slot, a value hosts write, so it is an entry).
//!   [`CodeTable::name`] consults both, so lookups do not depend on where a code lives.

use super::*;

/// Shorthand for an entry.
const fn c(code: u8, name: &'static str) -> Code {
    Code { code, name }
}

/// Shorthand for a range.
const fn r(first: u8, last: u8, name: &'static str) -> CodeRange {
    CodeRange { first, last, name }
}

/// The generic codes 250–253 (used by tables that define all four).
const GENERIC_250_253: [CodeRange; 4] = [
    r(250, 250, "not used"),
    r(251, 251, "none"),
    r(252, 252, "unknown"),
    r(253, 253, "special"),
];

/// Transfer function codes (how the primary variable maps onto the loop current),
/// e.g. cmd 15 byte 1 and cmd 47.
///
/// Common Table 3 (§11.2); sources: CISA `[S]`, codes 0 and 1 `[V]`. The hyperbolic
/// curves 30–45 are kept as one range: CISA defines 30, 31, 32, 34, 37 and 40–45 with
/// shape factors whose decimal placement cannot be read unambiguously from its labels,
/// so no shape factor is claimed here `[U]`.
pub static TRANSFER_FUNCTION: CodeTable = CodeTable {
    id: "CT3",
    title: "Transfer function",
    entries: &[
        c(0, "linear"),
        c(1, "square root"),
        c(2, "square root third power"),
        c(3, "square root fifth power"),
        c(4, "special curve"),
        c(5, "square"),
        c(6, "square root with cut-off"),
        c(10, "equal percentage 1:25"),
        c(11, "equal percentage 1:33"),
        c(12, "equal percentage 1:50"),
        c(15, "quick open 1:25"),
        c(16, "quick open 1:33"),
        c(17, "quick open 1:50"),
        c(100, "flat bottom tank"),
        c(101, "conical or pyramidal bottom tank"),
        c(102, "parabolic bottom tank"),
        c(103, "spherical bottom tank"),
        c(104, "angled bottom tank"),
        c(105, "flat end cylinder tank"),
        c(106, "parabolic end cylinder tank"),
        c(107, "spherical tank"),
        c(230, "discrete (switch)"),
        c(231, "square root plus special curve"),
        c(232, "square root third power plus special curve"),
        c(233, "square root fifth power plus special curve"),
    ],
    ranges: &[
        r(30, 45, "hyperbolic (shape factor selected by the code)"),
        r(210, 229, "manufacturer specific"),
        r(234, 249, "manufacturer specific"),
        GENERIC_250_253[0],
        GENERIC_250_253[1],
        GENERIC_250_253[2],
        GENERIC_250_253[3],
    ],
};

/// Alarm selection codes: where the loop current goes on a device failure
/// (cmd 15 byte 0).
///
/// Common Table 6 (§11.3); sources: CISA, GF `[V]`.
pub static ALARM_SELECTION: CodeTable = CodeTable {
    id: "CT6",
    title: "Alarm selection",
    entries: &[c(0, "high"), c(1, "low"), c(239, "hold last output value")],
    ranges: &[
        r(240, 249, "manufacturer specific"),
        GENERIC_250_253[0],
        GENERIC_250_253[1],
        GENERIC_250_253[2],
        GENERIC_250_253[3],
    ],
};

/// Write protect codes (cmd 15 byte 15); 251 "none" means the device has no
/// write-protect function.
///
/// Common Table 7 (§11.4); sources: CISA, GF, HF `[V]`.
pub static WRITE_PROTECT: CodeTable = CodeTable {
    id: "CT7",
    title: "Write protect",
    entries: &[c(0, "not write protected"), c(1, "write protected")],
    ranges: &[
        GENERIC_250_253[0],
        r(251, 251, "none (no write-protect function)"),
        GENERIC_250_253[2],
        GENERIC_250_253[3],
    ],
};

/// Burst mode control codes (cmd 105 byte 0, cmd 109 byte 0).
///
/// The reference (§9) names this "probably CT9"; the FCG server headers call it
/// "Common Table 33", which clashes with the burst trigger mode table. Several
/// independent HART stacks label it "Table 9. Burst Mode Control Codes", so the id
/// `"CT9"` is used.
///
/// Common Table 9; sources: HS-dt `[V for 0 and 1, S for 2–4]`.
pub static BURST_MODE_CONTROL: CodeTable = CodeTable {
    id: "CT9",
    title: "Burst mode control",
    entries: &[
        c(0, "off"),
        c(1, "enabled on the token-passing data link layer"),
        c(2, "enabled on the TDMA (WirelessHART) data link layer only"),
        c(3, "enabled on the TDMA and token-passing data link layers"),
        c(4, "enabled on HART-IP"),
    ],
    ranges: &[],
};

/// Physical signaling codes (cmd 0 byte 7, bits 2–0).
///
/// Common Table 10 (§11.10); sources: PyHART, CISA, HF-db `[V]`. Codes 5 and 7 are not
/// listed by any source and stay undefined `[U]`; code 4 was "unknown" before HART 7.
pub static PHYSICAL_SIGNALING: CodeTable = CodeTable {
    id: "CT10",
    title: "Physical signaling",
    entries: &[
        c(0, "Bell 202 current"),
        c(1, "Bell 202 voltage"),
        c(2, "RS-485"),
        c(3, "RS-232"),
        c(4, "wireless (IEEE 802.15.4)"),
        c(6, "special (e.g. Ethernet, TCP/IP, Wi-Fi)"),
    ],
    ranges: &[],
};

/// Device operating mode (cmd 48 byte 7). Only 0 is defined; devices send 0.
///
/// Common Table 14 (§5); sources: CISA, HF-cmd 48 `[V]`.
pub static DEVICE_OPERATING_MODE: CodeTable = CodeTable {
    id: "CT14",
    title: "Device operating mode",
    entries: &[c(0, "reserved (always 0)")],
    ranges: &[],
};

/// Loop current mode (cmd 6 byte 1, cmd 7 byte 1).
///
/// Common Table 16 (§6 cmd 6, §11.5); sources: HF-cmd 06, GF, CISA, Biffi `[V]`.
pub static LOOP_CURRENT_MODE: CodeTable = CodeTable {
    id: "CT16",
    title: "Loop current mode",
    entries: &[
        c(0, "disabled (loop current fixed, multidrop)"),
        c(1, "enabled"),
    ],
    ranges: &[],
};

/// Lock device codes (cmd 71 request).
///
/// Common Table 18 (§7, §11.13); source: CISA `[S]`.
pub static LOCK_DEVICE: CodeTable = CodeTable {
    id: "CT18",
    title: "Lock device",
    entries: &[
        c(0, "unlock"),
        c(1, "lock (temporary)"),
        c(2, "lock (permanent)"),
        c(3, "lock all"),
    ],
    ranges: &[],
};

/// Write device variable codes (cmd 79 byte 1: simulate a device variable or not).
///
/// Common Table 19 (§7, §11.13); sources: CISA `[S]`, HF-cmd 79.
pub static WRITE_DEVICE_VARIABLE_CODE: CodeTable = CodeTable {
    id: "CT19",
    title: "Write device variable code",
    entries: &[c(0, "normal"), c(1, "fixed value")],
    ranges: &[],
};

/// Device variable family codes (cmd 54 byte 22).
///
/// Common Table 20 (§11.9); source: CISA `[S]`.
pub static DEVICE_VARIABLE_FAMILY: CodeTable = CodeTable {
    id: "CT20",
    title: "Device variable family",
    entries: &[
        c(4, "temperature"),
        c(5, "pressure"),
        c(6, "valve/actuator"),
        c(7, "simple PID control"),
        c(8, "pH"),
        c(9, "conductivity"),
        c(10, "totalizer"),
        c(11, "level"),
        c(12, "vortex flow"),
        c(13, "magnetic flow"),
        c(14, "Coriolis flow"),
        c(15, "modulating final control element"),
    ],
    ranges: &[GENERIC_250_253[0]],
};

/// Device variable classification codes (cmd 8, cmd 9 slots, cmd 54 byte 21, burst
/// trigger classification). They also select the meaning of unit codes 170–219.
///
/// Common Table 21 (§11.8); sources: CISA, GF `[V]` for 0–90; codes 96 and above from
/// CISA only `[S]`. Codes 91–95 are not listed by any source.
pub static DEVICE_VARIABLE_CLASSIFICATION: CodeTable = CodeTable {
    id: "CT21",
    title: "Device variable classification",
    entries: &[
        c(0, "not classified"),
        c(64, "temperature"),
        c(65, "pressure"),
        c(66, "volumetric flow"),
        c(67, "velocity"),
        c(68, "volume"),
        c(69, "length"),
        c(70, "time"),
        c(71, "mass"),
        c(72, "mass flow"),
        c(73, "mass per volume"),
        c(74, "viscosity"),
        c(75, "angular velocity"),
        c(76, "area"),
        c(77, "energy (work)"),
        c(78, "force"),
        c(79, "power"),
        c(80, "frequency"),
        c(81, "analytical"),
        c(82, "capacitance"),
        c(83, "electromotive force"),
        c(84, "current"),
        c(85, "resistance"),
        c(86, "angle"),
        c(87, "conductance"),
        c(88, "volume per volume"),
        c(89, "volume per mass"),
        c(90, "concentration"),
        c(96, "acceleration"),
        c(97, "turbidity"),
        c(98, "temperature difference"),
        c(99, "volumetric gas flow per second"),
        c(100, "volumetric gas flow per minute"),
        c(101, "volumetric gas flow per hour"),
        c(102, "volumetric gas flow per day"),
        c(103, "volumetric liquid flow per second"),
        c(104, "volumetric liquid flow per minute"),
        c(105, "volumetric liquid flow per hour"),
        c(106, "volumetric liquid flow per day"),
        c(107, "thermal expansion"),
        c(108, "volumetric energy density"),
        c(109, "mass energy density"),
        c(110, "torque"),
        c(111, "miscellaneous"),
        c(112, "torsional stiffness"),
        c(113, "linear stiffness"),
    ],
    ranges: &[r(1, 63, "reserved")],
};

/// Trim point support codes (which trim points a device variable accepts).
///
/// Common Table 22 (§11.13); source: CISA `[S]`.
pub static TRIM_POINT_SUPPORT: CodeTable = CodeTable {
    id: "CT22",
    title: "Trim point support",
    entries: &[
        c(0, "no trim points supported"),
        c(1, "lower trim point supported"),
        c(2, "upper trim point supported"),
        c(3, "lower and upper trim points supported"),
    ],
    ranges: &[],
};

/// Burst message trigger modes (cmd 104 byte 1, cmd 105 byte 22). In every mode the
/// message is also published when the maximum update period expires.
///
/// Common Table 33 (§9); sources: HS-dt, HF, Biffi `[V]`.
pub static BURST_TRIGGER_MODE: CodeTable = CodeTable {
    id: "CT33",
    title: "Burst message trigger mode",
    entries: &[
        c(0, "continuous"),
        c(1, "window"),
        c(2, "rising"),
        c(3, "falling"),
        c(4, "on change"),
    ],
    ranges: &[],
};

/// Device variable codes (cmd 9, 33, 50–56, 107 and others): the special codes
/// 243–250, with 0–239 left to the device.
///
/// Common Table 34 (§11.7); sources: HF-db, GF `[V]`; 243 battery life from GF only `[S]`;
/// the upper bound 239 of the device-specific range is approximate in the reference
/// `[U]`. Codes 240–242 are not listed by any source.
pub static DEVICE_VARIABLE_CODE: CodeTable = CodeTable {
    id: "CT34",
    title: "Device variable code",
    entries: &[
        c(243, "battery life"),
        c(244, "percent range"),
        c(245, "loop current"),
        c(246, "primary variable"),
        c(247, "secondary variable"),
        c(248, "tertiary variable"),
        c(249, "quaternary variable"),
        c(250, "not used"),
    ],
    ranges: &[r(0, 239, "device-specific device variable")],
};

/// Device profile codes (cmd 0 byte 21, HART 7).
///
/// Common Table 57 (§11.12); sources: PyHART, CISA `[V]`, HF-db uses 65.
pub static DEVICE_PROFILE: CodeTable = CodeTable {
    id: "CT57",
    title: "Device profile",
    entries: &[
        c(1, "process automation device"),
        c(2, "discrete device"),
        c(3, "hybrid device (process automation and discrete)"),
        c(4, "I/O system"),
        c(14, "discrete adapter"),
        c(65, "HART-IP process automation device"),
        c(66, "HART-IP discrete device"),
        c(67, "HART-IP hybrid device"),
        c(68, "HART-IP I/O system"),
        c(129, "WirelessHART process automation device"),
        c(130, "WirelessHART discrete device"),
        c(131, "WirelessHART hybrid device"),
        c(132, "WirelessHART gateway"),
        c(140, "WirelessHART access point"),
        c(141, "WirelessHART process adapter"),
        c(142, "WirelessHART discrete adapter"),
        c(
            144,
            "WirelessHART-enabled handheld or portable maintenance tool",
        ),
    ],
    ranges: &[],
};

/// Squawk control codes (optional cmd 72 request byte).
///
/// Common Table 66 (§7, §11.13); source: CISA `[S]`.
pub static SQUAWK: CodeTable = CodeTable {
    id: "CT66",
    title: "Squawk control",
    entries: &[c(0, "squawk off"), c(1, "squawk on"), c(2, "squawk once")],
    ranges: &[],
};

/// Process data status: the two-bit field in bits 7–6 of a device variable status
/// byte (cmd 9 slots, burst messages). Look up `(status >> 6) & 0x03`.
///
/// §11.6; sources: CISA (Common Table A-3), GF, HF `[V]`.
pub static PROCESS_DATA_STATUS: CodeTable = CodeTable {
    id: "process-data-status",
    title: "Process data status (device variable status bits 7-6)",
    entries: &[
        c(0, "bad"),
        c(1, "poor accuracy"),
        c(2, "manual/fixed"),
        c(3, "good"),
    ],
    ranges: &[],
};

/// Limit status: the two-bit field in bits 5–4 of a device variable status byte.
/// Look up `(status >> 4) & 0x03`.
///
/// §11.6; sources: CISA (Common Table A-3), GF, HF `[V]`.
pub static LIMIT_STATUS: CodeTable = CodeTable {
    id: "limit-status",
    title: "Limit status (device variable status bits 5-4)",
    entries: &[
        c(0, "not limited"),
        c(1, "low limited"),
        c(2, "high limited"),
        c(3, "constant"),
    ],
    ranges: &[],
};

/// Every code table of this module, for generic listing and for the tests.
pub static CODE_TABLES: &[&CodeTable] = &[
    &TRANSFER_FUNCTION,
    &ALARM_SELECTION,
    &WRITE_PROTECT,
    &BURST_MODE_CONTROL,
    &PHYSICAL_SIGNALING,
    &DEVICE_OPERATING_MODE,
    &LOOP_CURRENT_MODE,
    &LOCK_DEVICE,
    &WRITE_DEVICE_VARIABLE_CODE,
    &DEVICE_VARIABLE_FAMILY,
    &DEVICE_VARIABLE_CLASSIFICATION,
    &TRIM_POINT_SUPPORT,
    &BURST_TRIGGER_MODE,
    &DEVICE_VARIABLE_CODE,
    &DEVICE_PROFILE,
    &SQUAWK,
    &PROCESS_DATA_STATUS,
    &LIMIT_STATUS,
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entries_sorted_unique_named() {
        for t in CODE_TABLES {
            assert!(!t.id.is_empty() && !t.title.is_empty());
            assert!(!t.entries.is_empty(), "{} has no entries", t.id);
            for w in t.entries.windows(2) {
                assert!(
                    w[0].code < w[1].code,
                    "{}: not sorted/unique at {}",
                    t.id,
                    w[1].code
                );
            }
            for e in t.entries {
                assert!(!e.name.is_empty(), "{}: empty name for {}", t.id, e.code);
            }
        }
    }

    #[test]
    fn ranges_sorted_disjoint_and_not_shadowing_entries() {
        for t in CODE_TABLES {
            for rg in t.ranges {
                assert!(rg.first <= rg.last, "{}: inverted range", t.id);
                assert!(!rg.name.is_empty());
                for e in t.entries {
                    assert!(
                        e.code < rg.first || e.code > rg.last,
                        "{}: entry {} inside range {}-{}",
                        t.id,
                        e.code,
                        rg.first,
                        rg.last
                    );
                }
            }
            for w in t.ranges.windows(2) {
                assert!(
                    w[0].last < w[1].first,
                    "{}: ranges overlap or unsorted",
                    t.id
                );
            }
        }
    }

    #[test]
    fn ids_unique() {
        for (i, a) in CODE_TABLES.iter().enumerate() {
            for b in &CODE_TABLES[i + 1..] {
                assert_ne!(a.id, b.id);
            }
        }
    }

    #[test]
    fn spot_checks() {
        assert_eq!(TRANSFER_FUNCTION.name(0), Some("linear"));
        assert_eq!(TRANSFER_FUNCTION.name(1), Some("square root"));
        assert_eq!(TRANSFER_FUNCTION.name(215), Some("manufacturer specific"));
        assert_eq!(TRANSFER_FUNCTION.name(230), Some("discrete (switch)"));
        assert_eq!(TRANSFER_FUNCTION.name(240), Some("manufacturer specific"));
        assert!(TRANSFER_FUNCTION
            .name(35)
            .unwrap()
            .starts_with("hyperbolic"));
        assert_eq!(TRANSFER_FUNCTION.name(7), None);
        assert_eq!(ALARM_SELECTION.name(239), Some("hold last output value"));
        assert_eq!(ALARM_SELECTION.name(245), Some("manufacturer specific"));
        assert_eq!(ALARM_SELECTION.name(250), Some("not used"));
        assert_eq!(ALARM_SELECTION.name(2), None);
        assert!(WRITE_PROTECT.name(251).unwrap().starts_with("none"));
        assert_eq!(WRITE_PROTECT.name(253), Some("special"));
        assert_eq!(PHYSICAL_SIGNALING.name(5), None);
        assert_eq!(LOOP_CURRENT_MODE.name(1), Some("enabled"));
        assert_eq!(DEVICE_VARIABLE_CLASSIFICATION.name(65), Some("pressure"));
        assert_eq!(DEVICE_VARIABLE_CLASSIFICATION.name(10), Some("reserved"));
        assert_eq!(DEVICE_VARIABLE_CLASSIFICATION.name(93), None);
        assert_eq!(DEVICE_VARIABLE_CODE.name(246), Some("primary variable"));
        assert_eq!(
            DEVICE_VARIABLE_CODE.name(0),
            Some("device-specific device variable")
        );
        assert_eq!(DEVICE_VARIABLE_CODE.name(241), None);
        assert_eq!(
            DEVICE_PROFILE.name(65),
            Some("HART-IP process automation device")
        );
        assert_eq!(BURST_TRIGGER_MODE.name(4), Some("on change"));
        assert_eq!(BURST_MODE_CONTROL.name(0), Some("off"));
        assert_eq!(DEVICE_VARIABLE_FAMILY.name(250), Some("not used"));
        // Status byte 0x30: bad + constant (used for unsupported cmd 9 slots).
        let process_data = |status: u8| (status >> 6) & 0x03;
        let limit = |status: u8| (status >> 4) & 0x03;
        assert_eq!(PROCESS_DATA_STATUS.name(process_data(0x30)), Some("bad"));
        assert_eq!(LIMIT_STATUS.name(limit(0x30)), Some("constant"));
        assert_eq!(PROCESS_DATA_STATUS.name(process_data(0xC0)), Some("good"));
        assert_eq!(LIMIT_STATUS.name(limit(0xC0)), Some("not limited"));
    }
}
