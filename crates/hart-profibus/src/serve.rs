//! The gateway's PROFIBUS DP front end: the polling engine's devices as modules of one
//! or more DP slave stations on a serial line (RS-485 adapter or pseudo-terminal),
//! 8E1 at the line's bit rate, set up by `hart-serial`.
//!
//! [`Front`] is the part without I/O: stations, their inputs from the image, their
//! outputs turned into writes. [`serve`] reads and writes the port around it.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use hart_poller::{Engine, WriteFailure, WriteOp};

use crate::map::{self, Outputs, WriteResult, WriteState, DEVICES_PER_STATION, OUTPUT_LEN};
use crate::{Event, Slave, SlaveConfig};

/// The default ident number of the gateway's stations (not assigned by PROFIBUS
/// International: "HT").
pub const DEFAULT_IDENT_NUMBER: u16 = 0x4854;

/// Serial settings and station of the PROFIBUS front end.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProfibusPort {
    /// Device path (`/dev/ttyUSB0`, a pseudo-terminal).
    pub path: String,
    /// Station address of the first 8 devices; further devices take the next
    /// addresses.
    pub address: u8,
    /// Bit rate: 9600, 19200, 45450 or 93750.
    pub baud: u32,
    /// Ident number (the GSD's).
    pub ident_number: u16,
}

impl ProfibusPort {
    /// Checks the settings: a rate the slave supports, addresses in 0..=125 for
    /// `devices` devices.
    pub fn check(&self, devices: usize) -> Result<(), String> {
        if crate::max_tsdr_bits(self.baud).is_none() {
            return Err(format!(
                "--profibus-baud {}: give 9600, 19200, 45450 or 93750",
                self.baud
            ));
        }
        let stations = devices.div_ceil(DEVICES_PER_STATION).max(1);
        let last = usize::from(self.address) + stations - 1;
        if last > 125 {
            return Err(format!(
                "--profibus-address {}: {devices} devices need {stations} stations, up to address {last}, but DP slaves end at 125",
                self.address
            ));
        }
        Ok(())
    }
}

/// A write an output module asks for.
#[derive(Debug, Clone, PartialEq)]
pub struct WriteRequest {
    /// The device's position in the image.
    pub position: usize,
    /// The write counter that asked.
    pub counter: u8,
    /// What to write.
    pub op: WriteOp,
    /// The master that wrote the output image.
    pub master: Option<u8>,
    /// The station whose outputs asked (its master's watchdog ends the loop test).
    pub station: u8,
}

struct Station {
    slave: Slave,
    first: usize,
    count: usize,
    /// Set when data exchange begins: the Data_Exchange count then. The first output
    /// image after it sets the write counters' baseline without writing.
    baseline_after: Option<u64>,
}

/// What [`Front::poll`] gives.
#[derive(Debug, Default)]
pub struct Polled {
    /// Bytes to send now.
    pub reply: Option<Vec<u8>>,
    /// Writes the new outputs ask for.
    pub writes: Vec<WriteRequest>,
    /// What to log: `true` for a fault (a warning).
    pub log: Vec<(bool, String)>,
    /// Stations whose master's watchdog expired (their outputs cleared): the loop
    /// tests their modules started are released ([`holder`]).
    pub watchdog_expired: Vec<u8>,
}

/// The holder of the loop tests station `address`'s outputs start: the engine
/// releases them when the master's watchdog on that station expires.
pub fn holder(address: u8) -> String {
    format!("profibus station {address}")
}

/// The stations of the front end, without I/O: feed it the line's bytes, the image,
/// and the results of writes.
pub struct Front {
    stations: Vec<Station>,
    start: Instant,
    /// Per device: the write counter last seen (`None` before the first output image).
    counters: Vec<Option<u8>>,
    writes: Arc<Mutex<Vec<WriteState>>>,
}

