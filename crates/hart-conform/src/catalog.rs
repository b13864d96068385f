//! The catalogue: every test once, as data. Each entry names its test as a typed value
//! (`Test`), on which the runner dispatches exhaustively; the reports and
//! docs/conform.md list what is here (a test checks the docs against it).

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
    /// The test itself, for the runner.
    pub(crate) test: Test,
}

/// Defines the tests of one group: an enum with the stable ID of each variant.
macro_rules! test_ids {
    ($(#[$m:meta])* $name:ident { $($variant:ident = $id:literal,)* }) => {
        $(#[$m])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        pub(crate) enum $name {
            $($variant,)*
        }

        impl $name {
            /// Every test of the group.
            #[cfg(test)]
            pub(crate) const ALL: &'static [$name] = &[$($name::$variant),*];

            /// The stable ID (reports, JSON, `--only` and expect files, docs).
            pub(crate) const fn id(self) -> &'static str {
                match self {
                    $($name::$variant => $id,)*
                }
            }
        }
    };
}

test_ids! {
    /// The data-link tests (`LINK-`).
    LinkTest {
        ShortFrame = "LINK-001",
        LongFrame = "LINK-002",
        OtherPollingAddress = "LINK-003",
        OtherUniqueId = "LINK-004",
        BroadcastTag = "LINK-005",
        BroadcastLongTag = "LINK-006",
        MasterBit = "LINK-007",
        ReplyPreambles = "LINK-008",
        RequestPreambles = "LINK-009",
        ReplyDelay = "LINK-010",
        ReplyGaps = "LINK-011",
        BadCheckByte = "LINK-012",
        ParityError = "LINK-013",
        BadDelimiter = "LINK-014",
        GapInRequest = "LINK-015",
        ReplyCheckBytes = "LINK-016",
        BusyWithoutData = "LINK-017",
    }
}

test_ids! {
    /// The tests of universal and common-practice commands (`CMD-`).
    CommandTest {
        Layout0 = "CMD-000",
        Layout1 = "CMD-001",
        Layout2 = "CMD-002",
        Layout3 = "CMD-003",
        Layout7 = "CMD-007",
        Layout8 = "CMD-008",
        Layout9 = "CMD-009",
        Layout12 = "CMD-012",
        Layout13 = "CMD-013",
        Layout14 = "CMD-014",
        Layout15 = "CMD-015",
        Layout16 = "CMD-016",
        Layout20 = "CMD-020",
        AdditionalStatus = "CMD-048",
        WriteMessage = "CMD-017",
        WriteTag = "CMD-018",
        WriteFinalAssemblyNumber = "CMD-019",
        WriteLongTag = "CMD-022",
        ConfigChanged = "CMD-038",
        TooFewDataBytes = "CMD-101",
        NotImplemented = "CMD-102",
        InvalidSelection = "CMD-103",
        WriteProtected = "CMD-104",
        CommonPractice = "CMD-105",
        ResponsePreambles = "CMD-106",
        ExpectCommands = "CMD-200",
        ExpectIdentity = "CMD-201",
    }
}

test_ids! {
    /// The burst-mode tests (`BURST-`).
    BurstTest {
        Periods = "BURST-001",
        MasterBits = "BURST-002",
        RequestBetween = "BURST-003",
        Configuration = "BURST-004",
        InvalidMessage = "BURST-005",
        PeriodAdjusted = "BURST-006",
        TriggerModeRefused = "BURST-007",
        CommandRefused = "BURST-008",
    }
}

test_ids! {
    /// The physical-layer tests on a recording (`PHY-`).
    PhyTest {
        Amplitude = "PHY-001",
        Frequencies = "PHY-002",
        BitRate = "PHY-003",
        PhaseContinuity = "PHY-004",
        CarrierTiming = "PHY-005",
        SignalToNoise = "PHY-006",
    }
}

