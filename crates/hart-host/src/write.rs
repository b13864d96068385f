//! The writes a host makes by name (`hartkit write WHAT VALUES`, the Python package's
//! `Device.write`): the command, its data built from the values given, and the command
//! that reads the value back.

use hart_proto::command::{self as cmd, Empty};
use hart_proto::types::{
    Date, Latin1String, LoopCurrentMode, MilliAmps, PackedString, Seconds, UnitCode,
};
use hart_proto::wire::{Reader, Wire};
use hart_proto::Request;

use crate::error::HostError;
use crate::transport::Transport;
use crate::{Client, DeviceInfo, Reply};

/// A write a host makes by name ([`Client::write_request`]): the request, and the read
/// that shows the value afterwards.
#[derive(Debug, Clone, PartialEq)]
pub struct HostWrite {
    /// The write.
    pub request: Request,
    /// The read of the value written.
    pub read_back: Request,
}

fn decode<T: Wire>(r: &Reply, what: &str) -> Result<T, HostError> {
    T::decode(&mut Reader::new(&r.data)).map_err(|e| HostError::Usage(format!("{what}: {e}")))
}

impl<T: Transport> Client<T> {
    /// What `hartkit write WHAT VALUES...` sends to device `d`: the request, and the
    /// one that reads the value back. Reads what it needs first (command
    /// 13 for a tag alone, 15 for the range units). `what` is one of tag, long-tag,
    /// descriptor, message, date, range, units, damping, polling-address,
    /// fixed-current, preambles; a value that does not fit is a
    /// [`HostError::Usage`] naming it.
    pub async fn write_request(
        &mut self,
        d: &DeviceInfo,
        what: &str,
        args: &[String],
    ) -> Result<HostWrite, HostError> {
        let c = self;
        let need = |n: usize| -> Result<(), HostError> {
            if args.len() < n {
                Err(HostError::Usage(format!(
                    "write {what}: needs {n} value(s)"
                )))
            } else {
                Ok(())
            }
        };
        let num = |s: &str| -> Result<f32, HostError> {
            s.parse::<f32>()
                .map_err(|_| HostError::Usage(format!("write {what}: {s:?} is not a number")))
        };
        let int = |s: &str| -> Result<u8, HostError> {
            s.parse::<u8>()
                .map_err(|_| HostError::Usage(format!("write {what}: {s:?} is not a number 0-255")))
        };
        let read = Request::ReadTagDescriptorDate(Empty {});
        let (request, read_back) = match what {
            "tag" | "descriptor" | "date" => {
                need(1)?;
                // Read the current tag/descriptor/date so one of them can change alone.
                let mut t: cmd::TagDescriptorDate = decode(&c.request(d, &read).await?, "command 13")?;
                match what {
                    "tag" => t.tag = PackedString::new(&args[0]).map_err(|e| HostError::Usage(format!("tag: {e}")))?,
                    "descriptor" => t.descriptor = PackedString::new(&args[0]).map_err(|e| HostError::Usage(format!("descriptor: {e}")))?,
                    _ => {
                        let p: Vec<&str> = args[0].split('-').collect();
                        let bad = || HostError::Usage(format!("date {:?}: expected YYYY-MM-DD", args[0]));
                        if p.len() != 3 {
                            return Err(bad());
                        }
                        t.date = Date::new(p[0].parse().map_err(|_| bad())?, p[1].parse().map_err(|_| bad())?, p[2].parse().map_err(|_| bad())?).map_err(|e| HostError::Usage(format!("date: {e}")))?;
                    }
                }
                (Request::WriteTagDescriptorDate(t), read)
            }
            "message" => {
                need(1)?;
                let m = cmd::Message { message: PackedString::new(&args.join(" ")).map_err(|e| HostError::Usage(format!("message: {e}")))? };
                (Request::WriteMessage(m), Request::ReadMessage(Empty {}))
            }
            "long-tag" => {
                need(1)?;
                if d.revision() < 6 {
                    return Err(HostError::Usage(format!("write long-tag: the device is HART {}; long tags need HART 6 or later", d.revision())));
                }
                let t = cmd::LongTag { long_tag: Latin1String::new(&args.join(" ")).map_err(|e| HostError::Usage(format!("long tag: {e}")))? };
                (Request::WriteLongTag(t), Request::ReadLongTag(Empty {}))
            }
            "range" => {
                need(2)?;
                let (urv, lrv) = (num(&args[0])?, num(&args[1])?);
                let units_code = match args.get(2) {
                    Some(u) => int(u)?,
                    None => decode::<cmd::DeviceInformation>(&c.request(d, &Request::ReadDeviceInformation(Empty {})).await?, "command 15")?.range_units.0,
                };
                let r = cmd::RangeValues { range_units: UnitCode(units_code), upper_range_value: urv, lower_range_value: lrv };
                (Request::WritePvRange(r), Request::ReadDeviceInformation(Empty {}))
            }
            "units" => {
                need(1)?;
                let units = cmd::PvUnits { pv_units: UnitCode(int(&args[0])?) };
                (Request::WritePvUnits(units), Request::ReadPrimaryVariable(Empty {}))
            }
            "damping" => {
                need(1)?;
                let damping = cmd::Damping { damping: Seconds(num(&args[0])?) };
                (Request::WritePvDamping(damping), Request::ReadDeviceInformation(Empty {}))
            }
            "polling-address" => {
                need(1)?;
                let p = int(&args[0])?;
                let mode = match args.get(1) {
                    Some(m) => int(m)?,
                    None => u8::from(p == 0),
                };
                let address = cmd::PollingAddress { polling_address: p, loop_current_mode: (d.revision() >= 6).then_some(LoopCurrentMode(mode)) };
                (Request::WritePollingAddress(address), Request::ReadLoopConfiguration(Empty {}))
            }
            "fixed-current" => {
                need(1)?;
                let fixed = cmd::FixedCurrent { loop_current: MilliAmps(num(&args[0])?) };
                (Request::EnterExitFixedCurrent(fixed), Request::ReadLoopCurrent(Empty {}))
            }
            "preambles" => {
                need(1)?;
                let preambles = cmd::ResponsePreambles { response_preambles: int(&args[0])? };
                (Request::WriteResponsePreambles(preambles), Request::ReadUniqueIdentifier(Empty {}))
            }
            other => return Err(HostError::Usage(format!("write {other}: expected tag, long-tag, descriptor, message, date, range, units, damping, polling-address, fixed-current or preambles"))),
        };
        Ok(HostWrite { request, read_back })
    }
}
