//! The catalogue: every test once, as data. The runner dispatches on the ID, the
//! reports and docs/conform.md list what is here (a test checks the docs against it).

use serde::Serialize;

/// A group of tests (`--only`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Hash)]
#[serde(rename_all = "kebab-case")]
pub enum Group {
    /// Data link: addressing, framing, timing, communication errors.
    Link,
    /// Universal and common-practice commands.
    Commands,
    /// Burst mode.
    Burst,
    /// Physical layer, from a recording.
    Phy,
}

impl Group {
    /// Every group, in report order.
    pub const ALL: [Group; 4] = [Group::Link, Group::Commands, Group::Burst, Group::Phy];

    /// The group's name (`--only` and JSON).
    pub fn name(self) -> &'static str {
        match self {
            Group::Link => "link",
            Group::Commands => "commands",
            Group::Burst => "burst",
            Group::Phy => "phy",
        }
    }

    /// Parses a comma-separated `--only` list; the error names the groups.
    pub fn parse_list(text: &str) -> Result<Vec<Group>, String> {
        let mut out = vec![];
        for part in text.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let g = Group::ALL
                .into_iter()
                .find(|g| g.name() == part)
                .ok_or_else(|| {
                    format!("--only {text}: unknown group {part:?} (link, commands, burst, phy)")
                })?;
            if !out.contains(&g) {
                out.push(g);
            }
        }
        if out.is_empty() {
            return Err(format!(
                "--only {text:?}: name at least one group (link, commands, burst, phy)"
            ));
        }
        Ok(out)
    }
}

/// What a test needs from the transport and the run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Needs {
    /// Any transport that carries requests and replies.
    Pdu,
    /// Character-level access to the line with timing (serial, RS-485, simulated
    /// lines); HART-IP hides it.
    Line,
    /// `--allow-writes` (the test writes and restores).
    Writes,
    /// A recording (physical-layer tests).
    Recording,
}

/// One test's definition.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TestDef {
    /// Stable identifier.
    pub id: &'static str,
    /// Group.
    pub group: Group,
    /// The rule in one line.
    pub rule: &'static str,
    /// Sources: sections of docs/hart-reference.md ("HART ref") and
    /// docs/physical-layer-notes.md ("PHY notes"), with the source keys they cite.
    pub source: &'static str,
    /// True when the rule rests on one source only, or on our decision over a point
    /// the references mark uncertain (the docs say which).
    pub single_source: bool,
    /// What the test needs.
    pub needs: Needs,
}

const fn t(
    id: &'static str,
    group: Group,
    rule: &'static str,
    source: &'static str,
    single_source: bool,
    needs: Needs,
) -> TestDef {
    TestDef {
        id,
        group,
        rule,
        source,
        single_source,
        needs,
    }
}

use Group::{Burst, Commands, Link, Phy};
use Needs::{Line, Pdu, Recording, Writes};

