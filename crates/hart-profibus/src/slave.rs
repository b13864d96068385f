//! The DP-V0 slave: FDL station plus the DP services, as a state machine fed with
//! bytes and the time they were read.
//!
//! | SAP | service | states |
//! | --- | --- | --- |
//! | none (default) | Data_Exchange: outputs in, inputs out | Data_Exch, the owning master |
//! | 56 | RD_Inp: the inputs | Data_Exch, any master |
//! | 57 | RD_Outp: the outputs | Data_Exch, any master |
//! | 58 | Global_Control: clear, sync/unsync, freeze/unfreeze (broadcast or to us) | Data_Exch, the owning master |
//! | 59 | Get_Cfg: our configuration identifiers | all |
//! | 60 | Slave_Diag | all, any master |
//! | 61 | Set_Prm: lock, watchdog, min TSDR, ident number, group | Wait_Prm, or the owning master |
//! | 62 | Chk_Cfg: the master's configuration against ours | Wait_Cfg, Data_Exch |
//!
//! Other SAPs, and a service in a state where it is not allowed, are answered "RS"
//! (service access point not activated). An FDL status request (SD1, FC 9) is
//! answered with an SD1 status reply, so masters' live lists find the station.

use std::fmt;
use std::time::Duration;

use crate::cfg::{io_lengths, CfgError, IoLengths};
use crate::fdl::{self, DataTelegram, DecodeError, FunctionCode, Request, Status, Telegram};

/// DP SAP of Set_Slave_Add (not supported: answered RS).
pub const SAP_SET_SLAVE_ADD: u8 = 55;
/// DP SAP of RD_Inp.
pub const SAP_RD_INP: u8 = 56;
/// DP SAP of RD_Outp.
pub const SAP_RD_OUTP: u8 = 57;
/// DP SAP of Global_Control.
pub const SAP_GLOBAL_CONTROL: u8 = 58;
/// DP SAP of Get_Cfg.
pub const SAP_GET_CFG: u8 = 59;
/// DP SAP of Slave_Diag.
pub const SAP_SLAVE_DIAG: u8 = 60;
/// DP SAP of Set_Prm.
pub const SAP_SET_PRM: u8 = 61;
/// DP SAP of Chk_Cfg.
pub const SAP_CHK_CFG: u8 = 62;

/// The smallest station delay a slave keeps before Set_Prm sets one, in bit times.
pub const DEFAULT_MIN_TSDR_BITS: u8 = 11;
/// The idle time a receiver needs before a start delimiter after a damaged or cut
/// short telegram (TSYN), in bit times.
pub const TSYN_BITS: u32 = 33;
/// The longest block of device-related diagnosis (its header byte included).
pub const MAX_UNIT_DIAG_BLOCK: usize = 63;

/// How the slave is set up.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SlaveConfig {
    /// The station address, 0..=125.
    pub address: u8,
    /// The ident number (the GSD's `Ident_Number`) that Set_Prm must carry.
    pub ident_number: u16,
    /// The configuration identifiers that Chk_Cfg must match and Get_Cfg returns.
    pub cfg: Vec<u8>,
    /// The line's bit rate (bit/s), for the station delay and idle times.
    pub baud: u32,
    /// The longest station delay in bit times (the GSD's `MaxTsdr_*` at this rate): a
    /// reply that cannot start within it is counted late.
    pub max_tsdr_bits: u16,
    /// User parameter bytes after the 7 standard Set_Prm bytes (the GSD's
    /// `User_Prm_Data_Len`); a Set_Prm with another number is a parameter fault.
    pub user_prm_len: usize,
}

/// Why a [`SlaveConfig`] is not usable.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ConfigError {
    /// The address is above 125 (126 is the default address of an uncommissioned
    /// slave, 127 the broadcast).
    Address(u8),
    /// The configuration identifiers do not parse.
    Cfg(CfgError),
    /// More than 244 input or output bytes.
    TooMuchData(IoLengths),
    /// A bit rate of 0.
    Baud,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ConfigError::Address(a) => write!(
                f,
                "PROFIBUS station address {a}: a DP slave takes 0..=125"
            ),
            ConfigError::Cfg(e) => write!(f, "configuration identifiers: {e}"),
            ConfigError::TooMuchData(io) => write!(
                f,
                "{} input and {} output bytes: a DP-V0 station carries at most 244 each way; spread the devices over further station addresses",
                io.inputs, io.outputs
            ),
            ConfigError::Baud => write!(f, "a bit rate of 0"),
        }
    }
}