impl Front {
    /// Stations for `devices` devices from `port.address` on; `start` is time zero.
    pub fn new(port: &ProfibusPort, devices: usize, start: Instant) -> Result<Front, String> {
        port.check(devices)?;
        let max_tsdr = crate::max_tsdr_bits(port.baud).unwrap_or(60);
        let stations = devices.div_ceil(DEVICES_PER_STATION).max(1);
        let mut out = vec![];
        for s in 0..stations {
            let first = s * DEVICES_PER_STATION;
            let count = devices.saturating_sub(first).min(DEVICES_PER_STATION);
            let slave = Slave::new(SlaveConfig {
                address: port.address + s as u8,
                ident_number: port.ident_number,
                cfg: map::station_cfg(count),
                baud: port.baud,
                max_tsdr_bits: max_tsdr,
                user_prm_len: 0,
            })
            .map_err(|e| e.to_string())?;
            let mut slave = slave;
            slave.set_partial_timeout(PARTIAL_TIMEOUT);
            out.push(Station {
                slave,
                first,
                count,
                baseline_after: None,
            });
        }
        Ok(Front {
            stations: out,
            start,
            counters: vec![None; devices],
            writes: Arc::new(Mutex::new(vec![WriteState::default(); devices])),
        })
    }

    /// The write states, shared with the tasks that carry writes out.
    pub fn write_states(&self) -> Arc<Mutex<Vec<WriteState>>> {
        self.writes.clone()
    }

    /// The slaves, first station first.
    pub fn slaves(&self) -> impl Iterator<Item = &Slave> {
        self.stations.iter().map(|s| &s.slave)
    }

    fn t(&self, at: Instant) -> Duration {
        at.saturating_duration_since(self.start)
    }

    /// Takes bytes read at `at`.
    pub fn receive(&mut self, at: Instant, bytes: &[u8]) {
        let t = self.t(at);
        for s in &mut self.stations {
            s.slave.receive(t, bytes);
        }
    }

    /// When a station next needs [`Front::poll`].
    pub fn deadline(&self) -> Option<Instant> {
        self.stations
            .iter()
            .filter_map(|s| s.slave.deadline())
            .min()
            .map(|d| self.start + d)
    }

    /// Runs the stations' timers at `now`: the bytes to send now (at most one reply
    /// is due at a time on a bus), the writes the outputs ask for, and what to log.
    pub fn poll(&mut self, now: Instant) -> Polled {
        let t = self.t(now);
        let mut reply = None;
        let mut writes = vec![];
        let mut log = vec![];
        let mut watchdog_expired = vec![];
        for i in 0..self.stations.len() {
            if let Some(r) = self.stations[i].slave.poll_transmit(t) {
                reply = Some(r);
            }
            let events = self.stations[i].slave.take_events();
            let address = self.stations[i].slave.config().address;
            for e in events {
                match e {
                    Event::Outputs => writes.extend(self.outputs(i)),
                    Event::Configured { .. } => {
                        let s = &mut self.stations[i];
                        s.baseline_after = Some(s.slave.stats().data_exchanges);
                        log.push((false, format!("station {address}: {e}")));
                    }
                    e => {
                        if matches!(e, Event::WatchdogExpired { .. }) {
                            watchdog_expired.push(address);
                        }
                        let fault = matches!(
                            e,
                            Event::ParameterFault { .. }
                                | Event::ConfigurationFault { .. }
                                | Event::WatchdogExpired { .. }
                        );
                        log.push((fault, format!("station {address}: {e}")));
                    }
                }
            }
            // The first output image of a data exchange (the master's after it
            // configured the station, or after a restart of either): what it holds is
            // not a request, whatever its counters.
            let s = &mut self.stations[i];
            if s.baseline_after
                .is_some_and(|n| s.slave.stats().data_exchanges > n)
            {
                s.baseline_after = None;
                let (first, count) = (s.first, s.count);
                let bytes = s.slave.outputs().to_vec();
                for slot in 0..count {
                    let module = bytes.get(slot * OUTPUT_LEN..(slot + 1) * OUTPUT_LEN);
                    self.counters[first + slot] =
                        Some(module.map_or(0, |m| map::decode_outputs(m).counter));
                }
            }
        }
        Polled {
            reply,
            writes,
            log,
            watchdog_expired,
        }
    }

    /// The writes station `i`'s new outputs ask for: a module whose counter changed
    /// to a value other than 0. The first output image of a data exchange only sets
    /// what "changed" means.
    fn outputs(&mut self, i: usize) -> Vec<WriteRequest> {
        let s = &self.stations[i];
        if s.baseline_after.is_some() {
            return vec![];
        }
        let master = s.slave.master();
        let bytes = s.slave.outputs().to_vec();
        let mut out = vec![];
        for slot in 0..s.count {
            let position = s.first + slot;
            let Some(module) = bytes.get(slot * OUTPUT_LEN..(slot + 1) * OUTPUT_LEN) else {
                continue;
            };
            let Outputs {
                counter,
                fixed_current,
            } = map::decode_outputs(module);
            let last = self.counters[position].replace(counter);
            if counter == 0 || last.is_none_or(|l| l == counter) {
                continue;
            }
            out.push(WriteRequest {
                position,
                counter,
                op: WriteOp::FixedCurrent(fixed_current),
                master,
                station: s.slave.config().address,
            });
        }
        out
    }