/// Every test, in run and report order.
pub const TESTS: &[TestDef] = &[
    t("LINK-001", Link, "The device answers command 0 at its polling address in a short frame (ACK, same address, response code 0).", "HART ref §2.3 Addresses [V]; §6 Cmd 0 [V]", false, Pdu),
    t("LINK-002", Link, "The device answers command 0 at its unique ID in a long frame.", "HART ref §2.3 Addresses [V]", false, Pdu),
    t("LINK-003", Link, "No reply to a short frame for another polling address.", "HART ref §2.3 Addresses [V]; §3.3 Behaviour rules [S GF]", false, Pdu),
    t("LINK-004", Link, "No reply to a long frame for another unique ID.", "HART ref §2.3 Addresses [V]; §3.3 Behaviour rules [S GF]", false, Pdu),
    t("LINK-005", Link, "Command 11 at the broadcast address is answered with the device's tag, not with another tag.", "HART ref §2.3 Addresses (broadcast) [V]; §6 Cmd 11 [V]; §3.3 [V]", false, Pdu),
    t("LINK-006", Link, "Command 21 at the broadcast address is answered with the device's long tag (HART 6+), not with another.", "HART ref §2.3 Addresses (broadcast) [V]; §6 Cmd 21 [V]", false, Pdu),
    t("LINK-007", Link, "Replies carry the requesting master's address bit, for the primary and the secondary master.", "HART ref §2.3 Addresses (reply copies the address) [V]; §8.2 point 2 [V]", false, Line),
    t("LINK-008", Link, "Replies carry at least the preambles command 0 states (byte 12, HART 6+).", "HART ref §2.1 Preamble (response preambles) [V]; §6 Cmd 0 byte 12 [V]", false, Line),
    t("LINK-009", Link, "Requests with 2, 5 and 20 preambles are answered (2 and up accepted when at least the device's stated minimum).", "HART ref §2.1 Preamble (SOM: two 0xFF, 5-20 range) [V]", false, Line),
    t("LINK-010", Link, "The reply starts within the slave time-out STO (28 character times) after the request.", "HART ref §8.1 Timers (STO) [V]", false, Line),
    t("LINK-011", Link, "No gap inside a reply is longer than one character time.", "HART ref §1 Character layer (inter-character gap) [V]; §8.1 Gap [V]", false, Line),
    t("LINK-012", Link, "A request with a bad check byte is answered only with the communication-error summary (0x88, no data, command not executed).", "HART ref §3.1 Communication-error summary; §3.3 Behaviour rules", true, Line),
    t("LINK-013", Link, "A parity error after the device's address is answered with the communication-error summary (parity bit).", "HART ref §3.1 Communication-error summary (GF)", true, Line),
    t("LINK-014", Link, "No reply to a frame with an invalid delimiter.", "HART ref §3.1 (errors in delimiter or address: silence, GF); §2.2 Delimiter [V]", true, Line),
    t("LINK-015", Link, "No reply to a request with a gap of more than one character time inside it.", "HART ref §1 Character layer (gap error) [V]; §2.1 SOM rule [V]", false, Line),
    t("LINK-016", Link, "Every reply's check byte is the XOR of its bytes from the delimiter on.", "HART ref §2 Token-passing frame (check byte) [V]", false, Line),
    t("LINK-017", Link, "Busy and delayed-response codes (32-36), when they occur, carry no data.", "HART ref §3.2 Command response codes (classes; error replies carry no data) [V]; §3.3 delayed response [S]", false, Pdu),
    t("CMD-000", Commands, "Command 0: 12, 17 or 22 data bytes for HART 5, 6 or 7; byte 0 is 254; revision 5-7; request preambles 2-20.", "HART ref §6 Cmd 0 [V]", false, Pdu),
    t("CMD-001", Commands, "Command 1: 5 data bytes, units code from Common Table 2.", "HART ref §6 Cmd 1 [V]; §11.1 units [V]", false, Pdu),
    t("CMD-002", Commands, "Command 2: 8 data bytes, loop current and percent of range as floats.", "HART ref §6 Cmd 2 [V]", false, Pdu),
    t("CMD-003", Commands, "Command 3: 9, 14, 19 or 24 data bytes, units codes from Common Table 2.", "HART ref §6 Cmd 3 [V]", false, Pdu),
    t("CMD-007", Commands, "Command 7 (HART 6+): 2 data bytes, the polling address and a loop current mode 0 or 1.", "HART ref §6 Cmd 7 [V]; §11.5 [V]", false, Pdu),
    t("CMD-008", Commands, "Command 8 (HART 6+): 4 data bytes of classification codes.", "HART ref §6 Cmd 8 [V]", false, Pdu),
    t("CMD-009", Commands, "Command 9 (HART 6+) for one slot: 13 data bytes with a valid device variable status.", "HART ref §6 Cmd 9 [V]; §11.6 [V]", false, Pdu),
    t("CMD-012", Commands, "Command 12: 24 data bytes of packed ASCII.", "HART ref §6 Cmd 12 [V]; §10.1 Packed ASCII [V]", false, Pdu),
    t("CMD-013", Commands, "Command 13: 21 data bytes; the date is a valid day, month and year.", "HART ref §6 Cmd 13 [V]", false, Pdu),
    t("CMD-014", Commands, "Command 14: 16 data bytes, units code from Common Table 2.", "HART ref §6 Cmd 14 [V]", false, Pdu),
    t("CMD-015", Commands, "Command 15: 18 data bytes (17 for HART 5); alarm, transfer function and write-protect codes from their tables; byte 16 is 250 (HART 6+).", "HART ref §6 Cmd 15 [V]; §11.2-11.4", false, Pdu),
    t("CMD-016", Commands, "Command 16: 3 data bytes.", "HART ref §6 Cmd 16 [V]", false, Pdu),
    t("CMD-020", Commands, "Command 20 (HART 6+): 32 data bytes.", "HART ref §6 Cmd 20 [V]", false, Pdu),
    t("CMD-048", Commands, "Command 48: 9 to 25 data bytes (HART 7), answered when the status says more status is available.", "HART ref §6 Cmd 48 [V]; §4 (more status available) [V]", false, Pdu),
    t("CMD-017", Commands, "Command 17 writes the message; command 12 reads back exactly what was written (restored afterwards).", "HART ref §6 Cmd 17, Cmd 12 [V]", false, Writes),
    t("CMD-018", Commands, "Command 18 writes tag, descriptor and date; command 13 reads them back exactly (restored afterwards).", "HART ref §6 Cmd 18, Cmd 13 [V]", false, Writes),
    t("CMD-019", Commands, "Command 19 writes the final assembly number; command 16 reads it back exactly (restored afterwards).", "HART ref §6 Cmd 19, Cmd 16 [V]", false, Writes),
    t("CMD-022", Commands, "Command 22 (HART 6+) writes the long tag; command 20 reads it back exactly (restored afterwards).", "HART ref §6 Cmd 22, Cmd 20 [V]", false, Writes),
    t("CMD-038", Commands, "A write sets \"configuration changed\"; command 38 resets it for the asking master only.", "HART ref §4 Second status byte (per master) [V]; §6 Cmd 38 [V]", false, Writes),
    t("CMD-101", Commands, "A request with too few data bytes is answered with response code 5 and no data.", "HART ref §3.3 Behaviour rules [V]; §3.2 code 5 [V]", false, Pdu),
    t("CMD-102", Commands, "A command the device does not implement (127) is answered with response code 64.", "HART ref §3.3 Behaviour rules [V]; §3.2 code 64 [V]", false, Pdu),
    t("CMD-103", Commands, "Command 9 with device variable code 255 is answered with response code 2 (invalid selection) (HART 6+).", "HART ref §6 Cmd 9 RC 2 (HF, GF) [V]", false, Pdu),
    t("CMD-104", Commands, "A write to a write-protected device is answered with response code 7 and changes nothing.", "HART ref §3.2 code 7 [V]; §6 Cmd 17 [V]; §6 Cmd 15 byte 15 [V]", false, Writes),
    t("CMD-105", Commands, "The common-practice read commands the device answers (33, 50, 54, 95) have their layouts; the others answer 64.", "HART ref §7 Common-practice commands (layouts [S]/[U])", true, Pdu),
    t("CMD-106", Commands, "Command 59 with 255 or 0 reply preambles is refused as too large (3) or too small (4), or set to the nearest value (8); the original is restored (HART 6+).", "HART ref §7 Cmd 59 (5-20; RC 3, 4, 8) [V Biffi]; §3.2 codes 3, 4 [V]", false, Writes),
    t("CMD-200", Commands, "The device-specific commands listed in --expect answer with response code 0 (and their fixed reply).", "The device maker's --expect file", true, Pdu),
    t("CMD-201", Commands, "The identity matches --expect (expanded device type, device revision, universal revision).", "The device maker's --expect file; HART ref §6 Cmd 0 [V]", true, Pdu),
    t("BURST-001", Burst, "Burst frames of each enabled message come at its update period, within ±10 % (our tolerance).", "HART ref §9 Burst mode (update periods) [V]; tolerance ours [U]", true, Line),
    t("BURST-002", Burst, "Consecutive burst frames alternate the master address bit.", "HART ref §8.2 point 5 [V]", false, Line),
    t("BURST-003", Burst, "A request between burst frames is answered.", "HART ref §8.2 point 5 [V]; §9 [V]", false, Pdu),
    t("BURST-004", Burst, "Command 105 answers with the burst configuration (27 or 29 bytes) and response code 9 for a message number the device does not have.", "HART ref §9 Cmd 105 table and RC list [V-ish HF; S Biffi]", true, Pdu),
    t("BURST-005", Burst, "Commands 103, 104, 107, 108 and 109 for a burst message the device does not have answer response code 9 and change nothing (HART 7).", "HART ref §9 Burst mode (RC 9 invalid burst message) [V]", false, Writes),
    t("BURST-006", Burst, "Command 103 with an update period that is not allowed (0.3 s) answers response code 8 with the nearest legal period; the original is restored (HART 7).", "HART ref §9 Update periods (legal values, RC 8 update times adjusted) [V Biffi, HF-burst]", false, Writes),
    t("BURST-007", Burst, "Command 104 with a trigger mode that Common Table 33 does not define (5) answers response code 13 and changes nothing (HART 7).", "HART ref §9 Burst trigger modes (CT33: 0-4), Cmd 104 RC 13 [V Biffi, HF-cmd c104]", false, Writes),
    t("BURST-008", Burst, "Command 108 with a command that cannot be burst (6, a write) answers response code 2 and changes nothing (HART 7).", "HART ref §9 Burstable commands [V HF-burst], Cmd 108 RC 2 (not burstable) [V HF]", false, Writes),
    t("PHY-001", Phy, "The carrier amplitude is 120-750 mV peak-to-peak: at least the level receivers must hear (120 mVpp), at most 1.5 mA into 500 Ω (typical 500 mVpp).", "PHY notes §5 (transmit level, carrier detect) [S TI]", true, Recording),
    t("PHY-002", Phy, "Mark and space frequencies are 1200 Hz and 2200 Hz within ±1 %.", "PHY notes §5 (frequency tolerance ±1 % not confirmed) [U]", true, Recording),
    t("PHY-003", Phy, "The bit rate is 1200 bit/s within ±1 %.", "PHY notes §5 (bit-rate tolerance ±1 % not confirmed) [U]; HART ref §1 [V]", true, Recording),
    t("PHY-004", Phy, "The signal is phase continuous: every transmission decodes without error and no sample step exceeds what a continuous tone and the noise allow.", "PHY notes §5 (phase continuous, phase continuity error 0°) [S AD5700, TI]", true, Recording),
    t("PHY-005", Phy, "The carrier starts less than 5 ms before the first character and stops less than 5 ms after the last.", "PHY notes §5 (carrier start/stop) [S TI]; HART ref §1 (carrier control) [S RA]", true, Recording),
    t("PHY-006", Phy, "The signal-to-noise ratio in the message is at least 20 dB (our floor; in-band noise ≤ 55 mVpp against 500 mVpp).", "PHY notes §5 (noise sensitivity test) [S TI]; floor ours [U]", true, Recording),
];

