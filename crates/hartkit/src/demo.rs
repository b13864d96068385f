//! `hartkit demo`: a simulated plant, found by scan and shown live.
//!
//! The plant: an FSK multidrop loop with a pressure transmitter (polling address 1), a
//! temperature transmitter publishing burst messages (2), a valve positioner (3) and a
//! second pressure transmitter above the HART 5 range (17); a secondary master reads
//! now and then. hartkit acts as the primary master.

use std::collections::HashMap;
use std::io::{IsTerminal, Write};

use hart_host::target::AnyTransport;
use hart_host::transport::Transport;
use hart_host::{Client, DeviceInfo};
use hart_proto::command::ReadDynamicVariablesResponse;
use hart_proto::frame::{Address, Frame};
use hart_proto::tables;
use hart_proto::wire::{Reader, Wire};
use serde_json::json;

struct Row {
    info: DeviceInfo,
    pv: Option<(f32, u8)>,
    current: Option<f32>,
    status: u8,
    bursts: u64,
    last_burst: Option<(f32, u8)>,
    error: Option<String>,
}

fn status_words(s: u8) -> String {
    if s & 0xCF == 0 {
        return "ok".into();
    }
    tables::FIELD_DEVICE_STATUS
        .set_bits(s & 0xCF)
        .map(|b| b.key.replace('_', " "))
        .collect::<Vec<_>>()
        .join(", ")
}

fn symbol(u: u8) -> &'static str {
    tables::unit(u).map_or("?", |u| u.symbol)
}

/// Polling addresses the demo scans: 0 up to this.
const SCAN_TO: u8 = 20;

/// What the demo knows, and how it shows it.
struct View {
    rows: Vec<Row>,
    /// The next polling address to scan, while the scan goes on.
    next_scan: Option<u8>,
    /// Line statistics at the start, and the scan's share (its empty addresses are no
    /// failures).
    base: hart_link::master::MasterStats,
    scan_cost: hart_link::master::MasterStats,
    start: u64,
    as_json: bool,
    tty: bool,
}

impl View {
    /// Takes the burst frames heard since the last call, per device.
    fn take_bursts(&mut self, c: &mut Client<AnyTransport>) {
        let mut by_id: HashMap<hart_proto::UniqueId, (u64, Option<(f32, u8)>)> = HashMap::new();
        for pdu in c.take_bursts() {
            if let Ok(f) = Frame::parse_pdu(&pdu) {
                if let Address::Long(a) = f.address {
                    let e = by_id.entry(a.id).or_default();
                    e.0 += 1;
                    if f.command == 3 {
                        // The PV and its units, from the published command 3 reply.
                        let pv = ReadDynamicVariablesResponse::decode(&mut Reader::new(f.data))
                            .ok()
                            .and_then(|r| r.variables.as_slice().first().copied());
                        if let Some(pv) = pv {
                            e.1 = Some((pv.value, pv.units.0));
                        }
                    }
                }
            }
        }
        for row in &mut self.rows {
            if let Some((n, last)) = by_id.get(&row.info.unique_id()) {
                row.bursts += n;
                if last.is_some() {
                    row.last_burst = *last;
                }
            }
        }
    }

    /// Shows what is known now: one JSON object, or the table.
    fn show(&self, c: &Client<AnyTransport>, out: &mut impl Write) {
        let now = c.transport().now();
        let mut st = c.stats();
        let (base, scan) = (&self.base, &self.scan_cost);
        st.completed -= (base.completed + scan.completed).min(st.completed);
        st.failed -= (base.failed + scan.failed).min(st.failed);
        st.retries -= (base.retries + scan.retries).min(st.retries);
        let secondary = match c.transport() {
            AnyTransport::Sim(s) => s.secondary_transactions(),
            _ => 0,
        };
        let t_s = (now - self.start) as f64 / 1e6;
        if self.as_json {
            let devices: Vec<_> = self
                .rows
                .iter()
                .map(|r| {
                    json!({
                        "polling_address": r.info.polling_address,
                        "unique_id": r.info.unique_id().to_string(),
                        "tag": r.info.tag,
                        "pv": r.pv.map(|p| crate::json::float(p.0)),
                        "units": r.pv.map(|p| p.1),
                        "units_symbol": r.pv.map(|p| symbol(p.1)),
                        "loop_current": r.current.map(crate::json::float),
                        "device_status": r.status,
                        "device_status_set": crate::json::device_status_set(r.status),
                        "bursts": r.bursts,
                        "error": r.error,
                    })
                })
                .collect();
            let _ = writeln!(
                out,
                "{}",
                json!({"t_s": t_s, "scanning": self.next_scan, "devices": devices, "line": {"transactions": st.completed, "failed": st.failed, "retries": st.retries, "bursts_received": st.bursts, "secondary_transactions": secondary}})
            );
            let _ = out.flush();
            return;
        }
        let mut s = String::new();
        if self.tty {
            s.push_str("\x1b[H\x1b[2J");
        }
        s.push_str(&format!(
            "hartkit demo: {} — {:.0} s (Ctrl-C to stop)\n{}\n",
            c.transport().describe(),
            t_s,
            match self.next_scan {
                Some(p) => format!("scanning polling addresses 0-{SCAN_TO}: next {p}"),
                None => format!("scanned polling addresses 0-{SCAN_TO}"),
            }
        ));
        s.push_str(&format!(
            "{:>4}  {:<8}  {:>14}  {:>9}  {:>7}  {:<30}\n",
            "poll", "tag", "PV", "loop mA", "bursts", "status"
        ));
        for r in &self.rows {
            let pv = match (r.pv, r.last_burst) {
                (Some((v, u)), _) => format!("{v:>9.3} {:<4}", symbol(u)),
                _ => "-".into(),
            };
            let cur = r.current.map_or("-".into(), |c| format!("{c:.3}"));
            let status = r.error.clone().unwrap_or_else(|| status_words(r.status));
            s.push_str(&format!(
                "{:>4}  {:<8}  {:>14}  {:>9}  {:>7}  {:<30}\n",
                r.info.polling_address.unwrap_or(0),
                r.info.tag.as_deref().unwrap_or(""),
                pv,
                cur,
                r.bursts,
                status
            ));
        }
        s.push_str(&format!(
            "\nline: {} transactions, {} failed, {} retries, {} burst frames heard; secondary master {} transactions\n",
            st.completed, st.failed, st.retries, st.bursts, secondary
        ));
        let _ = write!(out, "{s}");
        let _ = out.flush();
    }
}