    /// Sets every station's inputs and device diagnosis from the image at `now`.
    pub fn refresh(&mut self, image: &[hart_poller::DeviceImage], now: Instant) {
        let writes = self.writes.lock().map(|w| w.clone()).unwrap_or_default();
        for s in &mut self.stations {
            let mut inputs = Vec::with_capacity(s.count * map::INPUT_LEN);
            let mut diag = vec![0u8; s.count.div_ceil(8)];
            for slot in 0..s.count {
                let position = s.first + slot;
                let module = match image.get(position) {
                    Some(d) => {
                        if d.quality(now) == hart_poller::Quality::NoReply {
                            diag[slot / 8] |= 1 << (slot % 8);
                        }
                        map::encode_inputs(
                            d,
                            now,
                            writes.get(position).copied().unwrap_or_default(),
                        )
                    }
                    None => {
                        diag[slot / 8] |= 1 << (slot % 8);
                        map::absent_inputs()
                    }
                };
                inputs.extend_from_slice(&module);
            }
            s.slave.set_inputs(&inputs);
            s.slave.set_unit_diag(&diag);
        }
    }
}

/// The result code a write's outcome shows in the input module.
pub fn result_of(r: &Result<(), WriteFailure>) -> WriteResult {
    match r {
        Ok(()) => WriteResult::Done,
        Err(WriteFailure::NotPermitted(_)) => WriteResult::Refused,
        Err(WriteFailure::Invalid(_)) => WriteResult::Invalid,
        Err(WriteFailure::NotReadYet(_)) | Err(WriteFailure::Link(_)) => WriteResult::NoReply,
        Err(WriteFailure::Refused { .. }) => WriteResult::DeviceRefused,
    }
}

/// Carries out `w` through the engine's write path (allow-list, read only, audit) and
/// records its result for the input module.
pub async fn carry_out(
    engine: Engine,
    states: Arc<Mutex<Vec<WriteState>>>,
    path: String,
    w: WriteRequest,
) {
    let set = |result| {
        if let Ok(mut s) = states.lock() {
            if let Some(x) = s.get_mut(w.position) {
                *x = WriteState {
                    counter: w.counter,
                    result,
                };
            }
        }
    };
    set(WriteResult::Busy);
    let origin = hart_access::WriteRecord {
        front_end: "profibus",
        peer: match w.master {
            Some(m) => format!("master {m} on {path}"),
            None => format!("serial {path}"),
        },
        via: format!(
            "output module {} (write counter {})",
            w.position % DEVICES_PER_STATION + 1,
            w.counter
        ),
        ..Default::default()
    };
    // A loop test lasts while the master keeps the station in data exchange: its
    // watchdog expiring releases it (as well as the gateway's limit and stop).
    let lease = hart_poller::LeaseTerms {
        limit: None,
        holder: Some(holder(w.station)),
        by: format!("profibus {}", origin.peer),
    };
    let r = engine
        .apply_with(w.position, &w.op, &origin, lease)
        .await
        .map(|_| ());
    if let Err(e) = &r {
        tracing::warn!(
            "profibus: write to device {} ({}) not done: {e}",
            w.position,
            w.op.describe()
        );
    }
    set(result_of(&r));
}

/// How long a telegram begun may wait for its next bytes on a host (USB adapters hand
/// bytes over in bursts, every 16 ms for an FTDI chip by default).
pub const PARTIAL_TIMEOUT: Duration = Duration::from_millis(50);

/// How often the inputs are refreshed from the image.
pub const REFRESH: Duration = Duration::from_millis(100);

