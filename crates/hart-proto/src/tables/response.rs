//! Command response codes: the first status byte of a response when its bit 7 is clear.
//!
//! Source keys and section numbers refer to the project's HART reference
//! (`hart-reference.md`): §3.2 for the classes and the single-definition codes, §6, §7
//! and §9 for the command-specific meanings. When bit 7
//! is set the byte is a communication-error summary instead, decoded bit by bit with
//! `COMMUNICATION_ERROR` (module `bits`); this module never names such bytes.

use super::*;

/// Named response codes that mean the same for every command.
///
/// §3.2 (single-definition codes); sources as noted on each constant.
pub mod rc {
    /// 0: success (no command-specific error or warning). `[V]`
    pub const SUCCESS: u8 = 0;
    /// 1: undefined; not returned by conforming devices. Sources: PRO, ICP `[V]`.
    pub const UNDEFINED: u8 = 1;
    /// 2: invalid selection. `[V]`
    pub const INVALID_SELECTION: u8 = 2;
    /// 3: passed parameter too large. `[V]`
    pub const TOO_LARGE: u8 = 3;
    /// 4: passed parameter too small. `[V]`
    pub const TOO_SMALL: u8 = 4;
    /// 5: too few data bytes received. `[V]`
    pub const TOO_FEW_DATA_BYTES: u8 = 5;
    /// 6: device-specific command error (HART 5: "transmitter-specific"). `[V]`
    pub const DEVICE_SPECIFIC_ERROR: u8 = 6;
    /// 7: in write-protect mode. `[V]`
    pub const WRITE_PROTECTED: u8 = 7;
    /// 16: access restricted. `[V]`
    pub const ACCESS_RESTRICTED: u8 = 16;
    /// 17: invalid device variable index. Source: HS-defs `[S]`.
    pub const INVALID_DEVICE_VARIABLE_INDEX: u8 = 17;
    /// 18: invalid units code. Source: HS-defs `[S]`.
    pub const INVALID_UNITS_CODE: u8 = 18;
    /// 19: device variable index not allowed. Source: HS-defs `[S]`.
    pub const DEVICE_VARIABLE_INDEX_NOT_ALLOWED: u8 = 19;
    /// 20: invalid extended command number (cmd 31 expansion). Source: HS-defs `[S]`.
    pub const INVALID_EXTENDED_COMMAND: u8 = 20;
    /// 21: invalid I/O card number (I/O systems, cmd 77). `[U]`
    pub const INVALID_IO_CARD: u8 = 21;
    /// 22: invalid channel number (I/O systems, cmd 77). `[U]`
    pub const INVALID_CHANNEL: u8 = 22;
    /// 23: sub-device response too long (I/O systems, cmd 77). `[U]`
    pub const SUB_DEVICE_RESPONSE_TOO_LONG: u8 = 23;
    /// 32: busy; the command cannot be executed now (HART 6/7: a delayed response
    /// could not be initiated). Sources: Biffi, PRO `[V]`.
    pub const BUSY: u8 = 32;
    /// 33: delayed response initiated; repeat the identical request later.
    /// Sources: HS-defs, HF-dll, Biffi `[V]`.
    pub const DR_INITIATED: u8 = 33;
    /// 34: delayed response running; repeat the identical request later. `[V]`
    pub const DR_RUNNING: u8 = 34;
    /// 35: delayed response dead; the pending delayed response was lost. `[V]`
    pub const DR_DEAD: u8 = 35;
    /// 36: delayed response conflict; a different delayed response is pending. `[V]`
    pub const DR_CONFLICT: u8 = 36;
    /// 64: command not implemented. `[V]`
    pub const NOT_IMPLEMENTED: u8 = 64;
}

/// Whether a response code reports success, an error (no response data follows) or
/// a warning (the normal response data follows).
///
/// §3.2 class ranges; sources: HF-dll, HS-tppdu, HF-base `[V]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ResponseClass {
    /// Code 0: the command was executed.
    Success,
    /// The command was not executed; the response carries no data.
    Error,
    /// The command was executed with a remark; the response carries its normal data.
    Warning,
}

/// The class of a first-status-byte value.
///
/// Warnings are 8, 14, 24–27, 30, 31 and 96–127; 0 is success; every other value below
/// 128 is an error. Values of 128 and above are communication-error summaries and are
/// classed as errors.
///
/// §3.2 class ranges; sources: HF-dll, HS-tppdu, HF-base `[V]`.
pub fn response_class(code: u8) -> ResponseClass {
    match code {
        0 => ResponseClass::Success,
        8 | 14 | 24..=27 | 30 | 31 | 96..=127 => ResponseClass::Warning,
        _ => ResponseClass::Error,
    }
}

