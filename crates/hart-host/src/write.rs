//! The writes a host makes by name (`hartkit write WHAT VALUES`, the Python package's
//! `Device.write`): the command, its data built from the values given, and the command
//! that reads the value back.

use hart_proto::command as cmd;
use hart_proto::types::{Date, Latin1String, PackedString};
use hart_proto::wire::{EncodeError, Reader, Wire, Writer};

use crate::error::HostError;
use crate::transport::Transport;
use crate::{Client, DeviceInfo, Reply};

fn decode<T: Wire>(r: &Reply, what: &str) -> Result<T, HostError> {
    T::decode(&mut Reader::new(&r.data)).map_err(|e| HostError::Usage(format!("{what}: {e}")))
}

impl<T: Transport> Client<T> {
    /// What `hartkit write WHAT VALUES...` sends to device `d`: the command, its data,
    /// and the command that reads the value back. Reads what it needs first (command
    /// 13 for a tag alone, 15 for the range units). `what` is one of tag, long-tag,
    /// descriptor, message, date, range, units, damping, polling-address,
    /// fixed-current, preambles; a value that does not fit is a
    /// [`HostError::Usage`] naming it.
    pub async fn write_request(
        &mut self,
        d: &DeviceInfo,
        what: &str,
        args: &[String],
    ) -> Result<(u16, Vec<u8>, u16), HostError> {
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
        let enc =
            |v: &dyn Fn(&mut Writer<'_>) -> Result<(), EncodeError>| -> Result<Vec<u8>, HostError> {
                let mut buf = [0u8; 64];
                let mut w = Writer::new(&mut buf);
                v(&mut w).map_err(|e| HostError::Usage(format!("write {what}: {e}")))?;
                Ok(w.written().to_vec())
            };
        let (command, data, confirm): (u16, Vec<u8>, u16) = match what {
            "tag" | "descriptor" | "date" => {
                need(1)?;
                // Read the current tag/descriptor/date so one of them can change alone.
                let mut t: cmd::TagDescriptorDate = decode(&c.command(d, 13, &[]).await?, "command 13")?;
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
                (18, enc(&|w| t.encode(w))?, 13)
            }
            "message" => {
                need(1)?;
                let m = cmd::Message { message: PackedString::new(&args.join(" ")).map_err(|e| HostError::Usage(format!("message: {e}")))? };
                (17, enc(&|w| m.encode(w))?, 12)
            }
            "long-tag" => {
                need(1)?;
                if d.revision() < 6 {
                    return Err(HostError::Usage(format!("write long-tag: the device is HART {}; long tags need HART 6 or later", d.revision())));
                }
                let t = cmd::LongTag { long_tag: Latin1String::new(&args.join(" ")).map_err(|e| HostError::Usage(format!("long tag: {e}")))? };
                (22, enc(&|w| t.encode(w))?, 20)
            }
            "range" => {
                need(2)?;
                let (urv, lrv) = (num(&args[0])?, num(&args[1])?);
                let units_code = match args.get(2) {
                    Some(u) => int(u)?,
                    None => decode::<cmd::DeviceInformation>(&c.command(d, 15, &[]).await?, "command 15")?.range_units.0,
                };
                let r = cmd::RangeValues { range_units: hart_proto::types::UnitCode(units_code), upper_range_value: urv, lower_range_value: lrv };
                (35, enc(&|w| r.encode(w))?, 15)
            }
            "units" => {
                need(1)?;
                (44, vec![int(&args[0])?], 1)
            }
            "damping" => {
                need(1)?;
                (34, num(&args[0])?.to_be_bytes().to_vec(), 15)
            }
            "polling-address" => {
                need(1)?;
                let p = int(&args[0])?;
                let mode = match args.get(1) {
                    Some(m) => int(m)?,
                    None => u8::from(p == 0),
                };
                let data = if d.revision() >= 6 { vec![p, mode] } else { vec![p] };
                (6, data, 7)
            }
            "fixed-current" => {
                need(1)?;
                (40, num(&args[0])?.to_be_bytes().to_vec(), 2)
            }
            "preambles" => {
                need(1)?;
                (59, vec![int(&args[0])?], 0)
            }
            other => return Err(HostError::Usage(format!("write {other}: expected tag, long-tag, descriptor, message, date, range, units, damping, polling-address, fixed-current or preambles"))),
        };
        Ok((command, data, confirm))
    }
}
