//! The roles in real time, on any `hart_host::Transport` (a serial port, RS-485, a
//! pseudo-terminal): the sans-IO cores with the bytes moved and the time read from a
//! [`Clock`].

use std::io;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use hart_host::transport::Transport;
use tracing::{info, warn};

use crate::archive::{Archive, CalibrationSender, Collector, PullLog, Step, TransferError};
use crate::calibration::Sensor;
use crate::concentrator::Concentrator;
use crate::handheld::HandheldStation;
use crate::proto::{Message, Received, Receiver, Station, StationStatus, DIAGNOSTICS};
use crate::sensor::SimSensor;
use crate::Millis;

/// The time the roles see: the system clock (UTC), or with `speed` above 1 a clock
/// that runs `speed` times as fast from the start of the current UTC day (for
/// demonstrations and tests): roles started separately, and a role restarted, agree
/// on the time as long as they have the same speed.
#[derive(Debug, Clone, Copy)]
pub struct Clock {
    start: Instant,
    start_ms: Millis,
    speed: f64,
}

impl Clock {
    /// The system clock, `speed` times as fast (1 for real time).
    pub fn new(speed: f64) -> Self {
        let real = hart_clock::epoch::millis(SystemTime::now()) as Millis;
        let speed = if speed.is_finite() && speed > 0.0 {
            speed
        } else {
            1.0
        };
        let day = real - real % 86_400_000;
        let start_ms = day + ((real - day) as f64 * speed) as Millis;
        Clock {
            start: Instant::now(),
            start_ms,
            speed,
        }
    }

    /// Now, ms since the Unix epoch. At speed 1 the system clock itself, read each
    /// time, so a correction of the system clock is followed at once.
    pub fn now(&self) -> Millis {
        if self.speed == 1.0 {
            return SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map_or(0, |d| d.as_millis() as Millis);
        }
        self.start_ms + (self.start.elapsed().as_secs_f64() * 1000.0 * self.speed) as Millis
    }

    /// Real time until the clock shows `t`.
    pub fn until(&self, t: Millis) -> Duration {
        let now = self.now();
        Duration::from_secs_f64(t.saturating_sub(now) as f64 / 1000.0 / self.speed)
    }
}

/// Silence inside a frame after which the part received is dropped (a call that
/// dropped mid-frame, or modem text, must not swallow the next frames). 54 character
/// times at 1200 bit/s, room for a telephone modem's buffering.
pub const FRAME_GAP: Duration = Duration::from_millis(500);

/// Waits for the next frame on `t`: it must start within `timeout` of real time; once
/// it has started it may take as long as its bytes need, as long as no gap inside it
/// is longer than [`FRAME_GAP`] (a gap drops the part received). Damaged frames are
/// logged and skipped.
pub async fn next_message<T: Transport>(
    t: &mut T,
    rx: &mut Receiver,
    pending: &mut Vec<Message>,
    timeout: Duration,
) -> io::Result<Option<Message>> {
    if !pending.is_empty() {
        return Ok(Some(pending.remove(0)));
    }
    let deadline = t.now() + timeout.as_micros() as u64;
    let gap = FRAME_GAP.as_micros() as u64;
    // However a frame keeps going, the wait ends when the longest frame would have.
    let hard = deadline + 260 * t.profile().char_time + gap;
    let mut last = t.now();
    loop {
        if t.now() > hard {
            rx.reset();
            return Ok(None);
        }
        let until = if rx.in_frame() { last + gap } else { deadline };
        let chars = t.recv_flagged(until).await?;
        if chars.is_empty() {
            let partial = rx.in_frame();
            rx.reset();
            if partial && t.now() < deadline {
                continue;
            }
            return Ok(None);
        }
        last = t.now();
        let flagged: Vec<_> = chars.iter().map(|c| (c.byte, c.flags)).collect();
        for r in rx.push(&flagged) {
            match r {
                Received::Message(m) => pending.push(m),
                Received::Damaged { errors } => warn!(
                    "damaged frame ignored (errors 0x{errors:02X}); if this repeats, check \
                     the bit rate (--baud), odd parity on both ends, and --two-wire on a \
                     two-wire RS-485 adapter"
                ),
            }
        }
        if !pending.is_empty() {
            return Ok(Some(pending.remove(0)));
        }
    }
}

