//! The gateway's PROFIBUS map, as data: which bytes of a device's input module hold
//! which value of the polling engine's image, and what its output module writes. The
//! printed map (`hartkit serve --print-map --profibus`), the GSD file
//! (`hartkit serve --print-gsd`), the configuration identifiers the slave checks and
//! the bytes it sends all come from [`INPUTS`] and [`OUTPUTS`].
//!
//! Each HART device is one module of the station: [`INPUT_LEN`] input bytes and
//! [`OUTPUT_LEN`] output bytes, big-endian (IEEE-754 floats as PROFIBUS sends them).
//! A station holds at most [`DEVICES_PER_STATION`] devices (≤ 244 input bytes); the
//! gateway serves further devices at the next station addresses.

use std::fmt::Write as _;
use std::time::Instant;

use hart_poller::DeviceImage;
use hart_values::{number, Value};

use crate::cfg;

/// How a field is encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// IEEE-754 single precision, big-endian (NaN: no value).
    F32,
    /// Unsigned byte (255: none, for codes).
    U8,
    /// Unsigned 16-bit, big-endian (65535: none).
    U16,
}

impl Kind {
    /// Bytes it takes.
    pub const fn size(self) -> usize {
        match self {
            Kind::F32 => 4,
            Kind::U8 => 1,
            Kind::U16 => 2,
        }
    }

    /// Its name in the printed map.
    pub fn name(self) -> &'static str {
        match self {
            Kind::F32 => "float32",
            Kind::U8 => "uint8",
            Kind::U16 => "uint16",
        }
    }
}

/// Where an input field's value comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Source {
    /// A value of the device's image, with the codes every front end gives it.
    Value(Value),
    /// The write counter of the output write last taken.
    WriteCounter,
    /// The result of that write ([`WriteResult`]).
    WriteResult,
}

/// One field of a module.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Field {
    /// Byte offset in the module.
    pub offset: usize,
    /// Encoding.
    pub kind: Kind,
    /// Name in the printed map.
    pub name: &'static str,
    /// What it holds (input fields).
    pub source: Option<Source>,
    /// What it means.
    pub description: &'static str,
}

const fn input(offset: usize, kind: Kind, name: &'static str, source: Source) -> Field {
    Field {
        offset,
        kind,
        name,
        source: Some(source),
        description: "",
    }
}

/// The input module of a device (device to master).
pub const INPUTS: [Field; 12] = [
    input(0, Kind::F32, "pv", Source::Value(Value::Pv)),
    input(4, Kind::F32, "sv", Source::Value(Value::Sv)),
    input(8, Kind::F32, "tv", Source::Value(Value::Tv)),
    input(12, Kind::F32, "qv", Source::Value(Value::Qv)),
    input(
        16,
        Kind::F32,
        "loop_current",
        Source::Value(Value::LoopCurrent),
    ),
    input(20, Kind::U8, "pv_units", Source::Value(Value::PvUnits)),
    input(
        21,
        Kind::U8,
        "device_status",
        Source::Value(Value::DeviceStatus),
    ),
    input(
        22,
        Kind::U8,
        "extended_status",
        Source::Value(Value::ExtendedStatus),
    ),
    input(23, Kind::U8, "quality", Source::Value(Value::Quality)),
    input(24, Kind::U16, "age", Source::Value(Value::Age)),
    input(26, Kind::U8, "write_counter", Source::WriteCounter),
    input(27, Kind::U8, "write_result", Source::WriteResult),
];

/// The output module of a device (master to device).
pub const OUTPUTS: [Field; 3] = [
    Field {
        offset: 0,
        kind: Kind::U8,
        name: "write_counter",
        source: None,
        description: "a change to a value other than 0 carries out this module's write once",
    },
    Field {
        offset: 1,
        kind: Kind::U8,
        name: "reserved",
        source: None,
        description: "0",
    },
    Field {
        offset: 2,
        kind: Kind::F32,
        name: "fixed_current",
        source: None,
        description: "loop test: fixed loop current, mA (command 40); 0 leaves fixed current mode",
    },
];

