//! Typed writes: the changes the gateway's front ends offer (range, damping, units,
//! fixed current, tag, descriptor, date, message, long tag), each turned into its HART
//! command in one place, audited before it goes on the loop, and judged by one mapping
//! of the device's response codes ([`DeviceRefusal`]) that every front end translates
//! into its own words (Modbus exceptions, OPC UA status codes).

use hart_access::{NotPermitted, WriteOutcome, WriteRecord};
use hart_proto::command::{
    Damping, Empty, FixedCurrent, LongTag, Message, PvUnits, RangeValues, TagDescriptorDate,
};
use hart_proto::tables::{rc, response_class, ResponseClass};
use hart_proto::types::{Date, Latin1String, MilliAmps, PackedString, Seconds, UnitCode};
use hart_proto::wire::{Reader, Wire};
use hart_proto::Request;

use crate::lease::LeaseTerms;
use crate::{Engine, WriteError, WriteReply};

/// What a reply (or its absence) to a write of `command` means for the audit: for
/// every front end that carries a write's frame itself (HART-IP) as for the engine's
/// own.
pub fn outcome_of(command: u16, reply: Option<&[u8]>) -> WriteOutcome {
    let Some(reply) = reply else {
        return WriteOutcome::NoReply;
    };
    match hart_proto::frame::Frame::parse_pdu(reply) {
        Err(e) => WriteOutcome::Failed(format!("bad reply: {e}")),
        Ok(f) if f.is_communication_error() => WriteOutcome::Failed(format!(
            "the device reports a communication error ({:#04x})",
            f.response_code.unwrap_or(0)
        )),
        Ok(f) => {
            let code = f.response_code.unwrap_or(0);
            if DeviceRefusal::of(command, code).is_some() {
                WriteOutcome::Refused {
                    response_code: code,
                }
            } else {
                WriteOutcome::Done {
                    response_code: code,
                }
            }
        }
    }
}

impl WriteFailure {
    /// The audit's outcome of a write that failed so.
    pub fn outcome(&self) -> WriteOutcome {
        match self {
            WriteFailure::NotPermitted(why) => WriteOutcome::NotPermitted(why.to_string()),
            WriteFailure::Refused { code, .. } => WriteOutcome::Refused {
                response_code: *code,
            },
            WriteFailure::Link(WriteError::NoReply) => WriteOutcome::NoReply,
            other => WriteOutcome::Failed(other.to_string()),
        }
    }
}

/// A change to one device.
#[derive(Debug, Clone, PartialEq)]
pub enum WriteOp {
    /// PV range values (command 35); a part not given keeps the device's value.
    Range {
        /// Upper range value (20 mA).
        upper: Option<f32>,
        /// Lower range value (4 mA).
        lower: Option<f32>,
        /// Units code of the range values.
        units: Option<u8>,
    },
    /// PV damping, seconds (command 34).
    Damping(f32),
    /// PV units code (command 44).
    PvUnits(u8),
    /// Fixed current mode, mA (command 40); 0 leaves it (the loop test's release).
    FixedCurrent(f32),
    /// Tag, 8 packed characters (command 18; descriptor and date kept).
    Tag(String),
    /// Descriptor, 16 packed characters (command 18; tag and date kept).
    Descriptor(String),
    /// Date (command 18; tag and descriptor kept).
    Date(Date),
    /// Message, 32 packed characters (command 17).
    Message(String),
    /// Long tag, 32 Latin-1 characters (command 22).
    LongTag(String),
}

impl WriteOp {
    /// The HART command that carries it.
    pub fn command(&self) -> u16 {
        match self {
            WriteOp::Range { .. } => 35,
            WriteOp::Damping(_) => 34,
            WriteOp::PvUnits(_) => 44,
            WriteOp::FixedCurrent(_) => 40,
            WriteOp::Tag(_) | WriteOp::Descriptor(_) | WriteOp::Date(_) => 18,
            WriteOp::Message(_) => 17,
            WriteOp::LongTag(_) => 22,
        }
    }