/// Drops whatever has arrived and not been read, until the line has been quiet for
/// 20 ms (at most 1 s of it): the rest of an earlier try's late reply must not be
/// taken for the reply to the next request.
pub async fn discard_input<T: Transport>(t: &mut T) -> io::Result<()> {
    let give_up = t.now() + 1_000_000;
    while t.now() < give_up {
        if t.recv_flagged(t.now() + 20_000).await?.is_empty() {
            break;
        }
    }
    Ok(())
}

/// A simulated sensor on a line: answers every request to its address until the
/// line fails.
pub async fn run_sensor<T: Transport>(
    mut t: T,
    mut sensor: SimSensor,
    clock: Clock,
) -> io::Result<()> {
    let mut rx = Receiver::new();
    let mut pending = Vec::new();
    info!("{} answering on {}", sensor.station(), t.describe());
    loop {
        let Some(m) =
            next_message(&mut t, &mut rx, &mut pending, Duration::from_secs(3600)).await?
        else {
            continue;
        };
        if let Some(r) = sensor.handle(&m, clock.now()) {
            t.send(&r.to_bytes()).await?;
        }
    }
}

/// What the concentrator shows after each poll and transfer.
pub type View<'a> = &'a (dyn Fn(&Concentrator) + Sync);

/// Opens a line (again, after it failed).
pub type Opener<'a, T> = &'a (dyn Fn() -> io::Result<T> + Sync);

/// The first wait before a failed line is opened again (each next one twice the last,
/// up to [`REOPEN_MAX`]). Not shorter: a pseudo-terminal or USB adapter that went away
/// leaves its path behind for a moment, and a path opened too soon may be a stale one.
pub const REOPEN_AFTER: Duration = Duration::from_secs(5);

/// The longest wait before a failed line is opened again.
pub const REOPEN_MAX: Duration = Duration::from_secs(30);

fn lock(c: &std::sync::Mutex<Concentrator>) -> std::sync::MutexGuard<'_, Concentrator> {
    c.lock().unwrap_or_else(|p| p.into_inner())
}

/// The concentrator: polls its sensors on the bus and serves the uplink at the same
/// time, each on its own thread (a long reply on the uplink does not hold up a poll).
/// A line that fails is logged and opened again (after [`REOPEN_AFTER`], then up to
/// every [`REOPEN_MAX`]): the
/// concentrator goes on polling whatever happens to its uplink. Returns only when
/// both lines have been given up, which never happens; blocks the calling thread.
pub fn run_concentrator<B: Transport, U: Transport + Send>(
    open_bus: Opener<'_, B>,
    open_uplink: Option<Opener<'_, U>>,
    conc: Concentrator,
    clock: Clock,
    reply_timeout: Duration,
    view: View<'_>,
) -> io::Result<()> {
    let rt = || {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
    };
    let conc = std::sync::Mutex::new(conc);
    let conc = &conc;
    // Open both once here, so a wrong path fails at start.
    let bus_rt = rt()?;
    let first_bus = bus_rt.block_on(async { open_bus() })?;
    let uplink_rt = rt()?;
    let first_uplink = match open_uplink {
        Some(o) => Some(uplink_rt.block_on(async { o() })?),
        None => None,
    };
    std::thread::scope(|scope| {
        if let (Some(open), Some(first)) = (open_uplink, first_uplink) {
            scope.spawn(move || {
                fatal_on_panic("uplink", || {
                    uplink_rt.block_on(keep_open("uplink", first, open, |up| {
                        serve_uplink(up, conc, clock, view)
                    }))
                })
            });
        }
        fatal_on_panic("bus", || {
            bus_rt.block_on(keep_open("bus", first_bus, open_bus, |bus| {
                poll_bus(bus, conc, clock, reply_timeout, view)
            }))
        })
    })
}

