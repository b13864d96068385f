//! A device's configuration: what a profile file describes and what the state file
//! keeps across restarts (the device's non-volatile memory).

use serde::{Deserialize, Serialize};

/// Kind of instrument.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum DeviceKind {
    /// A transmitter: the loop current is an output computed from PV.
    #[default]
    Transmitter,
    /// A valve positioner: the loop current is an input (the setpoint).
    ValvePositioner,
}

/// Identity (command 0).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Identity {
    /// Expanded device type (14 bits in the long address).
    pub expanded_device_type: u16,
    /// Manufacturer identification code.
    pub manufacturer_id: u16,
    /// Private label distributor code.
    pub private_label_distributor: u16,
    /// 24-bit device ID.
    pub device_id: u32,
    /// Device revision.
    pub device_revision: u8,
    /// Software revision.
    pub software_revision: u8,
    /// Hardware revision (0-31).
    pub hardware_revision: u8,
    /// Device profile (Common Table 57).
    pub device_profile: u8,
    /// Preambles the device needs in requests.
    pub min_request_preambles: u8,
    /// Flags (Common Table 11).
    pub flags: u8,
    /// HART universal revision the device speaks: 7 (default), 6 or 5. A HART 5 or 6
    /// device answers command 0 in the 12- or 17-byte form; a HART 5 device does not
    /// implement commands 7, 8, 9, 20, 21 and 22.
    pub universal_revision: u8,
}

impl Default for Identity {
    fn default() -> Self {
        Identity {
            expanded_device_type: 0x26F0,
            manufacturer_id: 0x00F0,
            private_label_distributor: 0x00F0,
            device_id: 0x000001,
            device_revision: 1,
            software_revision: 1,
            hardware_revision: 1,
            device_profile: 1,
            min_request_preambles: 5,
            flags: 0,
            universal_revision: 7,
        }
    }
}

/// How a simulated process value moves.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Waveform {
    /// A fixed value.
    Constant {
        /// The value.
        value: f32,
    },
    /// `offset + amplitude · sin(2π t / period_s)`.
    Sine {
        /// Mean.
        offset: f32,
        /// Amplitude.
        amplitude: f32,
        /// Period, s.
        period_s: f32,
    },
    /// From `from` to `to` over `period_s`, then again.
    Ramp {
        /// Start value.
        from: f32,
        /// End value.
        to: f32,
        /// Duration of one ramp, s.
        period_s: f32,
    },
    /// A bounded random walk: every `interval_s` a step of up to ±`step`.
    RandomWalk {
        /// Start value.
        start: f32,
        /// Largest step.
        step: f32,
        /// Lower bound.
        min: f32,
        /// Upper bound.
        max: f32,
        /// Time between steps, s.
        #[serde(default = "one")]
        interval_s: f32,
    },
    /// Each value in turn for `period_s`.
    Steps {
        /// The values.
        values: Vec<f32>,
        /// Time on each value, s.
        period_s: f32,
    },
}

fn one() -> f32 {
    1.0
}

/// A device variable.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Variable {
    /// Device variable code (0-239).
    pub code: u8,
    /// Name, for people.
    pub name: String,
    /// Classification (Common Table 21), e.g. 65 pressure, 64 temperature.
    pub classification: u8,
    /// Engineering units the value is reported in.
    pub units: u8,
    /// Device variable family (Common Table 20; 250 none).
    pub family: u8,
    /// The process value, in `units`.
    pub waveform: Waveform,
    /// Lower sensor limit, in `units`.
    pub lower_limit: f32,
    /// Upper sensor limit, in `units`.
    pub upper_limit: f32,
    /// Minimum span, in `units`.
    pub minimum_span: f32,
    /// Damping of this variable, s.
    pub damping: f32,
    /// Transducer serial number.
    pub serial_number: u32,
    /// Acquisition period, ms.
    pub update_period_ms: u32,
}

