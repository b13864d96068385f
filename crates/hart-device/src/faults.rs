//! Faults a simulated device can be told to commit, so that a conformance tester
//! (`hartkit conform`) can be tested on devices that break one rule each.
//!
//! A [`Fault`] is selected by name (`late-reply`, `gap-in-reply`, ...) in a plant file
//! (`faults = ["late-reply"]` on a `[[device]]`) or through [`crate::Node::set_faults`].
//! Each fault breaks exactly one rule and leaves everything else as a well-made device
//! does it.

use serde::{Deserialize, Serialize};

/// One way a device can break the rules.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Fault {
    /// Replies start 40 character times after the request, well after STO (28).
    LateReply,
    /// Replies pause for 3 character times after their sixth byte (a gap inside a frame).
    GapInReply,
    /// Replies (not burst frames) carry a wrong check byte.
    BadReplyCheckByte,
    /// A request whose only fault is its check byte is executed and answered normally,
    /// instead of with the communication-error summary.
    ExecutesBadCheckByte,
    /// Replies carry the other master's address bit.
    MasterBitNotEchoed,
    /// Replies carry 2 preambles, fewer than command 0 states.
    TooFewPreambles,
    /// The device answers requests for any polling address and any unique ID.
    AnswersOtherAddress,
    /// A request with too few data bytes is answered with response code 0 and no data
    /// instead of 5.
    NoTooFewDataBytes,
    /// Command 38 answers success but leaves "configuration changed" set.
    Cmd38NoReset,
    /// Burst frames go out at 1.5 times the configured period.
    BurstPeriodOff,
    /// Command 104 takes a trigger mode that is not in Common Table 33 (5 and above)
    /// instead of refusing it with response code 13.
    BurstTriggerAnyMode,
    /// Command 108 takes a command that cannot be burst (a write such as command 6)
    /// instead of refusing it with response code 2.
    BurstAnyCommand,
}

/// Every fault with its name (as in plant files) and what it does.
pub const ALL: &[(Fault, &str, &str)] = &[
    (
        Fault::LateReply,
        "late-reply",
        "replies start 40 character times after the request (after STO)",
    ),
    (
        Fault::GapInReply,
        "gap-in-reply",
        "a gap of 3 character times inside every reply",
    ),
    (
        Fault::BadReplyCheckByte,
        "bad-reply-check-byte",
        "replies carry a wrong check byte",
    ),
    (
        Fault::ExecutesBadCheckByte,
        "executes-bad-check-byte",
        "a request with a bad check byte is executed and answered normally",
    ),
    (
        Fault::MasterBitNotEchoed,
        "master-bit-not-echoed",
        "replies carry the other master's bit",
    ),
    (
        Fault::TooFewPreambles,
        "too-few-preambles",
        "replies carry 2 preambles",
    ),
    (
        Fault::AnswersOtherAddress,
        "answers-other-address",
        "answers requests for any polling address or unique ID",
    ),
    (
        Fault::NoTooFewDataBytes,
        "no-too-few-data-bytes",
        "a request with too few data bytes gets response code 0",
    ),
    (
        Fault::Cmd38NoReset,
        "cmd38-no-reset",
        "command 38 leaves \"configuration changed\" set",
    ),
    (
        Fault::BurstPeriodOff,
        "burst-period-off",
        "bursts at 1.5 times the configured period",
    ),
    (
        Fault::BurstTriggerAnyMode,
        "burst-trigger-any-mode",
        "command 104 takes an undefined trigger mode",
    ),
    (
        Fault::BurstAnyCommand,
        "burst-any-command",
        "command 108 takes a command that cannot be burst",
    ),
];

impl Fault {
    /// The fault's name in plant files.
    pub fn name(self) -> &'static str {
        ALL.iter()
            .find(|(f, _, _)| *f == self)
            .map_or("?", |(_, n, _)| n)
    }

    /// The fault named `name`; the error lists the names.
    pub fn parse(name: &str) -> Result<Fault, String> {
        ALL.iter()
            .find(|(_, n, _)| *n == name)
            .map(|(f, _, _)| *f)
            .ok_or_else(|| {
                let names: Vec<&str> = ALL.iter().map(|(_, n, _)| *n).collect();
                format!("unknown fault {name:?}: one of {}", names.join(", "))
            })
    }
}

/// A set of faults.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Faults(u32);

impl Faults {
    /// No fault.
    pub const NONE: Faults = Faults(0);

    /// The set of `faults`.
    pub fn of(faults: &[Fault]) -> Self {
        Faults(faults.iter().fold(0, |a, f| a | (1 << (*f as u32))))
    }

    /// True when `fault` is in the set.
    pub fn has(self, fault: Fault) -> bool {
        self.0 & (1 << (fault as u32)) != 0
    }
}