/// Whether `code` has one meaning for every command (single-definition code), as
/// opposed to a command-specific (multiple-definition) meaning.
///
/// Single-definition: 0 (success), errors 1–7, 16–23, 32–64 and warnings 24–27,
/// 96–111. Command-specific: 8–15, 28–31, 65–95, 112–127. Values of 128 and above are
/// not response codes and return `false`.
///
/// §3.2 class ranges; sources: HF-dll, HS-tppdu, HF-base `[V]`.
pub fn is_single_definition(code: u8) -> bool {
    matches!(code, 0..=7 | 16..=27 | 32..=64 | 96..=111)
}

/// Shorthand for a response code entry.
const fn c(code: u8, name: &'static str) -> Code {
    Code { code, name }
}

/// The named single-definition response codes, sorted by code. Codes 24–27, 37–63
/// and 96–111 are single-definition too but have no name in the available sources.
///
/// §3.2; sources: HS-defs, HF-dll, PRO, ICP, Biffi `[V]`; 17–20 HS-defs `[S]`; 21–23 `[U]`.
pub static RESPONSE_CODES: &[Code] = &[
    c(rc::SUCCESS, "success"),
    c(rc::UNDEFINED, "undefined"),
    c(rc::INVALID_SELECTION, "invalid selection"),
    c(rc::TOO_LARGE, "passed parameter too large"),
    c(rc::TOO_SMALL, "passed parameter too small"),
    c(rc::TOO_FEW_DATA_BYTES, "too few data bytes received"),
    c(rc::DEVICE_SPECIFIC_ERROR, "device-specific command error"),
    c(rc::WRITE_PROTECTED, "in write-protect mode"),
    c(rc::ACCESS_RESTRICTED, "access restricted"),
    c(
        rc::INVALID_DEVICE_VARIABLE_INDEX,
        "invalid device variable index",
    ),
    c(rc::INVALID_UNITS_CODE, "invalid units code"),
    c(
        rc::DEVICE_VARIABLE_INDEX_NOT_ALLOWED,
        "device variable index not allowed",
    ),
    c(
        rc::INVALID_EXTENDED_COMMAND,
        "invalid extended command number",
    ),
    // 21–23 [U]: the reference gives these names from memory, and HIPPY calls 21
    // "invalid analog channel number". We keep the I/O-system reading (card, channel,
    // sub-device response), which several unrelated HART code bases spell the same way
    // and which fits cmd 77 (send command to sub-device). Confirm against
    // HCF_SPEC-307 when possible.
    c(rc::INVALID_IO_CARD, "invalid I/O card number"),
    c(rc::INVALID_CHANNEL, "invalid channel number"),
    c(
        rc::SUB_DEVICE_RESPONSE_TOO_LONG,
        "sub-device response too long",
    ),
    c(rc::BUSY, "busy"),
    c(rc::DR_INITIATED, "delayed response initiated"),
    c(rc::DR_RUNNING, "delayed response running"),
    c(rc::DR_DEAD, "delayed response dead"),
    c(rc::DR_CONFLICT, "delayed response conflict"),
    c(rc::NOT_IMPLEMENTED, "command not implemented"),
];

/// The meaning of a command-specific (multiple-definition) response code for one
/// command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CommandResponseCode {
    /// Command number (16 bits, to cover cmd 31 expanded commands).
    pub command: u16,
    /// Response code.
    pub code: u8,
    /// Meaning of `code` for `command`.
    pub name: &'static str,
}

/// Shorthand for a command-specific entry.
const fn cc(command: u16, code: u8, name: &'static str) -> CommandResponseCode {
    CommandResponseCode {
        command,
        code,
        name,
    }
}