/// Runs `run` on the line, and whenever it fails: logs why, closes the line (a USB
/// adapter plugged back in gets its old name only if nobody holds it), waits, opens it
/// again and goes on. Never returns. The waits are the project's one reconnect policy
/// ([`hart_host::reconnect::Backoff`], as the gateway's loops and Modbus RTU slave):
/// [`REOPEN_AFTER`], doubling up to [`REOPEN_MAX`], and the first again after a line
/// that ran for a while.
async fn keep_open<T, Fut>(
    what: &str,
    first: T,
    open: Opener<'_, T>,
    mut run: impl FnMut(T) -> Fut,
) -> io::Result<()>
where
    Fut: std::future::Future<Output = io::Result<()>>,
{
    let mut backoff = hart_host::reconnect::Backoff::new(REOPEN_AFTER, REOPEN_MAX);
    let mut line = Some(first);
    loop {
        let l = match line.take() {
            Some(l) => l,
            None => match open() {
                Ok(l) => l,
                Err(e) => {
                    let wait = backoff.failed(std::time::Instant::now());
                    warn!("{what}: {e}; trying again in {wait:?}");
                    tokio::time::sleep(wait).await;
                    continue;
                }
            },
        };
        // `run` owns the line: it is closed when `run` ends.
        let started = std::time::Instant::now();
        if let Err(e) = run(l).await {
            if started.elapsed() >= STEADY {
                backoff.reset();
            }
            let wait = backoff.failed(std::time::Instant::now());
            warn!("{what}: {e}; the concentrator goes on; opening it again in {wait:?}");
            tokio::time::sleep(wait).await;
        }
    }
}

/// A line that ran this long before it failed was working: its next reopen waits the
/// shortest time again.
const STEADY: Duration = Duration::from_secs(30);

/// Runs `f`; a panic in it ends the process (exit status 70) instead of leaving a
/// concentrator that looks alive with one of its loops dead: a supervisor (systemd)
/// starts it again, and the store makes that safe.
fn fatal_on_panic<R>(what: &str, f: impl FnOnce() -> R) -> R {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)) {
        Ok(r) => r,
        Err(_) => {
            tracing::error!("the {what} loop failed unexpectedly; stopping so the concentrator can be restarted");
            std::process::exit(70);
        }
    }
}

async fn poll_bus<B: Transport>(
    mut bus: B,
    conc: &std::sync::Mutex<Concentrator>,
    clock: Clock,
    reply_timeout: Duration,
    view: View<'_>,
) -> io::Result<()> {
    let mut rx = Receiver::new();
    let mut pending = Vec::new();
    loop {
        let req = lock(conc).bus_request(clock.now());
        let Some(req) = req else {
            let next = lock(conc).next_deadline();
            tokio::time::sleep(clock.until(next).min(Duration::from_secs(1))).await;
            continue;
        };
        pending.clear();
        rx.reset();
        // The time the request reached the sensor: it answers with the three minutes
        // before the one in progress then.
        let mut sent_at = clock.now();
        let exchanged: io::Result<Option<Message>> = async {
            discard_input(&mut bus).await?;
            bus.send(&req.to_bytes()).await?;
            sent_at = clock.now();
            let deadline = std::time::Instant::now() + reply_timeout;
            loop {
                let left = deadline.saturating_duration_since(std::time::Instant::now());
                match next_message(&mut bus, &mut rx, &mut pending, left).await? {
                    None => return Ok(None),
                    Some(m) if m.reply && m.station == req.station => return Ok(Some(m)),
                    Some(_) => continue,
                }
            }
        }
        .await;
        let at = sent_at;
        let reply = match exchanged {
            Ok(r) => r,
            Err(e) => {
                // The request in progress ends as unanswered, so the poll goes on
                // with the line opened again.
                let _ = lock(conc).bus_result(at, None);
                return Err(e);
            }
        };
        let mut c = lock(conc);
        if let Some(r) = c.bus_result(at, reply.as_ref()) {
            match r {
                Ok(o) => info!(
                    "poll: {} new minutes, {} completed{}{}",
                    o.new_minutes,
                    o.completed,
                    if o.dropped_unsent > 0 {
                        format!(", {} UNSENT MINUTES DROPPED (store full)", o.dropped_unsent)
                    } else {
                        String::new()
                    },
                    if o.behind_clock > 0 {
                        format!(
                            ", {} minutes dated before the data handed over: CHECK THE CLOCK",
                            o.behind_clock
                        )
                    } else {
                        String::new()
                    }
                ),
                Err(e) => warn!("{e}"),
            }
            view(&c);
        }
    }
}

