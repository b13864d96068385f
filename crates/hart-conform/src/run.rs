//! Running the catalogue against a device.

use hart_host::transport::Transport;
use hart_proto::command::{Empty, Identity};
use hart_proto::frame::{Address, FrameType, MasterKind};
use hart_proto::wire::{Reader, Wire};
use hart_proto::Request;

use crate::catalog::{Needs, Test, TestDef, TESTS};
use crate::model::{DeviceSummary, Group, Report, TestResult};
use crate::probe::{Exchange, Probe};
use crate::runner::{cnr, hex_id, Known, Outcome, Runner};
pub use crate::runner::{DeviceAddress, Options};

/// After this many exchanges in a row without the reply they expected, the device is
/// taken to have stopped answering and the remaining tests are not run.
const SILENT_LIMIT: u32 = 4;

/// Runs the tests of `opts.groups` (except `phy`) against the device on `t`. Never
/// panics on what the device sends; every wait is bounded.
pub async fn run<T: Transport>(t: &mut T, opts: &Options) -> Report {
    let mut p = Probe::new(t);
    let transport = p.describe();
    let mut warnings = vec![];
    // Listen first: traffic of another master means the loop is in use.
    let heard = p.listen(p.char_time * 45, 600_000).await;
    let foreign = heard.iter().filter(|f| {
        f.frame().is_some_and(|fr| {
            fr.frame_type() == FrameType::Stx
                || (fr.frame_type() == FrameType::Ack
                    && fr.address.master() == MasterKind::Secondary)
        })
    });
    if foreign.count() > 0 {
        warnings.push(
            "the loop is in use: another master's requests or replies were heard before the run; \
             tests that write need --allow-writes and should wait for a maintenance window"
                .to_string(),
        );
    }
    let groups: Vec<Group> = if opts.groups.is_empty() {
        vec![Group::Link, Group::Commands, Group::Burst]
    } else {
        opts.groups.clone()
    };
    let selected: Vec<&TestDef> = TESTS
        .iter()
        .filter(|d| groups.contains(&d.group) && d.group != Group::Phy)
        .collect();
    if groups.contains(&Group::Phy) {
        warnings.push(
            "the phy group needs a recording of the device's signal: run `hartkit conform phy FILE.wav`"
                .to_string(),
        );
    }
    let start = p.now();
    let found = identify(&mut p, opts.address).await;
    let ident_evidence = std::mem::take(&mut p.evidence);
    let (dev, mut results) = match found {
        Ok(dev) => (Some(dev), vec![]),
        Err(why) => {
            let results = selected
                .iter()
                .map(|d| {
                    let (verdict, detail) = cnr(why.clone());
                    TestResult::of(d, verdict, detail, ident_evidence.clone(), 0)
                })
                .collect();
            (None, results)
        }
    };
    let mut summary = None;
    if let Some(dev) = dev {
        summary = Some(DeviceSummary {
            unique_id: hex_id(dev.uid),
            polling_address: dev.poll,
            universal_revision: dev.revision,
            expanded_device_type: dev.identity.expanded_device_type,
            device_id: dev.identity.device_id.get(),
            tag: None,
        });
        let mut r = Runner {
            p,
            opts,
            dev,
            stopped: None,
        };
        for d in &selected {
            let t_start = r.p.now();
            let outcome = r.one(d).await;
            let evidence = std::mem::take(&mut r.p.evidence);
            let took = r.p.now().saturating_sub(t_start);
            results.push(TestResult::of(d, outcome.0, outcome.1, evidence, took));
            if r.stopped.is_none() && r.p.silent_streak >= SILENT_LIMIT {
                r.stopped = Some(format!(
                    "the device stopped answering ({} requests in a row got no reply); check its power and wiring",
                    r.p.silent_streak
                ));
            }
        }
        if let Some(s) = &mut summary {
            s.tag = r.tag().await;
        }
        let end = r.p.now();
        return Report {
            target: opts.target.clone(),
            transport,
            device: summary,
            warnings,
            results,
            duration_us: end.saturating_sub(start),
            line_time_us: r.p.line_time,
        };
    }
    let end = p.now();
    Report {
        target: opts.target.clone(),
        transport,
        device: summary,
        warnings,
        results,
        duration_us: end.saturating_sub(start),
        line_time_us: p.line_time,
    }
}

/// Finds the device: command 0 at its polling address or unique ID.
async fn identify<T: Transport>(p: &mut Probe<'_, T>, a: DeviceAddress) -> Result<Known, String> {
    let (address, what) = match a {
        DeviceAddress::Poll(n) => (
            Address::short(n),
            format!("command 0 at polling address {n}"),
        ),
        DeviceAddress::UniqueId(id) => (
            Address::long(id),
            format!("command 0 at unique ID {}", hex_id(id)),
        ),
    };
    let req = Probe::<T>::frame(20, address, &Request::ReadUniqueIdentifier(Empty {}));
    let mut last = Exchange::default();
    for attempt in 1..=3 {
        last = p
            .exchange(&format!("{what} (attempt {attempt})"), &req, true)
            .await;
        if last.reply().is_some() {
            break;
        }
        if last.error.is_some() {
            break;
        }
    }
    if let Some(e) = &last.error {
        return Err(format!("{what}: {e}"));
    }
    let Some(f) = last.reply() else {
        let heard = match last.frames.first() {
            None => "nothing came back".to_string(),
            Some(f) if f.complete && f.frame().is_some() => {
                format!("only other traffic was heard: {}", f.summary())
            }
            Some(f) => format!("only an undecodable answer came back: {}", f.summary()),
        };
        return Err(format!(
            "no device answered {what} in 3 tries ({heard}): check the address (--poll/--unique-id), the port, the modem's power and the loop resistor"
        ));
    };
    if f.response_code.is_some_and(|rc| rc & 0x80 != 0) {
        return Err(format!(
            "{what}: the device answered with a communication error (0x{:02X}); the line is damaging requests (check the modem and the loop)",
            f.response_code.unwrap_or(0)
        ));
    }
    let identity = Identity::decode(&mut Reader::new(f.data)).map_err(|e| {
        format!("{what}: the reply's identity does not decode ({e}); this is no HART device or the line damages replies")
    })?;
    let revision = identity.universal_revision;
    let preambles = usize::from(identity.min_request_preambles).clamp(5, 20);
    Ok(Known {
        uid: identity.unique_id(),
        poll: match a {
            DeviceAddress::Poll(n) => Some(n),
            DeviceAddress::UniqueId(_) => None,
        },
        revision,
        preambles,
        identity,
    })
}

impl<T: Transport> Runner<'_, '_, T> {
    /// Runs test `d`, unless what it needs is missing.
    async fn one(&mut self, d: &TestDef) -> Outcome {
        if let Some(why) = &self.stopped {
            return cnr(why.clone());
        }
        match d.needs {
            Needs::Line if !self.p.timing_visible => {
                return cnr(
                    "the transport (HART-IP) carries whole PDUs and hides the line's characters and timing",
                )
            }
            Needs::Writes if !self.opts.allow_writes => {
                return cnr("this test writes (and restores); run with --allow-writes");
            }
            Needs::Recording => return cnr("needs a recording: hartkit conform phy FILE.wav"),
            _ => {}
        }
        match d.test {
            Test::Link(t) => self.link(t).await,
            Test::Commands(t) => self.commands(t).await,
            Test::Burst(t) => self.burst_test(t).await,
            Test::Phy(_) => cnr("needs a recording: hartkit conform phy FILE.wav"),
        }
    }
}
