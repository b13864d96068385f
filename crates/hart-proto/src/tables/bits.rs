//! Bit-field tables: the two status bytes of every response, the cmd 48 status bytes
//! and the other one-byte flag sets.
//!
//! Source keys and section numbers refer to the project's HART reference
//! (`hart-reference.md`). Bits are listed most significant first. Reserved or
//! undefined bits are left out, so
//! [`BitTable::undefined_bits`] reports them when a device sets them.
//!
//! The masks that code commonly tests are also exported as named constants
//! ([`field_device_status`], [`comm_error`], [`extended_device_status`],
//! [`device_variable_status`]); the tables are built from those constants so each mask
//! is written once.

use super::*;

/// Shorthand for a bit definition.
const fn b(mask: u8, key: &'static str, name: &'static str) -> Bit {
    Bit { mask, key, name }
}

/// Masks of the field device status byte (second status byte of every response).
///
/// §4; sources: GF, HF-dll, CISA, PRO, CMS, HIPPY `[V]`.
pub mod field_device_status {
    /// Bit 7: device malfunction.
    pub const DEVICE_MALFUNCTION: u8 = 0x80;
    /// Bit 6: configuration changed (kept per master; cleared by cmd 38).
    pub const CONFIGURATION_CHANGED: u8 = 0x40;
    /// Bit 5: cold start (kept per master).
    pub const COLD_START: u8 = 0x20;
    /// Bit 4: more status available (read cmd 48).
    pub const MORE_STATUS_AVAILABLE: u8 = 0x10;
    /// Bit 3: loop current (PV analog output) fixed.
    pub const LOOP_CURRENT_FIXED: u8 = 0x08;
    /// Bit 2: loop current (PV analog output) saturated.
    pub const LOOP_CURRENT_SATURATED: u8 = 0x04;
    /// Bit 1: a non-primary variable is out of its limits.
    pub const NON_PRIMARY_VARIABLE_OUT_OF_LIMITS: u8 = 0x02;
    /// Bit 0: the primary variable is out of its limits.
    pub const PRIMARY_VARIABLE_OUT_OF_LIMITS: u8 = 0x01;
}

/// Masks of the first status byte when it is a communication-error summary
/// (bit 7 set) instead of a response code.
///
/// §3.1; sources: GF, HIPPY, CMS, ICP, PRO `[V]`. Bits 2 and 0 are reserved.
pub mod comm_error {
    /// Bit 7: the byte is a communication-error summary, not a response code.
    pub const FLAG: u8 = 0x80;
    /// Bit 6: vertical (character) parity error.
    pub const PARITY: u8 = 0x40;
    /// Bit 5: overrun error.
    pub const OVERRUN: u8 = 0x20;
    /// Bit 4: framing error.
    pub const FRAMING: u8 = 0x10;
    /// Bit 3: longitudinal parity (check byte) error.
    pub const CHECK_BYTE: u8 = 0x08;
    /// Bit 1: buffer overflow (message longer than the receive buffer).
    pub const BUFFER_OVERFLOW: u8 = 0x02;
}

/// Masks of the extended field device status byte (cmd 0 byte 16, cmd 9 byte 0,
/// cmd 48 byte 6, HART-IP direct PDU header).
///
/// Common Table 17 (§5); sources: CISA, PyHART, GF `[V]`. Bits 7–6 are undefined.
pub mod extended_device_status {
    /// Bit 5: function check (NE 107).
    pub const FUNCTION_CHECK: u8 = 0x20;
    /// Bit 4: out of specification (NE 107).
    pub const OUT_OF_SPECIFICATION: u8 = 0x10;
    /// Bit 3: failure (NE 107).
    pub const FAILURE: u8 = 0x08;
    /// Bit 2: critical power failure.
    pub const CRITICAL_POWER_FAILURE: u8 = 0x04;
    /// Bit 1: device variable alert.
    pub const DEVICE_VARIABLE_ALERT: u8 = 0x02;
    /// Bit 0: maintenance required.
    pub const MAINTENANCE_REQUIRED: u8 = 0x01;
}

