//! A run in progress: what it knows about the device, and the exchanges the tests are
//! made of (typed requests, with raw ones only for what no layout makes on purpose).

use hart_host::transport::Transport;
use hart_link::Micros;
use hart_proto::command::{Empty, Identity, TagDescriptorDate};
use hart_proto::frame::{Address, MasterKind, UniqueId};
use hart_proto::types::DeviceVariableCode;
use hart_proto::wire::{List, Reader, Wire, Writer};
use hart_proto::Request;

use crate::expect::Expect;
use crate::model::{Group, Verdict};
use crate::probe::{Exchange, Probe};

/// Which device to test.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceAddress {
    /// By polling address (command 0 in a short frame).
    Poll(u8),
    /// By unique ID (command 0 in a long frame).
    UniqueId(UniqueId),
}

/// Settings of a run.
#[derive(Debug, Clone)]
pub struct Options {
    /// The device.
    pub address: DeviceAddress,
    /// Groups to run (empty: all but `phy`, which needs a recording).
    pub groups: Vec<Group>,
    /// Allow tests that write (and restore).
    pub allow_writes: bool,
    /// What the device maker says the device is (`--expect`).
    pub expect: Option<Expect>,
    /// The longest a burst test listens, µs.
    pub burst_listen_max: Micros,
    /// Test-run label for the report (the `-p` target).
    pub target: String,
}

impl Options {
    /// Defaults for the device at `address` on `target`.
    pub fn new(target: &str, address: DeviceAddress) -> Self {
        Options {
            address,
            groups: vec![],
            allow_writes: false,
            expect: None,
            burst_listen_max: 70_000_000,
            target: target.to_string(),
        }
    }
}

/// Why a writing test could not run on a write-protected device.
pub(crate) const WRITE_PROTECTED: &str =
    "the device is write protected (response code 7 to a write); this test needs it writable (CMD-104 checks the protection)";

pub(crate) type Outcome = (Verdict, String);

pub(crate) fn pass(s: impl Into<String>) -> Outcome {
    (Verdict::Pass, s.into())
}
pub(crate) fn fail(s: impl Into<String>) -> Outcome {
    (Verdict::Fail, s.into())
}
pub(crate) fn na(s: impl Into<String>) -> Outcome {
    (Verdict::NotApplicable, s.into())
}
pub(crate) fn cnr(s: impl Into<String>) -> Outcome {
    (Verdict::CouldNotRun, s.into())
}

/// Command 0: identity.
pub(crate) const READ_0: Request = Request::ReadUniqueIdentifier(Empty {});
/// Command 1: primary variable.
pub(crate) const READ_1: Request = Request::ReadPrimaryVariable(Empty {});
/// Command 12: message.
pub(crate) const READ_12: Request = Request::ReadMessage(Empty {});
/// Command 13: tag, descriptor, date.
pub(crate) const READ_13: Request = Request::ReadTagDescriptorDate(Empty {});

/// `data` decoded with the layout `L`, when it decodes.
pub(crate) fn decode<L: Wire>(data: &[u8]) -> Option<L> {
    L::decode(&mut Reader::new(data)).ok()
}

/// The bytes `value` encodes to (empty when it does not encode).
pub(crate) fn encoded<L: Wire>(value: &L) -> Vec<u8> {
    let mut buf = [0u8; 255];
    let mut w = Writer::new(&mut buf);
    match value.encode(&mut w) {
        Ok(()) => w.written().to_vec(),
        Err(_) => vec![],
    }
}

/// A list of device variable codes (a request's slots); codes beyond its room are
/// left out.
pub(crate) fn slots<const N: usize, const MIN: usize>(
    codes: &[u8],
) -> List<DeviceVariableCode, N, MIN> {
    let mut l = List::default();
    for &c in codes {
        let _ = l.push(DeviceVariableCode(c));
    }
    l
}

/// What the run learnt about the device.
#[derive(Debug, Clone)]
pub(crate) struct Known {
    pub(crate) identity: Identity,
    pub(crate) uid: UniqueId,
    pub(crate) poll: Option<u8>,
    pub(crate) revision: u8,
    pub(crate) preambles: usize,
}