impl Default for Variable {
    fn default() -> Self {
        Variable {
            code: 0,
            name: "PV".into(),
            classification: 0,
            units: 57,
            family: 250,
            waveform: Waveform::Constant { value: 0.0 },
            lower_limit: -1.0e6,
            upper_limit: 1.0e6,
            minimum_span: 0.0,
            damping: 0.0,
            serial_number: 0,
            update_period_ms: 100,
        }
    }
}

/// Configuration of the primary variable's analog output (or input).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Range {
    /// Units of the range values (the PV's units).
    pub units: u8,
    /// Upper range value (20 mA).
    pub upper: f32,
    /// Lower range value (4 mA).
    pub lower: f32,
    /// PV damping, s (first-order filter time constant).
    pub damping: f32,
    /// Transfer function (Common Table 3): 0 linear, 1 square root.
    pub transfer_function: u8,
    /// Alarm selection (Common Table 6): 0 high, 1 low.
    pub alarm_selection: u8,
}

impl Default for Range {
    fn default() -> Self {
        Range {
            units: 57,
            upper: 100.0,
            lower: 0.0,
            damping: 0.0,
            transfer_function: 0,
            alarm_selection: 0,
        }
    }
}

/// One burst message's configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BurstMessage {
    /// Burst mode control code: 0 off, 1 token-passing, 2 TDMA only, 3 both, 4 HART-IP.
    pub control: u8,
    /// Command published.
    pub command: u16,
    /// Device variable codes of slots 0-7 (250 unused).
    pub slots: [u8; 8],
    /// Minimum update period, 1/32 ms.
    pub update_period: u32,
    /// Maximum update period, 1/32 ms.
    pub max_update_period: u32,
    /// Trigger mode (Common Table 33).
    pub trigger_mode: u8,
    /// Trigger classification.
    pub trigger_classification: u8,
    /// Trigger units.
    pub trigger_units: u8,
    /// Trigger level.
    pub trigger_level: f32,
}

impl Default for BurstMessage {
    fn default() -> Self {
        BurstMessage {
            control: 0,
            command: 1,
            slots: [0, 250, 250, 250, 250, 250, 250, 250],
            update_period: 16_000 * 2,
            max_update_period: 32_000 * 60,
            trigger_mode: 0,
            trigger_classification: 0,
            trigger_units: 250,
            trigger_level: f32::from_bits(hart_proto::types::HART_NAN_BITS),
        }
    }
}

/// A device-specific command: a fixed reply, or one of the computed replies the
/// device offers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CustomCommand {
    /// Command number (128-253 device specific, or an extended number).
    pub number: u16,
    /// Fixed reply data as hex.
    #[serde(default)]
    pub reply_hex: Option<String>,
    /// A computed reply: `"variable:CODE"` (units + float of a device variable),
    /// `"setpoint"`, `"write_setpoint"`, `"input_current"`, `"write_input_current"`.
    #[serde(default)]
    pub computed: Option<String>,
}

/// Valve positioner settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Valve {
    /// `"analog"` (setpoint from the loop current) or `"digital"` (command 129).
    pub setpoint_source: String,
    /// Digital setpoint, % travel.
    pub digital_setpoint: f32,
    /// Loop current driving the analog setpoint, mA (what the controller outputs).
    pub input_current: f32,
    /// Travel time constant, s.
    pub time_constant_s: f32,
    /// Largest travel rate, %/s.
    pub rate_limit: f32,
}

impl Default for Valve {
    fn default() -> Self {
        Valve {
            setpoint_source: "analog".into(),
            digital_setpoint: 50.0,
            input_current: 12.0,
            time_constant_s: 2.0,
            rate_limit: 20.0,
        }
    }
}

/// Physical layer the device is on (limits the shortest burst period).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Phy {
    /// FSK: 0.5 s shortest burst period.
    #[default]
    Fsk,
    /// RS-485 or PSK: 0.1 s.
    Fast,
    /// HART-IP: 0.05 s.
    HartIp,
}