/// Fields of the device variable status byte (cmd 9 slots, burst messages).
///
/// §11.6; sources: CISA (Common Table A-3), GF, HF `[V]`. The two-bit fields are
/// decoded with `PROCESS_DATA_STATUS` and `LIMIT_STATUS` (module `codes`).
pub mod device_variable_status {
    /// Bits 7–6: process data status field.
    pub const PROCESS_DATA_MASK: u8 = 0xC0;
    /// Shift that brings the process data status field down to bits 1–0.
    pub const PROCESS_DATA_SHIFT: u32 = 6;
    /// Bits 5–4: limit status field.
    pub const LIMIT_MASK: u8 = 0x30;
    /// Shift that brings the limit status field down to bits 1–0.
    pub const LIMIT_SHIFT: u32 = 4;
    /// Bit 3: more device variable status available.
    pub const MORE_STATUS_AVAILABLE: u8 = 0x08;
    /// Bits 2–0: device-family-specific status.
    pub const FAMILY_SPECIFIC_MASK: u8 = 0x07;
}

/// Field device status (second status byte of every response).
///
/// §4; sources: GF, HF-dll, CISA, PRO, CMS, HIPPY `[V]`.
pub static FIELD_DEVICE_STATUS: BitTable = {
    use field_device_status::*;
    BitTable {
        id: "field-device-status",
        title: "Field device status",
        bits: &[
            b(
                DEVICE_MALFUNCTION,
                "device_malfunction",
                "device malfunction",
            ),
            b(
                CONFIGURATION_CHANGED,
                "configuration_changed",
                "configuration changed",
            ),
            b(COLD_START, "cold_start", "cold start"),
            b(
                MORE_STATUS_AVAILABLE,
                "more_status_available",
                "more status available",
            ),
            b(
                LOOP_CURRENT_FIXED,
                "loop_current_fixed",
                "loop current fixed",
            ),
            b(
                LOOP_CURRENT_SATURATED,
                "loop_current_saturated",
                "loop current saturated",
            ),
            b(
                NON_PRIMARY_VARIABLE_OUT_OF_LIMITS,
                "non_primary_variable_out_of_limits",
                "non-primary variable out of limits",
            ),
            b(
                PRIMARY_VARIABLE_OUT_OF_LIMITS,
                "primary_variable_out_of_limits",
                "primary variable out of limits",
            ),
        ],
    }
};

/// Communication-error summary: the first status byte when its bit 7 is set. Bit 7
/// itself ([`comm_error::FLAG`]) only marks the byte and is not listed here.
///
/// §3.1; sources: GF, HIPPY, CMS, ICP, PRO `[V]`.
pub static COMMUNICATION_ERROR: BitTable = {
    use comm_error::*;
    BitTable {
        id: "comm-error",
        title: "Communication error summary",
        bits: &[
            b(PARITY, "parity_error", "vertical parity error"),
            b(OVERRUN, "overrun_error", "overrun error"),
            b(FRAMING, "framing_error", "framing error"),
            b(
                CHECK_BYTE,
                "check_byte_error",
                "longitudinal parity (check byte) error",
            ),
            b(BUFFER_OVERFLOW, "buffer_overflow", "buffer overflow"),
        ],
    }
};

/// Extended field device status.
///
/// Common Table 17 (§5); sources: CISA, PyHART, GF `[V]`.
pub static EXTENDED_DEVICE_STATUS: BitTable = {
    use extended_device_status::*;
    BitTable {
        id: "CT17",
        title: "Extended field device status",
        bits: &[
            b(FUNCTION_CHECK, "function_check", "function check"),
            b(
                OUT_OF_SPECIFICATION,
                "out_of_specification",
                "out of specification",
            ),
            b(FAILURE, "failure", "failure"),
            b(
                CRITICAL_POWER_FAILURE,
                "critical_power_failure",
                "critical power failure",
            ),
            b(
                DEVICE_VARIABLE_ALERT,
                "device_variable_alert",
                "device variable alert",
            ),
            b(
                MAINTENANCE_REQUIRED,
                "maintenance_required",
                "maintenance required",
            ),
        ],
    }
};

