//! `hartkit wells`: the well-monitoring network's roles (docs/wells.md). Options are
//! read here; the work is hart-wells'.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::Duration;

use clap::{Args, Subcommand};
use hart_host::transport::{Rts, SerialOptions, SerialTransport};
use hart_wells::archive::Archive;
use hart_wells::calibration::{CalibrationFile, Sensor};
use hart_wells::concentrator::{Concentrator, ConcentratorConfig};
use hart_wells::proto::{state_name, Station};
use hart_wells::run::{self, Clock, Requester};
use hart_wells::sensor::{Fault, SensorConfig, SimSensor};
use hart_wells::sim::SimConfig;
use hart_wells::store::{Durability, Store, DAY_MINUTES};

/// `hartkit wells ...`.
#[derive(Subcommand)]
pub enum WellsCmd {
    /// A simulated sensor on a serial port or pseudo-terminal, answering commands 1
    /// and 14.
    Sensor(SensorArgs),
    /// The data concentrator: polls its sensors on --bus, serves the handheld and
    /// the PC on --uplink, keeps the minutes in --store.
    Concentrator(ConcentratorArgs),
    /// The handheld: collect from a concentrator on site, serve the PC at the bureau.
    #[command(subcommand)]
    Handheld(HandheldCmd),
    /// The bureau's PC.
    #[command(subcommand)]
    Pc(PcCmd),
    /// The whole network in virtual time: sensors, concentrators, telephone lines that
    /// fail, handheld trips, the PC's schedule; reports what was lost (nothing).
    Sim(WellsSimArgs),
    /// A four-wire RS-485 bus of pseudo-terminals: a concentrator and several sensors
    /// sharing one bus on one machine.
    Bus(BusArgs),
}

/// `wells bus`.
#[derive(Args)]
pub struct BusArgs {
    /// The concentrator's end (a link made at this path).
    #[arg(long, value_name = "PATH")]
    pub master: PathBuf,
    /// A sensor's end; give one per sensor.
    #[arg(long = "drop", value_name = "PATH", required = true)]
    pub drops: Vec<PathBuf>,
}

/// The serial line options every role has.
#[derive(Args, Clone)]
pub struct LineArgs {
    /// Bit rate (11-bit characters: 8 data bits, odd parity, 1 stop bit).
    #[arg(long, default_value_t = 1200)]
    pub baud: u32,
    /// Two-wire RS-485: drop our own transmission read back (the network's bus is
    /// four-wire, where nothing comes back).
    #[arg(long)]
    pub two_wire: bool,
}

/// `wells sensor`.
#[derive(Args)]
pub struct SensorArgs {
    /// The bus: a serial port or pseudo-terminal.
    #[arg(long, value_name = "PORT")]
    pub bus: PathBuf,
    /// Address on the bus, 1-15.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=15))]
    pub address: u8,
    /// What it measures.
    #[arg(long, value_parser = ["temperature", "level"])]
    pub kind: String,
    /// A fault for its self-diagnosis to find.
    #[arg(long, default_value = "none", value_parser = ["none", "element", "adc", "power"])]
    pub fault: String,
    /// Seed of its noise and of its well's water.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Run the clock this many times as fast, counted from the start of the current
    /// UTC day (demonstrations and tests; give every role the same value, and they
    /// agree on the time even when started or restarted apart).
    #[arg(long, default_value_t = 1.0)]
    pub speed: f64,
    #[command(flatten)]
    pub line: LineArgs,
}

/// `wells concentrator`.
#[derive(Args)]
pub struct ConcentratorArgs {
    /// Its well, 1-15 (it answers 0x80 + well on the uplink).
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=15))]
    pub well: u8,
    /// The sensors' bus.
    #[arg(long, value_name = "PORT")]
    pub bus: PathBuf,
    /// The uplink (telephone modem or cable) to the handheld and the PC.
    #[arg(long, value_name = "PORT")]
    pub uplink: Option<PathBuf>,
    /// The store (SQLite; created if missing).
    #[arg(long, value_name = "FILE")]
    pub store: PathBuf,
    /// Time between polls: 3m (default), 1m; seconds for tests (10s, 2s).
    #[arg(long, default_value = "3m", value_name = "DURATION", value_parser = parse_duration)]
    pub poll_interval: Duration,
    /// Calibration tables for a new store (CSV, docs/wells.md); a table downloaded
    /// later with command 160 stays in force over restarts.
    #[arg(long, value_name = "FILE")]
    pub calibration: Option<PathBuf>,
    /// Room in the store, days (at least 7).
    #[arg(long, default_value_t = 14, value_parser = clap::value_parser!(u32).range(7..=3650))]
    pub capacity_days: u32,
    /// Show the concentrator's state (latest values, sensors, store, last transfer)
    /// after each poll and transfer.
    #[arg(long)]
    pub view: bool,
    /// Run the clock this many times as fast, as the sensors do (see `wells sensor
    /// --speed`).
    #[arg(long, default_value_t = 1.0)]
    pub speed: f64,
    /// Time a sensor has to answer, ms.
    #[arg(long, default_value_t = 700)]
    pub reply_timeout_ms: u64,
    /// Bit rate of the uplink (default: --baud).
    #[arg(long)]
    pub uplink_baud: Option<u32>,
    #[command(flatten)]
    pub line: LineArgs,
}