    /// In words, for the audit and messages.
    pub fn describe(&self) -> String {
        let opt = |v: Option<f32>| v.map_or("kept".to_string(), |v| v.to_string());
        match self {
            WriteOp::Range {
                upper,
                lower,
                units,
            } => format!(
                "range: upper {}, lower {}, units {}",
                opt(*upper),
                opt(*lower),
                units.map_or("kept".to_string(), unit_name)
            ),
            WriteOp::Damping(s) => format!("damping {s} s"),
            WriteOp::PvUnits(u) => format!("PV units {}", unit_name(*u)),
            WriteOp::FixedCurrent(ma) if *ma == 0.0 => "leave fixed current mode".to_string(),
            WriteOp::FixedCurrent(ma) => format!("fixed current {ma} mA"),
            WriteOp::Tag(t) => format!("tag {t:?}"),
            WriteOp::Descriptor(t) => format!("descriptor {t:?}"),
            WriteOp::Date(d) => format!("date {d}"),
            WriteOp::Message(t) => format!("message {t:?}"),
            WriteOp::LongTag(t) => format!("long tag {t:?}"),
        }
    }

    /// Checks the values before anything is sent (a tag too long, a damping that is
    /// not a number).
    pub fn validate(&self) -> Result<(), WriteFailure> {
        let finite = |v: f32, what: &str| {
            if v.is_finite() {
                Ok(())
            } else {
                Err(WriteFailure::Invalid(format!(
                    "{what} must be a finite number"
                )))
            }
        };
        let packed = |t: &str, n: usize, what: &str| {
            let ok = match n {
                8 => PackedString::<6>::new(t).is_ok(),
                16 => PackedString::<12>::new(t).is_ok(),
                _ => PackedString::<24>::new(t).is_ok(),
            };
            if ok {
                Ok(())
            } else {
                Err(WriteFailure::Invalid(format!(
                    "{what} {t:?}: at most {n} characters of packed ASCII (letters, \
                     stored upper-case, digits, space and @[\\]^_ !\"#$%&'()*+,-./:;<=>?)"
                )))
            }
        };
        match self {
            WriteOp::Range { upper, lower, .. } => {
                upper.map_or(Ok(()), |v| finite(v, "the upper range value"))?;
                lower.map_or(Ok(()), |v| finite(v, "the lower range value"))
            }
            WriteOp::Damping(s) => {
                finite(*s, "the damping")?;
                if *s < 0.0 {
                    return Err(WriteFailure::Invalid(format!(
                        "a damping of {s} s: a damping time is 0 s or more"
                    )));
                }
                Ok(())
            }
            WriteOp::FixedCurrent(ma) => {
                finite(*ma, "the loop current")?;
                if *ma != 0.0 && !(FIXED_CURRENT_MA.0..=FIXED_CURRENT_MA.1).contains(ma) {
                    return Err(WriteFailure::Invalid(format!(
                        "a loop current of {ma} mA: give 0 to leave fixed current mode, or a \
                         current from {} to {} mA",
                        FIXED_CURRENT_MA.0, FIXED_CURRENT_MA.1
                    )));
                }
                Ok(())
            }
            WriteOp::PvUnits(_) | WriteOp::Date(_) => Ok(()),
            WriteOp::Tag(t) => packed(t, 8, "tag"),
            WriteOp::Descriptor(t) => packed(t, 16, "descriptor"),
            WriteOp::Message(t) => packed(t, 32, "message"),
            WriteOp::LongTag(t) => Latin1String::<32>::new(t).map(|_| ()).map_err(|_| {
                WriteFailure::Invalid(format!(
                    "long tag {t:?}: at most 32 characters of ISO Latin-1"
                ))
            }),
        }
    }
}