/// Flag assignments (cmd 0 byte 8). Bit 5 (0x20) is undefined.
///
/// Common Table 11 (§11.11); sources: PyHART, CISA `[V]`; bit 4 (SafeHART) CISA only `[S]`.
pub static FLAGS: BitTable = BitTable {
    id: "CT11",
    title: "Flag assignments",
    bits: &[
        b(0x80, "c8psk_multidrop_only", "C8PSK in multidrop only"),
        b(0x40, "c8psk_capable", "C8PSK capable field device"),
        b(0x10, "safehart_capable", "SafeHART capable field device"),
        b(
            0x08,
            "ieee_802_15_4_dsss_oqpsk",
            "IEEE 802.15.4 2.4 GHz DSSS with O-QPSK modulation",
        ),
        b(0x04, "protocol_bridge_device", "protocol bridge device"),
        b(0x02, "eeprom_control", "EEPROM control (cmd 39 required)"),
        b(
            0x01,
            "multi_sensor_field_device",
            "multi-sensor field device",
        ),
    ],
};

/// Standardized status 0 (cmd 48 byte 8).
///
/// Common Table 29 (§5); sources: CISA, GF `[V]`.
pub static STANDARDIZED_STATUS_0: BitTable = BitTable {
    id: "CT29",
    title: "Standardized status 0",
    bits: &[
        b(
            0x80,
            "device_configuration_locked",
            "device configuration locked",
        ),
        b(
            0x40,
            "electronic_defect",
            "electronic defect (hardware problem)",
        ),
        b(
            0x20,
            "environmental_conditions_out_of_range",
            "environmental conditions out of range",
        ),
        b(
            0x10,
            "power_supply_conditions_out_of_range",
            "power supply conditions out of range",
        ),
        b(0x08, "watchdog_reset_executed", "watchdog reset executed"),
        b(0x04, "volatile_memory_defect", "volatile memory defect"),
        b(
            0x02,
            "non_volatile_memory_defect",
            "non-volatile memory defect",
        ),
        b(
            0x01,
            "device_variable_simulation_active",
            "device variable simulation active",
        ),
    ],
};

/// Standardized status 1 (cmd 48 byte 9). Bit 4 is reserved; bits 7–5 undefined.
///
/// Common Table 30 (§5); source: CISA `[S]`.
pub static STANDARDIZED_STATUS_1: BitTable = BitTable {
    id: "CT30",
    title: "Standardized status 1",
    bits: &[
        b(
            0x08,
            "battery_or_power_supply_needs_maintenance",
            "battery or power supply needs maintenance",
        ),
        b(
            0x04,
            "event_notification_overflow",
            "event notification overflow",
        ),
        b(
            0x02,
            "discrete_variable_simulation_active",
            "discrete variable simulation active",
        ),
        b(0x01, "status_simulation_active", "status simulation active"),
    ],
};

/// Standardized status 2 (cmd 48 byte 11; I/O systems and adapters).
///
/// Common Table 31 (§5); source: CISA `[S]`.
pub static STANDARDIZED_STATUS_2: BitTable = BitTable {
    id: "CT31",
    title: "Standardized status 2",
    bits: &[
        b(0x10, "stale_data_notice", "stale data notice"),
        b(
            0x08,
            "sub_devices_with_duplicate_ids",
            "sub-devices with duplicate IDs found",
        ),
        b(0x04, "sub_device_mismatch", "sub-device mismatch"),
        b(
            0x02,
            "duplicate_master_detected",
            "duplicate master detected",
        ),
        b(0x01, "sub_device_list_changed", "sub-device list changed"),
    ],
};