async fn serve_uplink<U: Transport>(
    mut up: U,
    conc: &std::sync::Mutex<Concentrator>,
    clock: Clock,
    view: View<'_>,
) -> io::Result<()> {
    let mut rx = Receiver::new();
    let mut pending = Vec::new();
    loop {
        let Some(m) =
            next_message(&mut up, &mut rx, &mut pending, Duration::from_secs(3600)).await?
        else {
            continue;
        };
        let reply = lock(conc).uplink(&m, clock.now());
        if let Some(r) = reply {
            up.send(&r.to_bytes()).await?;
            if m.command == crate::proto::TRANSFER {
                view(&lock(conc));
            }
        }
    }
}

/// Why a pull or a collection failed.
#[derive(Debug)]
pub enum PullError {
    /// The line failed.
    Io(io::Error),
    /// No reply after the retries.
    NoReply {
        /// The station.
        station: Station,
        /// Tries made.
        tries: u32,
    },
    /// The station refused, or its reply or the archive failed.
    Transfer(TransferError),
}

impl std::fmt::Display for PullError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PullError::Io(e) => write!(f, "{e}"),
            PullError::NoReply { station, tries } => write!(
                f,
                "no reply from the {station} after {tries} tries; check the cable or the \
                 telephone connection, the port's bit rate (--baud) and the well number, \
                 and on a slow modem raise --timeout-ms (it is the time for a reply to \
                 start)"
            ),
            PullError::Transfer(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for PullError {}

impl From<io::Error> for PullError {
    fn from(e: io::Error) -> Self {
        PullError::Io(e)
    }
}

/// Settings of a requester on a line.
#[derive(Debug, Clone, Copy)]
pub struct Requester {
    /// Time for a reply to arrive.
    pub timeout: Duration,
    /// Tries of each request.
    pub tries: u32,
}

impl Default for Requester {
    fn default() -> Self {
        Requester {
            timeout: Duration::from_secs(2),
            tries: 3,
        }
    }
}

/// Sends `req` and waits for its reply, trying again on time-out.
pub async fn exchange<T: Transport>(
    t: &mut T,
    req: &Message,
    r: Requester,
) -> Result<Message, PullError> {
    let mut rx = Receiver::new();
    let mut pending = Vec::new();
    for _ in 0..r.tries.max(1) {
        pending.clear();
        rx.reset();
        discard_input(t).await?;
        t.send(&req.to_bytes()).await?;
        let deadline = Instant::now() + r.timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match next_message(t, &mut rx, &mut pending, left).await? {
                None => break,
                Some(m) if m.reply && m.station == req.station && m.command == req.command => {
                    return Ok(m)
                }
                Some(_) => continue,
            }
        }
    }
    Err(PullError::NoReply {
        station: req.station,
        tries: r.tries.max(1),
    })
}

/// What a pull brought.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct PullSummary {
    /// The station.
    pub station: u8,
    /// The well.
    pub well: u8,
    /// Batches received.
    pub batches: u32,
    /// Minutes new to the archive.
    pub new_minutes: u32,
    /// Minutes the archive had already.
    pub duplicated: u32,
    /// The station's status (concentrators), when it answered command 14.
    pub status: Option<serde_json::Value>,
    /// Calibration tables downloaded on the way (handheld visits).
    pub calibration_downloaded: Vec<String>,
    /// Calibration tables that could not be downloaded, and why (kept for the next
    /// visit).
    pub calibration_errors: Vec<String>,
}