/// The loop currents a loop test may fix, mA (0 leaves fixed current mode): every
/// current a 4-20 mA loop carries, its alarm levels too (NAMUR NE 43: at most 3.6 mA
/// low, at least 21 mA high), with room for devices that go further. A value outside
/// is a mistake or an attack (a DCMD of 2^64-1 read as a signed integer is -1 mA),
/// refused before anything reaches the device.
pub const FIXED_CURRENT_MA: (f32, f32) = (3.0, 24.0);

/// Who asked, in words, for a loop test's lease: `web session 3 (admin)`.
fn describe_origin(o: &WriteRecord) -> String {
    let mut s = o.front_end.to_string();
    if let Some(n) = o.session {
        s.push_str(&format!(" session {n}"));
    }
    if !o.peer.is_empty() && o.peer != "-" {
        s.push_str(&format!(" from {}", o.peer));
    }
    if let Some(i) = &o.identity {
        s.push_str(&format!(" ({i})"));
    }
    s
}

fn unit_name(u: u8) -> String {
    hart_proto::tables::unit_symbol(u).map_or(format!("code {u}"), str::to_string)
}

/// What kind of "no" a device's response code is, for the front ends to translate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceRefusal {
    /// The value is not acceptable: invalid selection, too large, too small, a units
    /// code it does not know, command 35's range limits.
    OutOfRange,
    /// Write protected, or access restricted.
    NotWritable,
    /// Busy, or a delayed response under way: try again.
    Busy,
    /// The device does not implement the command.
    NotImplemented,
    /// Anything else: the device will not do it now (in multidrop mode for a fixed
    /// current, device-specific errors).
    Failed,
}

impl DeviceRefusal {
    /// The refusal a response code to `command` means; `None` when the code is
    /// success or a warning (the write was done).
    pub fn of(command: u16, code: u8) -> Option<DeviceRefusal> {
        if response_class(code) != ResponseClass::Error {
            return None;
        }
        Some(match (command, code) {
            (_, rc::INVALID_SELECTION | rc::TOO_LARGE | rc::TOO_SMALL | rc::INVALID_UNITS_CODE)
            | (35, 9..=13) => DeviceRefusal::OutOfRange,
            (_, rc::WRITE_PROTECTED | rc::ACCESS_RESTRICTED) => DeviceRefusal::NotWritable,
            (_, rc::BUSY | rc::DR_INITIATED | rc::DR_RUNNING | rc::DR_CONFLICT) => {
                DeviceRefusal::Busy
            }
            (_, rc::NOT_IMPLEMENTED) => DeviceRefusal::NotImplemented,
            _ => DeviceRefusal::Failed,
        })
    }
}

/// Why a typed write was not done.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum WriteFailure {
    /// The gateway does not let it through (`--read-only`, `--allow-commands`):
    /// nothing was sent.
    NotPermitted(NotPermitted),
    /// The value cannot be sent (checked before anything went on the loop).
    Invalid(String),
    /// What the write needs from the device is not known yet (its range before
    /// command 15 was answered).
    NotReadYet(&'static str),
    /// The request did not reach the device, or its answer was not a reply.
    Link(WriteError),
    /// The device refused it with response code `code`.
    Refused {
        /// The command refused.
        command: u16,
        /// The response code.
        code: u8,
        /// What kind of refusal.
        refusal: DeviceRefusal,
    },
}

impl std::fmt::Display for WriteFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            WriteFailure::NotPermitted(why) => why.fmt(f),
            WriteFailure::Invalid(m) => f.write_str(m),
            WriteFailure::NotReadYet(what) => write!(
                f,
                "the device's {what} is not known yet (not polled since the start); try again in a few seconds"
            ),
            WriteFailure::Link(e) => e.fmt(f),
            WriteFailure::Refused { command, code, .. } => write!(
                f,
                "the device refused command {command}: response code {code} ({})",
                hart_proto::tables::response_code_name(*command, *code).unwrap_or("no name")
            ),
        }
    }
}

impl std::error::Error for WriteFailure {}

/// A write done: the device's reply (its response code may be a warning, e.g. 8 "set
/// to nearest possible value").
pub type Applied = WriteReply;