const fn module_len(fields: &[Field]) -> usize {
    let last = fields[fields.len() - 1];
    last.offset + last.kind.size()
}

/// Input bytes per device.
pub const INPUT_LEN: usize = module_len(&INPUTS);
/// Output bytes per device.
pub const OUTPUT_LEN: usize = module_len(&OUTPUTS);
/// Devices per station: as many input modules as fit 244 bytes.
pub const DEVICES_PER_STATION: usize = 244 / INPUT_LEN;

/// The configuration identifiers of one device's module: its inputs and its outputs,
/// each consistent as a whole.
pub fn module_cfg() -> [u8; 2] {
    [
        cfg::compact(INPUT_LEN, false).unwrap_or(0),
        cfg::compact(OUTPUT_LEN, true).unwrap_or(0),
    ]
}

/// The configuration identifiers of a station with `devices` modules.
pub fn station_cfg(devices: usize) -> Vec<u8> {
    std::iter::repeat_n(module_cfg(), devices)
        .flatten()
        .collect()
}

/// The description of an input field.
pub fn description(f: &Field) -> String {
    match f.source {
        Some(Source::Value(Value::Age)) => {
            "seconds since the last good reply (65535: none yet, or more)".into()
        }
        Some(Source::Value(Value::PvUnits)) => {
            "PV units code (HART Common Table 2; 250: not known)".into()
        }
        Some(Source::Value(v)) => v.description().into(),
        Some(Source::WriteCounter) => {
            "the output module's write counter last taken (its write's result follows)".into()
        }
        Some(Source::WriteResult) => WriteResult::ALL
            .iter()
            .map(|r| format!("{} {}", *r as u8, r.name()))
            .collect::<Vec<_>>()
            .join(", "),
        None => f.description.into(),
    }
}

/// The result of a write from an output module.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum WriteResult {
    /// No write since the gateway started.
    None = 0,
    /// Being carried out.
    Busy = 1,
    /// Done: the device accepted it.
    Done = 2,
    /// Refused by the gateway (read only, or the command is not allowed).
    Refused = 3,
    /// The value cannot be sent (not a number, out of range).
    Invalid = 4,
    /// The device refused it.
    DeviceRefused = 5,
    /// The device did not answer, or is not known.
    NoReply = 6,
}

impl WriteResult {
    /// Every result, in code order.
    pub const ALL: [WriteResult; 7] = [
        WriteResult::None,
        WriteResult::Busy,
        WriteResult::Done,
        WriteResult::Refused,
        WriteResult::Invalid,
        WriteResult::DeviceRefused,
        WriteResult::NoReply,
    ];

    /// In words.
    pub fn name(self) -> &'static str {
        match self {
            WriteResult::None => "no write yet",
            WriteResult::Busy => "busy",
            WriteResult::Done => "done",
            WriteResult::Refused => "refused by the gateway",
            WriteResult::Invalid => "invalid value",
            WriteResult::DeviceRefused => "refused by the device",
            WriteResult::NoReply => "no reply",
        }
    }
}

/// The state of a device's output writes, shown in its input module.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WriteState {
    /// The write counter last taken.
    pub counter: u8,
    /// Its result.
    pub result: WriteResult,
}

impl Default for WriteState {
    fn default() -> Self {
        WriteState {
            counter: 0,
            result: WriteResult::None,
        }
    }
}

/// The input module of device `d` at `now`.
pub fn encode_inputs(d: &DeviceImage, now: Instant, write: WriteState) -> [u8; INPUT_LEN] {
    let mut out = [0u8; INPUT_LEN];
    for f in &INPUTS {
        let n = match f.source {
            Some(Source::Value(v)) => number(v, d, now),
            Some(Source::WriteCounter) => Some(f64::from(write.counter)),
            Some(Source::WriteResult) => Some(f64::from(write.result as u8)),
            None => None,
        };
        put(&mut out[f.offset..f.offset + f.kind.size()], f.kind, n);
    }
    out
}