/// Pulls everything `station` holds into `archive`: its status (a concentrator's
/// command 14), any calibration table waiting for it (the handheld), then command
/// 144 until a batch comes back empty. Each batch is stored before it is
/// acknowledged, so a pull cut at any point goes on where it stopped.
pub async fn pull<T: Transport>(
    t: &mut T,
    archive: &mut Archive,
    station: Station,
    r: Requester,
    clock: Clock,
    download_calibration: bool,
) -> Result<PullSummary, PullError> {
    let well = station.number();
    let mut summary = PullSummary {
        station: station.0,
        well,
        batches: 0,
        new_minutes: 0,
        duplicated: 0,
        status: None,
        calibration_downloaded: vec![],
        calibration_errors: vec![],
    };
    if station.role() == crate::proto::Role::Concentrator {
        let m = exchange(t, &Message::request(station, DIAGNOSTICS, vec![]), r).await?;
        if let Ok(s) = StationStatus::decode(m.status.unwrap_or([0, 0]), &m.data) {
            let _ = archive.log_status(well, crate::minute_of(clock.now()), &s);
            summary.status = Some(status_json(&s));
        }
    }
    let mut col = Collector::new(archive, station)
        .map_err(|e| PullError::Transfer(TransferError::Store(e)))?;
    let result = loop {
        let m = match exchange(t, &col.request(), r).await {
            Ok(m) => m,
            Err(e) => break Err(e),
        };
        match col.on_reply(&m, archive, crate::minute_of(clock.now())) {
            Ok(Step::More) => {
                info!("batch {}: {} minutes remain", col.batches, col.remaining);
            }
            Ok(Step::Done) => break Ok(()),
            Err(e) => break Err(PullError::Transfer(e)),
        }
    };
    summary.batches = col.batches;
    summary.new_minutes = col.new;
    summary.duplicated = col.duplicated;
    let _ = archive.log_pull(&PullLog {
        at: crate::minute_of(clock.now()),
        well,
        via: crate::archive::Via::of(station),
        outcome: if result.is_ok() { "ok" } else { "cut" }.into(),
        records: col.new,
        batches: col.batches,
        detail: result
            .as_ref()
            .err()
            .map_or(String::new(), |e| e.to_string()),
    });
    result?;
    // Calibration tables waiting for this well go down after the data, so a failed
    // download never costs a visit's data; a failure is reported, the table kept.
    if download_calibration && station.role() == crate::proto::Role::Concentrator {
        for sensor in Sensor::ALL {
            let Ok(Some(table)) = archive.pending_calibration(well, sensor) else {
                continue;
            };
            let mut s = CalibrationSender::new(station, sensor, table);
            let sent = loop {
                let m = match exchange(t, &s.request(), r).await {
                    Ok(m) => m,
                    Err(e) => break Err(e.to_string()),
                };
                match s.on_reply(&m) {
                    Ok(Step::More) => continue,
                    Ok(Step::Done) => break Ok(()),
                    Err(e) => break Err(e.to_string()),
                }
            };
            match sent {
                Ok(()) => {
                    let _ = archive.clear_pending_calibration(well, sensor);
                    info!(
                        "{} calibration table downloaded to the {station}",
                        sensor.name()
                    );
                    summary
                        .calibration_downloaded
                        .push(sensor.name().to_string());
                }
                Err(e) => {
                    warn!(
                        "{} calibration table not downloaded (kept for the next visit): {e}",
                        sensor.name()
                    );
                    summary
                        .calibration_errors
                        .push(format!("{}: {e}", sensor.name()));
                }
            }
        }
    }
    Ok(summary)
}

/// A station's status as JSON.
pub fn status_json(s: &StationStatus) -> serde_json::Value {
    serde_json::json!({
        "summary": match s.summary { 0 => "ok", 1 => "sensor fault", _ => "store dropped unsent minutes" },
        "clock_minute": s.clock,
        "stored": s.stored,
        "unsent": s.unsent,
        "store_fill": s.fill_permille as f64 / 1000.0,
        "dropped_unsent": s.dropped_unsent,
        "sensors": s.sensors.iter().map(|x| x.to_json()).collect::<Vec<_>>(),
    })
}

/// The handheld at the bureau: answers the PC for every well it holds, until the
/// line fails.
pub async fn run_handheld_station<T: Transport>(
    mut t: T,
    mut archive: Archive,
    clock: Clock,
) -> io::Result<()> {
    let mut station = HandheldStation::new();
    let mut rx = Receiver::new();
    let mut pending = Vec::new();
    info!("handheld answering on {}", t.describe());
    loop {
        let Some(m) =
            next_message(&mut t, &mut rx, &mut pending, Duration::from_secs(3600)).await?
        else {
            continue;
        };
        if let Some(r) = station.answer(&mut archive, &m, clock.now()) {
            t.send(&r.to_bytes()).await?;
        }
    }
}