impl Engine {
    /// Carries out `op` on the device at image `position`, ahead of the loop's polls:
    /// asks the engine's [`WritePolicy`](hart_access::WritePolicy) (`--read-only`,
    /// `--allow-commands`), checks the values, reads what the command keeps (the
    /// range's other value, the tag's descriptor and date), records the write in the
    /// audit just before it goes on the loop, judges the reply and records what became
    /// of it (a second audit record). A refusal by the policy is audited too.
    ///
    /// `origin` says who asks: the front end, its session, peer, identity and path
    /// (`via`); the engine fills in the device, the command and the operation. A fixed
    /// current (loop test) is held with the engine's limit ([`Engine::apply_with`]
    /// for other terms).
    pub async fn apply(
        &self,
        position: usize,
        op: &WriteOp,
        origin: &WriteRecord,
    ) -> Result<Applied, WriteFailure> {
        let lease = LeaseTerms {
            by: describe_origin(origin),
            ..LeaseTerms::default()
        };
        self.apply_with(position, op, origin, lease).await
    }

    /// [`Engine::apply`] with the terms of the loop test a fixed current starts: a
    /// shorter limit, a holder whose leaving releases it ([`crate::lease`]).
    pub async fn apply_with(
        &self,
        position: usize,
        op: &WriteOp,
        origin: &WriteRecord,
        lease: LeaseTerms,
    ) -> Result<Applied, WriteFailure> {
        let command = op.command();
        let device = self.describe_device(position);
        let record = WriteRecord {
            device: device
                .clone()
                .unwrap_or_else(|| format!("unit {}", position + 1)),
            command,
            operation: Some(op.describe()),
            ..origin.clone()
        };
        if let Err(why) = self.write_policy().permits(command) {
            self.write_policy().audit.refused(&record, &why.to_string());
            return Err(WriteFailure::NotPermitted(why));
        }
        op.validate()?;
        device.ok_or(WriteFailure::Link(WriteError::UnknownDevice))?;
        let audit = &self.write_policy().audit;
        // The device's own lock: a read-modify-write (command 13 then 18) is never
        // interleaved with another write to the same device.
        let _turn = self.device_lock(position).lock_owned().await;
        let request = match self.request(position, op).await {
            Ok(r) => r,
            Err(e) => {
                let n = audit.record(&record);
                audit.outcome(n, &record, &e.outcome());
                return Err(e);
            }
        };
        let n = audit.record(&record);
        let result = match self.write(position, &request, lease).await {
            Err(e) => Err(e),
            Ok(reply) => match DeviceRefusal::of(command, reply.response_code) {
                None => Ok(reply),
                Some(refusal) => Err(WriteFailure::Refused {
                    command,
                    code: reply.response_code,
                    refusal,
                }),
            },
        };
        let outcome = match &result {
            Ok(r) => WriteOutcome::Done {
                response_code: r.response_code,
            },
            Err(e) => e.outcome(),
        };
        audit.outcome(n, &record, &outcome);
        result
    }

    /// The device at `position` as the audit names it, when it is identified.
    fn describe_device(&self, position: usize) -> Option<String> {
        self.image().with(position, |d| {
            format!(
                "{} ({}, unit {})",
                d.display_name(),
                d.unique_id()
                    .map_or("unique ID not known".to_string(), |u| format!(
                        "unique ID {u}"
                    )),
                d.position + 1
            )
        })
    }