/// Standardized status 3 (cmd 48 byte 12; wireless devices). Bit 1 is reserved.
///
/// Common Table 32 (§5); source: CISA `[S]`.
pub static STANDARDIZED_STATUS_3: BitTable = BitTable {
    id: "CT32",
    title: "Standardized status 3",
    bits: &[
        b(0x10, "radio_failure", "radio failure"),
        b(0x08, "block_transfer_pending", "block transfer pending"),
        b(
            0x04,
            "bandwidth_allocation_pending",
            "bandwidth allocation pending",
        ),
        b(0x01, "capacity_denied", "capacity denied"),
    ],
};

/// Analog channel saturated (cmd 48 byte 10): one bit per additional analog channel,
/// bit 0 being the second channel.
///
/// Common Table 27 (§5); source: CISA `[S]`.
pub static ANALOG_CHANNEL_SATURATED: BitTable = BitTable {
    id: "CT27",
    title: "Analog channel saturated",
    bits: &[
        b(
            0x08,
            "analog_channel_5_saturated",
            "fifth analog channel saturated",
        ),
        b(
            0x04,
            "analog_channel_4_saturated",
            "fourth analog channel saturated",
        ),
        b(
            0x02,
            "analog_channel_3_saturated",
            "third analog channel saturated",
        ),
        b(
            0x01,
            "analog_channel_2_saturated",
            "second analog channel saturated",
        ),
    ],
};

/// Analog channel fixed (cmd 48 byte 13): one bit per additional analog channel,
/// bit 0 being the second channel.
///
/// Common Table 28 (§5); layout assumed identical to Common Table 27 `[U]`.
pub static ANALOG_CHANNEL_FIXED: BitTable = BitTable {
    id: "CT28",
    title: "Analog channel fixed",
    bits: &[
        b(0x08, "analog_channel_5_fixed", "fifth analog channel fixed"),
        b(
            0x04,
            "analog_channel_4_fixed",
            "fourth analog channel fixed",
        ),
        b(0x02, "analog_channel_3_fixed", "third analog channel fixed"),
        b(
            0x01,
            "analog_channel_2_fixed",
            "second analog channel fixed",
        ),
    ],
};

/// Analog channel flags (cmd 15 byte 17, HART 6+): bit 0 set means the PV analog
/// channel is an input, clear means an output.
///
/// Common Table 26 (§6 cmd 15); sources: CISA, GF, DVC; polarity `[U]`.
pub static ANALOG_CHANNEL_FLAGS: BitTable = BitTable {
    id: "CT26",
    title: "Analog channel flags",
    bits: &[b(0x01, "analog_input_channel", "analog input channel")],
};

/// The single flag bit of the device variable status byte (bit 3). The other fields
/// of that byte are two-bit codes (`PROCESS_DATA_STATUS`, `LIMIT_STATUS`) or
/// device-family specific (bits 2–0).
///
/// §11.6; sources: CISA (Common Table A-3), GF, HF `[V]`.
pub static DEVICE_VARIABLE_STATUS_MORE: BitTable = BitTable {
    id: "device-variable-status",
    title: "Device variable status flags",
    bits: &[b(
        device_variable_status::MORE_STATUS_AVAILABLE,
        "more_device_variable_status_available",
        "more device variable status available",
    )],
};

/// Every bit table of this module, for generic listing and for the tests.
pub static BIT_TABLES: &[&BitTable] = &[
    &FIELD_DEVICE_STATUS,
    &COMMUNICATION_ERROR,
    &EXTENDED_DEVICE_STATUS,
    &FLAGS,
    &STANDARDIZED_STATUS_0,
    &STANDARDIZED_STATUS_1,
    &STANDARDIZED_STATUS_2,
    &STANDARDIZED_STATUS_3,
    &ANALOG_CHANNEL_SATURATED,
    &ANALOG_CHANNEL_FIXED,
    &ANALOG_CHANNEL_FLAGS,
    &DEVICE_VARIABLE_STATUS_MORE,
];

#[cfg(test)]
mod tests {
    use super::*;