/// Sends every table of `file` to `station` with command 160, segment by segment;
/// returns the sensors whose tables the station took. A concentrator puts each in
/// force; the handheld keeps it for the well's next visit.
pub async fn send_calibration<T: Transport>(
    t: &mut T,
    station: Station,
    file: &crate::calibration::CalibrationFile,
    r: Requester,
) -> Result<Vec<Sensor>, PullError> {
    let mut done = Vec::new();
    for sensor in Sensor::ALL {
        let Some(table) = file.table(sensor) else {
            continue;
        };
        let mut s = CalibrationSender::new(station, sensor, table.clone());
        loop {
            let m = exchange(t, &s.request(), r).await?;
            match s.on_reply(&m).map_err(PullError::Transfer)? {
                Step::More => continue,
                Step::Done => break,
            }
        }
        done.push(sensor);
    }
    Ok(done)
}

/// How to reach a well: by a telephone number through a Hayes modem on the port, or
/// straight down the line (a cable or a leased line) when `number` is `None`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Route {
    /// The well.
    pub well: u8,
    /// The number to dial.
    pub number: Option<String>,
}

/// One well's outcome in a round.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct WellOutcome {
    /// The well.
    pub well: u8,
    /// Reached and pulled to the end.
    pub ok: bool,
    /// Attempts made.
    pub attempts: u32,
    /// What was pulled (the last attempt).
    pub pull: Option<PullSummary>,
    /// Why it failed, in words (the last attempt).
    pub error: Option<String>,
    /// Sensors the concentrator reported faulty or not answering.
    pub sensor_faults: Vec<String>,
}

/// Dials `route`'s number (when it has one), runs `f` on the line, and hangs up
/// whatever `f` gave; straight down the line without a number. Every dialled exchange
/// (a pull, parameters, a calibration) goes through here.
pub async fn on_route<T: Transport, R>(
    t: &mut T,
    route: &Route,
    dial: &crate::hayes::DialOptions,
    f: impl AsyncFnOnce(&mut T) -> Result<R, String>,
) -> Result<R, String> {
    let Some(n) = &route.number else {
        return f(t).await;
    };
    let opts = crate::hayes::DialOptions {
        number: n.clone(),
        ..dial.clone()
    };
    let connect = crate::hayes::dial(t, &opts)
        .await
        .map_err(|e| e.to_string())?;
    info!("well {}: {connect}", route.well);
    let result = f(t).await;
    if let Err(e) = crate::hayes::hang_up(t, &opts).await {
        warn!("well {}: hanging up: {e}", route.well);
    }
    result
}

/// Dials (when the route has a number), pulls, hangs up (whatever happened).
pub async fn pull_route<T: Transport>(
    t: &mut T,
    archive: &mut Archive,
    route: &Route,
    dial: &crate::hayes::DialOptions,
    r: Requester,
    clock: Clock,
) -> Result<PullSummary, String> {
    let station = Station::concentrator(route.well);
    on_route(t, route, dial, async |t: &mut T| {
        pull(t, archive, station, r, clock, false)
            .await
            .map_err(|e| e.to_string())
    })
    .await
}

/// Time from `now_s` (Unix seconds) to the next of `times` (seconds of the UTC day).
pub fn until_next(times: &[u32], now_s: u64) -> Duration {
    let sod = (now_s % 86_400) as u32;
    let next = times
        .iter()
        .map(|&t| if t > sod { t - sod } else { t + 86_400 - sod })
        .min()
        .unwrap_or(86_400);
    Duration::from_secs(next as u64)
}

/// What a scheduled round does.
#[derive(Debug, Clone)]
pub struct RoundPlan {
    /// The wells, in order.
    pub routes: Vec<Route>,
    /// How to dial (the number comes from each route).
    pub dial: crate::hayes::DialOptions,
    /// Requester timing.
    pub requester: Requester,
    /// Attempts after the first, per well.
    pub retries: u32,
    /// Time between attempts.
    pub retry_wait: Duration,
}