impl std::error::Error for ConfigError {}

/// The slave's DP state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DpState {
    /// Waiting for parameters (Set_Prm).
    WaitPrm,
    /// Parameterised, waiting for the configuration (Chk_Cfg).
    WaitCfg,
    /// Exchanging data with its master.
    DataExch,
}

impl fmt::Display for DpState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            DpState::WaitPrm => "Wait_Prm",
            DpState::WaitCfg => "Wait_Cfg",
            DpState::DataExch => "Data_Exch",
        })
    }
}

/// Something the application may want to log or act on.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Event {
    /// A master parameterised the slave.
    Parameterised {
        /// Its address.
        master: u8,
    },
    /// Set_Prm was refused.
    ParameterFault {
        /// The master.
        master: u8,
        /// What was wrong.
        reason: String,
    },
    /// Chk_Cfg matched: data exchange begins.
    Configured {
        /// The master.
        master: u8,
    },
    /// Chk_Cfg did not match our configuration.
    ConfigurationFault {
        /// The master.
        master: u8,
        /// What it sent.
        got: Vec<u8>,
        /// What we have.
        want: Vec<u8>,
    },
    /// The watchdog ran out: no telegram from the master within its time.
    WatchdogExpired {
        /// The master.
        master: u8,
        /// The watchdog time.
        timeout: Duration,
    },
    /// The master unlocked the slave (Set_Prm with Unlock_Req).
    Unlocked {
        /// The master.
        master: u8,
    },
    /// The outputs changed (new data, a Sync, a Clear_Data, or cleared on leaving data
    /// exchange).
    Outputs,
}

impl fmt::Display for Event {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Event::Parameterised { master } => write!(f, "parameterised by master {master}"),
            Event::ParameterFault { master, reason } => write!(
                f,
                "parameters from master {master} refused: {reason}; check the master's project against the GSD file"
            ),
            Event::Configured { master } => {
                write!(f, "configuration from master {master} matches: data exchange")
            }
            Event::ConfigurationFault { master, got, want } => write!(
                f,
                "configuration from master {master} is {} but this station has {}: add the modules in the GSD's order, one per HART device",
                hex(got),
                hex(want)
            ),
            Event::WatchdogExpired { master, timeout } => write!(
                f,
                "no telegram from master {master} within the watchdog time {} ms: outputs cleared, waiting for parameters (is the master running, the cable connected?)",
                timeout.as_millis()
            ),
            Event::Unlocked { master } => write!(f, "released by master {master}"),
            Event::Outputs => write!(f, "outputs changed"),
        }
    }
}