/// `wells handheld ...`.
#[derive(Subcommand)]
pub enum HandheldCmd {
    /// Collect everything a concentrator has not handed over yet (command 144 in
    /// batches), and download calibration tables waiting for it.
    Collect(CollectArgs),
    /// At the bureau: answer the PC at 0xC0 + well for each well held.
    Serve(ServeArgs),
}

/// `wells handheld collect`.
#[derive(Args)]
pub struct CollectArgs {
    #[command(flatten)]
    pub to: ToWell,
    /// The handheld's store.
    #[arg(long, value_name = "FILE")]
    pub store: PathBuf,
    /// Print the result as JSON.
    #[arg(long)]
    pub json: bool,
}

/// `wells handheld serve`.
#[derive(Args)]
pub struct ServeArgs {
    /// The cable to the PC.
    #[arg(long, value_name = "PORT")]
    pub port: PathBuf,
    /// The handheld's store.
    #[arg(long, value_name = "FILE")]
    pub store: PathBuf,
    #[command(flatten)]
    pub line: LineArgs,
}

/// A well and the line to it.
#[derive(Args, Clone)]
pub struct ToWell {
    /// The line: a cable, or a telephone modem (dialled with --dial where offered).
    #[arg(long, value_name = "PORT")]
    pub port: PathBuf,
    /// The well, 1-15.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=15))]
    pub well: u8,
    #[command(flatten)]
    pub req: ReqArgs,
    #[command(flatten)]
    pub line: LineArgs,
}

/// Requester timing.
#[derive(Args, Clone)]
pub struct ReqArgs {
    /// Time for a reply to start, ms (a long reply may then take as long as its bytes
    /// need).
    #[arg(long, default_value_t = 2000)]
    pub timeout_ms: u64,
    /// Tries of each request.
    #[arg(long, default_value_t = 3)]
    pub tries: u32,
}

/// `wells pc ...`.
#[derive(Subcommand)]
pub enum PcCmd {
    /// Pull a well's data into the PC's database: from its concentrator (0x80 + well),
    /// through a telephone modem with --dial, or with --handheld from the handheld
    /// (0xC0 + well).
    Pull(PullArgs),
    /// Pull every well on a timetable, dialling each, with retries, and report the
    /// wells that could not be reached and the sensors in trouble.
    Schedule(ScheduleArgs),
    /// Export the minutes or their averages as CSV, or as GeoJSON points for a GIS.
    Export(crate::wells_export::ExportArgs),
    /// Draw the trends of level and temperature per well into a PNG.
    Plot(crate::wells_export::PlotArgs),
    /// Read or change a concentrator's parameters online (command 161): the poll
    /// interval and the retries; a restart keeps them.
    Set(SetArgs),
    /// Download a calibration file (CSV) with command 160: to the concentrator, which
    /// puts it in force, or with --handheld to the handheld, which downloads it on its
    /// next visit to the well.
    Calibrate(CalibrateArgs),
}

/// `wells pc set`.
#[derive(Args)]
pub struct SetArgs {
    #[command(flatten)]
    pub to: ToWell,
    /// New time between polls (1 s to 3 min); without it, unchanged.
    #[arg(long, value_name = "DURATION", value_parser = parse_duration)]
    pub poll_interval: Option<Duration>,
    /// New retries of a sensor request (0-5); without it, unchanged.
    #[arg(long)]
    pub retries: Option<u8>,
    /// Dial this number first.
    #[arg(long, value_name = "NUMBER")]
    pub dial: Option<String>,
    #[command(flatten)]
    pub modem: ModemArgs,
}