/// One scheduled round: every route in turn, each tried up to `1 + retries` times
/// `retry_wait` apart; wells that could not be reached are logged in the archive
/// (outcome `unreachable`) and reported.
pub async fn round<T: Transport>(
    t: &mut T,
    archive: &mut Archive,
    plan: &RoundPlan,
    clock: Clock,
) -> Vec<WellOutcome> {
    let (dial, r, retries, retry_wait) =
        (&plan.dial, plan.requester, plan.retries, plan.retry_wait);
    let mut out = Vec::new();
    for route in &plan.routes {
        let mut o = WellOutcome {
            well: route.well,
            ok: false,
            attempts: 0,
            pull: None,
            error: None,
            sensor_faults: vec![],
        };
        while o.attempts <= retries {
            if o.attempts > 0 {
                tokio::time::sleep(retry_wait).await;
            }
            o.attempts += 1;
            match pull_route(t, archive, route, dial, r, clock).await {
                Ok(s) => {
                    o.sensor_faults = s
                        .status
                        .as_ref()
                        .and_then(|st| st["sensors"].as_array().cloned())
                        .unwrap_or_default()
                        .iter()
                        .filter(|x| x["state"] != "healthy")
                        .map(|x| {
                            format!(
                                "sensor {} ({}): {}",
                                x["address"],
                                x["kind"].as_str().unwrap_or("?"),
                                x["state"].as_str().unwrap_or("?")
                            )
                        })
                        .collect();
                    o.ok = true;
                    o.error = None;
                    o.pull = Some(s);
                    break;
                }
                Err(e) => {
                    warn!("well {}: attempt {}: {e}", route.well, o.attempts);
                    o.error = Some(e);
                }
            }
        }
        if !o.ok {
            let _ = archive.log_pull(&PullLog {
                at: crate::minute_of(clock.now()),
                well: route.well,
                via: crate::archive::Via::Concentrator,
                outcome: "unreachable".into(),
                records: 0,
                batches: 0,
                detail: o.error.clone().unwrap_or_default(),
            });
        }
        out.push(o);
    }
    out
}