/// Serves PROFIBUS DP on `port` for as long as the gateway runs, opening the port
/// again (after 2 s, doubling to 30 s) when it fails.
pub async fn serve_forever(engine: Engine, port: ProfibusPort) {
    let mut backoff =
        hart_host::reconnect::Backoff::new(Duration::from_secs(2), Duration::from_secs(30));
    loop {
        let started = Instant::now();
        let task = tokio::spawn(serve(engine.clone(), port.clone()));
        let outcome = task.await;
        if started.elapsed() > Duration::from_secs(60) {
            backoff.reset();
        }
        match outcome {
            Ok(Ok(())) => tracing::warn!("profibus: {} closed", port.path),
            Ok(Err(e)) => tracing::error!("profibus: {e}"),
            Err(e) if e.is_panic() => {
                tracing::error!("profibus: {}: the slave failed (a bug)", port.path)
            }
            Err(_) => return,
        }
        let wait = backoff.failed(Instant::now());
        tracing::info!(
            "profibus: opening {} again in {} s",
            port.path,
            wait.as_secs()
        );
        tokio::time::sleep(wait).await;
    }
}

/// The line of `port`: 8E1 at its rate.
pub fn line(port: &ProfibusPort) -> hart_serial::Line {
    hart_serial::Line::even(port.baud)
}

/// Opens `port` and serves until it fails (an error that says how).
pub async fn serve(engine: Engine, port: ProfibusPort) -> std::io::Result<()> {
    // The stations' modules are the devices the loops list once they are ready (the
    // configured ones and those the first scan found).
    engine.ready().await;
    let devices = engine.image().len();
    let mut front = Front::new(&port, devices, Instant::now()).map_err(std::io::Error::other)?;
    let serial = hart_serial::Port::open(
        std::path::Path::new(&port.path),
        &line(&port),
        hart_serial::OpenOptions {
            exclusive: true,
            mark_errors: false,
        },
    )
    .map_err(|e| std::io::Error::new(e.kind(), format!("--profibus {}: {e}", port.path)))?;
    let writer = serial.try_clone()?;
    let mut reader = hart_serial::aio::Reader::spawn(serial);
    let states = front.write_states();
    let mut next_refresh = Instant::now();
    loop {
        let now = Instant::now();
        if now >= next_refresh {
            let clock_now = engine.clock().now();
            front.refresh(&engine.image().snapshot(), clock_now);
            next_refresh = now + REFRESH;
        }
        let Polled {
            reply,
            writes,
            log,
            watchdog_expired,
        } = front.poll(Instant::now());
        for station in watchdog_expired {
            engine.release_held_by(&holder(station));
        }
        if let Some(reply) = reply {
            writer.write_all_async(&reply).await?;
        }
        for (fault, line) in log {
            if fault {
                tracing::warn!("profibus: {line}");
            } else {
                tracing::info!("profibus: {line}");
            }
        }
        for w in writes {
            tokio::spawn(carry_out(
                engine.clone(),
                states.clone(),
                port.path.clone(),
                w,
            ));
        }
        let wake = front
            .deadline()
            .map_or(next_refresh, |d| d.min(next_refresh));
        tokio::select! {
            biased;
            r = reader.recv() => {
                let (bytes, at) = r?;
                front.receive(at, &bytes);
                while let Some(r) = reader.try_recv() {
                    let (bytes, at) = r?;
                    front.receive(at, &bytes);
                }
            }
            _ = tokio::time::sleep_until(tokio::time::Instant::from_std(wake)) => {}
        }
    }
}