/// `wells pc calibrate`.
#[derive(Args)]
pub struct CalibrateArgs {
    #[command(flatten)]
    pub to: ToWell,
    /// The calibration file (docs/wells.md); refused whole if anything in it is wrong.
    #[arg(long, value_name = "FILE")]
    pub file: PathBuf,
    /// Send it to the handheld instead of the concentrator.
    #[arg(long, conflicts_with = "dial")]
    pub handheld: bool,
    /// Dial this number first (Hayes modem on --port).
    #[arg(long, value_name = "NUMBER")]
    pub dial: Option<String>,
    #[command(flatten)]
    pub modem: ModemArgs,
}

/// `wells pc pull`.
#[derive(Args)]
pub struct PullArgs {
    #[command(flatten)]
    pub to: ToWell,
    /// The PC's database (SQLite; created if missing).
    #[arg(long, value_name = "FILE")]
    pub db: PathBuf,
    /// Pull from the handheld instead of the concentrator.
    #[arg(long, conflicts_with = "dial")]
    pub handheld: bool,
    /// Dial this number with the Hayes modem on --port first (ATD), and hang up
    /// (+++, ATH) after.
    #[arg(long, value_name = "NUMBER")]
    pub dial: Option<String>,
    #[command(flatten)]
    pub modem: ModemArgs,
    /// Print the result as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Telephone modem options.
#[derive(Args, Clone)]
pub struct ModemArgs {
    /// Commands sent to the modem before dialling.
    #[arg(long, default_value = "ATE0V1Q0", value_name = "AT...")]
    pub modem_init: String,
    /// Time for the other modem to answer, s.
    #[arg(long, default_value_t = 60)]
    pub connect_timeout_s: u64,
}

impl ModemArgs {
    fn options(&self, number: &str) -> hart_wells::hayes::DialOptions {
        hart_wells::hayes::DialOptions {
            number: number.to_string(),
            init: self.modem_init.clone(),
            connect_timeout: Duration::from_secs(self.connect_timeout_s.max(1)),
            ..Default::default()
        }
    }
}

/// `wells pc schedule`.
#[derive(Args)]
pub struct ScheduleArgs {
    /// The line: a Hayes modem (wells with numbers) or a cable.
    #[arg(long, value_name = "PORT")]
    pub port: PathBuf,
    /// The PC's database.
    #[arg(long, value_name = "FILE")]
    pub db: PathBuf,
    /// A well to pull: `W=NUMBER` to dial, or `W` for a well on a direct line; give
    /// one per well, in the order to call them.
    #[arg(long = "well", value_name = "W[=NUMBER]", required = true, value_parser = parse_route)]
    pub wells: Vec<run::Route>,
    /// Time between rounds (the first starts at once).
    #[arg(long, default_value = "6h", value_name = "DURATION", value_parser = parse_duration)]
    pub every: Duration,
    /// Instead of --every: a time of day (UTC) for a round, HH:MM or HH:MM:SS; give
    /// one per round of the day (e.g. --at 06:00 --at 18:00). The first round waits
    /// for the next of them.
    #[arg(long = "at", value_name = "HH:MM", value_parser = parse_time_of_day, conflicts_with = "every")]
    pub at: Vec<u32>,
    /// Attempts after the first for a well that cannot be reached.
    #[arg(long, default_value_t = 2)]
    pub retries: u32,
    /// Time between attempts.
    #[arg(long, default_value = "10m", value_name = "DURATION", value_parser = parse_duration)]
    pub retry_wait: Duration,
    /// Stop after this many rounds (default: run until stopped).
    #[arg(long)]
    pub rounds: Option<u32>,
    #[command(flatten)]
    pub modem: ModemArgs,
    /// One JSON report per round instead of text.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub req: ReqArgs,
    #[command(flatten)]
    pub line: LineArgs,
}

/// Parses `HH:MM` or `HH:MM:SS` into seconds of the day.
pub fn parse_time_of_day(s: &str) -> Result<u32, String> {
    let parts: Vec<&str> = s.trim().split(':').collect();
    let num = |p: &str, max: u32| p.parse::<u32>().ok().filter(|v| *v <= max);
    let (h, m, sec) = match parts[..] {
        [h, m] => (num(h, 23), num(m, 59), Some(0)),
        [h, m, x] => (num(h, 23), num(m, 59), num(x, 59)),
        _ => (None, None, None),
    };
    match (h, m, sec) {
        (Some(h), Some(m), Some(x)) => Ok(h * 3600 + m * 60 + x),
        _ => Err(format!("{s:?}: a time of day, HH:MM or HH:MM:SS (UTC)")),
    }
}

/// Parses `W` or `W=NUMBER`.
pub fn parse_route(s: &str) -> Result<run::Route, String> {
    let (w, n) = match s.split_once('=') {
        Some((w, n)) => (w, Some(n.trim().to_string())),
        None => (s, None),
    };
    let well: u8 = w
        .trim()
        .parse()
        .ok()
        .filter(|w| (1..=15).contains(w))
        .ok_or_else(|| format!("{s:?}: the well, 1-15, then optionally =NUMBER"))?;
    if let Some(n) = &n {
        hart_wells::hayes::check_number(n).map_err(|e| format!("{s:?}: {e}"))?;
    }
    Ok(run::Route { well, number: n })
}

/// `wells sim`.
#[derive(Args)]
pub struct WellsSimArgs {
    /// Wells, 1-15.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u8).range(1..=15))]
    pub wells: u8,
    /// Days of virtual time.
    #[arg(long, default_value_t = 30.0)]
    pub days: f64,
    /// Telephone outages per well per day.
    #[arg(long, default_value_t = 0.1, value_name = "R")]
    pub phone_outage_rate: f64,
    /// Mean length of an outage, days.
    #[arg(long, default_value_t = 2.0)]
    pub outage_mean_days: f64,
    /// Days between the handheld's checks for wells in a long outage (a day or more).
    #[arg(long, default_value_t = 3.0, value_name = "DAYS")]
    pub handheld_every: f64,
    /// Hours between the PC's scheduled rounds.
    #[arg(long, default_value_t = 6.0)]
    pub pull_every_hours: f64,
    /// Probability that a frame on a working telephone line is lost.
    #[arg(long, default_value_t = 0.002)]
    pub frame_loss: f64,
    /// Power losses per concentrator per day.
    #[arg(long, default_value_t = 0.05)]
    pub restart_rate: f64,
    /// Room in each concentrator's store, days.
    #[arg(long, default_value_t = 14)]
    pub capacity_days: u32,
    /// Seconds between polls.
    #[arg(long, default_value_t = 180)]
    pub poll_interval_s: u64,
    /// Failures per sensor per day (it stops answering, for half a day on average).
    #[arg(long, default_value_t = 0.0)]
    pub sensor_failure_rate: f64,
    /// Seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Keep the stores here (default: a temporary directory, removed).
    #[arg(long, value_name = "DIR")]
    pub dir: Option<PathBuf>,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Parses `3m`, `180s`, `180`, `1h`, `500ms`.
pub fn parse_duration(s: &str) -> Result<Duration, String> {
    let s = s.trim();
    let (num, unit) = s
        .find(|c: char| c.is_ascii_alphabetic())
        .map_or((s, "s"), |i| (&s[..i], &s[i..]));
    let v: f64 = num
        .trim()
        .parse()
        .map_err(|_| format!("{s:?}: a duration such as 3m, 180s or 1h"))?;
    let secs = match unit {
        "ms" => v / 1000.0,
        "s" => v,
        "m" | "min" => v * 60.0,
        "h" => v * 3600.0,
        _ => return Err(format!("{s:?}: unit {unit:?}; use ms, s, m or h")),
    };
    if !(secs.is_finite() && secs > 0.0) {
        return Err(format!("{s:?}: must be more than 0"));
    }
    Duration::try_from_secs_f64(secs).map_err(|_| format!("{s:?}: too long"))
}

fn open_line(
    path: &std::path::Path,
    line: &LineArgs,
    baud: Option<u32>,
) -> Result<SerialTransport, String> {
    SerialTransport::open(SerialOptions {
        path: path.to_path_buf(),
        baud: baud.unwrap_or(line.baud),
        rts: Rts::None,
        rts_pre: Duration::ZERO,
        rts_post: Duration::ZERO,
        rs485: line.two_wire,
        carrier_detect: false,
    })
    .map_err(|e| e.to_string())
}

/// Runs a `wells` command.
pub fn run(cmd: &WellsCmd) -> Result<String, String> {
    match cmd {
        WellsCmd::Sim(a) => sim(a),
        WellsCmd::Pc(PcCmd::Calibrate(a)) => calibrate(a),
        WellsCmd::Pc(PcCmd::Set(a)) => set(a),
        WellsCmd::Pc(PcCmd::Export(a)) => crate::wells_export::export(a).map(|summary| {
            eprintln!("{summary}");
            String::new()
        }),
        WellsCmd::Pc(PcCmd::Plot(a)) => crate::wells_export::plot(a),
        WellsCmd::Pc(PcCmd::Schedule(a)) => schedule(a),
        WellsCmd::Bus(a) => crate::wells_bus::run(&a.master, &a.drops),
        WellsCmd::Sensor(a) => sensor(a),
        WellsCmd::Concentrator(a) => concentrator(a),
        WellsCmd::Handheld(HandheldCmd::Collect(a)) => {
            crate::gateway::init_log();
            let mut archive =
                Archive::open(&a.store, Durability::Full).map_err(|e| e.to_string())?;
            let s = crate::host::block_on(async {
                let mut t = open_line(&a.to.port, &a.to.line, None)?;
                run::pull(
                    &mut t,
                    &mut archive,
                    Station::concentrator(a.to.well),
                    requester(&a.to.req),
                    Clock::new(1.0),
                    true,
                )
                .await
                .map_err(|e| e.to_string())
            })?;
            summary(&s, a.json)
        }
        WellsCmd::Handheld(HandheldCmd::Serve(a)) => {
            crate::gateway::init_log();
            let archive = Archive::open(&a.store, Durability::Full).map_err(|e| e.to_string())?;
            crate::host::block_on(async {
                let t = open_line(&a.port, &a.line, None)?;
                run::run_handheld_station(t, archive, Clock::new(1.0))
                    .await
                    .map_err(|e| e.to_string())
            })?;
            Ok(String::new())
        }
        WellsCmd::Pc(PcCmd::Pull(a)) => {
            crate::gateway::init_log();
            let mut archive = Archive::open(&a.db, Durability::Full).map_err(|e| e.to_string())?;
            let station = if a.handheld {
                Station::handheld(a.to.well)
            } else {
                Station::concentrator(a.to.well)
            };
            let s = crate::host::block_on(async {
                let mut t = open_line(&a.to.port, &a.to.line, None)?;
                if a.handheld {
                    return run::pull(
                        &mut t,
                        &mut archive,
                        station,
                        requester(&a.to.req),
                        Clock::new(1.0),
                        false,
                    )
                    .await
                    .map_err(|e| e.to_string());
                }
                let route = run::Route {
                    well: a.to.well,
                    number: a.dial.clone(),
                };
                let opts = a.modem.options("");
                run::pull_route(
                    &mut t,
                    &mut archive,
                    &route,
                    &opts,
                    requester(&a.to.req),
                    Clock::new(1.0),
                )
                .await
            })?;
            summary(&s, a.json)
        }
    }
}

fn schedule(a: &ScheduleArgs) -> Result<String, String> {
    use std::io::Write as _;
    crate::gateway::init_log();
    let mut archive = Archive::open(&a.db, Durability::Full).map_err(|e| e.to_string())?;
    let plan = run::RoundPlan {
        routes: a.wells.clone(),
        dial: a.modem.options(""),
        requester: requester(&a.req),
        retries: a.retries,
        retry_wait: a.retry_wait,
    };
    let clock = Clock::new(1.0);
    let unreachable = crate::host::block_on(async {
        let mut t = open_line(&a.port, &a.line, None)?;
        let mut n = 0u32;
        if !a.at.is_empty() {
            let wait = run::until_next(&a.at, unix_now());
            tracing::info!("first round in {wait:?}");
            tokio::time::sleep(wait).await;
        }
        loop {
            let started = std::time::Instant::now();
            let outcomes = run::round(&mut t, &mut archive, &plan, clock).await;
            n += 1;
            let unreachable = outcomes.iter().filter(|o| !o.ok).count();
            let text = if a.json {
                serde_json::json!({
                    "round": n,
                    "at_minute": hart_wells::minute_of(clock.now()),
                    "wells": outcomes,
                    "unreachable": outcomes.iter().filter(|o| !o.ok).map(|o| o.well).collect::<Vec<_>>(),
                })
                .to_string()
            } else {
                round_text(n, &outcomes)
            };
            let _ = writeln!(std::io::stdout(), "{text}");
            if a.rounds.is_some_and(|r| n >= r) {
                break Ok::<usize, String>(unreachable);
            }
            if a.at.is_empty() {
                tokio::time::sleep(a.every.saturating_sub(started.elapsed())).await;
            } else {
                tokio::time::sleep(run::until_next(&a.at, unix_now())).await;
            }
        }
    })?;
    if unreachable > 0 {
        return Err(format!(
            "{unreachable} well(s) could not be reached in the last round (see above)"
        ));
    }
    Ok(String::new())
}

fn unix_now() -> u64 {
    hart_clock::epoch::seconds(std::time::SystemTime::now())
}

fn round_text(n: u32, outcomes: &[run::WellOutcome]) -> String {
    let mut out = format!("round {n}:");
    for o in outcomes {
        match (&o.pull, &o.error) {
            (Some(p), _) => out.push_str(&format!(
                "\n  well {}: {} new minutes{}",
                o.well,
                p.new_minutes,
                if o.attempts > 1 {
                    format!(" (attempt {})", o.attempts)
                } else {
                    String::new()
                }
            )),
            (None, e) => out.push_str(&format!(
                "\n  well {}: UNREACHABLE after {} attempts: {}",
                o.well,
                o.attempts,
                e.as_deref().unwrap_or("?")
            )),
        }
        for f in &o.sensor_faults {
            out.push_str(&format!("\n    {f}"));
        }
    }
    out
}

fn set(a: &SetArgs) -> Result<String, String> {
    let poll = match a.poll_interval {
        None => 0,
        Some(d) if (1..=180).contains(&d.as_secs()) => d.as_secs() as u16,
        Some(d) => return Err(format!("--poll-interval {d:?}: 1 s to 3 min")),
    };
    let retries = match a.retries {
        None => 0xFF,
        Some(r) if r <= 5 => r,
        Some(r) => return Err(format!("--retries {r}: 0-5")),
    };
    let p = crate::host::block_on(async {
        let mut t = open_line(&a.to.port, &a.to.line, None)?;
        let route = run::Route {
            well: a.to.well,
            number: a.dial.clone(),
        };
        run::parameters(
            &mut t,
            &route,
            &a.modem.options(""),
            hart_wells::proto::Parameters {
                poll_interval_s: poll,
                retries,
            },
            requester(&a.to.req),
        )
        .await
    })?;
    Ok(format!(
        "well {}: poll interval {} s, {} retries",
        a.to.well, p.poll_interval_s, p.retries
    ))
}

fn calibrate(a: &CalibrateArgs) -> Result<String, String> {
    let file = CalibrationFile::read(&a.file).map_err(|e| format!("{e}; nothing was sent"))?;
    let station = if a.handheld {
        Station::handheld(a.to.well)
    } else {
        Station::concentrator(a.to.well)
    };
    let done = crate::host::block_on(async {
        let mut t = open_line(&a.to.port, &a.to.line, None)?;
        let route = run::Route {
            well: a.to.well,
            number: a.dial.clone(),
        };
        run::on_route(&mut t, &route, &a.modem.options(""), async |t| {
            run::send_calibration(t, station, &file, requester(&a.to.req))
                .await
                .map_err(|e| e.to_string())
        })
        .await
    })?;
    let names: Vec<&str> = done.iter().map(|s| s.name()).collect();
    Ok(if a.handheld {
        format!(
            "{} table(s) kept by the handheld for well {}'s next visit",
            names.join(" and "),
            a.to.well
        )
    } else {
        format!(
            "{} table(s) in force at well {}",
            names.join(" and "),
            a.to.well
        )
    })
}

fn requester(a: &ReqArgs) -> Requester {
    Requester {
        timeout: Duration::from_millis(a.timeout_ms.max(1)),
        tries: a.tries.max(1),
    }
}

fn summary(s: &run::PullSummary, json: bool) -> Result<String, String> {
    if json {
        return serde_json::to_string_pretty(s).map_err(|e| e.to_string());
    }
    let mut out = format!(
        "well {}: {} new minutes in {} batches{}",
        s.well,
        s.new_minutes,
        s.batches,
        if s.duplicated > 0 {
            format!(", {} already held", s.duplicated)
        } else {
            String::new()
        }
    );
    if let Some(st) = &s.status {
        out.push_str(&format!("\nstatus: {st}"));
    }
    for c in &s.calibration_downloaded {
        out.push_str(&format!("\n{c} calibration table downloaded"));
    }
    for e in &s.calibration_errors {
        out.push_str(&format!(
            "\ncalibration table NOT downloaded (kept for the next visit): {e}"
        ));
    }
    Ok(out)
}

fn sim(a: &WellsSimArgs) -> Result<String, String> {
    let r = hart_wells::sim::run(SimConfig {
        wells: a.wells,
        days: a.days,
        phone_outage_rate: a.phone_outage_rate,
        outage_mean_days: a.outage_mean_days,
        handheld_every: a.handheld_every,
        pull_every_hours: a.pull_every_hours,
        frame_loss: a.frame_loss,
        restart_rate: a.restart_rate,
        capacity_days: a.capacity_days,
        poll_interval_s: a.poll_interval_s,
        sensor_failure_rate: a.sensor_failure_rate,
        uplink_baud: 1200,
        seed: a.seed,
        dir: a.dir.clone(),
    })
    .map_err(|e| e.to_string())?;
    if a.json {
        return serde_json::to_string_pretty(&r).map_err(|e| e.to_string());
    }
    Ok(format!(
        "{} wells, {} days: {} minutes sampled, {} at the PC, {} lost, {} duplicated ({} minutes without any value: a concentrator down longer than its sensors remember, or both sensors down)\n\
         store fill at most {:.1} %, {} minutes pending at the end (drained)\n\
         {} outages ({:.1} well-days without a line), {} restarts, {} handheld trips ({} minutes via the handheld)\n\
         {} sensor failures, shown {} times in the status the PC read; {} minutes with a quantity missing\n\
         {} pulls: {} complete, {} cut, {} rounds unreachable; {} batches\n\
         values checked against the stores: {} ({} different); {:.2} s",
        r.wells,
        r.days,
        r.minutes_sampled,
        r.minutes_at_pc,
        r.lost,
        r.duplicated,
        r.minutes_missed,
        r.max_store_fill * 100.0,
        r.pending_at_end,
        r.outages,
        r.outage_days,
        r.restarts,
        r.handheld_trips,
        r.minutes_via_handheld,
        r.sensor_failures,
        r.faults_reported,
        r.partial_minutes,
        r.pulls,
        r.pulls_complete,
        r.pulls_cut,
        r.unreachable.len(),
        r.batches,
        r.values_checked,
        r.values_mismatched,
        r.elapsed_s
    ))
}

fn sensor(a: &SensorArgs) -> Result<String, String> {
    crate::gateway::init_log();
    let kind = Sensor::from_name(&a.kind).ok_or("--kind: temperature or level")?;
    let fault = Fault::from_name(&a.fault).ok_or("--fault: none, element, adc or power")?;
    let s = SimSensor::new(SensorConfig {
        address: a.address,
        kind,
        fault,
        seed: a.seed,
    });
    crate::host::block_on(async {
        let t = open_line(&a.bus, &a.line, None)?;
        run::run_sensor(t, s, Clock::new(a.speed))
            .await
            .map_err(|e| e.to_string())
    })?;
    Ok(String::new())
}

fn concentrator(a: &ConcentratorArgs) -> Result<String, String> {
    crate::gateway::init_log();
    if !(1_000..=180_000).contains(&a.poll_interval.as_millis()) {
        return Err(format!(
            "--poll-interval {:?}: 1 s to 3 min (the sensors keep three minutes)",
            a.poll_interval
        ));
    }
    let mut store = Store::open(
        &a.store,
        a.well,
        a.capacity_days * DAY_MINUTES,
        Durability::Full,
    )
    .map_err(|e| e.to_string())?;
    if let Some(p) = &a.calibration {
        // The file gives the first tables; a table downloaded since (command 160)
        // stays in force over restarts.
        let file = CalibrationFile::read(p).map_err(|e| format!("--calibration: {e}"))?;
        for s in Sensor::ALL {
            if let Some(t) = file.table(s) {
                match store.calibration(s).map_err(|e| e.to_string())? {
                    Some(old) if &old != t => tracing::warn!(
                        "--calibration: the {} table downloaded earlier stays in force (the file gives the first table only)",
                        s.name()
                    ),
                    Some(_) => {}
                    None => store.set_calibration(s, t).map_err(|e| e.to_string())?,
                }
            }
        }
    }
    let clock = Clock::new(a.speed);
    let mut cfg = ConcentratorConfig::reference(a.well);
    cfg.poll_interval = a.poll_interval.as_millis().max(1) as u64;
    let conc = Concentrator::new(cfg, store, clock.now()).map_err(|e| e.to_string())?;
    let tty = std::io::stdout().is_terminal();
    let show = |c: &Concentrator| {
        if a.view {
            let text = view(c);
            if tty {
                print!("\x1b[2J\x1b[H{text}");
            } else {
                println!("{text}");
            }
        }
    };
    let open_bus = || open_line(&a.bus, &a.line, None).map_err(std::io::Error::other);
    let open_up = a
        .uplink
        .as_ref()
        .map(|p| move || open_line(p, &a.line, a.uplink_baud).map_err(std::io::Error::other));
    run::run_concentrator(
        &open_bus,
        open_up
            .as_ref()
            .map(|f| f as run::Opener<'_, SerialTransport>),
        conc,
        clock,
        Duration::from_millis(a.reply_timeout_ms),
        &show,
    )
    .map_err(|e| e.to_string())?;
    Ok(String::new())
}

/// The concentrator's terminal view.
pub fn view(c: &Concentrator) -> String {
    let mut out = format!("well {} concentrator\n", c.config().well);
    match c.latest() {
        Ok(Some(r)) => {
            let t = |v: f64, d: usize| {
                if v.is_finite() {
                    format!("{v:.d$}")
                } else {
                    "-".into()
                }
            };
            out.push_str(&format!(
                "  minute {}: water {} °C, level {} m, level sensor {} °C\n",
                iso_minute(r.minute),
                t(r.temperature, 3),
                t(r.level, 3),
                if r.valid & 4 != 0 {
                    format!("{:.1}", hart_wells::sensor::body_celsius(r.ls_raw))
                } else {
                    "-".into()
                }
            ));
        }
        _ => out.push_str("  no values yet\n"),
    }
    if let Ok(Some(r)) = c.latest() {
        use hart_wells::average::{averages, period_of, Every};
        for every in [
            Every::Hour,
            Every::Day,
            Every::Pentad,
            Every::Dekad,
            Every::Month,
        ] {
            let (from, to) = period_of(r.minute, every);
            let Ok(recs) = c.store().range(from, to.saturating_sub(1)) else {
                continue;
            };
            if let Some(a) = averages(recs, every).pop() {
                let f = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.3}"));
                out.push_str(&format!(
                    "  this {:<6} from {}: water {} °C, level {} m ({} minutes)\n",
                    every.name(),
                    iso_minute(a.start),
                    f(a.temperature),
                    f(a.level),
                    a.temperature_n.max(a.level_n)
                ));
            }
        }
    }
    for s in c.sensors() {
        out.push_str(&format!(
            "  sensor {} ({}): {}\n",
            s.status.address,
            s.status.kind.name(),
            state_name(s.status.state)
        ));
    }
    let st = c.store();
    if let (Ok((stored, unsent, _)), Ok(dropped)) = (st.counts(), st.dropped_unsent()) {
        out.push_str(&format!(
            "  store: {stored} minutes ({:.1} % of {} days), {unsent} not handed over{}\n",
            stored as f64 * 100.0 / st.capacity() as f64,
            st.capacity() / DAY_MINUTES,
            if dropped > 0 {
                format!(", {dropped} DROPPED BEFORE HAND-OVER")
            } else {
                String::new()
            }
        ));
    }
    match st.last_transfer() {
        Ok(Some((at, n))) => out.push_str(&format!(
            "  last transfer: {} ({n} minutes handed over in all)\n",
            iso_minute(at)
        )),
        _ => out.push_str("  last transfer: never\n"),
    }
    out
}

/// A minute as `YYYY-MM-DD HH:MM` UTC.
pub fn iso_minute(m: u32) -> String {
    // `YYYY-MM-DDTHH:MM:00Z`, always ASCII of that shape.
    let s = hart_wells::export::iso8601(m);
    format!("{} {}", &s[..10], &s[11..16])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_and_dates() {
        assert_eq!(parse_duration("3m").unwrap(), Duration::from_secs(180));
        assert_eq!(parse_duration("2").unwrap(), Duration::from_secs(2));
        assert_eq!(parse_duration("500ms").unwrap(), Duration::from_millis(500));
        assert!(parse_duration("3x").is_err());
        assert!(parse_duration("0s").is_err());
        assert_eq!(iso_minute(1_772_323_200 / 60), "2026-03-01 00:00");
        assert_eq!(parse_time_of_day("06:30").unwrap(), 6 * 3600 + 1800);
        assert_eq!(parse_time_of_day("23:59:59").unwrap(), 86_399);
        assert!(parse_time_of_day("24:00").is_err() && parse_time_of_day("6").is_err());
        // At 05:00 the next of 06:00 and 18:00 is in an hour; at 19:00, 06:00 tomorrow.
        let day = 1_772_323_200;
        let t = [6 * 3600, 18 * 3600];
        assert_eq!(
            run::until_next(&t, day + 5 * 3600),
            Duration::from_secs(3600)
        );
        assert_eq!(
            run::until_next(&t, day + 19 * 3600),
            Duration::from_secs(11 * 3600)
        );
        assert_eq!(
            run::until_next(&t, day + 6 * 3600),
            Duration::from_secs(12 * 3600)
        );
    }
}