/// The input module of a slot with no device (a configured device not found): NaN
/// values, units 250, quality "no reply".
pub fn absent_inputs() -> [u8; INPUT_LEN] {
    let mut out = [0u8; INPUT_LEN];
    for f in &INPUTS {
        let n = match f.source {
            Some(Source::Value(Value::Quality)) => {
                Some(f64::from(hart_poller::Quality::NoReply.code()))
            }
            Some(Source::Value(Value::PvUnits)) => Some(250.0),
            Some(Source::Value(Value::DeviceStatus | Value::ExtendedStatus))
            | Some(Source::WriteCounter | Source::WriteResult) => Some(0.0),
            _ => None,
        };
        put(&mut out[f.offset..f.offset + f.kind.size()], f.kind, n);
    }
    out
}

fn put(out: &mut [u8], kind: Kind, n: Option<f64>) {
    let n = n.filter(|x| !x.is_nan() || kind == Kind::F32);
    match kind {
        Kind::F32 => out.copy_from_slice(&(n.unwrap_or(f64::NAN) as f32).to_be_bytes()),
        Kind::U8 => out[0] = n.map_or(255, |x| x.clamp(0.0, 255.0) as u8),
        Kind::U16 => out.copy_from_slice(
            &n.map_or(65_535, |x| x.clamp(0.0, 65_535.0) as u16)
                .to_be_bytes(),
        ),
    }
}

/// A device's output module, decoded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outputs {
    /// The write counter.
    pub counter: u8,
    /// Fixed loop current, mA (0: leave fixed current mode).
    pub fixed_current: f32,
}

/// Decodes one output module (`OUTPUT_LEN` bytes; fewer read as zeros).
pub fn decode_outputs(bytes: &[u8]) -> Outputs {
    let mut b = [0u8; OUTPUT_LEN];
    let n = bytes.len().min(OUTPUT_LEN);
    b[..n].copy_from_slice(&bytes[..n]);
    Outputs {
        counter: b[OUTPUTS[0].offset],
        fixed_current: f32::from_be_bytes([b[2], b[3], b[4], b[5]]),
    }
}

/// Where device `position` is served: station address `first + position / 8`,
/// module (slot) `position % 8`.
pub fn station_of(first: u8, position: usize) -> (u8, usize) {
    (
        first.saturating_add((position / DEVICES_PER_STATION) as u8),
        position % DEVICES_PER_STATION,
    )
}

/// The map as text for `devices` (their names, in position order) served from
/// station `first`.
pub fn map_text(first: u8, devices: &[String]) -> String {
    let mut out = String::new();
    let stations = devices.len().div_ceil(DEVICES_PER_STATION).max(1);
    let _ = writeln!(
        out,
        "PROFIBUS DP: one module per HART device, {INPUT_LEN} input bytes and {OUTPUT_LEN} output bytes each \
         (configuration identifiers {}), at most {DEVICES_PER_STATION} devices per station",
        hex(&module_cfg())
    );
    for s in 0..stations {
        let in_station: Vec<_> = devices
            .iter()
            .enumerate()
            .skip(s * DEVICES_PER_STATION)
            .take(DEVICES_PER_STATION)
            .collect();
        let address = first.saturating_add(s as u8);
        let _ = writeln!(
            out,
            "station {address}: {} modules, {} input bytes, {} output bytes, Chk_Cfg {}",
            in_station.len(),
            in_station.len() * INPUT_LEN,
            in_station.len() * OUTPUT_LEN,
            hex(&station_cfg(in_station.len()))
        );
        for (slot, (position, name)) in in_station.iter().enumerate() {
            let _ = writeln!(
                out,
                "  module {} (slot {slot}): device {position} {name}: inputs {}..{}, outputs {}..{}",
                slot + 1,
                slot * INPUT_LEN,
                (slot + 1) * INPUT_LEN - 1,
                slot * OUTPUT_LEN,
                (slot + 1) * OUTPUT_LEN - 1
            );
        }
    }
    let _ = writeln!(out, "input module (byte offset in the module, big-endian):");
    for f in &INPUTS {
        let _ = writeln!(
            out,
            "  {:>2} {:<7} {:<16} {}",
            f.offset,
            f.kind.name(),
            f.name,
            description(f)
        );
    }
    let _ = writeln!(out, "output module:");
    for f in &OUTPUTS {
        let _ = writeln!(
            out,
            "  {:>2} {:<7} {:<16} {}",
            f.offset,
            f.kind.name(),
            f.name,
            f.description
        );
    }
    out
}