    fn is_snake_case(s: &str) -> bool {
        !s.is_empty()
            && !s.starts_with('_')
            && !s.ends_with('_')
            && !s.contains("__")
            && s.bytes()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == b'_')
    }

    #[test]
    fn bits_single_ordered_unique_named() {
        for t in BIT_TABLES {
            assert!(!t.id.is_empty() && !t.title.is_empty());
            assert!(!t.bits.is_empty());
            for bit in t.bits {
                assert_eq!(
                    bit.mask.count_ones(),
                    1,
                    "{}: {} not one bit",
                    t.id,
                    bit.key
                );
                assert!(is_snake_case(bit.key), "{}: bad key {}", t.id, bit.key);
                assert!(!bit.name.is_empty());
            }
            // Most significant first, hence strictly decreasing and unique.
            for w in t.bits.windows(2) {
                assert!(w[0].mask > w[1].mask, "{}: bits out of order", t.id);
            }
            // Keys unique within a table.
            for (i, x) in t.bits.iter().enumerate() {
                for y in &t.bits[i + 1..] {
                    assert_ne!(x.key, y.key);
                }
            }
        }
    }

    #[test]
    fn ids_unique() {
        for (i, a) in BIT_TABLES.iter().enumerate() {
            for b in &BIT_TABLES[i + 1..] {
                assert_ne!(a.id, b.id);
            }
        }
    }

    #[test]
    fn field_device_status_decoding() {
        let mut it = FIELD_DEVICE_STATUS.set_bits(0x50);
        assert_eq!(it.next().map(|b| b.key), Some("configuration_changed"));
        assert_eq!(it.next().map(|b| b.key), Some("more_status_available"));
        assert!(it.next().is_none());
        assert_eq!(FIELD_DEVICE_STATUS.bits.len(), 8);
        assert_eq!(FIELD_DEVICE_STATUS.undefined_bits(0xFF), 0);
        assert_eq!(field_device_status::DEVICE_MALFUNCTION, 0x80);
        assert_eq!(field_device_status::PRIMARY_VARIABLE_OUT_OF_LIMITS, 0x01);
    }

    #[test]
    fn comm_error_decoding() {
        assert!(COMMUNICATION_ERROR
            .bits
            .iter()
            .all(|b| b.mask != comm_error::FLAG));
        // 0x80 flag + check byte error.
        let mut it = COMMUNICATION_ERROR.set_bits(0x88);
        assert_eq!(it.next().map(|b| b.key), Some("check_byte_error"));
        assert!(it.next().is_none());
        // Bit 7 and the reserved bits 2 and 0 are not defined by the table.
        assert_eq!(COMMUNICATION_ERROR.undefined_bits(0xFF), 0x85);
        assert_eq!(comm_error::PARITY, 0x40);
        assert_eq!(comm_error::OVERRUN, 0x20);
        assert_eq!(comm_error::FRAMING, 0x10);
        assert_eq!(comm_error::CHECK_BYTE, 0x08);
        assert_eq!(comm_error::BUFFER_OVERFLOW, 0x02);
    }

    #[test]
    fn other_spot_checks() {
        assert_eq!(EXTENDED_DEVICE_STATUS.undefined_bits(0xFF), 0xC0);
        let mut it = EXTENDED_DEVICE_STATUS.set_bits(0x01);
        assert_eq!(it.next().map(|b| b.key), Some("maintenance_required"));
        assert_eq!(FLAGS.undefined_bits(0xFF), 0x20);
        assert_eq!(STANDARDIZED_STATUS_0.undefined_bits(0xFF), 0);
        assert_eq!(STANDARDIZED_STATUS_1.undefined_bits(0xFF), 0xF0);
        assert_eq!(STANDARDIZED_STATUS_3.undefined_bits(0xFF), 0xE2);
        assert_eq!(ANALOG_CHANNEL_FLAGS.bits[0].mask, 0x01);
        assert_eq!(DEVICE_VARIABLE_STATUS_MORE.bits[0].mask, 0x08);
        assert_eq!(
            device_variable_status::PROCESS_DATA_MASK >> device_variable_status::PROCESS_DATA_SHIFT,
            3
        );
        assert_eq!(
            device_variable_status::LIMIT_MASK >> device_variable_status::LIMIT_SHIFT,
            3
        );
    }
}