/// A run in progress.
pub(crate) struct Runner<'a, 'b, T: Transport> {
    pub(crate) p: Probe<'a, T>,
    pub(crate) opts: &'b Options,
    pub(crate) dev: Known,
    /// A reason the run stopped (device silent).
    pub(crate) stopped: Option<String>,
}

pub(crate) fn hex_id(id: UniqueId) -> String {
    id.to_bytes().iter().map(|b| format!("{b:02X}")).collect()
}

impl<T: Transport> Runner<'_, '_, T> {
    pub(crate) fn long(&self, m: MasterKind) -> Address {
        Address::long(self.dev.uid).with_master(m)
    }

    /// A request to the device (long frame, primary master) and its reply.
    pub(crate) async fn cmd(&mut self, req: &Request) -> Exchange {
        self.cmd_as(MasterKind::Primary, req).await
    }

    /// A request to the device from master `m` and its reply.
    pub(crate) async fn cmd_as(&mut self, m: MasterKind, req: &Request) -> Exchange {
        match req.to_vec() {
            Ok(data) => self.cmd_raw_as(m, req.command(), &data).await,
            Err(e) => Exchange {
                error: Some(format!(
                    "command {}: the request does not encode ({e})",
                    req.command()
                )),
                ..Exchange::default()
            },
        }
    }

    /// Raw request data, for what no layout makes on purpose: requests too short for
    /// their command (CMD-101), a command hart-proto does not know (CMD-102) and the
    /// device-specific commands of an `--expect` file (CMD-200).
    pub(crate) async fn cmd_raw(&mut self, command: u16, data: &[u8]) -> Exchange {
        self.cmd_raw_as(MasterKind::Primary, command, data).await
    }

    async fn cmd_raw_as(&mut self, m: MasterKind, command: u16, data: &[u8]) -> Exchange {
        let req = Probe::<T>::request(self.dev.preambles, self.long(m), command, data);
        let what = if data.is_empty() {
            format!("command {command}")
        } else {
            format!("command {command} with data {}", crate::model::hex(data))
        };
        self.p.exchange(&what, &req, true).await
    }

    /// Reads with `req` and expects a reply: its response code, data and device status.
    pub(crate) async fn read(&mut self, req: &Request) -> Result<(u8, Vec<u8>, u8), Outcome> {
        let ex = self.cmd(req).await;
        Self::replied(req.command(), ex)
    }

    /// [`Runner::read`] with raw request data (see [`Runner::cmd_raw`]).
    pub(crate) async fn read_raw(
        &mut self,
        command: u16,
        data: &[u8],
    ) -> Result<(u8, Vec<u8>, u8), Outcome> {
        let ex = self.cmd_raw(command, data).await;
        Self::replied(command, ex)
    }

    fn replied(command: u16, ex: Exchange) -> Result<(u8, Vec<u8>, u8), Outcome> {
        if let Some(e) = ex.error {
            return Err(cnr(e));
        }
        let Some(f) = ex.reply() else {
            return Err(fail(format!("no reply to command {command}")));
        };
        let rc = f.response_code.unwrap_or(0);
        Ok((rc, f.data.to_vec(), f.device_status.unwrap_or(0)))
    }

    pub(crate) async fn tag(&mut self) -> Option<String> {
        let (rc, data, _) = self.read(&READ_13).await.ok()?;
        if rc != 0 {
            return None;
        }
        let t = decode::<TagDescriptorDate>(&data)?;
        Some(t.tag.with_str(str::to_string))
    }

    /// `None` when the device is HART 6 or later, else the verdict of test `id`, a
    /// HART 6+ rule: not applicable.
    pub(crate) fn needs6(&self, id: &str) -> Option<Outcome> {
        let rev = self.dev.revision;
        (rev < 6).then(|| na(format!("{id} is a HART 6+ rule; the device is HART {rev}")))
    }
}