fn hex(b: &[u8]) -> String {
    b.iter()
        .map(|x| format!("0x{x:02X}"))
        .collect::<Vec<_>>()
        .join(",")
}

/// What the GSD file says of the station besides the map.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct GsdInfo {
    /// `Ident_Number`.
    pub ident_number: u16,
    /// `Revision`, `Software_Release`: the gateway's version.
    pub version: String,
}

/// The GSD file (GSD revision 3, DP-V0, modular station) of the gateway's station.
pub fn gsd(info: &GsdInfo) -> String {
    let mut g = String::new();
    let version = &info.version;
    let _ = writeln!(
        g,
        ";==============================================================\n\
         ; GSD file of hartkit's HART gateway as a PROFIBUS DP-V0 slave.\n\
         ; Written by `hartkit serve --print-gsd` from the same table as\n\
         ; `hartkit serve --print-map --profibus`; see docs/profibus.md.\n\
         ; Ident number 0x{:04X} is not assigned by PROFIBUS International:\n\
         ; give your own with [profibus] ident_number if you have one.\n\
         ;==============================================================\n\
         #Profibus_DP\n\
         GSD_Revision=3\n\
         Vendor_Name=\"hartkit\"\n\
         Model_Name=\"hartkit HART gateway\"\n\
         Revision=\"{version}\"\n\
         Ident_Number=0x{:04X}\n\
         Protocol_Ident=0\n\
         Station_Type=0\n\
         FMS_supp=0\n\
         Hardware_Release=\"none\"\n\
         Software_Release=\"{version}\"\n\
         Info_Text=\"HART devices' PV, SV, TV, QV, loop current, status and quality; loop test writes\"",
        info.ident_number, info.ident_number
    );
    for (baud, _) in crate::BAUD_RATES {
        let _ = writeln!(g, "{}_supp=1", gsd_rate(baud));
    }
    for (baud, tsdr) in crate::BAUD_RATES {
        let _ = writeln!(g, "MaxTsdr_{}={tsdr}", gsd_rate(baud));
    }
    let diag_bytes = DEVICES_PER_STATION.div_ceil(8);
    let _ = writeln!(
        g,
        "Redundancy=0\n\
         Repeater_Ctrl_Sig=0\n\
         24V_Pins=0\n\
         Implementation_Type=\"software (hartkit)\"\n\
         Freeze_Mode_supp=1\n\
         Sync_Mode_supp=1\n\
         Auto_Baud_supp=0\n\
         Set_Slave_Add_supp=0\n\
         Fail_Safe=0\n\
         Min_Slave_Intervall=1\n\
         Modular_Station=1\n\
         Max_Module={DEVICES_PER_STATION}\n\
         Max_Input_Len={}\n\
         Max_Output_Len={}\n\
         Max_Data_Len={}\n\
         Modul_Offset=0\n\
         Slave_Family=9@HART\n\
         User_Prm_Data_Len=0\n\
         Max_Diag_Data_Len={}",
        DEVICES_PER_STATION * INPUT_LEN,
        DEVICES_PER_STATION * OUTPUT_LEN,
        DEVICES_PER_STATION * (INPUT_LEN + OUTPUT_LEN),
        6 + 1 + diag_bytes
    );
    for i in 0..DEVICES_PER_STATION {
        let _ = writeln!(
            g,
            "Unit_Diag_Bit({i})=\"module {}: HART device no reply\"",
            i + 1
        );
    }
    let [i, o] = module_cfg();
    let _ = writeln!(
        g,
        "Module=\"HART device {INPUT_LEN} in/{OUTPUT_LEN} out\" 0x{i:02X},0x{o:02X}\n\
         1\n\
         Info_Text=\"PV SV TV QV loop current (float32), PV units, status, extended status, quality, age, write result; out: write counter, fixed current\"\n\
         EndModule"
    );
    g
}

