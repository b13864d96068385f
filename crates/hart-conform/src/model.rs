//! What a conformance run produces: a verdict per test with its evidence.

use serde::Serialize;

use crate::catalog::TestDef;
// The group of a test is defined with the catalogue, which sorts tests into groups.
pub use crate::catalog::Group;

/// The verdict of one test.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Verdict {
    /// The device follows the rule.
    Pass,
    /// The device breaks the rule (the evidence shows how).
    Fail,
    /// The rule does not apply to this device (its HART revision, no burst mode, ...).
    NotApplicable,
    /// The rule applies but could not be checked (the transport hides timing, writes
    /// were not allowed, the device stopped answering, ...).
    CouldNotRun,
}

impl Verdict {
    /// The name used in JSON and reports.
    pub fn name(self) -> &'static str {
        match self {
            Verdict::Pass => "pass",
            Verdict::Fail => "fail",
            Verdict::NotApplicable => "not-applicable",
            Verdict::CouldNotRun => "could-not-run",
        }
    }
}

/// A frame seen on the line during a test.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SeenFrame {
    /// The bytes as received, preambles included, in hex.
    pub hex: String,
    /// Preambles before the delimiter.
    pub preambles: usize,
    /// When its first character started, µs since the run started.
    pub start_us: u64,
    /// When its last character ended, µs since the run started.
    pub end_us: u64,
    /// Longest pause between two of its characters, µs (beyond the character time).
    pub max_gap_us: u64,
    /// A short decoding: frame type, address, command, status, or what is wrong.
    pub summary: String,
}

/// One exchange of a test: what was sent, what came back, with timing.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Evidence {
    /// What the exchange tries (e.g. "command 0, short frame, polling address 0").
    pub what: String,
    /// The request as sent, preambles included, in hex (empty when the test only
    /// listened).
    pub sent_hex: String,
    /// When the request started, µs since the run started.
    pub sent_start_us: u64,
    /// When its last character left, µs since the run started.
    pub sent_end_us: u64,
    /// Frames received until the test stopped listening.
    pub received: Vec<SeenFrame>,
    /// The delay from the end of the request to the start of the reply, µs, when a
    /// reply came and the transport shows timing.
    pub reply_delay_us: Option<u64>,
    /// An error of the transport, if the exchange failed.
    pub error: Option<String>,
}

/// The result of one test.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TestResult {
    /// Stable identifier, e.g. `LINK-001`.
    pub id: &'static str,
    /// The group.
    pub group: Group,
    /// The rule, in one line.
    pub rule: &'static str,
    /// Where the rule comes from (reference document sections).
    pub source: &'static str,
    /// True when the rule rests on one source only (or on a decision of ours over an
    /// uncertain point).
    pub single_source: bool,
    /// The verdict.
    pub verdict: Verdict,
    /// What was found, in one or two sentences.
    pub detail: String,
    /// The exchanges behind the verdict.
    pub evidence: Vec<Evidence>,
    /// How long the test took, µs of the transport's clock.
    pub duration_us: u64,
}

impl TestResult {
    /// The result of test `d`: its catalogue entry with what was found.
    pub fn of(
        d: &TestDef,
        verdict: Verdict,
        detail: String,
        evidence: Vec<Evidence>,
        duration_us: u64,
    ) -> TestResult {
        TestResult {
            id: d.id,
            group: d.group,
            rule: d.rule,
            source: d.source,
            single_source: d.single_source,
            verdict,
            detail,
            evidence,
            duration_us,
        }
    }
}

/// What the run knows about the device it tested.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct DeviceSummary {
    /// Unique ID, 10 hex digits.
    pub unique_id: String,
    /// Polling address, when found by it.
    pub polling_address: Option<u8>,
    /// HART universal revision from command 0.
    pub universal_revision: u8,
    /// Expanded device type.
    pub expanded_device_type: u16,
    /// Device ID.
    pub device_id: u32,
    /// Tag, if read.
    pub tag: Option<String>,
}

/// A whole run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Report {
    /// The target tested (`-p`), or the recording for a physical-layer run.
    pub target: String,
    /// The transport's description.
    pub transport: String,
    /// The device, when one answered.
    pub device: Option<DeviceSummary>,
    /// Warnings about the run (e.g. other traffic on the loop).
    pub warnings: Vec<String>,
    /// The results, in catalogue order.
    pub results: Vec<TestResult>,
    /// The run's length, µs of the transport's clock.
    pub duration_us: u64,
    /// Line time of the exchanges (requests and replies on the wire), µs.
    pub line_time_us: u64,
}

impl Report {
    /// How many results have `verdict`.
    pub fn count(&self, verdict: Verdict) -> usize {
        self.results.iter().filter(|r| r.verdict == verdict).count()
    }

    /// True when no test failed.
    pub fn passed(&self) -> bool {
        self.count(Verdict::Fail) == 0
    }
}

/// Bytes as upper-case hex with spaces.
pub fn hex(bytes: &[u8]) -> String {
    let mut s = String::with_capacity(bytes.len() * 3);
    for (i, b) in bytes.iter().enumerate() {
        if i > 0 {
            s.push(' ');
        }
        s.push_str(&format!("{b:02X}"));
    }
    s
}