/// Reads or changes a concentrator's parameters (command 161), dialling first when
/// the route has a number; returns the values in force.
pub async fn parameters<T: Transport>(
    t: &mut T,
    route: &Route,
    dial: &crate::hayes::DialOptions,
    p: crate::proto::Parameters,
    r: Requester,
) -> Result<crate::proto::Parameters, String> {
    let req = Message::request(
        Station::concentrator(route.well),
        crate::proto::PARAMETERS,
        p.encode(),
    );
    let m = on_route(t, route, dial, async |t: &mut T| {
        exchange(t, &req, r).await.map_err(|e| e.to_string())
    })
    .await?;
    match m.response_code() {
        Some(0) => crate::proto::Parameters::decode(&m.data).map_err(|e| e.to_string()),
        Some(3) => {
            Err("the concentrator refused the values: poll interval 1-180 s, retries 0-5".into())
        }
        Some(c) => Err(TransferError::Refused {
            station: req.station,
            code: c,
        }
        .to_string()),
        None => Err("a reply without status".into()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::proto::{Batch, Record, TRANSFER};
    use hart_link::TimingProfile;

    /// What the far end answers to the n-th send: (delay µs, bytes).
    type Answer = Box<dyn FnMut(u64) -> Vec<(u64, Vec<u8>)>>;

    /// A line in virtual time: after each send, `answer` gives (delay µs, bytes) to
    /// deliver one character at a time at `char_us` apart.
    struct Paced {
        now: u64,
        inbox: std::collections::VecDeque<(u64, u8)>,
        char_us: u64,
        answer: Answer,
        sends: u64,
    }

    impl Transport for Paced {
        fn profile(&self) -> TimingProfile {
            TimingProfile::rs485(1200)
        }
        fn now(&self) -> u64 {
            self.now
        }
        async fn send(&mut self, _bytes: &[u8]) -> io::Result<()> {
            self.sends += 1;
            for (delay, bytes) in (self.answer)(self.sends) {
                let mut at = self.now + delay;
                for b in bytes {
                    at += self.char_us;
                    self.inbox.push_back((at, b));
                }
            }
            Ok(())
        }
        async fn recv(&mut self, deadline: u64) -> io::Result<Vec<(u8, u64)>> {
            match self.inbox.front() {
                Some(&(at, b)) if at <= deadline => {
                    self.inbox.pop_front();
                    self.now = self.now.max(at);
                    Ok(vec![(b, at)])
                }
                _ => {
                    self.now = self.now.max(deadline);
                    Ok(vec![])
                }
            }
        }
        fn describe(&self) -> String {
            "paced line".into()
        }
    }

    fn full_batch() -> Vec<u8> {
        let records = (0..11).map(|i| Record::empty(1000 + i)).collect();
        let data = Batch {
            remaining: 3,
            records,
        }
        .encode();
        Message::reply(Station::concentrator(1), TRANSFER, [0, 0], data).to_bytes()
    }

    fn block_on<F: std::future::Future>(f: F) -> F::Output {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap()
            .block_on(f)
    }

    /// A full batch at 1200 bit/s takes 2.4 s, longer than the 2 s time-out: the
    /// time-out is for the reply's start, so it arrives.
    #[test]
    fn a_reply_longer_than_the_time_out_arrives() {
        let reply = full_batch();
        assert_eq!(reply.len(), 257);
        let mut t = Paced {
            now: 0,
            inbox: Default::default(),
            char_us: 9_167,
            answer: Box::new(move |_| vec![(50_000, reply.clone())]),
            sends: 0,
        };
        let req = Message::request(Station::concentrator(1), TRANSFER, vec![0; 4]);
        let m = block_on(exchange(&mut t, &req, Requester::default())).unwrap();
        assert_eq!(Batch::decode(&m.data).unwrap().records.len(), 11);
        assert_eq!(t.sends, 1);
        assert!(t.now > 2_400_000, "{}", t.now);
    }

    /// A reply cut by a gap longer than FRAME_GAP is dropped; the try after it gets
    /// the whole reply, and not the stale remains.
    #[test]
    fn a_gap_drops_the_partial_frame() {
        let reply = full_batch();
        let mut t = Paced {
            now: 0,
            inbox: Default::default(),
            char_us: 9_167,
            answer: Box::new(move |n| {
                if n == 1 {
                    // Half a reply, then silence: the call dropped.
                    vec![(50_000, reply[..100].to_vec())]
                } else {
                    vec![(50_000, reply.clone())]
                }
            }),
            sends: 0,
        };
        let req = Message::request(Station::concentrator(1), TRANSFER, vec![0; 4]);
        let m = block_on(exchange(&mut t, &req, Requester::default())).unwrap();
        assert_eq!(Batch::decode(&m.data).unwrap().records.len(), 11);
        assert_eq!(t.sends, 2);
    }

    /// A line whose writes fail (a USB adapter pulled out).
    struct Broken;

    impl Transport for Broken {
        fn profile(&self) -> TimingProfile {
            TimingProfile::rs485(1200)
        }
        fn now(&self) -> u64 {
            0
        }
        async fn send(&mut self, _bytes: &[u8]) -> io::Result<()> {
            Err(io::Error::other("gone"))
        }
        async fn recv(&mut self, _deadline: u64) -> io::Result<Vec<(u8, u64)>> {
            Ok(vec![])
        }
        fn describe(&self) -> String {
            "broken".into()
        }
    }

    /// A bus that fails mid-poll leaves no request hanging: with the line opened
    /// again, the poll goes on.
    #[test]
    fn a_failed_bus_does_not_leave_the_poll_stuck() {
        use crate::concentrator::{Concentrator, ConcentratorConfig};
        use crate::store::{Durability, Store};
        let d = tempfile::tempdir().unwrap();
        let store = Store::open(&d.path().join("c.db"), 1, 0, Durability::Process).unwrap();
        let clock = Clock::new(1.0);
        let mut cfg = ConcentratorConfig::reference(1);
        cfg.poll_interval = 1_000;
        let conc = std::sync::Mutex::new(Concentrator::new(cfg, store, clock.now()).unwrap());
        let view = |_: &Concentrator| {};
        let e = block_on(poll_bus(
            Broken,
            &conc,
            clock,
            Duration::from_millis(50),
            &view,
        ));
        assert!(e.is_err());
        // The request that failed counts as unanswered; the next one is ready.
        assert!(lock(&conc).bus_request(clock.now()).is_some());
    }
}