/// Everything a device keeps across power cycles.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DeviceConfig {
    /// Profile name.
    pub profile: String,
    /// Transmitter or valve positioner.
    pub kind: DeviceKind,
    /// Identity.
    pub identity: Identity,
    /// Polling address (0-63).
    pub polling_address: u8,
    /// Loop current mode: 1 enabled (analog), 0 disabled (multidrop, 4 mA).
    pub loop_current_mode: u8,
    /// Tag (8 packed characters).
    pub tag: String,
    /// Long tag (32 Latin-1 characters).
    pub long_tag: String,
    /// Descriptor (16 packed characters).
    pub descriptor: String,
    /// Message (32 packed characters).
    pub message: String,
    /// Date: day, month, year − 1900.
    pub date: [u8; 3],
    /// Final assembly number.
    pub final_assembly_number: u32,
    /// Preambles in replies (command 59).
    pub response_preambles: u8,
    /// PV range and analog settings.
    pub range: Range,
    /// Device variables mapped to PV, SV, TV, QV (250 = none).
    pub mapping: [u8; 4],
    /// The device variables.
    pub variables: Vec<Variable>,
    /// Loop current trim: zero correction, mA.
    pub trim_zero: f32,
    /// Loop current trim: gain correction factor.
    pub trim_gain: f32,
    /// Simulated analog output error: offset, mA (what a trim corrects).
    pub output_offset_error: f32,
    /// Simulated analog output error: gain factor.
    pub output_gain_error: f32,
    /// PV zero offset set by command 43, in PV units.
    pub pv_zero_offset: f32,
    /// Burst messages (at least 3).
    pub burst: Vec<BurstMessage>,
    /// Configuration change counter.
    pub config_change_counter: u16,
    /// Device-specific commands.
    pub commands: Vec<CustomCommand>,
    /// Valve positioner settings.
    pub valve: Valve,
    /// Physical layer.
    pub phy: Phy,
    /// Refuse configuration changes from the secondary master ("access restricted"),
    /// as a device locked for the control system.
    pub restrict_secondary_writes: bool,
}

impl Default for DeviceConfig {
    fn default() -> Self {
        DeviceConfig {
            profile: "generic".into(),
            kind: DeviceKind::Transmitter,
            identity: Identity::default(),
            polling_address: 0,
            loop_current_mode: 1,
            tag: "HARTKIT".into(),
            long_tag: String::new(),
            descriptor: String::new(),
            message: String::new(),
            date: [1, 1, 125],
            final_assembly_number: 0,
            response_preambles: 5,
            range: Range::default(),
            mapping: [0, 250, 250, 250],
            variables: vec![Variable::default()],
            trim_zero: 0.0,
            trim_gain: 1.0,
            output_offset_error: 0.0,
            output_gain_error: 1.0,
            pv_zero_offset: 0.0,
            burst: vec![
                BurstMessage::default(),
                BurstMessage::default(),
                BurstMessage::default(),
            ],
            config_change_counter: 0,
            commands: vec![],
            valve: Valve::default(),
            phy: Phy::Fsk,
            restrict_secondary_writes: false,
        }
    }
}

impl DeviceConfig {
    /// Parses a profile or state file (TOML).
    pub fn from_toml(text: &str) -> Result<Self, String> {
        let mut c: DeviceConfig = toml::from_str(text).map_err(|e| e.to_string())?;
        c.normalise();
        Ok(c)
    }

    /// Fixes up what a hand-written profile may leave out.
    pub fn normalise(&mut self) {
        while self.burst.len() < 3 {
            self.burst.push(BurstMessage::default());
        }
        self.polling_address &= 0x3F;
        if self.variables.is_empty() {
            self.variables.push(Variable::default());
        }
    }

    /// The variable with device variable code `code`.
    pub fn variable(&self, code: u8) -> Option<&Variable> {
        self.variables.iter().find(|v| v.code == code)
    }
}