    /// The request that carries `op` to the device at `position`: a part of the
    /// range not given is the device's own (from the image), and the tag,
    /// descriptor and date not written are read first (command 13), since command 18
    /// writes the three together.
    async fn request(&self, position: usize, op: &WriteOp) -> Result<Request, WriteFailure> {
        Ok(match op {
            WriteOp::Range {
                upper,
                lower,
                units,
            } => {
                let known = self
                    .image()
                    .with(position, |d| d.range)
                    .ok_or(WriteFailure::Link(WriteError::UnknownDevice))?;
                let (u, up, lo) = match (units, upper, lower, known) {
                    (Some(u), Some(up), Some(lo), _) => (*u, *up, *lo),
                    (_, _, _, Some(r)) => (
                        units.unwrap_or(r.units),
                        upper.unwrap_or(r.upper),
                        lower.unwrap_or(r.lower),
                    ),
                    (_, _, _, None) => return Err(WriteFailure::NotReadYet("range")),
                };
                Request::WritePvRange(RangeValues {
                    range_units: UnitCode(u),
                    upper_range_value: up,
                    lower_range_value: lo,
                })
            }
            WriteOp::Tag(_) | WriteOp::Descriptor(_) | WriteOp::Date(_) => {
                let read = Request::ReadTagDescriptorDate(Empty {});
                let current = self.write(position, &read, LeaseTerms::default()).await?;
                if let Some(refusal) = DeviceRefusal::of(13, current.response_code) {
                    return Err(WriteFailure::Refused {
                        command: 13,
                        code: current.response_code,
                        refusal,
                    });
                }
                let mut t =
                    TagDescriptorDate::decode(&mut Reader::new(&current.data)).map_err(|e| {
                        WriteFailure::Link(WriteError::BadReply(format!(
                            "command 13's reply does not hold the tag, descriptor and date: {e}"
                        )))
                    })?;
                match op {
                    WriteOp::Tag(v) => t.tag = packed(v, "tag")?,
                    WriteOp::Descriptor(v) => t.descriptor = packed(v, "descriptor")?,
                    WriteOp::Date(d) => t.date = *d,
                    _ => {}
                }
                Request::WriteTagDescriptorDate(t)
            }
            other => match other.request() {
                Some(r) => r?,
                None => return Err(WriteFailure::NotReadYet("the device's configuration")),
            },
        })
    }
}

/// `text` as a packed string of `N` bytes, or why not.
fn packed<const N: usize>(text: &str, what: &str) -> Result<PackedString<N>, WriteFailure> {
    PackedString::<N>::new(text).map_err(|_| WriteFailure::Invalid(format!("{what} {text:?}")))
}