/// A test: its group and which of the group's tests. The runner and the
/// physical-layer analysis match on it exhaustively, so a catalogued test without an
/// implementation does not compile.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) enum Test {
    /// Data link.
    Link(LinkTest),
    /// Universal and common-practice commands.
    Commands(CommandTest),
    /// Burst mode.
    Burst(BurstTest),
    /// Physical layer.
    Phy(PhyTest),
}

impl Test {
    /// The stable ID.
    pub(crate) const fn id(self) -> &'static str {
        match self {
            Test::Link(t) => t.id(),
            Test::Commands(t) => t.id(),
            Test::Burst(t) => t.id(),
            Test::Phy(t) => t.id(),
        }
    }

    /// The group.
    pub(crate) const fn group(self) -> Group {
        match self {
            Test::Link(_) => Group::Link,
            Test::Commands(_) => Group::Commands,
            Test::Burst(_) => Group::Burst,
            Test::Phy(_) => Group::Phy,
        }
    }
}

const fn t(
    test: Test,
    rule: &'static str,
    source: &'static str,
    single_source: bool,
    needs: Needs,
) -> TestDef {
    TestDef {
        id: test.id(),
        group: test.group(),
        test,
        rule,
        source,
        single_source,
        needs,
    }
}

use Needs::{Line, Pdu, Recording, Writes};
use Test::{Burst, Commands, Link, Phy};