/// The catalogue as a Markdown table (docs/conform.md carries it verbatim; a test
/// checks that it does).
pub fn markdown_table() -> String {
    let mut s = String::from("| ID | Group | Rule | Source | Needs |\n|---|---|---|---|---|\n");
    for t in TESTS {
        let needs = match t.needs {
            Needs::Pdu => "any transport",
            Needs::Line => "a line (not HART-IP)",
            Needs::Writes => "--allow-writes",
            Needs::Recording => "a recording",
        };
        s.push_str(&format!(
            "| {} | {} | {} | {}{} | {} |\n",
            t.id,
            t.group.name(),
            t.rule.replace('|', "\\|"),
            t.source,
            if t.single_source {
                " *(single source)*"
            } else {
                ""
            },
            needs
        ));
    }
    s
}

/// The test with `id`.
pub fn find(id: &str) -> Option<&'static TestDef> {
    TESTS.iter().find(|t| t.id == id)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_docs_list_every_test() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/conform.md");
        let docs = std::fs::read_to_string(path).unwrap_or_default();
        assert!(
            docs.contains(&markdown_table()),
            "docs/conform.md does not carry the catalogue as it is; put this table in it:\n{}",
            markdown_table()
        );
    }

    #[test]
    fn ids_are_unique_and_grouped() {
        for (i, a) in TESTS.iter().enumerate() {
            assert!(
                TESTS[i + 1..].iter().all(|b| b.id != a.id),
                "{} twice",
                a.id
            );
            let prefix = match a.group {
                Group::Link => "LINK-",
                Group::Commands => "CMD-",
                Group::Burst => "BURST-",
                Group::Phy => "PHY-",
            };
            assert!(a.id.starts_with(prefix), "{}", a.id);
            assert!(!a.rule.is_empty() && !a.source.is_empty());
        }
    }
}