fn gsd_rate(baud: u32) -> &'static str {
    match baud {
        9_600 => "9.6",
        19_200 => "19.2",
        45_450 => "45.45",
        _ => "93.75",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_is_contiguous_and_fits() {
        let mut end = 0;
        for f in &INPUTS {
            assert_eq!(f.offset, end, "{}", f.name);
            end += f.kind.size();
        }
        assert_eq!(INPUT_LEN, 28);
        assert_eq!(OUTPUT_LEN, 6);
        assert_eq!(DEVICES_PER_STATION, 8);
        assert_eq!(module_cfg(), [0xDD, 0xA5]);
        const { assert!(DEVICES_PER_STATION * INPUT_LEN <= 244) };
        assert_eq!(
            cfg::io_lengths(&station_cfg(3)).unwrap(),
            cfg::IoLengths {
                inputs: 84,
                outputs: 18
            }
        );
        assert_eq!(station_of(5, 0), (5, 0));
        assert_eq!(station_of(5, 9), (6, 1));
    }

    #[test]
    fn a_device_s_module() {
        let mut d = DeviceImage::new(0, 0, "loop1", std::time::Duration::from_secs(10));
        // Command 3: current 12 mA, PV 50.0 kPa (12).
        let data = [0x41, 0x40, 0, 0, 12, 0x42, 0x48, 0, 0];
        let now = Instant::now();
        d.apply_reply(3, 0, 0, &data, now, std::time::SystemTime::now());
        let m = encode_inputs(
            &d,
            now,
            WriteState {
                counter: 7,
                result: WriteResult::Done,
            },
        );
        assert_eq!(&m[0..4], &[0x42, 0x48, 0, 0]);
        assert!(f32::from_be_bytes([m[4], m[5], m[6], m[7]]).is_nan());
        assert_eq!(&m[16..20], &[0x41, 0x40, 0, 0]);
        assert_eq!(m[20], 12);
        assert_eq!(m[23], 0, "good");
        assert_eq!(&m[24..26], &[0, 0]);
        assert_eq!(&m[26..28], &[7, 2]);
        let waiting = encode_inputs(
            &DeviceImage::new(1, 0, "loop1", std::time::Duration::from_secs(10)),
            now,
            WriteState::default(),
        );
        assert_eq!(waiting[23], 5, "waiting for data");
        assert_eq!(&waiting[24..26], &[0xFF, 0xFF], "no age yet");
        assert_eq!(absent_inputs()[23], 2);
        let o = decode_outputs(&[3, 0, 0x40, 0x80, 0, 0]);
        assert_eq!(o.counter, 3);
        assert_eq!(o.fixed_current, 4.0);
    }

    #[test]
    fn the_map_and_the_gsd_name_the_modules() {
        let names: Vec<String> = (0..10).map(|i| format!("TT-{i}")).collect();
        let text = map_text(5, &names);
        assert!(text.contains("station 5: 8 modules"), "{text}");
        assert!(text.contains("station 6: 2 modules"), "{text}");
        assert!(text.contains("0xDD,0xA5"));
        let g = gsd(&GsdInfo {
            ident_number: 0x4854,
            version: "0.1.0".into(),
        });
        assert!(g.contains("Ident_Number=0x4854"));
        assert!(g.contains("Module=\"HART device 28 in/6 out\" 0xDD,0xA5"));
        assert!(g.contains("MaxTsdr_45.45=450"));
    }
}