impl WriteOp {
    /// The request of an operation that needs nothing from the device; `None` for the
    /// range given in part and the tag, descriptor and date, which [`Engine::apply`]
    /// completes from the device first.
    pub fn request(&self) -> Option<Result<Request, WriteFailure>> {
        let packed_or = |t: &str, what| packed::<24>(t, what);
        Some(Ok(match self {
            WriteOp::Range {
                upper: Some(up),
                lower: Some(lo),
                units: Some(u),
            } => Request::WritePvRange(RangeValues {
                range_units: UnitCode(*u),
                upper_range_value: *up,
                lower_range_value: *lo,
            }),
            WriteOp::Damping(s) => Request::WritePvDamping(Damping {
                damping: Seconds(*s),
            }),
            // -0.0 leaves fixed current mode as 0.0 does: sent as 0.0.
            WriteOp::FixedCurrent(ma) => Request::EnterExitFixedCurrent(FixedCurrent {
                loop_current: MilliAmps(if *ma == 0.0 { 0.0 } else { *ma }),
            }),
            WriteOp::PvUnits(u) => Request::WritePvUnits(PvUnits {
                pv_units: UnitCode(*u),
            }),
            WriteOp::Message(t) => match packed_or(t, "message") {
                Ok(message) => Request::WriteMessage(Message { message }),
                Err(e) => return Some(Err(e)),
            },
            WriteOp::LongTag(t) => match Latin1String::<32>::new(t) {
                Ok(long_tag) => Request::WriteLongTag(LongTag { long_tag }),
                Err(_) => return Some(Err(WriteFailure::Invalid(format!("long tag {t:?}")))),
            },
            WriteOp::Range { .. } | WriteOp::Tag(_) | WriteOp::Descriptor(_) | WriteOp::Date(_) => {
                return None
            }
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn response_codes_become_refusals() {
        assert_eq!(DeviceRefusal::of(34, 0), None);
        // Warning "set to nearest possible value": done.
        assert_eq!(DeviceRefusal::of(34, 8), None);
        assert_eq!(DeviceRefusal::of(34, 3), Some(DeviceRefusal::OutOfRange));
        assert_eq!(DeviceRefusal::of(35, 11), Some(DeviceRefusal::OutOfRange));
        // 11 for command 40 is "in multidrop mode": not the value's fault.
        assert_eq!(DeviceRefusal::of(40, 11), Some(DeviceRefusal::Failed));
        assert_eq!(DeviceRefusal::of(34, 7), Some(DeviceRefusal::NotWritable));
        assert_eq!(DeviceRefusal::of(34, 16), Some(DeviceRefusal::NotWritable));
        assert_eq!(DeviceRefusal::of(34, 32), Some(DeviceRefusal::Busy));
        assert_eq!(
            DeviceRefusal::of(40, 64),
            Some(DeviceRefusal::NotImplemented)
        );
    }

    #[test]
    fn each_operation_is_carried_by_its_own_command() {
        let ops = [
            WriteOp::Range {
                upper: Some(300.0),
                lower: Some(0.0),
                units: Some(12),
            },
            WriteOp::Damping(2.5),
            WriteOp::PvUnits(7),
            WriteOp::FixedCurrent(12.0),
            WriteOp::FixedCurrent(-0.0),
            WriteOp::Message("LOOP TEST".into()),
            WriteOp::LongTag("Reactor feed pressure".into()),
        ];
        for op in ops {
            let request = op.request().expect("complete").expect("valid");
            assert_eq!(op.command(), request.command(), "{op:?}");
        }
        assert_eq!(
            WriteOp::FixedCurrent(-0.0)
                .request()
                .unwrap()
                .unwrap()
                .to_vec(),
            Ok(vec![0, 0, 0, 0]),
            "-0.0 leaves fixed current mode as 0.0"
        );
        for partial in [
            WriteOp::Range {
                upper: Some(1.0),
                lower: None,
                units: None,
            },
            WriteOp::Tag("PT-101".into()),
            WriteOp::Descriptor("FEED".into()),
            WriteOp::Date(Date::new(2026, 1, 1).unwrap()),
        ] {
            assert!(
                partial.request().is_none(),
                "{partial:?} needs the device's values"
            );
        }
        assert!(matches!(
            WriteOp::Message("{}".into()).request(),
            Some(Err(WriteFailure::Invalid(_)))
        ));
    }

    #[test]
    fn values_are_checked_before_sending() {
        assert!(WriteOp::Tag("PT-101".into()).validate().is_ok());
        assert!(WriteOp::Tag("far-too-long".into()).validate().is_err());
        assert!(WriteOp::Tag("PT~101".into()).validate().is_err());
        assert!(WriteOp::Damping(f32::NAN).validate().is_err());
        assert!(WriteOp::Damping(-0.5).validate().is_err());
        assert!(WriteOp::Damping(0.0).validate().is_ok());
        assert!(WriteOp::FixedCurrent(-1.0).validate().is_err());
        assert!(WriteOp::FixedCurrent(1.8e19).validate().is_err());
        assert!(WriteOp::FixedCurrent(0.0).validate().is_ok());
        assert!(WriteOp::FixedCurrent(3.6).validate().is_ok());
        assert!(WriteOp::FixedCurrent(22.0).validate().is_ok());
        assert!(WriteOp::Range {
            upper: Some(f32::INFINITY),
            lower: None,
            units: None
        }
        .validate()
        .is_err());
        assert!(WriteOp::LongTag("Reactor feed pressure".into())
            .validate()
            .is_ok());
        assert_eq!(
            WriteOp::FixedCurrent(0.0).describe(),
            "leave fixed current mode"
        );
        assert_eq!(WriteOp::Damping(2.5).describe(), "damping 2.5 s");
    }
}