/// Command-specific meanings of the multiple-definition response codes (8–15, 28–31,
/// 65–95, 112–127), sorted by (command, code). Only multiple-definition codes are
/// listed; single-definition codes (e.g. 2, 5, 16, 32) fall back to
/// [`RESPONSE_CODES`].
///
/// §3.2, §6, §7, §9; sources: GF, HF-cmd, HF-dll, Biffi, DVC, HS-defs, SUP-104 — `[V]`
/// unless a comment on the entry says otherwise.
pub static COMMAND_RESPONSE_CODES: &[CommandResponseCode] = &[
    // Universal commands (§6).
    cc(1, 8, "update failure"),
    cc(2, 8, "update failure"),
    cc(3, 8, "update failure"),
    cc(6, 12, "invalid mode selection"),
    cc(9, 8, "update failure"),
    // [S Biffi p.25]
    cc(9, 14, "dynamic variables returned for device variables"),
    // [S HS-defs, HF-cmd 09]
    cc(9, 30, "command response truncated"),
    cc(18, 9, "invalid date code detected"),
    // Common-practice commands (§7).
    // Cmd 33 lists code 8 without a meaning [U]; read commands use it for "update
    // failure" (cmds 1, 2, 3, 9), so that meaning is assumed.
    cc(33, 8, "update failure"),
    cc(34, 8, "set to nearest possible value"),
    cc(35, 9, "lower range value too high"),
    cc(35, 10, "lower range value too low"),
    cc(35, 11, "upper range value too high"),
    cc(35, 12, "upper range value too low"),
    cc(35, 13, "upper and lower range values out of limits"),
    cc(35, 14, "span too small (accuracy may be impaired)"),
    // [S GF]
    cc(35, 29, "invalid span"),
    cc(36, 9, "applied process too high"),
    cc(36, 10, "applied process too low"),
    cc(36, 14, "span too small (accuracy may be impaired)"),
    cc(37, 9, "applied process too high"),
    cc(37, 10, "applied process too low"),
    // [S GF, HF-dll]
    cc(
        37,
        14,
        "new lower range value pushed upper range value over sensor limit",
    ),
    cc(38, 9, "configuration change counter mismatch"),
    cc(40, 11, "loop current not active (device in multidrop mode)"),
    cc(43, 9, "applied process too high"),
    cc(43, 10, "applied process too low"),
    cc(45, 9, "incorrect loop current mode or value"),
    cc(45, 11, "loop current not active (device in multidrop mode)"),
    cc(46, 9, "incorrect loop current mode or value"),
    cc(46, 11, "loop current not active (device in multidrop mode)"),
    // [S DVC p.12]
    cc(48, 14, "status bytes mismatch"),
    // Cmd 52 lists codes 9 and 10 without meanings [U]; assumed to match cmd 43 (set PV
    // zero), the same operation applied to any device variable.
    cc(52, 9, "applied process too high"),
    cc(52, 10, "applied process too low"),
    // [S HF-dll]
    cc(53, 11, "invalid device variable code"),
    // [S HF-dll, HF-cmd]
    cc(53, 12, "invalid units code"),
    cc(55, 8, "set to nearest possible value"),
    cc(59, 8, "set to nearest possible value"),
    // [S HF-cmd 79]
    cc(79, 10, "invalid write device variable command code"),
    // Burst mode commands (§9).
    cc(103, 8, "update times adjusted"),
    cc(103, 9, "invalid burst message"),
    cc(104, 9, "invalid burst message"),
    // [S HF-cmd c104]
    cc(104, 11, "invalid device variable classification"),
    // [S HF-cmd c104]
    cc(104, 12, "invalid units code"),
    cc(104, 13, "invalid burst trigger mode selection code"),
    // [S]
    cc(105, 9, "invalid burst message"),
    // [S Biffi p.42]
    cc(107, 8, "burst condition conflict"),
    cc(107, 9, "invalid burst message"),
    // [S Biffi p.43]
    cc(108, 8, "burst condition conflict"),
    cc(108, 9, "invalid burst message"),
    // [S Biffi p.44]
    cc(109, 8, "update period increased"),
    // [S Biffi p.44]
    cc(109, 9, "insufficient bandwidth"),
];