/// Runs the demo on `port` (normally `sim`).
///
/// The scan goes on in the background, one polling address at a time between rounds
/// that read the devices found so far; a device found is read at once, and every new
/// fact (a device found, a value, a status, a failure) is shown as soon as its reply
/// is in, not on a cadence.
pub fn run(port: &str, duration: Option<f64>, as_json: bool) -> Result<(), (String, u8)> {
    crate::host::block_on(async move {
        // Opened inside the runtime: serial ports register with its reactor.
        let mut t = hart_host::target::open(port).map_err(|e| (e, 2))?;
        if let AnyTransport::Sim(s) = &mut t {
            s.add_secondary(5_000_000);
        }
        let mut c = Client::new(t);
        let out = &mut std::io::stdout();
        let mut view = View {
            rows: vec![],
            next_scan: Some(0),
            base: c.stats(),
            scan_cost: Default::default(),
            start: c.transport().now(),
            as_json,
            tty: out.is_terminal() && !as_json,
        };
        let end = duration.map(|d| view.start + (d * 1e6) as u64);
        let over = |c: &Client<AnyTransport>| end.is_some_and(|e| c.transport().now() >= e);
        let stop = tokio::signal::ctrl_c();
        tokio::pin!(stop);
        loop {
            // Devices found (and read) by this round's scan step: the round leaves them.
            let mut just_read = 0..0;
            if let Some(poll) = view.next_scan {
                // One address of the scan: command 0 with one retry (an empty address
                // costs two slave time-outs, not four). A device found is shown at once,
                // read at once, and its tags read after its first value.
                let before = c.stats();
                let normal = hart_link::master::RetryPolicy::default();
                c.set_policy(hart_link::master::RetryPolicy {
                    retries: 1,
                    ..normal
                });
                let r = tokio::select! {
                    r = c.identify(poll) => r,
                    _ = &mut stop => return Ok(()),
                };
                c.set_policy(normal);
                let after = c.stats();
                view.scan_cost.completed += after.completed - before.completed;
                view.scan_cost.failed += after.failed - before.failed;
                view.scan_cost.retries += after.retries - before.retries;
                view.next_scan = (poll < SCAN_TO).then_some(poll + 1);
                let mut found = match r {
                    Ok(info) => vec![info],
                    Err(e) if e.exit_code() == 5 => return Err((e.to_string(), 5)),
                    Err(_) => vec![],
                };
                if let Some(io) = found
                    .first()
                    .filter(|i| i.is_io_system())
                    .map(|i| i.unique_id())
                {
                    let known: Vec<_> = view.rows.iter().map(|r| r.info.unique_id()).collect();
                    found.extend(c.sub_devices(io, &known).await);
                }
                let first_new = view.rows.len();
                view.rows.extend(found.into_iter().map(|info| Row {
                    info,
                    pv: None,
                    current: None,
                    status: 0,
                    bursts: 0,
                    last_burst: None,
                    error: None,
                }));
                view.take_bursts(&mut c);
                if first_new < view.rows.len() || view.rows.is_empty() {
                    view.show(&c, out);
                }
                for i in first_new..view.rows.len() {
                    tokio::select! {
                        _ = read(&mut c, &mut view.rows[i]) => {},
                        _ = &mut stop => return Ok(()),
                    }
                    view.take_bursts(&mut c);
                    view.show(&c, out);
                    let mut info = view.rows[i].info.clone();
                    tokio::select! {
                        _ = c.read_tags(&mut info) => {},
                        _ = &mut stop => return Ok(()),
                    }
                    view.rows[i].info = info;
                    view.take_bursts(&mut c);
                    view.show(&c, out);
                }
                if over(&c) {
                    return Ok(());
                }
                just_read = first_new..view.rows.len();
            }
            for i in (0..view.rows.len()).filter(|i| !just_read.contains(i)) {
                tokio::select! {
                    _ = read(&mut c, &mut view.rows[i]) => {},
                    _ = &mut stop => return Ok(()),
                }
                view.take_bursts(&mut c);
                view.show(&c, out);
                if over(&c) {
                    return Ok(());
                }
            }
        }
    })
}

/// Reads a device's dynamic variables (command 3) into its row.
async fn read(c: &mut Client<AnyTransport>, row: &mut Row) {
    match c.command(&row.info, 3, &[]).await {
        Ok(r) => {
            row.status = r.device_status;
            row.error = None;
            if let Ok(d) = ReadDynamicVariablesResponse::decode(&mut Reader::new(&r.data)) {
                row.current = Some(d.loop_current.0);
                row.pv = d.variables.as_slice().first().map(|v| (v.value, v.units.0));
            }
        }
        Err(e) => row.error = Some(e.to_string()),
    }
}