/// Every test, in run and report order.
pub const TESTS: &[TestDef] = &[
    t(Link(LinkTest::ShortFrame), "The device answers command 0 at its polling address in a short frame (ACK, same address, response code 0).", "HART ref §2.3 Addresses [V]; §6 Cmd 0 [V]", false, Pdu),
    t(Link(LinkTest::LongFrame), "The device answers command 0 at its unique ID in a long frame.", "HART ref §2.3 Addresses [V]", false, Pdu),
    t(Link(LinkTest::OtherPollingAddress), "No reply to a short frame for another polling address.", "HART ref §2.3 Addresses [V]; §3.3 Behaviour rules [S GF]", false, Pdu),
    t(Link(LinkTest::OtherUniqueId), "No reply to a long frame for another unique ID.", "HART ref §2.3 Addresses [V]; §3.3 Behaviour rules [S GF]", false, Pdu),
    t(Link(LinkTest::BroadcastTag), "Command 11 at the broadcast address is answered with the device's tag, not with another tag.", "HART ref §2.3 Addresses (broadcast) [V]; §6 Cmd 11 [V]; §3.3 [V]", false, Pdu),
    t(Link(LinkTest::BroadcastLongTag), "Command 21 at the broadcast address is answered with the device's long tag (HART 6+), not with another.", "HART ref §2.3 Addresses (broadcast) [V]; §6 Cmd 21 [V]", false, Pdu),
    t(Link(LinkTest::MasterBit), "Replies carry the requesting master's address bit, for the primary and the secondary master.", "HART ref §2.3 Addresses (reply copies the address) [V]; §8.2 point 2 [V]", false, Line),
    t(Link(LinkTest::ReplyPreambles), "Replies carry at least the preambles command 0 states (byte 12, HART 6+).", "HART ref §2.1 Preamble (response preambles) [V]; §6 Cmd 0 byte 12 [V]", false, Line),
    t(Link(LinkTest::RequestPreambles), "Requests with 2, 5 and 20 preambles are answered (2 and up accepted when at least the device's stated minimum).", "HART ref §2.1 Preamble (SOM: two 0xFF, 5-20 range) [V]", false, Line),
    t(Link(LinkTest::ReplyDelay), "The reply starts within the slave time-out STO (28 character times) after the request.", "HART ref §8.1 Timers (STO) [V]", false, Line),
    t(Link(LinkTest::ReplyGaps), "No gap inside a reply is longer than one character time.", "HART ref §1 Character layer (inter-character gap) [V]; §8.1 Gap [V]", false, Line),
    t(Link(LinkTest::BadCheckByte), "A request with a bad check byte is answered only with the communication-error summary (0x88, no data, command not executed).", "HART ref §3.1 Communication-error summary; §3.3 Behaviour rules", true, Line),
    t(Link(LinkTest::ParityError), "A parity error after the device's address is answered with the communication-error summary (parity bit).", "HART ref §3.1 Communication-error summary (GF)", true, Line),
    t(Link(LinkTest::BadDelimiter), "No reply to a frame with an invalid delimiter.", "HART ref §3.1 (errors in delimiter or address: silence, GF); §2.2 Delimiter [V]", true, Line),
    t(Link(LinkTest::GapInRequest), "No reply to a request with a gap of more than one character time inside it.", "HART ref §1 Character layer (gap error) [V]; §2.1 SOM rule [V]", false, Line),
    t(Link(LinkTest::ReplyCheckBytes), "Every reply's check byte is the XOR of its bytes from the delimiter on.", "HART ref §2 Token-passing frame (check byte) [V]", false, Line),
    t(Link(LinkTest::BusyWithoutData), "Busy and delayed-response codes (32-36), when they occur, carry no data.", "HART ref §3.2 Command response codes (classes; error replies carry no data) [V]; §3.3 delayed response [S]", false, Pdu),
    t(Commands(CommandTest::Layout0), "Command 0: 12, 17 or 22 data bytes for HART 5, 6 or 7; byte 0 is 254; revision 5-7; request preambles 2-20.", "HART ref §6 Cmd 0 [V]", false, Pdu),
    t(Commands(CommandTest::Layout1), "Command 1: 5 data bytes, units code from Common Table 2.", "HART ref §6 Cmd 1 [V]; §11.1 units [V]", false, Pdu),
    t(Commands(CommandTest::Layout2), "Command 2: 8 data bytes, loop current and percent of range as floats.", "HART ref §6 Cmd 2 [V]", false, Pdu),
    t(Commands(CommandTest::Layout3), "Command 3: 9, 14, 19 or 24 data bytes, units codes from Common Table 2.", "HART ref §6 Cmd 3 [V]", false, Pdu),
    t(Commands(CommandTest::Layout7), "Command 7 (HART 6+): 2 data bytes, the polling address and a loop current mode 0 or 1.", "HART ref §6 Cmd 7 [V]; §11.5 [V]", false, Pdu),
    t(Commands(CommandTest::Layout8), "Command 8 (HART 6+): 4 data bytes of classification codes.", "HART ref §6 Cmd 8 [V]", false, Pdu),
    t(Commands(CommandTest::Layout9), "Command 9 (HART 6+) for one slot: 13 data bytes with a valid device variable status.", "HART ref §6 Cmd 9 [V]; §11.6 [V]", false, Pdu),
    t(Commands(CommandTest::Layout12), "Command 12: 24 data bytes of packed ASCII.", "HART ref §6 Cmd 12 [V]; §10.1 Packed ASCII [V]", false, Pdu),
    t(Commands(CommandTest::Layout13), "Command 13: 21 data bytes; the date is a valid day, month and year.", "HART ref §6 Cmd 13 [V]", false, Pdu),
    t(Commands(CommandTest::Layout14), "Command 14: 16 data bytes, units code from Common Table 2.", "HART ref §6 Cmd 14 [V]", false, Pdu),
    t(Commands(CommandTest::Layout15), "Command 15: 18 data bytes (17 for HART 5); alarm, transfer function and write-protect codes from their tables; byte 16 is 250 (HART 6+).", "HART ref §6 Cmd 15 [V]; §11.2-11.4", false, Pdu),
    t(Commands(CommandTest::Layout16), "Command 16: 3 data bytes.", "HART ref §6 Cmd 16 [V]", false, Pdu),
    t(Commands(CommandTest::Layout20), "Command 20 (HART 6+): 32 data bytes.", "HART ref §6 Cmd 20 [V]", false, Pdu),
    t(Commands(CommandTest::AdditionalStatus), "Command 48: 9 to 25 data bytes (HART 7), answered when the status says more status is available.", "HART ref §6 Cmd 48 [V]; §4 (more status available) [V]", false, Pdu),
    t(Commands(CommandTest::WriteMessage), "Command 17 writes the message; command 12 reads back exactly what was written (restored afterwards).", "HART ref §6 Cmd 17, Cmd 12 [V]", false, Writes),
    t(Commands(CommandTest::WriteTag), "Command 18 writes tag, descriptor and date; command 13 reads them back exactly (restored afterwards).", "HART ref §6 Cmd 18, Cmd 13 [V]", false, Writes),
    t(Commands(CommandTest::WriteFinalAssemblyNumber), "Command 19 writes the final assembly number; command 16 reads it back exactly (restored afterwards).", "HART ref §6 Cmd 19, Cmd 16 [V]", false, Writes),
    t(Commands(CommandTest::WriteLongTag), "Command 22 (HART 6+) writes the long tag; command 20 reads it back exactly (restored afterwards).", "HART ref §6 Cmd 22, Cmd 20 [V]", false, Writes),
    t(Commands(CommandTest::ConfigChanged), "A write sets \"configuration changed\"; command 38 resets it for the asking master only.", "HART ref §4 Second status byte (per master) [V]; §6 Cmd 38 [V]", false, Writes),
    t(Commands(CommandTest::TooFewDataBytes), "A request with too few data bytes is answered with response code 5 and no data.", "HART ref §3.3 Behaviour rules [V]; §3.2 code 5 [V]", false, Pdu),
    t(Commands(CommandTest::NotImplemented), "A command the device does not implement (127) is answered with response code 64.", "HART ref §3.3 Behaviour rules [V]; §3.2 code 64 [V]", false, Pdu),
    t(Commands(CommandTest::InvalidSelection), "Command 9 with device variable code 255 is answered with response code 2 (invalid selection) (HART 6+).", "HART ref §6 Cmd 9 RC 2 (HF, GF) [V]", false, Pdu),
    t(Commands(CommandTest::WriteProtected), "A write to a write-protected device is answered with response code 7 and changes nothing.", "HART ref §3.2 code 7 [V]; §6 Cmd 17 [V]; §6 Cmd 15 byte 15 [V]", false, Writes),
    t(Commands(CommandTest::CommonPractice), "The common-practice read commands the device answers (33, 50, 54, 95) have their layouts; the others answer 64.", "HART ref §7 Common-practice commands (layouts [S]/[U])", true, Pdu),
    t(Commands(CommandTest::ResponsePreambles), "Command 59 with 255 or 0 reply preambles is refused as too large (3) or too small (4), or set to the nearest value (8); the original is restored (HART 6+).", "HART ref §7 Cmd 59 (5-20; RC 3, 4, 8) [V Biffi]; §3.2 codes 3, 4 [V]", false, Writes),
    t(Commands(CommandTest::ExpectCommands), "The device-specific commands listed in --expect answer with response code 0 (and their fixed reply).", "The device maker's --expect file", true, Pdu),
    t(Commands(CommandTest::ExpectIdentity), "The identity matches --expect (expanded device type, device revision, universal revision).", "The device maker's --expect file; HART ref §6 Cmd 0 [V]", true, Pdu),
    t(Burst(BurstTest::Periods), "Burst frames of each enabled message come at its update period, within ±10 % (our tolerance).", "HART ref §9 Burst mode (update periods) [V]; tolerance ours [U]", true, Line),
    t(Burst(BurstTest::MasterBits), "Consecutive burst frames alternate the master address bit.", "HART ref §8.2 point 5 [V]", false, Line),
    t(Burst(BurstTest::RequestBetween), "A request between burst frames is answered.", "HART ref §8.2 point 5 [V]; §9 [V]", false, Pdu),
    t(Burst(BurstTest::Configuration), "Command 105 answers with the burst configuration (27 or 29 bytes) and response code 9 for a message number the device does not have.", "HART ref §9 Cmd 105 table and RC list [V-ish HF; S Biffi]", true, Pdu),
    t(Burst(BurstTest::InvalidMessage), "Commands 103, 104, 107, 108 and 109 for a burst message the device does not have answer response code 9 and change nothing (HART 7).", "HART ref §9 Burst mode (RC 9 invalid burst message) [V]", false, Writes),
    t(Burst(BurstTest::PeriodAdjusted), "Command 103 with an update period that is not allowed (0.3 s) answers response code 8 with the nearest legal period; the original is restored (HART 7).", "HART ref §9 Update periods (legal values, RC 8 update times adjusted) [V Biffi, HF-burst]", false, Writes),
    t(Burst(BurstTest::TriggerModeRefused), "Command 104 with a trigger mode that Common Table 33 does not define (5) answers response code 13 and changes nothing (HART 7).", "HART ref §9 Burst trigger modes (CT33: 0-4), Cmd 104 RC 13 [V Biffi, HF-cmd c104]", false, Writes),
    t(Burst(BurstTest::CommandRefused), "Command 108 with a command that cannot be burst (6, a write) answers response code 2 and changes nothing (HART 7).", "HART ref §9 Burstable commands [V HF-burst], Cmd 108 RC 2 (not burstable) [V HF]", false, Writes),
    t(Phy(PhyTest::Amplitude), "The carrier amplitude is 120-750 mV peak-to-peak: at least the level receivers must hear (120 mVpp), at most 1.5 mA into 500 Ω (typical 500 mVpp).", "PHY notes §5 (transmit level, carrier detect) [S TI]", true, Recording),
    t(Phy(PhyTest::Frequencies), "Mark and space frequencies are 1200 Hz and 2200 Hz within ±1 %.", "PHY notes §5 (frequency tolerance ±1 % not confirmed) [U]", true, Recording),
    t(Phy(PhyTest::BitRate), "The bit rate is 1200 bit/s within ±1 %.", "PHY notes §5 (bit-rate tolerance ±1 % not confirmed) [U]; HART ref §1 [V]", true, Recording),
    t(Phy(PhyTest::PhaseContinuity), "The signal is phase continuous: every transmission decodes without error and no sample step exceeds what a continuous tone and the noise allow.", "PHY notes §5 (phase continuous, phase continuity error 0°) [S AD5700, TI]", true, Recording),
    t(Phy(PhyTest::CarrierTiming), "The carrier starts less than 5 ms before the first character and stops less than 5 ms after the last.", "PHY notes §5 (carrier start/stop) [S TI]; HART ref §1 (carrier control) [S RA]", true, Recording),
    t(Phy(PhyTest::SignalToNoise), "The signal-to-noise ratio in the message is at least 20 dB (our floor; in-band noise ≤ 55 mVpp against 500 mVpp).", "PHY notes §5 (noise sensitivity test) [S TI]; floor ours [U]", true, Recording),
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
    fn every_test_is_catalogued_once() {
        let all = LinkTest::ALL
            .iter()
            .map(|&t| Test::Link(t))
            .chain(CommandTest::ALL.iter().map(|&t| Test::Commands(t)))
            .chain(BurstTest::ALL.iter().map(|&t| Test::Burst(t)))
            .chain(PhyTest::ALL.iter().map(|&t| Test::Phy(t)));
        let mut n = 0;
        for test in all {
            n += 1;
            let entries = TESTS.iter().filter(|d| d.test == test).count();
            assert_eq!(
                entries,
                1,
                "{} is in the catalogue {entries} times",
                test.id()
            );
        }
        assert_eq!(n, TESTS.len());
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
