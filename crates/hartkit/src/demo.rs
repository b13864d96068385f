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

/// Runs the demo on `port` (normally `sim`).
pub fn run(port: &str, duration: Option<f64>, as_json: bool) -> Result<(), (String, u8)> {
    crate::host::block_on(async move {
        // Opened inside the runtime: serial ports register with its reactor.
        let mut t = hart_host::target::open(port).map_err(|e| (e, 2))?;
        if let AnyTransport::Sim(s) = &mut t {
            s.add_secondary(5_000_000);
        }
        let mut c = Client::new(t);
        let out = &mut std::io::stdout();
        let tty = out.is_terminal() && !as_json;
        // The scan goes on in the background: one polling address per round, between
        // the rounds that read the devices found so far, so the first device shows
        // within a second or two instead of after the whole scan.
        let mut rows: Vec<Row> = vec![];
        let mut next_scan = Some(0u8);
        // Line statistics leave out the scan's empty addresses (they are no failures).
        let base = c.stats();
        let mut scan_cost = hart_link::master::MasterStats::default();
        let start = c.transport().now();
        let end = duration.map(|d| start + (d * 1e6) as u64);
        let stop = tokio::signal::ctrl_c();
        tokio::pin!(stop);
        loop {
            // A device just found is shown at once; its values come with the next round.
            let mut known = rows.len();
            if let Some(poll) = next_scan {
                let before = c.stats();
                let found = tokio::select! {
                    r = c.scan(poll..=poll, |_| {}) => r.map_err(|e| (e.to_string(), e.exit_code()))?,
                    _ = &mut stop => return Ok(()),
                };
                let after = c.stats();
                scan_cost.completed += after.completed - before.completed;
                scan_cost.failed += after.failed - before.failed;
                scan_cost.retries += after.retries - before.retries;
                known = rows.len();
                rows.extend(found.into_iter().map(|info| Row {
                    info,
                    pv: None,
                    current: None,
                    status: 0,
                    bursts: 0,
                    last_burst: None,
                    error: None,
                }));
                next_scan = (poll < SCAN_TO).then_some(poll + 1);
            }
            for row in rows.iter_mut().take(known) {
                let info = row.info.clone();
                let r = tokio::select! {
                    r = c.command(&info, 3, &[]) => r,
                    _ = &mut stop => return Ok(()),
                };
                match r {
                    Ok(r) => {
                        row.status = r.device_status;
                        row.error = None;
                        if let Ok(d) =
                            ReadDynamicVariablesResponse::decode(&mut Reader::new(&r.data))
                        {
                            row.current = Some(d.loop_current.0);
                            row.pv = d.variables.as_slice().first().map(|v| (v.value, v.units.0));
                        }
                    }
                    Err(e) => row.error = Some(e.to_string()),
                }
            }
            // Burst frames heard meanwhile, per device.
            let mut by_id: HashMap<hart_proto::UniqueId, (u64, Option<(f32, u8)>)> = HashMap::new();
            for pdu in c.take_bursts() {
                if let Ok(f) = Frame::parse_pdu(&pdu) {
                    if let Address::Long(a) = f.address {
                        let e = by_id.entry(a.id).or_default();
                        e.0 += 1;
                        if f.command == 3 && f.data.len() >= 9 {
                            e.1 = Some((
                                f32::from_be_bytes([f.data[5], f.data[6], f.data[7], f.data[8]]),
                                f.data[4],
                            ));
                        }
                    }
                }
            }
            for row in &mut rows {
                if let Some((n, last)) = by_id.get(&row.info.unique_id()) {
                    row.bursts += n;
                    if last.is_some() {
                        row.last_burst = *last;
                    }
                }
            }
            let now = c.transport().now();
            let mut st = c.stats();
            st.completed -= (base.completed + scan_cost.completed).min(st.completed);
            st.failed -= (base.failed + scan_cost.failed).min(st.failed);
            st.retries -= (base.retries + scan_cost.retries).min(st.retries);
            let secondary = match c.transport() {
                AnyTransport::Sim(s) => s.secondary_transactions(),
                _ => 0,
            };
            let t_s = (now - start) as f64 / 1e6;
            if as_json {
                let devices: Vec<_> = rows
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
                            "status": status_words(r.status),
                            "bursts": r.bursts,
                            "error": r.error,
                        })
                    })
                    .collect();
                let _ = writeln!(
                    out,
                    "{}",
                    json!({"t_s": t_s, "scanning": next_scan, "devices": devices, "line": {"transactions": st.completed, "failed": st.failed, "retries": st.retries, "bursts_received": st.bursts, "secondary_transactions": secondary}})
                );
            } else {
                let mut s = String::new();
                if tty {
                    s.push_str("\x1b[H\x1b[2J");
                }
                s.push_str(&format!(
                    "hartkit demo: {} — {:.0} s (Ctrl-C to stop)\n{}\n",
                    c.transport().describe(),
                    t_s,
                    match next_scan {
                        Some(p) => format!("scanning polling addresses 0-{SCAN_TO}: next {p}"),
                        None => format!("scanned polling addresses 0-{SCAN_TO}"),
                    }
                ));
                s.push_str(&format!(
                    "{:>4}  {:<8}  {:>14}  {:>9}  {:>7}  {:<30}\n",
                    "poll", "tag", "PV", "loop mA", "bursts", "status"
                ));
                for r in &rows {
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
            if end.is_some_and(|e| now >= e) {
                return Ok(());
            }
        }
    })
}