fn hex(b: &[u8]) -> String {
    if b.is_empty() {
        return "(none)".into();
    }
    b.iter()
        .map(|x| format!("{x:02X}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Counts of what the slave saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Stats {
    /// Telegrams for this station (or broadcast) served.
    pub requests: u64,
    /// Replies sent.
    pub replies: u64,
    /// Replies repeated because the master repeated a request (same FCB).
    pub repeats: u64,
    /// Telegrams for other stations, tokens, replies of others.
    pub others: u64,
    /// Damaged telegrams (bad check sum, delimiter, length): never answered.
    pub damaged: u64,
    /// Telegrams cut short by an idle line.
    pub cut_short: u64,
    /// Replies sent later than the maximum station delay.
    pub late: u64,
    /// Requests dropped because a new telegram arrived before their reply was sent.
    pub superseded: u64,
    /// Watchdog expiries.
    pub watchdog: u64,
    /// Data_Exchange requests taken (outputs in, inputs out; repeats not counted).
    pub data_exchanges: u64,
}

#[derive(Debug, Clone)]
struct PendingReply {
    bytes: Vec<u8>,
    earliest: Duration,
    latest: Duration,
}

#[derive(Debug, Clone)]
struct LastReply {
    master: u8,
    fcb: bool,
    saps: (Option<u8>, Option<u8>),
    bytes: Vec<u8>,
}

/// A DP-V0 slave station, sans-IO.
///
/// Feed it what the line gives ([`Slave::receive`]); ask it for bytes to send when its
/// deadline comes ([`Slave::poll_transmit`], [`Slave::deadline`]); set its inputs and
/// read its outputs between.
#[derive(Debug, Clone)]
pub struct Slave {
    config: SlaveConfig,
    io: IoLengths,
    state: DpState,
    master: Option<u8>,
    watchdog: Option<Duration>,
    master_seen: Duration,
    min_tsdr_bits: u8,
    group: u8,
    sync_mode: bool,
    freeze_mode: bool,
    synced: bool,
    frozen: Option<Vec<u8>>,
    prm_fault: bool,
    cfg_fault: bool,
    not_supported: bool,
    static_diag: bool,
    diag_pending: bool,
    inputs: Vec<u8>,
    outputs: Vec<u8>,
    held_outputs: Option<Vec<u8>>,
    unit_diag: Vec<u8>,
    user_prm: Vec<u8>,
    rx: Vec<u8>,
    last_rx: Option<Duration>,
    partial_timeout: Option<Duration>,
    resync: bool,
    pending: Option<PendingReply>,
    last_reply: Option<LastReply>,
    last_error: Option<DecodeError>,
    events: Vec<Event>,
    stats: Stats,
}

impl Slave {
    /// A slave in Wait_Prm with zero inputs.
    pub fn new(config: SlaveConfig) -> Result<Slave, ConfigError> {
        if config.address > 125 {
            return Err(ConfigError::Address(config.address));
        }
        if config.baud == 0 {
            return Err(ConfigError::Baud);
        }
        let io = io_lengths(&config.cfg).map_err(ConfigError::Cfg)?;
        if io.inputs > 244 || io.outputs > 244 {
            return Err(ConfigError::TooMuchData(io));
        }
        Ok(Slave {
            io,
            state: DpState::WaitPrm,
            master: None,
            watchdog: None,
            master_seen: Duration::ZERO,
            min_tsdr_bits: DEFAULT_MIN_TSDR_BITS,
            group: 0,
            sync_mode: false,
            freeze_mode: false,
            synced: false,
            frozen: None,
            prm_fault: false,
            cfg_fault: false,
            not_supported: false,
            static_diag: false,
            diag_pending: false,
            inputs: vec![0; io.inputs],
            outputs: vec![0; io.outputs],
            held_outputs: None,
            unit_diag: Vec::new(),
            user_prm: Vec::new(),
            rx: Vec::new(),
            last_rx: None,
            partial_timeout: None,
            resync: false,
            pending: None,
            last_reply: None,
            last_error: None,
            events: Vec::new(),
            stats: Stats::default(),
            config,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &SlaveConfig {
        &self.config
    }

    /// Input and output lengths.
    pub fn io_lengths(&self) -> IoLengths {
        self.io
    }

    /// The DP state.
    pub fn state(&self) -> DpState {
        self.state
    }

    /// The master that parameterised the slave.
    pub fn master(&self) -> Option<u8> {
        self.master
    }

    /// The watchdog time Set_Prm set, if any.
    pub fn watchdog(&self) -> Option<Duration> {
        self.watchdog
    }

    /// The station delay Set_Prm set, in bit times.
    pub fn min_tsdr_bits(&self) -> u8 {
        self.min_tsdr_bits
    }

    /// The group bits Set_Prm set.
    pub fn group(&self) -> u8 {
        self.group
    }

    /// Whether Set_Prm asked for sync mode (Sync_Req) and freeze mode (Freeze_Req).
    pub fn modes(&self) -> (bool, bool) {
        (self.sync_mode, self.freeze_mode)
    }

    /// The user parameter bytes of the last accepted Set_Prm.
    pub fn user_parameters(&self) -> &[u8] {
        &self.user_prm
    }

    /// The outputs in force (zero outside data exchange and after Clear_Data).
    pub fn outputs(&self) -> &[u8] {
        &self.outputs
    }

    /// The inputs the next Data_Exchange returns (before any freeze).
    pub fn inputs(&self) -> &[u8] {
        &self.inputs
    }

    /// Sets the inputs; bytes beyond the input length are ignored, missing ones are 0.
    pub fn set_inputs(&mut self, inputs: &[u8]) {
        let n = inputs.len().min(self.inputs.len());
        self.inputs[..n].copy_from_slice(&inputs[..n]);
        self.inputs[n..].fill(0);
    }

    /// Sets the device-related diagnosis bits (bit `i` of byte `i / 8`): a block is
    /// sent, and Ext_Diag set, while any bit is set. At most 62 bytes are kept. A
    /// change makes the next Data_Exchange reply "data high" so that the master
    /// fetches the diagnosis.
    pub fn set_unit_diag(&mut self, bits: &[u8]) {
        let bits = &bits[..bits.len().min(MAX_UNIT_DIAG_BLOCK - 1)];
        if bits != self.unit_diag.as_slice() {
            self.unit_diag = bits.to_vec();
            self.diag_pending = true;
        }
    }

    /// Sets Stat_Diag: the master keeps fetching the diagnosis while it is set.
    pub fn set_static_diag(&mut self, on: bool) {
        if on != self.static_diag {
            self.static_diag = on;
            self.diag_pending = true;
        }
    }

    /// Counts so far.
    pub fn stats(&self) -> Stats {
        self.stats
    }

    /// The last damaged telegram's fault.
    pub fn last_error(&self) -> Option<DecodeError> {
        self.last_error
    }

    /// Events since the last call.
    pub fn take_events(&mut self) -> Vec<Event> {
        std::mem::take(&mut self.events)
    }

    /// `bits` bit times at the line's rate.
    pub fn bit_times(&self, bits: u32) -> Duration {
        Duration::from_nanos(u64::from(bits) * 1_000_000_000 / u64::from(self.config.baud))
    }

    /// The diagnosis as Slave_Diag returns it to `requester`.
    pub fn diagnosis(&self, requester: Option<u8>) -> Vec<u8> {
        let ext = self.unit_diag.iter().any(|b| *b != 0);
        let mut b0 = 0u8;
        if self.state != DpState::DataExch {
            b0 |= 0x02;
        }
        if self.cfg_fault {
            b0 |= 0x04;
        }
        if ext {
            b0 |= 0x08;
        }
        if self.not_supported {
            b0 |= 0x10;
        }
        if self.prm_fault {
            b0 |= 0x40;
        }
        if let (Some(m), Some(r)) = (self.master, requester) {
            if m != r && self.state != DpState::WaitPrm {
                b0 |= 0x80;
            }
        }
        let mut b1 = 0x04u8;
        if self.state == DpState::WaitPrm {
            b1 |= 0x01;
        }
        if self.static_diag {
            b1 |= 0x02;
        }
        if self.watchdog.is_some() {
            b1 |= 0x08;
        }
        if self.frozen.is_some() {
            b1 |= 0x10;
        }
        if self.synced {
            b1 |= 0x20;
        }
        let id = self.config.ident_number.to_be_bytes();
        let mut d = vec![b0, b1, 0, self.master.unwrap_or(0xFF), id[0], id[1]];
        if ext {
            d.push((self.unit_diag.len() + 1) as u8);
            d.extend_from_slice(&self.unit_diag);
        }
        d
    }

    /// When the slave next needs [`Slave::poll_transmit`]: a reply's send time, the
    /// watchdog, the end of a telegram cut short.
    pub fn deadline(&self) -> Option<Duration> {
        let mut d: Option<Duration> = self.pending.as_ref().map(|p| p.earliest);
        let mut consider = |t: Duration| d = Some(d.map_or(t, |x| x.min(t)));
        if let (Some(w), DpState::WaitCfg | DpState::DataExch) = (self.watchdog, self.state) {
            consider(self.master_seen + w);
        }
        if let Some(last) = self.last_rx {
            if self.resync {
                consider(last + self.bit_times(TSYN_BITS));
            }
            if !self.rx.is_empty() {
                consider(last + self.partial_timeout());
            }
        }
        d
    }

    /// How long a telegram begun may wait for its next bytes before it is dropped as
    /// cut short: by default TSYN (33 bit times), as on the line; a program behind a
    /// USB adapter or a pseudo-terminal sees bytes in bursts, with gaps between reads
    /// that are not on the line (an FTDI adapter hands over every 16 ms by default), and
    /// sets a longer one. The check sum and end delimiter still judge the telegram.
    pub fn set_partial_timeout(&mut self, timeout: Duration) {
        self.partial_timeout = Some(timeout);
    }

    fn partial_timeout(&self) -> Duration {
        self.partial_timeout
            .unwrap_or_else(|| self.bit_times(TSYN_BITS))
    }

    /// Runs the timers and returns the bytes to send now, if a reply is due.
    pub fn poll_transmit(&mut self, now: Duration) -> Option<Vec<u8>> {
        self.timers(now);
        if self.pending.as_ref()?.earliest > now {
            return None;
        }
        let p = self.pending.take()?;
        if now > p.latest {
            self.stats.late += 1;
        }
        self.stats.replies += 1;
        Some(p.bytes)
    }

    /// Takes bytes read from the line at `now`.
    pub fn receive(&mut self, now: Duration, bytes: &[u8]) {
        if bytes.is_empty() {
            self.timers(now);
            return;
        }
        self.timers(now);
        if self.pending.take().is_some() {
            self.stats.superseded += 1;
        }
        self.last_rx = Some(now);
        if self.resync {
            return;
        }
        self.rx.extend_from_slice(bytes);
        loop {
            match fdl::decode(&self.rx) {
                Ok(None) => break,
                Ok(Some((t, n))) => {
                    let t = own(&t);
                    self.rx.drain(..n);
                    self.handle(now, t);
                }
                Err(e) => {
                    self.stats.damaged += 1;
                    self.last_error = Some(e);
                    self.rx.clear();
                    self.resync = true;
                    self.pending = None;
                    break;
                }
            }
        }
    }

    fn timers(&mut self, now: Duration) {
        if let Some(last) = self.last_rx {
            if now >= last + self.bit_times(TSYN_BITS) {
                self.resync = false;
            }
            if !self.rx.is_empty() && now >= last + self.partial_timeout() {
                self.stats.cut_short += 1;
                self.rx.clear();
            }
        }
        if let (Some(w), Some(m)) = (self.watchdog, self.master) {
            if self.state != DpState::WaitPrm && now >= self.master_seen + w {
                self.stats.watchdog += 1;
                self.events.push(Event::WatchdogExpired {
                    master: m,
                    timeout: w,
                });
                self.leave(DpState::WaitPrm);
                self.master = None;
                self.watchdog = None;
            }
        }
    }

    /// Goes to `state` from data exchange or Wait_Cfg: outputs cleared, sync and
    /// freeze ended.
    fn leave(&mut self, state: DpState) {
        self.state = state;
        self.last_reply = None;
        self.synced = false;
        self.frozen = None;
        self.held_outputs = None;
        self.diag_pending = true;
        if self.outputs.iter().any(|b| *b != 0) {
            self.outputs.fill(0);
            self.events.push(Event::Outputs);
        }
    }

    fn handle(&mut self, now: Duration, t: OwnedTelegram) {
        let OwnedTelegram::Data {
            da,
            sa,
            dsap,
            ssap,
            fc,
            data,
        } = t
        else {
            self.stats.others += 1;
            return;
        };
        let FunctionCode::Request { request, fcb, fcv } = fc else {
            self.stats.others += 1;
            return;
        };
        let broadcast = da == fdl::BROADCAST;
        if da != self.config.address && !broadcast {
            self.stats.others += 1;
            return;
        }
        self.stats.requests += 1;
        if Some(sa) == self.master {
            self.master_seen = now;
        }
        let wants_reply = request.expects_reply() && !broadcast;
        if wants_reply && fcv {
            if let Some(last) = &self.last_reply {
                if last.master == sa && last.fcb == fcb && last.saps == (dsap, ssap) {
                    let bytes = last.bytes.clone();
                    self.stats.repeats += 1;
                    self.schedule(now, bytes);
                    return;
                }
            }
        }
        let reply = self.serve(now, sa, request, dsap, ssap, &data);
        if let (true, Some(reply)) = (wants_reply, reply) {
            let mut bytes = Vec::new();
            match reply {
                Reply::ShortAck => bytes.push(fdl::SC),
                Reply::Status(status) => {
                    let _ = fdl::encode(
                        &DataTelegram {
                            da: sa,
                            sa: self.config.address,
                            dsap: None,
                            ssap: None,
                            fc: FunctionCode::slave_reply(status),
                            data: &[],
                        },
                        &mut bytes,
                    );
                }
                Reply::Data(status, payload) => {
                    // Encoding fails only beyond 246 bytes, which no reply reaches
                    // (inputs and configuration are checked at 244, the diagnosis
                    // at 6 + 63).
                    let _ = fdl::encode(
                        &DataTelegram {
                            da: sa,
                            sa: self.config.address,
                            dsap: ssap,
                            ssap: dsap,
                            fc: FunctionCode::slave_reply(status),
                            data: &payload,
                        },
                        &mut bytes,
                    );
                }
            }
            self.last_reply = Some(LastReply {
                master: sa,
                fcb,
                saps: (dsap, ssap),
                bytes: bytes.clone(),
            });
            self.schedule(now, bytes);
        }
    }

    fn schedule(&mut self, now: Duration, bytes: Vec<u8>) {
        let earliest = now + self.bit_times(u32::from(self.min_tsdr_bits));
        let latest = now + self.bit_times(u32::from(self.config.max_tsdr_bits.max(1)));
        self.pending = Some(PendingReply {
            bytes,
            earliest,
            latest: latest.max(earliest),
        });
    }

    fn serve(
        &mut self,
        now: Duration,
        sa: u8,
        request: Request,
        dsap: Option<u8>,
        ssap: Option<u8>,
        data: &[u8],
    ) -> Option<Reply> {
        if request == Request::FdlStatus {
            return Some(Reply::Status(Status::Ok));
        }
        if !matches!(
            request,
            Request::SrdLow
                | Request::SrdHigh
                | Request::SdnLow
                | Request::SdnHigh
                | Request::SdaLow
                | Request::SdaHigh
        ) {
            return Some(Reply::Status(Status::SapNotActivated));
        }
        match dsap {
            None => Some(self.data_exchange(sa, data)),
            Some(SAP_SLAVE_DIAG) => {
                if self.master.is_none() || self.master == Some(sa) {
                    self.diag_pending = false;
                }
                Some(Reply::Data(Status::DataLow, self.diagnosis(Some(sa))))
            }
            Some(SAP_SET_PRM) => {
                self.set_prm(now, sa, data);
                Some(Reply::ShortAck)
            }
            Some(SAP_CHK_CFG) => {
                self.chk_cfg(sa, data);
                Some(Reply::ShortAck)
            }
            Some(SAP_GET_CFG) => Some(Reply::Data(Status::DataLow, self.config.cfg.clone())),
            Some(SAP_GLOBAL_CONTROL) => {
                self.global_control(sa, data);
                Some(Reply::ShortAck)
            }
            Some(SAP_RD_INP) if self.state == DpState::DataExch => {
                Some(Reply::Data(Status::DataLow, self.current_inputs().to_vec()))
            }
            Some(SAP_RD_OUTP) if self.state == DpState::DataExch => {
                Some(Reply::Data(Status::DataLow, self.outputs.clone()))
            }
            Some(_) => {
                let _ = ssap;
                Some(Reply::Status(Status::SapNotActivated))
            }
        }
    }

    fn current_inputs(&self) -> &[u8] {
        self.frozen.as_deref().unwrap_or(&self.inputs)
    }

    fn data_exchange(&mut self, sa: u8, data: &[u8]) -> Reply {
        if self.state != DpState::DataExch || self.master != Some(sa) {
            return Reply::Status(Status::SapNotActivated);
        }
        if data.len() != self.io.outputs {
            return Reply::Status(Status::SapNotActivated);
        }
        self.stats.data_exchanges += 1;
        if self.synced {
            self.held_outputs = Some(data.to_vec());
        } else if data != self.outputs.as_slice() {
            self.outputs.copy_from_slice(data);
            self.events.push(Event::Outputs);
        }
        let status = if self.diag_pending {
            Status::DataHigh
        } else {
            Status::DataLow
        };
        if self.io.inputs == 0 {
            return if self.diag_pending {
                Reply::Status(Status::DataHigh)
            } else {
                Reply::ShortAck
            };
        }
        Reply::Data(status, self.current_inputs().to_vec())
    }

    fn set_prm(&mut self, now: Duration, sa: u8, d: &[u8]) {
        if self.state != DpState::WaitPrm && self.master.is_some_and(|m| m != sa) {
            // Locked by another master: refused without changing anything; that
            // master's diagnosis shows Master_Lock.
            return;
        }
        let fault = |s: &mut Slave, reason: String| {
            s.prm_fault = true;
            s.events.push(Event::ParameterFault { master: sa, reason });
            if s.state != DpState::WaitPrm {
                s.leave(DpState::WaitPrm);
            }
            s.master = None;
            s.watchdog = None;
            s.diag_pending = true;
        };
        if d.len() < 7 {
            fault(self, format!("{} bytes, Set_Prm has at least 7", d.len()));
            return;
        }
        let status = d[0];
        let (lock, unlock) = (status & 0x80 != 0, status & 0x40 != 0);
        if unlock {
            if self.state != DpState::WaitPrm {
                self.leave(DpState::WaitPrm);
            }
            self.master = None;
            self.watchdog = None;
            self.events.push(Event::Unlocked { master: sa });
            return;
        }
        if !lock {
            // Lock_Req and Unlock_Req both clear: only the station delay changes.
            if d[3] != 0 {
                self.min_tsdr_bits = d[3];
            }
            return;
        }
        let ident = u16::from_be_bytes([d[4], d[5]]);
        if ident != self.config.ident_number {
            fault(
                self,
                format!(
                    "ident number 0x{ident:04X}, this station is 0x{:04X}",
                    self.config.ident_number
                ),
            );
            return;
        }
        let user = &d[7..];
        if user.len() != self.config.user_prm_len {
            fault(
                self,
                format!(
                    "{} bytes of user parameters, this station takes {}",
                    user.len(),
                    self.config.user_prm_len
                ),
            );
            return;
        }
        let watchdog = if status & 0x08 != 0 {
            let (f1, f2) = (u64::from(d[1]), u64::from(d[2]));
            if f1 == 0 || f2 == 0 {
                fault(
                    self,
                    format!("watchdog factors {f1} × {f2}: both must be 1..=255"),
                );
                return;
            }
            Some(Duration::from_millis(10 * f1 * f2))
        } else {
            None
        };
        if self.state != DpState::WaitPrm {
            self.leave(DpState::WaitPrm);
        }
        self.master = Some(sa);
        self.master_seen = now;
        self.watchdog = watchdog;
        if d[3] != 0 {
            self.min_tsdr_bits = d[3];
        }
        self.group = d[6];
        self.sync_mode = status & 0x20 != 0;
        self.freeze_mode = status & 0x10 != 0;
        self.user_prm = user.to_vec();
        self.prm_fault = false;
        self.cfg_fault = false;
        self.not_supported = false;
        self.state = DpState::WaitCfg;
        self.diag_pending = true;
        self.events.push(Event::Parameterised { master: sa });
    }

    fn chk_cfg(&mut self, sa: u8, d: &[u8]) {
        if self.state == DpState::WaitPrm || self.master != Some(sa) {
            return;
        }
        if d == self.config.cfg.as_slice() {
            self.cfg_fault = false;
            if self.state != DpState::DataExch {
                self.state = DpState::DataExch;
                self.events.push(Event::Configured { master: sa });
            }
        } else {
            self.cfg_fault = true;
            self.events.push(Event::ConfigurationFault {
                master: sa,
                got: d.to_vec(),
                want: self.config.cfg.clone(),
            });
            self.leave(DpState::WaitPrm);
        }
        self.diag_pending = true;
    }

    fn global_control(&mut self, sa: u8, d: &[u8]) {
        if self.state != DpState::DataExch || self.master != Some(sa) || d.len() < 2 {
            return;
        }
        let (cmd, groups) = (d[0], d[1]);
        if groups != 0 && groups & self.group == 0 {
            return;
        }
        if cmd & 0x02 != 0 {
            self.held_outputs = None;
            if self.outputs.iter().any(|b| *b != 0) {
                self.outputs.fill(0);
                self.events.push(Event::Outputs);
            }
        }
        if cmd & 0x10 != 0 {
            self.synced = false;
            if let Some(held) = self.held_outputs.take() {
                self.apply(held);
            }
        } else if cmd & 0x20 != 0 {
            if let Some(held) = self.held_outputs.take() {
                self.apply(held);
            }
            self.synced = true;
        }
        if cmd & 0x04 != 0 {
            self.frozen = None;
        } else if cmd & 0x08 != 0 {
            self.frozen = Some(self.inputs.clone());
        }
    }

    fn apply(&mut self, outputs: Vec<u8>) {
        if outputs != self.outputs {
            self.outputs = outputs;
            self.events.push(Event::Outputs);
        }
    }
}

enum Reply {
    ShortAck,
    Status(Status),
    Data(Status, Vec<u8>),
}

enum OwnedTelegram {
    Data {
        da: u8,
        sa: u8,
        dsap: Option<u8>,
        ssap: Option<u8>,
        fc: FunctionCode,
        data: Vec<u8>,
    },
    Other,
}

fn own(t: &Telegram<'_>) -> OwnedTelegram {
    match t {
        Telegram::Data(d) => OwnedTelegram::Data {
            da: d.da,
            sa: d.sa,
            dsap: d.dsap,
            ssap: d.ssap,
            fc: d.fc,
            data: d.data.to_vec(),
        },
        _ => OwnedTelegram::Other,
    }
}