/// The map as text for the devices of `image` from station `address` on.
pub fn map_text(address: u8, image: &[hart_poller::DeviceImage]) -> String {
    let names: Vec<String> = image.iter().map(|d| d.display_name()).collect();
    map::map_text(address, &names)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fdl::{encode, DataTelegram, FunctionCode, Request};

    fn port() -> ProfibusPort {
        ProfibusPort {
            path: "/dev/null".into(),
            address: 5,
            baud: 19_200,
            ident_number: DEFAULT_IDENT_NUMBER,
        }
    }

    fn request(da: u8, sap: Option<u8>, fcb: bool, data: &[u8]) -> Vec<u8> {
        let mut out = vec![];
        encode(
            &DataTelegram {
                da,
                sa: 2,
                dsap: sap,
                ssap: sap.map(|_| 62),
                fc: FunctionCode::Request {
                    request: Request::SrdHigh,
                    fcb,
                    fcv: true,
                },
                data,
            },
            &mut out,
        )
        .unwrap();
        out
    }

    /// Sends `bytes` and returns what the front end does 1 ms later.
    fn send(f: &mut Front, t: &mut Instant, bytes: &[u8]) -> Polled {
        *t += Duration::from_millis(20);
        f.receive(*t, bytes);
        f.poll(*t + Duration::from_millis(1))
    }

    fn outputs(modules: &[(u8, f32)]) -> Vec<u8> {
        modules
            .iter()
            .flat_map(|(c, current)| {
                let mut m = vec![*c, 0];
                m.extend_from_slice(&current.to_be_bytes());
                m
            })
            .collect()
    }

    #[test]
    fn ten_devices_are_two_stations_and_counters_write_once() {
        let mut t = Instant::now();
        let mut f = Front::new(&port(), 10, t).unwrap();
        let cfg: Vec<_> = f.slaves().map(|s| s.config().cfg.len()).collect();
        assert_eq!(cfg, [16, 4], "8 modules at 5, 2 at 6");
        let prm = [0x80, 0, 0, 11, 0x48, 0x54, 0];
        // Station 6: parameters, configuration, then data exchange.
        assert_eq!(
            send(&mut f, &mut t, &request(6, Some(61), true, &prm)).reply,
            Some(vec![0xE5])
        );
        let chk = map::station_cfg(2);
        let p = send(&mut f, &mut t, &request(6, Some(62), false, &chk));
        assert!(
            p.log
                .iter()
                .any(|(_, l)| l.contains("station 6: configuration")),
            "{:?}",
            p.log
        );
        // The first image sets the baseline: counter 3 is not a request.
        let p = send(
            &mut f,
            &mut t,
            &request(6, None, true, &outputs(&[(3, 12.0), (0, 0.0)])),
        );
        assert!(p.writes.is_empty());
        assert_eq!(p.reply.unwrap().len(), 56 + 9);
        // The same image again: nothing; counter 4: one write to device 8.
        let p = send(
            &mut f,
            &mut t,
            &request(6, None, false, &outputs(&[(3, 12.0), (0, 0.0)])),
        );
        assert!(p.writes.is_empty());
        let p = send(
            &mut f,
            &mut t,
            &request(6, None, true, &outputs(&[(4, 12.0), (0, 0.0)])),
        );
        assert_eq!(
            p.writes,
            [WriteRequest {
                position: 8,
                counter: 4,
                op: WriteOp::FixedCurrent(12.0),
                master: Some(2),
                station: 6,
            }]
        );
        // Repeated (same FCB): the reply again, no second write.
        let p = send(
            &mut f,
            &mut t,
            &request(6, None, true, &outputs(&[(4, 12.0), (0, 0.0)])),
        );
        assert!(p.writes.is_empty() && p.reply.is_some());
        // Counter back to 0: nothing; device 9's counter: a write of 0 mA (release).
        let p = send(
            &mut f,
            &mut t,
            &request(6, None, false, &outputs(&[(0, 0.0), (1, 0.0)])),
        );
        assert_eq!(p.writes.len(), 1);
        assert_eq!(p.writes[0].position, 9);
        assert_eq!(p.writes[0].op, WriteOp::FixedCurrent(0.0));
    }

    #[test]
    fn inputs_and_diagnosis_come_from_the_image() {
        let t = Instant::now();
        let mut f = Front::new(&port(), 2, t).unwrap();
        let mut answered = hart_poller::DeviceImage::new(0, 0, "loop1", Duration::from_secs(10));
        answered.apply_reply(
            3,
            0,
            0,
            &[0x41, 0x40, 0, 0, 12, 0x42, 0x48, 0, 0],
            t,
            std::time::SystemTime::now(),
        );
        let mut silent = hart_poller::DeviceImage::new(1, 0, "loop1", Duration::from_secs(10));
        silent.no_reply();
        f.write_states().lock().unwrap()[0] = WriteState {
            counter: 9,
            result: WriteResult::Done,
        };
        f.refresh(&[answered, silent], t);
        let s = f.slaves().next().unwrap();
        let i = s.inputs();
        assert_eq!(&i[0..4], &50f32.to_be_bytes());
        assert_eq!((i[26], i[27]), (9, 2));
        assert_eq!(i[28 + 23], 2, "no reply");
        let d = s.diagnosis(Some(2));
        assert_eq!(&d[6..], &[0x02, 0b10], "device-related block: module 2");
        assert!(Front::new(
            &ProfibusPort {
                address: 125,
                ..port()
            },
            9,
            t
        )
        .is_err());
    }
}