/// The meaning of response code `code` in a response to `command`: the
/// command-specific meaning if one is known, else the single-definition meaning.
///
/// Returns `None` for codes without a known meaning and for values of 128 and above
/// (communication-error summaries, decoded bit by bit with `COMMUNICATION_ERROR`).
///
/// §3.2, §6, §7, §9; sources as for [`COMMAND_RESPONSE_CODES`] and [`RESPONSE_CODES`].
pub fn response_code_name(command: u16, code: u8) -> Option<&'static str> {
    if code >= 0x80 {
        return None;
    }
    if let Ok(i) =
        COMMAND_RESPONSE_CODES.binary_search_by(|e| (e.command, e.code).cmp(&(command, code)))
    {
        return Some(COMMAND_RESPONSE_CODES[i].name);
    }
    RESPONSE_CODES
        .binary_search_by_key(&code, |e| e.code)
        .ok()
        .map(|i| RESPONSE_CODES[i].name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn response_codes_sorted_unique_named_single() {
        for w in RESPONSE_CODES.windows(2) {
            assert!(w[0].code < w[1].code, "not sorted/unique at {}", w[1].code);
        }
        for e in RESPONSE_CODES {
            assert!(!e.name.is_empty());
            assert!(
                is_single_definition(e.code),
                "{} is not single-definition",
                e.code
            );
        }
        assert_eq!(RESPONSE_CODES.len(), 22);
    }

    #[test]
    fn command_codes_sorted_unique_named_multiple() {
        for w in COMMAND_RESPONSE_CODES.windows(2) {
            assert!(
                (w[0].command, w[0].code) < (w[1].command, w[1].code),
                "not sorted/unique at cmd {} code {}",
                w[1].command,
                w[1].code
            );
        }
        for e in COMMAND_RESPONSE_CODES {
            assert!(!e.name.is_empty());
            assert!(e.code < 0x80);
            assert!(
                !is_single_definition(e.code),
                "cmd {} code {} is single-definition",
                e.command,
                e.code
            );
        }
    }

    #[test]
    fn classes() {
        assert_eq!(response_class(0), ResponseClass::Success);
        assert_eq!(response_class(8), ResponseClass::Warning);
        assert_eq!(response_class(14), ResponseClass::Warning);
        assert_eq!(response_class(24), ResponseClass::Warning);
        assert_eq!(response_class(30), ResponseClass::Warning);
        assert_eq!(response_class(31), ResponseClass::Warning);
        assert_eq!(response_class(96), ResponseClass::Warning);
        assert_eq!(response_class(127), ResponseClass::Warning);
        assert_eq!(response_class(1), ResponseClass::Error);
        assert_eq!(response_class(9), ResponseClass::Error);
        assert_eq!(response_class(28), ResponseClass::Error);
        assert_eq!(response_class(32), ResponseClass::Error);
        assert_eq!(response_class(64), ResponseClass::Error);
        assert_eq!(response_class(95), ResponseClass::Error);
        assert_eq!(response_class(0x80), ResponseClass::Error);
        assert_eq!(response_class(0xFF), ResponseClass::Error);
        // Every code's warning status agrees with the command-specific table.
        for e in COMMAND_RESPONSE_CODES {
            let warning = matches!(e.code, 8 | 14 | 30 | 31 | 112..=127);
            assert_eq!(response_class(e.code) == ResponseClass::Warning, warning);
        }
    }

    #[test]
    fn single_definition() {
        for code in [0u8, 1, 7, 16, 23, 24, 27, 32, 36, 64, 96, 111] {
            assert!(is_single_definition(code), "{code}");
        }
        for code in [
            8u8, 9, 13, 14, 15, 28, 29, 30, 31, 65, 95, 112, 127, 128, 255,
        ] {
            assert!(!is_single_definition(code), "{code}");
        }
    }

    #[test]
    fn names() {
        assert!(response_code_name(35, 9)
            .unwrap()
            .contains("lower range value too high"));
        assert_eq!(
            response_code_name(38, 9),
            Some("configuration change counter mismatch")
        );
        assert_eq!(response_code_name(1, 8), Some("update failure"));
        assert_eq!(response_code_name(103, 8), Some("update times adjusted"));
        assert_eq!(
            response_code_name(9, 30),
            Some("command response truncated")
        );
        assert_eq!(response_code_name(48, 14), Some("status bytes mismatch"));
        assert_eq!(response_code_name(6, 12), Some("invalid mode selection"));
        assert_eq!(
            response_code_name(40, 11),
            Some("loop current not active (device in multidrop mode)")
        );
        // Single-definition fallback, for any command.
        assert_eq!(response_code_name(0, 0), Some("success"));
        assert_eq!(
            response_code_name(35, rc::WRITE_PROTECTED),
            Some("in write-protect mode")
        );
        assert_eq!(
            response_code_name(500, rc::NOT_IMPLEMENTED),
            Some("command not implemented")
        );
        assert_eq!(
            response_code_name(1, rc::DR_INITIATED),
            Some("delayed response initiated")
        );
        // Command-specific code without a known meaning for this command.
        assert_eq!(response_code_name(0, 9), None);
        assert_eq!(response_code_name(1, 65), None);
        // Communication-error summaries are not response codes.
        assert_eq!(response_code_name(0, 0x80), None);
        assert_eq!(response_code_name(0, 0xC8), None);
    }

    #[test]
    fn constants() {
        assert_eq!(rc::SUCCESS, 0);
        assert_eq!(rc::INVALID_SELECTION, 2);
        assert_eq!(rc::TOO_LARGE, 3);
        assert_eq!(rc::TOO_SMALL, 4);
        assert_eq!(rc::TOO_FEW_DATA_BYTES, 5);
        assert_eq!(rc::DEVICE_SPECIFIC_ERROR, 6);
        assert_eq!(rc::WRITE_PROTECTED, 7);
        assert_eq!(rc::ACCESS_RESTRICTED, 16);
        assert_eq!(rc::INVALID_EXTENDED_COMMAND, 20);
        assert_eq!(rc::BUSY, 32);
        assert_eq!(rc::DR_INITIATED, 33);
        assert_eq!(rc::DR_RUNNING, 34);
        assert_eq!(rc::DR_DEAD, 35);
        assert_eq!(rc::DR_CONFLICT, 36);
        assert_eq!(rc::NOT_IMPLEMENTED, 64);
    }
}
