//! `hartkit`: the HART toolkit command line.

use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};
use hart_proto::frame::{
    Address, Frame, FrameSpec, FrameType, LongAddress, MasterKind, ShortAddress, UniqueId,
};
use hartkit::{annotate, hex, json};

/// HART toolkit: decode and encode frames, simulate devices and networks, and talk HART
/// to devices over serial modems, RS-485 and HART-IP.
#[derive(Parser)]
#[command(name = "hartkit", version, about, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Top,
    /// Log level on standard error: error, warn, info, debug (the host commands' raw
    /// traffic) or trace (frames decoded too). Default: RUST_LOG or HARTKIT_LOG, else
    /// info for servers and warn for the rest.
    #[arg(long, global = true, value_name = "LEVEL")]
    log_level: Option<String>,
    /// Log format: text, or json (one object a line, for a log collector).
    #[arg(long, global = true, value_name = "FORMAT", default_value = "text")]
    log_format: hartkit::logging::LogFormat,
}

#[derive(Subcommand)]
enum Top {
    /// Decode or build single HART frames.
    #[command(subcommand)]
    Frame(FrameCmd),
    /// Simulate a HART network in virtual time.
    #[command(subcommand)]
    Sim(SimCmd),
    /// The remote well-monitoring network: sensors, data concentrators, the
    /// handheld and the bureau's PC over RS-485 and telephone lines (docs/wells.md).
    #[command(subcommand)]
    Wells(hartkit::wells::WellsCmd),
    /// WirelessHART: decode 802.15.4 captures whole (MICs, decryption with keys
    /// learned on the way, commands by name) and build frames (docs/wireless.md).
    #[command(subcommand)]
    Wireless(hartkit::wireless::WirelessCmd),
    /// Find devices: command 0 in short frames over a polling-address range.
    Scan {
        #[command(flatten)]
        host: HostArgs,
        /// First polling address.
        #[arg(long, default_value_t = 0)]
        from: u8,
        /// Last polling address (15 for HART 5 loops, up to 63).
        #[arg(long, default_value_t = 15)]
        to: u8,
    },
    /// Read from a device: pv, loop, dynamic, vars CODES..., status, info.
    Read {
        #[command(flatten)]
        host: HostArgs,
        #[command(flatten)]
        target: TargetArgs,
        /// What to read.
        what: String,
        /// Device variable codes (for `vars`).
        codes: Vec<u8>,
    },
    /// Write to a device and read back: tag, long-tag, descriptor, message, date,
    /// range URV LRV [UNITS], units, damping, polling-address N [MODE], fixed-current,
    /// preambles.
    Write {
        #[command(flatten)]
        host: HostArgs,
        #[command(flatten)]
        target: TargetArgs,
        /// What to write.
        what: String,
        /// Value(s).
        #[arg(required = true, allow_negative_numbers = true)]
        values: Vec<String>,
    },
    /// Send any command (data as hex, or a typed command's fields as JSON) and decode
    /// the reply.
    Command {
        #[command(flatten)]
        host: HostArgs,
        #[command(flatten)]
        target: TargetArgs,
        /// Command number (0-65535).
        number: u16,
        /// Request data as hex, or the request's fields as a JSON object with the names
        /// `hartkit decode --json` shows, e.g. '{"pv_units": "kPa"}' for command 44.
        #[arg(default_value = "")]
        data: String,
    },
    /// Configure, enable, disable or show a burst message.
    Burst {
        #[command(flatten)]
        host: HostArgs,
        #[command(flatten)]
        target: TargetArgs,
        #[command(subcommand)]
        action: BurstCmd,
    },
    /// Print every frame seen on the line, decoded, with timing.
    Monitor {
        #[command(flatten)]
        host: HostArgs,
        /// Stop after this many seconds.
        #[arg(long)]
        duration: Option<f64>,
        /// Also write every frame to FILE as pcapng for Wireshark (`-`: standard output,
        /// the listing then goes to standard error): `hartkit monitor -p ... --pcap - |
        /// wireshark -k -i -`.
        #[arg(long, value_name = "FILE")]
        pcap: Option<String>,
    },
    /// Conformance tests of a field device: data link, commands, burst mode, and the
    /// physical layer from a recording (`conform phy FILE.wav`); see docs/conform.md.
    #[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
    Conform(Box<ConformCli>),
    /// HART captures: read back pcapng/pcap files (ours, or tcpdump's of HART-IP).
    #[command(subcommand)]
    Capture(CaptureCmd),
    /// The gateway: a polling engine in front of HART loops (serial or RS-485 lines,
    /// HART-IP servers, simulated plants), with HART-IP, Modbus TCP, Modbus RTU and
    /// OPC UA front ends. With no front end it shows the polled devices on the terminal.
    Serve(Box<ServeCli>),
    /// HART-IP tools: a load generator for HART-IP servers.
    #[command(subcommand)]
    HartIp(HartIpCmd),
    /// Modbus tools: a load generator for Modbus TCP servers (the gateway's front end).
    #[command(subcommand)]
    Modbus(ModbusCmd),
    /// OPC UA tools: the gateway's trust list of client certificates.
    #[command(subcommand)]
    Opcua(OpcUaCmd),
    /// The software Bell 202 modem: frames to and from WAV files or raw samples.
    #[command(subcommand)]
    Modem(ModemCmd),
    /// The 4-20 mA loop: cable length from the network's RC time constant.
    #[command(subcommand)]
    Loop(LoopCmd),
    /// The gateway's history (`hartkit serve --history`): the stored devices, and one
    /// variable of one device over a time range (docs/history.md).
    #[command(subcommand)]
    History(HistoryCmd),
    /// Shell completions on standard output, e.g. `hartkit completions bash >
    /// ~/.local/share/bash-completion/completions/hartkit`.
    Completions {
        /// bash, zsh, fish, elvish or powershell.
        shell: clap_complete::Shell,
    },
    /// Manual pages made from the same definitions as --help: hartkit.1 and one per
    /// command (hartkit-serve.1, hartkit-wells-pc.1, ...) in DIR; `man -l
    /// DIR/hartkit.1` shows one.
    Manual {
        /// Where to write them.
        #[arg(long, value_name = "DIR", default_value = ".")]
        dir: std::path::PathBuf,
    },
    /// The simulated plant: devices found by scan, shown live until Ctrl-C.
    Demo {
        /// Stop after this many seconds.
        #[arg(long)]
        duration: Option<f64>,
        /// One JSON object per update instead of the table.
        #[arg(long)]
        json: bool,
        /// Where the plant is (default: the built-in simulated plant).
        #[arg(long, short = 'p', default_value = "sim")]
        port: String,
    },
}

#[derive(Subcommand)]
enum CaptureCmd {
    /// Print every HART frame of a pcapng or pcap capture, as `monitor` prints them.
    Read {
        /// The capture file.
        file: String,
        /// HART-IP on these UDP/TCP ports (repeat for more; default 5094).
        #[arg(long = "port", value_name = "PORT", default_values_t = [5094u16])]
        ports: Vec<u16>,
        /// One JSON object per frame.
        #[arg(long)]
        json: bool,
    },
}

#[derive(Subcommand)]
enum HistoryCmd {
    /// One variable of one device over a time range: every stored sample, or buckets
    /// of --every aggregated with --agg. Times: RFC 3339 in UTC
    /// (2026-01-31T12:00:00Z), now, or before now (-1h, -30m, -7d).
    Query {
        /// The history database: an SQLite file or a postgres:// URL.
        #[arg(long, value_name = "FILE|URL")]
        db: String,
        /// The device: its tag (long tag) or unique ID (10 hex digits).
        #[arg(long, value_name = "TAG|UNIQUE_ID")]
        device: String,
        /// The variable: pv, sv, tv, qv, loop_current, percent_range or device_status.
        #[arg(long, default_value = "pv")]
        var: String,
        /// From this time (included).
        #[arg(
            long,
            value_name = "T",
            default_value = "-1h",
            allow_hyphen_values = true
        )]
        from: String,
        /// To this time (excluded).
        #[arg(
            long,
            value_name = "T",
            default_value = "now",
            allow_hyphen_values = true
        )]
        to: String,
        /// Buckets of this width (1s, 1m, 15min, 1h, 1d), aligned on whole multiples
        /// since 1970 UTC.
        #[arg(long, value_name = "DURATION")]
        every: Option<String>,
        /// How a bucket's samples become one value: mean, min, max or last.
        #[arg(long, default_value = "mean", requires = "every")]
        agg: String,
        /// A JSON array of {time, value, units, quality}.
        #[arg(long, conflicts_with = "csv")]
        json: bool,
        /// CSV: time,value,units,quality.
        #[arg(long)]
        csv: bool,
    },
    /// The stored devices: unique ID, tag, loop, first and last sample, samples.
    Devices {
        /// The history database: an SQLite file or a postgres:// URL.
        #[arg(long, value_name = "FILE|URL")]
        db: String,
        /// JSON.
        #[arg(long, conflicts_with = "csv")]
        json: bool,
        /// CSV.
        #[arg(long)]
        csv: bool,
    },
    /// Subscribe to a Sparkplug group's topics (QoS 1, persistent session) and store
    /// every gateway's data in one historian, until Ctrl-C: many `hartkit serve
    /// --mqtt` gateways, one shared history (docs/history.md, docs/mqtt.md).
    Ingest {
        /// The broker, mqtt://HOST[:PORT], or a cluster's nodes,
        /// mqtt://H1:P1,H2:P2,H3:P3 (the next one when the connection is lost).
        #[arg(long, value_name = "URL")]
        mqtt: String,
        /// The Sparkplug group ID the gateways publish in.
        #[arg(long, value_name = "G", default_value = "hartkit")]
        group: String,
        /// The history database: an SQLite file or a postgres:// URL.
        #[arg(long, value_name = "FILE|URL")]
        history: String,
        /// The MQTT client ID; keep it stable, the broker keeps the session's
        /// messages under it while the ingest is away (default hartkit-ingest-G).
        #[arg(long, value_name = "ID")]
        client_id: Option<String>,
        /// User name for the broker.
        #[arg(long, value_name = "NAME")]
        username: Option<String>,
        /// A file whose first line is the broker password (never on the command line).
        #[arg(long, value_name = "FILE", requires = "username")]
        password_file: Option<std::path::PathBuf>,
        /// mqtts://: PEM file of the certificate authorities of the broker's
        /// certificate (default: the system's).
        #[arg(long, value_name = "FILE")]
        ca_file: Option<std::path::PathBuf>,
    },
    /// Inserts samples as the gateway's writer does and times a one-day query
    /// (scripts/bench-history).
    #[command(hide = true)]
    Bench {
        /// A new SQLite file, or the URL of an empty PostgreSQL database.
        #[arg(long, value_name = "FILE|URL")]
        db: String,
        /// Devices, each with its 7 variables once a second.
        #[arg(long, default_value_t = 2)]
        devices: usize,
        /// Seconds of data.
        #[arg(long, default_value_t = 86_400)]
        seconds: u64,
        /// Query repetitions (the median is shown).
        #[arg(long, default_value_t = 5)]
        repeat: usize,
    },
}

fn history(cmd: &HistoryCmd) -> Result<String, (String, u8)> {
    use hart_history::{cli, Format};
    let format = |json: bool, csv: bool| match (json, csv) {
        (true, _) => Format::Json,
        (_, true) => Format::Csv,
        _ => Format::Text,
    };
    match cmd {
        HistoryCmd::Query {
            db,
            device,
            var,
            from,
            to,
            every,
            agg,
            json,
            csv,
        } => cli::query_command(
            &cli::QueryArgs {
                db: db.clone(),
                device: device.clone(),
                var: var.clone(),
                from: from.clone(),
                to: to.clone(),
                every: every.clone(),
                agg: agg.clone(),
                format: format(*json, *csv),
            },
            std::time::SystemTime::now(),
        ),
        HistoryCmd::Devices { db, json, csv } => cli::devices_command(db, format(*json, *csv)),
        HistoryCmd::Ingest {
            mqtt,
            group,
            history,
            client_id,
            username,
            password_file,
            ca_file,
        } => hart_ingest::cli::ingest_command(&hart_ingest::cli::IngestArgs {
            mqtt: mqtt.clone(),
            group: group.clone(),
            history: history.clone(),
            client_id: client_id.clone(),
            username: username.clone(),
            password_file: password_file.clone(),
            ca_file: ca_file.clone(),
        }),
        HistoryCmd::Bench {
            db,
            devices,
            seconds,
            repeat,
        } => hart_history::bench::run(&hart_history::bench::BenchArgs {
            db: db.clone(),
            devices: *devices,
            seconds: *seconds,
            repeat: *repeat,
        })
        .map(|r| r.to_string())
        .map_err(|e| e.into()),
    }
}

#[derive(Subcommand)]
enum OpcUaCmd {
    /// Trust an OPC UA client's certificate: the gateway's Basic256Sha256 endpoint lets
    /// in only clients whose certificate is trusted; an unknown one is refused and kept
    /// in <DIR>/rejected. This moves it (FILE: its file name or the start of its
    /// thumbprint, or any certificate file, DER or PEM; --all: every rejected one) into
    /// <DIR>/trusted, where the running gateway finds it at the client's next attempt.
    /// --list shows both folders.
    Trust(OpcUaTrustArgs),
}

#[derive(Args)]
struct OpcUaTrustArgs {
    /// The gateway's PKI directory, as given to `hartkit serve --opcua-pki` (default
    /// ~/.local/share/hartkit/opcua-pki, or under $XDG_DATA_HOME).
    #[arg(long, value_name = "DIR")]
    opcua_pki: Option<std::path::PathBuf>,
    /// The certificate: a rejected one's file name or thumbprint (4 hex digits or
    /// more), or a certificate file.
    #[arg(
        value_name = "FILE",
        required_unless_present_any = ["all", "list"],
        conflicts_with_all = ["all", "list"]
    )]
    file: Option<String>,
    /// Trust every rejected certificate.
    #[arg(long, conflicts_with = "list")]
    all: bool,
    /// List the rejected and trusted certificates (subject, thumbprint, validity).
    #[arg(long)]
    list: bool,
}

#[derive(Subcommand)]
enum ModbusCmd {
    /// Load a Modbus TCP server: CLIENTS connections, each reading COUNT input
    /// registers of the units in turn, one request at a time, for --duration seconds;
    /// reports requests/s, latency and errors. Runs in its own process, so start the
    /// gateway separately (hartkit serve --sim --instant --modbus 127.0.0.1:1502).
    Bench(ModbusBenchArgs),
}

#[derive(Args)]
struct ModbusBenchArgs {
    /// The server, HOST:PORT (port 502 by default).
    #[arg(long, short = 'p', value_name = "HOST[:PORT]")]
    port: String,
    /// Connections at once.
    #[arg(long, default_value_t = 10)]
    clients: usize,
    /// Seconds to run.
    #[arg(long, default_value_t = 10.0)]
    duration: f64,
    /// Unit ids to read, in turn (e.g. 1-4 or 1,3).
    #[arg(long, default_value = "1")]
    units: String,
    /// First input register.
    #[arg(long, default_value_t = 0)]
    register: u16,
    /// Registers per request (1-125).
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u16).range(1..=125))]
    count: u16,
    /// Worker threads of the load generator (0: one per core).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// JSON output.
    #[arg(long)]
    json: bool,
}

#[derive(Subcommand)]
enum HartIpCmd {
    /// Load a HART-IP server: SESSIONS sessions, each sending a request (command 1 to
    /// the device at --poll, in a long frame) after the previous response, for
    /// --duration seconds; reports transactions/s, latency and errors. Runs in its own
    /// process, so start the server separately (hartkit serve --hart-ip ADDR --sim
    /// --instant --max-sessions 2000 measures the server without line timing).
    Bench(IpBenchArgs),
}

#[derive(Args)]
struct IpBenchArgs {
    /// The server: udp://HOST[:PORT] or tcp://HOST[:PORT] (port 5094 by default).
    #[arg(long, short = 'p', value_name = "TARGET")]
    port: String,
    /// Sessions at once, each with one request in flight.
    #[arg(long, default_value_t = 1)]
    sessions: usize,
    /// Seconds of load.
    #[arg(long, default_value_t = 10.0)]
    duration: f64,
    /// The command each request carries (0-65535).
    #[arg(long, default_value_t = 1)]
    command: u16,
    /// Request data as hex, or the request's fields as a JSON object.
    #[arg(long, value_name = "HEX|JSON", default_value = "")]
    data: String,
    /// Polling address where command 0 finds the target device (0 is the server
    /// itself, a HART I/O system, which answers without its loop).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(0..=63))]
    poll: u8,
    /// Time-out of each request, ms: a response that does not come in time counts as
    /// an error.
    #[arg(long, default_value_t = 2000)]
    timeout_ms: u64,
    /// Worker threads of the load generator's runtime (0: one per core).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Print one JSON object instead of the summary.
    #[arg(long)]
    json: bool,
}

#[derive(Subcommand)]
enum ModemCmd {
    /// A simulated line in a pipe: raw s16le samples from standard input to standard
    /// output with a cable low-pass, mains hum and noise (`hartkit modem tx --out - |
    /// hartkit modem channel --snr-db 15 --rc-us 65 --hum-hz 50 | hartkit modem rx --raw
    /// s16le --rate 48000 -`).
    Channel {
        /// Sample rate of the stream, Hz.
        #[arg(long, default_value_t = 48_000)]
        rate: u32,
        /// Signal-to-noise ratio, dB, against a sine of --signal-mvpp (none: no noise).
        #[arg(long, allow_negative_numbers = true)]
        snr_db: Option<f64>,
        /// The signal level the SNR refers to, mV peak to peak.
        #[arg(long, default_value_t = 500.0)]
        signal_mvpp: f64,
        /// Cable low-pass time constant, µs (the loop resistance times the cable and
        /// device capacitance; 0: none).
        #[arg(long, default_value_t = 0.0)]
        rc_us: f64,
        /// Mains hum frequency, Hz (50 or 60; 0: none).
        #[arg(long, default_value_t = 0.0)]
        hum_hz: f64,
        /// Hum level, mV peak to peak.
        #[arg(long, default_value_t = 100.0)]
        hum_mvpp: f64,
        /// The 4-20 mA loop current, mA, whose voltage across --loop-ohm is added
        /// (raise --volts-per-fs to keep it within full scale: 12 mA across 250 Ω is 3 V).
        #[arg(long, value_name = "MA")]
        analog_ma: Option<f64>,
        /// Sweep the loop current 4 ↔ 20 mA at this rate instead (the receiver test's
        /// worst case is 10-18 Hz).
        #[arg(long, value_name = "HZ", conflicts_with = "analog_ma")]
        analog_sweep_hz: Option<f64>,
        /// Sense resistor the analog current flows through, Ω.
        #[arg(long, default_value_t = 250.0)]
        loop_ohm: f64,
        /// Volts represented by a full-scale sample.
        #[arg(long, default_value_t = 1.0)]
        volts_per_fs: f64,
        /// Noise seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Modulate frames (hex, delimiter through check byte) into a mono WAV file, or
    /// (`--out -`) raw signed 16-bit samples on standard output for a pipe.
    Tx {
        /// Output file (`-`: raw s16le samples on standard output).
        #[arg(long, value_name = "FILE.wav")]
        out: std::path::PathBuf,
        /// Sample rate, Hz (8000-192000).
        #[arg(long, default_value_t = 48000)]
        rate: u32,
        /// Signal level, mV peak-to-peak (a device's 1 mApp across 250 Ω is 500).
        #[arg(long, default_value_t = 500.0)]
        amplitude_mvpp: f64,
        /// Preamble characters (0xFF) before each frame.
        #[arg(long, default_value_t = 5)]
        preambles: usize,
        /// Silence before, between and after frames, ms.
        #[arg(long, default_value_t = 30.0)]
        gap_ms: f64,
        /// Volts represented by a full-scale sample.
        #[arg(long, default_value_t = 1.0)]
        volts_per_fs: f64,
        /// Write 32-bit float samples instead of 16-bit PCM.
        #[arg(long)]
        float: bool,
        /// Add white noise over the whole recording, silence included: signal-to-noise
        /// ratio in dB against a sine of --amplitude-mvpp (as `modem channel --snr-db`).
        #[arg(long, allow_negative_numbers = true, value_name = "DB")]
        snr_db: Option<f64>,
        /// Seed of the noise.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Read frames from FILE, one hex frame per line.
        #[arg(long = "in", value_name = "FILE")]
        input: Option<std::path::PathBuf>,
        /// Frames as hex (delimiter through check byte).
        frames: Vec<String>,
    },
    /// Decode every frame in a mono WAV file (16/24/32-bit PCM or float, 8-192 kHz), or
    /// in raw samples (`--raw s16le --rate R`, from FILE or standard input).
    Rx {
        /// The WAV file (or, with --raw, a raw file; `-` or nothing: standard input).
        file: Option<std::path::PathBuf>,
        /// One JSON object per line and frame: t, hex, preambles, checksum_ok,
        /// parity_errors, level_mvpp.
        #[arg(long)]
        json: bool,
        /// Volts represented by a full-scale sample (1.0).
        #[arg(long, default_value_t = 1.0)]
        volts_per_fs: f64,
        /// Raw sample format instead of WAV (only s16le: signed 16-bit little-endian mono).
        #[arg(long, value_name = "FORMAT")]
        raw: Option<String>,
        /// Sample rate of raw input, Hz.
        #[arg(long)]
        rate: Option<u32>,
        /// Also write every frame decoded to FILE as pcapng for Wireshark (`-`:
        /// standard output; the listing then goes to standard error).
        #[arg(long, value_name = "FILE")]
        pcap: Option<String>,
        /// Listen to a sound card's input instead (`default`, or a name from
        /// --list-sound-cards); needs a hartkit built with the `sound-card` feature.
        #[arg(long, value_name = "NAME", conflicts_with_all = ["file", "raw"])]
        sound_card: Option<String>,
        /// List the sound cards' inputs and stop.
        #[arg(long)]
        list_sound_cards: bool,
        /// Show the carrier, the level and the frames live on one line of standard
        /// error.
        #[arg(long)]
        live: bool,
        /// Decode a long file on N cores (default: every core this process may use);
        /// the output is the same as on one, byte for byte. Standard input, the live
        /// view and files under 2^21 samples (44 s at 48 kHz) decode on one.
        #[arg(long, value_name = "N")]
        jobs: Option<usize>,
        /// Samples per piece decoded on its own with --jobs (tests).
        #[arg(long, hide = true)]
        chunk_samples: Option<u64>,
    },
    /// Measure the demodulator: frame error rate against Eb/N0 and impairments, speed;
    /// writes the report.
    Bench(ModemBenchArgs),
}

#[derive(Args)]
struct ModemBenchArgs {
    /// Frames per condition.
    #[arg(long, default_value_t = 1000)]
    frames: usize,
    /// Directory for the report (modem-bench.md, modem-bench.csv).
    #[arg(long, default_value = "docs")]
    out: std::path::PathBuf,
    /// Sample rate, Hz.
    #[arg(long, default_value_t = 48000)]
    rate: u32,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Only these conditions (names as in the report; default all).
    #[arg(long, value_name = "NAME")]
    only: Vec<String>,
    /// Run minimodem side by side when it is installed (needs a scratch directory).
    #[arg(long)]
    minimodem: bool,
}

#[derive(Subcommand)]
enum LoopCmd {
    /// Longest cable for a network: by the rule (the RC time constant of loop
    /// resistance and cable plus device capacitance within 65 µs), and with --simulate
    /// from the signal (the network on the analog loop, sample by sample).
    Cable(CableArgs),
}

#[derive(Args)]
struct CableArgs {
    /// Cable capacitance, pF per metre (without it: the whole classic table).
    #[arg(long, allow_hyphen_values = true)]
    capacitance_pf_per_m: Option<f64>,
    /// Devices on the loop.
    #[arg(long, default_value_t = 1)]
    devices: u32,
    /// The whole classic table: 65, 95, 160 and 225 pF/m against 1, 5, 10 and 15
    /// devices, with the published figures (the default without
    /// --capacitance-pf-per-m).
    #[arg(long, conflicts_with = "capacitance_pf_per_m")]
    table: bool,
    /// Also find the longest cable from the signal: the primary master polls every
    /// device on the analog loop, and the cable is lengthened until fewer than 99.9 %
    /// of frames are decoded by their addressee (each cell takes seconds; the table
    /// runs its cells in parallel).
    #[arg(long)]
    simulate: bool,
    /// With --simulate: transactions of the confirming measurement (each at least
    /// two frames; the search itself uses a fifth of them).
    #[arg(long, default_value_t = 500)]
    transactions: usize,
    /// With --simulate: resolution of the search, m.
    #[arg(long, default_value_t = 25.0, value_name = "M")]
    resolution_m: f64,
    /// With --simulate: write every measurement (pF/m, devices, length, frames,
    /// decoded, FER) as CSV to FILE, for scripts/plot-cable.py.
    #[arg(long, value_name = "FILE")]
    csv: Option<std::path::PathBuf>,
    /// With --simulate: also measure this many lengths from 80 % to 120 % of the
    /// length found (a fifth of the transactions each), to draw the edge.
    #[arg(long, default_value_t = 0, value_name = "N")]
    sweep: usize,
    /// Seed of the receivers' noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Print JSON.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    analog: hartkit::sim::LoopArgs,
}

#[derive(Args, Clone)]
struct HostArgs {
    /// Where the devices are: /dev/ttyUSB0, serial:PATH?baud=1200&rts=high-tx&carrier=dcd,
    /// rs485:PATH?baud=19200, sim, sim:PLANT.toml, sim?virtual, sim?medium=analog&cable_m=N
    /// (the loop sample by sample), udp://HOST[:PORT],
    /// tcp://HOST[:PORT] (HART-IP, port 5094 by default), tls://HOST[:PORT],
    /// dtls://HOST[:PORT] (HART-IP version 2, with --psk or --psk-file).
    #[arg(long, short = 'p', value_name = "TARGET")]
    port: String,
    /// Print JSON instead of tables.
    #[arg(long)]
    json: bool,
    /// Write every transfer as one JSON object per line to FILE.
    #[arg(long, value_name = "FILE")]
    trace: Option<std::path::PathBuf>,
    /// Act as the secondary master (default primary).
    #[arg(long)]
    secondary: bool,
    /// Pre-shared key for tls:// and dtls:// targets (HART-IP version 2).
    #[arg(long, value_name = "IDENTITY:HEXKEY", conflicts_with = "psk_file")]
    psk: Option<String>,
    /// File with the pre-shared key for tls:// and dtls:// targets (its first line
    /// IDENTITY:HEXKEY is used).
    #[arg(long, value_name = "FILE")]
    psk_file: Option<std::path::PathBuf>,
}

impl HostArgs {
    /// The key --psk or --psk-file gives, if any.
    fn key(&self) -> Result<Option<hart_ip_tls::Psk>, (String, u8)> {
        if let Some(text) = &self.psk {
            return hart_ip_tls::Psk::parse(text)
                .map(Some)
                .map_err(|e| (format!("--psk: {e}"), 2));
        }
        if let Some(path) = &self.psk_file {
            let table = hart_ip_tls::PskTable::load(path).map_err(|e| (e, 2))?;
            return Ok(table.keys.into_iter().next());
        }
        Ok(None)
    }
}

#[derive(Args, Clone)]
struct TargetArgs {
    /// The device at this polling address.
    #[arg(long)]
    poll: Option<u8>,
    /// The device with this tag.
    #[arg(long)]
    tag: Option<String>,
    /// The device with this long tag.
    #[arg(long)]
    long_tag: Option<String>,
    /// The device with this unique ID (10 hex digits).
    #[arg(long)]
    unique_id: Option<String>,
}

/// `hartkit conform`.
#[derive(Args)]
struct ConformCli {
    #[command(subcommand)]
    cmd: Option<ConformCmd>,
    /// Where the device is: any target the host commands take (/dev/ttyUSB0,
    /// rs485:PATH, sim, sim:PLANT.toml?virtual, udp://HOST[:PORT], tcp://..., tls://...).
    #[arg(long, short = 'p', value_name = "TARGET")]
    port: Option<String>,
    /// JSON instead of the summary: one object per test per line.
    #[arg(long)]
    json: bool,
    /// Pre-shared key for tls:// and dtls:// targets (HART-IP version 2).
    #[arg(long, value_name = "IDENTITY:HEXKEY", conflicts_with = "psk_file")]
    psk: Option<String>,
    /// File with the pre-shared key for tls:// and dtls:// targets.
    #[arg(long, value_name = "FILE")]
    psk_file: Option<std::path::PathBuf>,
    /// The device at this polling address (default 0).
    #[arg(long, conflicts_with = "unique_id")]
    poll: Option<u8>,
    /// The device with this unique ID (10 hex digits).
    #[arg(long, value_name = "HEX")]
    unique_id: Option<String>,
    /// Only these groups: link, commands, burst (comma-separated).
    #[arg(long, value_name = "GROUPS")]
    only: Option<String>,
    /// What the device should be: a profile file like the simulated devices' (its
    /// identity and device-specific commands are checked).
    #[arg(long, value_name = "DEVICE.toml")]
    expect: Option<std::path::PathBuf>,
    /// Write a self-contained HTML report to FILE.
    #[arg(long, value_name = "FILE.html")]
    report: Option<std::path::PathBuf>,
    /// Allow the tests that write (each restores what it changes).
    #[arg(long)]
    allow_writes: bool,
}

#[derive(Subcommand)]
enum ConformCmd {
    /// The physical-layer tests on a recording of the device's signal.
    Phy {
        /// The recording (WAV).
        file: std::path::PathBuf,
        /// JSON, one object per test per line.
        #[arg(long)]
        json: bool,
        /// Write a self-contained HTML report to FILE.
        #[arg(long, value_name = "FILE.html")]
        report: Option<std::path::PathBuf>,
    },
}

/// `hartkit conform`: opens the target like the other host commands and hands over to
/// `hart_conform::cli`.
fn conform(a: &ConformCli) -> Result<String, (String, u8)> {
    let (report, text) = match &a.cmd {
        Some(ConformCmd::Phy { file, json, report }) => {
            hart_conform::cli::phy(file, *json, report.as_deref()).map_err(|e| (e, 2))?
        }
        None => {
            let Some(port) = a.port.clone() else {
                return Err((
                    "give the device's port: hartkit conform -p TARGET (or conform phy FILE.wav)"
                        .into(),
                    2,
                ));
            };
            // The host commands' options, to open the target as they do.
            let h = &HostArgs {
                port,
                json: a.json,
                trace: None,
                secondary: false,
                psk: a.psk.clone(),
                psk_file: a.psk_file.clone(),
            };
            let args = hart_conform::cli::Args {
                target: h.port.clone(),
                poll: a.poll,
                unique_id: a.unique_id.clone(),
                only: a.only.clone(),
                expect: a.expect.clone(),
                json: h.json,
                report: a.report.clone(),
                allow_writes: a.allow_writes,
            };
            hart_conform::cli::options(&args).map_err(|e| (e, 2))?;
            hartkit::host::block_on(async {
                let psk = h.key()?;
                let mut t = hart_host::target::open_async_with(&h.port, psk.as_ref())
                    .await
                    .map_err(|e| (e, 2))?;
                hart_conform::cli::run(&mut t, &args)
                    .await
                    .map_err(|e| (e, 2))
            })?
        }
    };
    use std::io::Write as _;
    let _ = write!(std::io::stdout(), "{text}");
    match hart_conform::cli::exit_code(&report) {
        0 => Ok(String::new()),
        1 => Err((
            format!(
                "{} conformance test(s) failed",
                report.count(hart_conform::Verdict::Fail)
            ),
            1,
        )),
        code => Err(("no test could run; see the reasons above".into(), code)),
    }
}

#[derive(Subcommand, Clone)]
enum BurstCmd {
    /// Configure a burst message.
    Config {
        /// Burst message number.
        #[arg(long, default_value_t = 0)]
        message: u8,
        /// Command to publish (1, 2, 3, 9, 33, 38, 48).
        #[arg(long)]
        command: u16,
        /// Device variable codes for the slots (commands 9 and 33).
        #[arg(long, value_delimiter = ',')]
        vars: Vec<u8>,
        /// Update period, s.
        #[arg(long)]
        period: f32,
        /// Maximum update period, s.
        #[arg(long)]
        max_period: Option<f32>,
        /// continuous, window, rising, falling or on-change.
        #[arg(long, default_value = "continuous")]
        trigger: String,
        /// Trigger level (window, rising, falling).
        #[arg(long, allow_negative_numbers = true)]
        level: Option<f32>,
    },
    /// Enable a burst message.
    On {
        /// Burst message number.
        #[arg(long, default_value_t = 0)]
        message: u8,
    },
    /// Disable a burst message.
    Off {
        /// Burst message number.
        #[arg(long, default_value_t = 0)]
        message: u8,
    },
    /// Show a burst message's configuration.
    Show {
        /// Burst message number.
        #[arg(long, default_value_t = 0)]
        message: u8,
    },
}

#[derive(Subcommand)]
enum SimCmd {
    /// Run a simulated network (discovery, then round-robin polling) and report
    /// throughput, failures, collisions and efficiency.
    Bench(BenchArgs),
    /// Run simulated field devices on a serial port or a pseudo-terminal, in real time.
    Serve(ServeArgs),
}

#[derive(Args)]
struct ServeArgs {
    /// Create a pseudo-terminal pair; the first line printed is `pty: /dev/pts/N`, the
    /// path a host opens.
    #[arg(long, conflicts_with = "serial", required_unless_present = "serial")]
    pty: bool,
    /// Serial port of a HART modem (1200 bit/s 8O1 unless --baud says otherwise).
    #[arg(long, value_name = "PATH")]
    serial: Option<std::path::PathBuf>,
    /// Baud rate of the serial port.
    #[arg(long, default_value_t = 1200)]
    baud: u32,
    /// Device profile: pressure, temperature, valve, or a profile file (TOML).
    /// Repeat for several devices (multidrop).
    #[arg(long = "profile", value_name = "NAME|FILE", default_value = "pressure")]
    profiles: Vec<String>,
    /// Polling address of each device, in the order of --profile (default 0, 1, 2...).
    #[arg(long = "poll", value_name = "N", value_parser = clap::value_parser!(u8).range(0..=63))]
    polls: Vec<u8>,
    /// Keep each device's configuration in DIR/device-NN.toml (NN = its --poll), so it
    /// survives restarts.
    #[arg(long, value_name = "DIR")]
    state_dir: Option<std::path::PathBuf>,
    /// Set the write-protect jumper of every device.
    #[arg(long)]
    write_protect: bool,
    /// Stop after this many seconds (default: run until killed).
    #[arg(long, value_name = "SECONDS")]
    run_for: Option<f64>,
    /// Make every device break this rule on purpose, to test a conformance tester
    /// (`hartkit conform`): late-reply, gap-in-reply, bad-reply-check-byte, ... (the
    /// list is in docs/conform.md). Repeat for several.
    #[arg(long = "fault", value_name = "NAME")]
    faults: Vec<String>,
}

#[derive(Args)]
struct BenchArgs {
    /// Physical layer: fsk, rs485:BAUD, psk or infrared.
    #[arg(long, default_value = "fsk")]
    phy: String,
    /// Number of devices (polling addresses 1..N, at most 63).
    #[arg(long, default_value_t = 15, value_parser = clap::value_parser!(u8).range(1..=63))]
    devices: u8,
    /// Add a secondary master polling command 1.
    #[arg(long)]
    secondary: bool,
    /// Put device 1 in burst mode publishing command 3.
    #[arg(long)]
    burst: bool,
    /// Burst period in seconds.
    #[arg(long, default_value_t = 1.0)]
    burst_period: f64,
    /// Command the primary master polls.
    #[arg(long, default_value_t = 3)]
    command: u16,
    /// Virtual seconds to simulate.
    #[arg(long, default_value_t = 60.0)]
    duration: f64,
    /// Bit error rate at every receiver (e.g. 1e-4).
    #[arg(long, default_value_t = 0.0)]
    ber: f64,
    /// Seed of the random generator (same seed, same run).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Write every transmission as one JSON object per line to FILE.
    #[arg(long, value_name = "FILE")]
    trace: Option<std::path::PathBuf>,
    /// Print one JSON object instead of the summary.
    #[arg(long)]
    json: bool,
    /// Run full field devices of this built-in profile (pressure, temperature, valve)
    /// instead of minimal responders.
    #[arg(long, value_name = "NAME")]
    profile: Option<String>,
    /// What carries the characters: digital (whole characters, --ber) or analog (the
    /// 4-20 mA loop sample by sample, every station with its own modem; FSK only).
    #[arg(long, default_value = "digital", value_parser = ["digital", "analog"])]
    medium: String,
    /// Analog medium: cable length, m.
    #[arg(long, default_value_t = 0.0, value_name = "M")]
    cable_m: f64,
    #[command(flatten)]
    analog: hartkit::sim::LoopArgs,
}

#[derive(Subcommand)]
enum FrameCmd {
    /// Decode a frame given as hex (spaces and colons allowed; with or without preamble).
    Decode {
        /// The frame bytes, e.g. `FF FF FF FF FF 02 80 00 00 82`.
        #[arg(required = true, num_args = 1..)]
        hex: Vec<String>,
        /// Print one JSON object instead of the annotated view.
        #[arg(long)]
        json: bool,
    },
    /// Build a frame and print it as hex.
    Encode(EncodeArgs),
}

#[derive(Args)]
struct EncodeArgs {
    /// Short frame to this polling address (0-63).
    #[arg(
        long,
        value_name = "N",
        conflicts_with = "long",
        required_unless_present = "long"
    )]
    short: Option<u8>,
    /// Long frame to this unique ID (10 hex digits, e.g. 264E0000D2; 0000000000 = broadcast).
    #[arg(long, value_name = "HEX")]
    long: Option<String>,
    /// Command number (0-65535; above 255 is sent through command 31).
    #[arg(long)]
    command: u16,
    /// Send the command through command 31 even if it is below 256.
    #[arg(long)]
    extended: bool,
    /// Data bytes as hex, or the fields of the command's request (of its reply with
    /// --ack/--back) as a JSON object, e.g. '{"pv_units": "kPa", "pv": 1.5}'.
    #[arg(long, value_name = "HEX|JSON", default_value = "")]
    data: String,
    /// Secondary master (default primary).
    #[arg(long)]
    secondary: bool,
    /// Set the burst-mode bit of the address.
    #[arg(long)]
    burst: bool,
    /// Number of preamble bytes.
    #[arg(long, default_value_t = hart_proto::frame::DEFAULT_PREAMBLES)]
    preambles: usize,
    /// Build a reply (ACK).
    #[arg(long, conflicts_with = "back")]
    ack: bool,
    /// Build a burst frame (BACK).
    #[arg(long)]
    back: bool,
    /// Response code (first status byte) of an ACK/BACK (decimal, or hex with 0x).
    #[arg(long, default_value = "0", value_parser = byte_arg)]
    rc: u8,
    /// Field device status (second status byte) of an ACK/BACK (decimal, or hex with
    /// 0x: 0x40 is "configuration changed").
    #[arg(long, default_value = "0", value_parser = byte_arg)]
    status: u8,
    /// Expansion bytes as hex (0-3 bytes; no use is defined).
    #[arg(long, value_name = "HEX", default_value = "")]
    expansion: String,
}

fn decode(args: &[String], as_json: bool) -> Result<String, String> {
    let bytes = hex::parse(args)?;
    let frame = Frame::parse(&bytes).map_err(|e| e.to_string())?;
    if as_json {
        Ok(serde_json::to_string_pretty(&json::frame(&frame)).map_err(|e| e.to_string())?)
    } else {
        Ok(annotate::frame(&frame).trim_end().to_string())
    }
}

/// A byte given in decimal (64) or hex with `0x` (0x40), as status bytes are written.
fn byte_arg(s: &str) -> Result<u8, String> {
    let t = s.trim();
    match t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
        Some(h) => u8::from_str_radix(h, 16),
        None => t.parse(),
    }
    .map_err(|_| format!("{s:?}: a byte, 0-255 or 0x00-0xFF"))
}

fn optional_hex(s: &str) -> Result<Vec<u8>, String> {
    if s.trim().is_empty() {
        Ok(vec![])
    } else {
        hex::parse(&[s])
    }
}

fn encode(a: &EncodeArgs) -> Result<String, String> {
    let master = if a.secondary {
        MasterKind::Secondary
    } else {
        MasterKind::Primary
    };
    let address = match (&a.short, &a.long) {
        (Some(p), _) => {
            if *p > 63 {
                return Err(format!("--short {p}: polling address must be 0-63"));
            }
            Address::Short(ShortAddress {
                master,
                burst: a.burst,
                polling_address: *p,
            })
        }
        (None, Some(id)) => Address::Long(LongAddress {
            master,
            burst: a.burst,
            id: UniqueId::parse_hex(id).map_err(|e| format!("--long {id}: {e}"))?,
        }),
        (None, None) => return Err("give --short N or --long HEX".into()),
    };
    let data = hartkit::fields::data_arg(a.command, &a.data, a.ack || a.back)
        .map_err(|e| format!("--data: {e}"))?;
    let expansion = optional_hex(&a.expansion).map_err(|e| format!("--expansion: {e}"))?;
    let frame_type = if a.ack {
        FrameType::Ack
    } else if a.back {
        FrameType::Back
    } else {
        FrameType::Stx
    };
    let spec = FrameSpec {
        preambles: a.preambles,
        frame_type,
        address,
        expansion: &expansion,
        physical_layer: 0,
        command: a.command,
        extended: a.extended,
        status: Some((a.rc, a.status)),
        data: &data,
    };
    let mut out = vec![0u8; spec.encoded_len()];
    let n = spec.encode(&mut out).map_err(|e| e.to_string())?;
    Ok(hex::spaced(&out[..n]))
}

fn sim_bench(a: &BenchArgs) -> Result<String, String> {
    let profile = hartkit::sim::parse_phy(&a.phy)?;
    if !(a.duration > 0.0 && a.duration <= 30.0 * 86_400.0) {
        return Err(format!(
            "--duration {}: must be more than 0 and at most 30 days of virtual time",
            a.duration
        ));
    }
    if !(0.0..=0.5).contains(&a.ber) {
        return Err(format!("--ber {}: bit error rate must be 0..0.5", a.ber));
    }
    if !(a.burst_period >= 0.05 && a.burst_period <= 3600.0) {
        return Err(format!(
            "--burst-period {}: must be 0.05..3600 s",
            a.burst_period
        ));
    }
    let cfg = hart_sim::SimConfig {
        profile,
        devices: a.devices,
        secondary: a.secondary,
        burst_period: a.burst.then_some((a.burst_period * 1e6) as u64),
        command: a.command,
        duration: (a.duration * 1e6) as u64,
        ber: a.ber,
        seed: a.seed,
        trace: a.trace.is_some(),
        faults: hart_sim::Faults::default(),
        device_profile: match a.profile.as_deref() {
            None => None,
            Some(name) => Some(
                hart_device::profiles::BUILTIN
                    .iter()
                    .find(|(n, _)| *n == name)
                    .map(|(n, _)| *n)
                    .ok_or_else(|| {
                        format!("--profile {name}: expected pressure, temperature or valve")
                    })?,
            ),
        },
        medium: match a.medium.as_str() {
            "analog" if profile.name != "fsk" => {
                return Err(format!(
                    "--medium analog models the FSK loop; --phy {} has no analog medium",
                    a.phy
                ))
            }
            "analog" => a.analog.medium(a.cable_m, a.seed)?,
            _ => hart_sim::Medium::Digital,
        },
    };
    let started = std::time::Instant::now();
    let report = hart_sim::run(&cfg);
    let wall = started.elapsed().as_secs_f64();
    if let Some(path) = &a.trace {
        let file =
            std::fs::File::create(path).map_err(|e| format!("--trace {}: {e}", path.display()))?;
        let mut w = std::io::BufWriter::new(file);
        report
            .write_trace(&mut w)
            .map_err(|e| format!("--trace {}: {e}", path.display()))?;
    }
    if a.json {
        serde_json::to_string_pretty(&report.to_json(&cfg, wall)).map_err(|e| e.to_string())
    } else {
        Ok(hartkit::sim::report_text(&cfg, &report, wall))
    }
}

fn sim_serve(a: &ServeArgs) -> Result<String, String> {
    use hartkit::serve::{DeviceSpec, Port, ServeOptions};
    if a.polls.len() > a.profiles.len() {
        return Err(format!(
            "{} --poll given for {} --profile; give one --profile per device",
            a.polls.len(),
            a.profiles.len()
        ));
    }
    let devices: Vec<DeviceSpec> = a
        .profiles
        .iter()
        .enumerate()
        .map(|(i, p)| DeviceSpec {
            profile: p.clone(),
            poll: a.polls.get(i).copied().unwrap_or(i as u8),
        })
        .collect();
    let mut seen = std::collections::HashSet::new();
    for d in &devices {
        if !seen.insert(d.poll) {
            return Err(format!(
                "--poll {}: two devices at one polling address",
                d.poll
            ));
        }
    }
    let port = match &a.serial {
        Some(path) => Port::Serial(path.clone(), a.baud),
        None => Port::Pty,
    };
    let opts = ServeOptions {
        port,
        devices,
        state_dir: a.state_dir.clone(),
        write_protect: a.write_protect,
        run_for: a.run_for.map(std::time::Duration::from_secs_f64),
        faults: a
            .faults
            .iter()
            .map(|f| hart_device::faults::Fault::parse(f).map_err(|e| format!("--fault: {e}")))
            .collect::<Result<_, _>>()?,
    };
    hartkit::serve::serve(&opts, |line| {
        use std::io::Write as _;
        let mut out = std::io::stdout();
        let _ = writeln!(out, "{line}");
        let _ = out.flush();
    })?;
    Ok(String::new())
}

async fn host_client(
    h: &HostArgs,
) -> Result<hart_host::Client<hart_host::target::AnyTransport>, (String, u8)> {
    let verbose = hartkit::logging::traffic();
    let psk = h.key()?;
    hartkit::host::client(
        &h.port,
        psk.as_ref(),
        h.trace.as_deref(),
        verbose,
        h.secondary,
    )
    .await
}

fn target(t: &TargetArgs) -> Result<hart_host::DeviceRef, (String, u8)> {
    hartkit::host::device_ref(
        t.poll,
        t.tag.as_deref(),
        t.long_tag.as_deref(),
        t.unique_id.as_deref(),
    )
}

fn run_host(top: &Top) -> Option<Result<String, (String, u8)>> {
    use hartkit::host;
    // Ports are opened inside the runtime (serial ports register with its reactor).
    Some(match top {
        Top::Scan { host: h, from, to } => host::block_on(async {
            let mut c = host_client(h).await?;
            host::scan(&mut c, *from, *to, h.json).await
        }),
        Top::Read {
            host: h,
            target: t,
            what,
            codes,
        } => host::block_on(async {
            let d = target(t)?;
            let mut c = host_client(h).await?;
            host::read(&mut c, &d, what, codes, h.json).await
        }),
        Top::Write {
            host: h,
            target: t,
            what,
            values,
        } => host::block_on(async {
            let d = target(t)?;
            let mut c = host_client(h).await?;
            host::write(&mut c, &d, what, values, h.json).await
        }),
        Top::Command {
            host: h,
            target: t,
            number,
            data,
        } => host::block_on(async {
            let d = target(t)?;
            let bytes = hartkit::fields::data_arg(*number, data, false)
                .map_err(|e| (format!("data: {e}"), 2))?;
            let mut c = host_client(h).await?;
            host::command(&mut c, &d, *number, &bytes, h.json).await
        }),
        Top::Burst {
            host: h,
            target: t,
            action,
        } => host::block_on(async {
            let d = target(t)?;
            let a = match action.clone() {
                BurstCmd::Config {
                    message,
                    command,
                    vars,
                    period,
                    max_period,
                    trigger,
                    level,
                } => host::BurstAction::Config {
                    message,
                    command,
                    vars,
                    period,
                    max_period,
                    trigger,
                    level,
                },
                BurstCmd::On { message } => host::BurstAction::On { message },
                BurstCmd::Off { message } => host::BurstAction::Off { message },
                BurstCmd::Show { message } => host::BurstAction::Show { message },
            };
            let mut c = host_client(h).await?;
            host::burst(&mut c, &d, &a, h.json).await
        }),
        Top::Monitor {
            host: h,
            duration,
            pcap,
        } => host::block_on(async {
            let psk = h.key()?;
            let mut t = hart_host::target::open_async_with(&h.port, psk.as_ref())
                .await
                .map_err(|e| (e, 2))?;
            let mut capture = pcap
                .as_deref()
                .map(|p| host::Capture::create(p, &h.port))
                .transpose()?;
            // With the capture on standard output, the listing goes to standard error.
            let mut out: Box<dyn std::io::Write> = if pcap.as_deref() == Some("-") {
                Box::new(std::io::stderr())
            } else {
                Box::new(std::io::stdout())
            };
            host::monitor(&mut t, *duration, h.json, &mut out, capture.as_mut())
                .await
                .map(|_| String::new())
        }),
        Top::Capture(CaptureCmd::Read { file, ports, json }) => {
            let mut out = std::io::stdout();
            host::capture_read(file, ports, *json, &mut out).map(|_| String::new())
        }
        Top::Demo {
            duration,
            json,
            port,
        } => hartkit::demo::run(port, *duration, *json).map(|_| String::new()),
        Top::Serve(a) => hartkit::gateway::run(
            a.options(),
            hartkit::gateway::RunMode {
                print_map: a.print_map,
                print_gsd: a.print_gsd,
                run_for: a.run_for,
            },
        ),
        Top::Conform(a) => conform(a),
        Top::HartIp(HartIpCmd::Bench(a)) => hart_ip_bench(a),
        Top::Modbus(ModbusCmd::Bench(a)) => modbus_bench(a),
        Top::Opcua(OpcUaCmd::Trust(a)) => hartkit::gateway::opcua_trust(
            a.opcua_pki.clone(),
            match (&a.file, a.all, a.list) {
                (_, _, true) => hartkit::gateway::TrustAction::List,
                (_, true, _) => hartkit::gateway::TrustAction::All,
                (Some(f), _, _) => hartkit::gateway::TrustAction::File(f.clone()),
                (None, false, false) => unreachable!("clap requires FILE, --all or --list"),
            },
        ),
        _ => return None,
    })
}

/// `hartkit modbus bench`: the load generator of `hart_modbus::load`.
fn modbus_bench(a: &ModbusBenchArgs) -> Result<String, (String, u8)> {
    let address = hartkit::gateway::socket_addr("--port", &a.port, 502)?;
    if !(a.duration > 0.0 && a.duration <= 86_400.0) {
        return Err((
            format!(
                "--duration {}: must be more than 0 and at most 86400 s",
                a.duration
            ),
            2,
        ));
    }
    let mut units = vec![];
    for part in a.units.split(',').filter(|p| !p.trim().is_empty()) {
        let bad = || {
            (
                format!("--units {}: give unit ids 1-247 like 1-4 or 1,3", a.units),
                2,
            )
        };
        let (lo, hi) = part.split_once('-').unwrap_or((part, part));
        let (lo, hi): (u8, u8) = (
            lo.trim().parse().map_err(|_| bad())?,
            hi.trim().parse().map_err(|_| bad())?,
        );
        if lo > hi {
            return Err(bad());
        }
        units.extend(lo..=hi);
    }
    let opts = hart_modbus::load::LoadOptions {
        address,
        clients: a.clients.max(1),
        duration: std::time::Duration::from_secs_f64(a.duration),
        units,
        register: a.register,
        count: a.count,
        threads: a.threads,
    };
    let r = hart_modbus::load::run_blocking(&opts).map_err(|e| (e.to_string(), 5))?;
    if a.json {
        return serde_json::to_string_pretty(&r).map_err(|e| (e.to_string(), 5));
    }
    Ok(format!(
        "{} clients, {:.1} s: {} requests, {:.0} requests/s, {} errors\nlatency ms: p50 {:.3}  p90 {:.3}  p99 {:.3}  max {:.3}",
        r.clients, r.seconds, r.requests, r.per_second, r.errors,
        r.latency_ms[0], r.latency_ms[1], r.latency_ms[2], r.latency_ms[3]
    ))
}

/// `hartkit hart-ip bench`: the load generator of `hart_host::load`, on a
/// multi-threaded runtime.
fn hart_ip_bench(a: &IpBenchArgs) -> Result<String, (String, u8)> {
    let (address, tcp) = match hart_host::target::parse(&a.port).map_err(|e| (e, 2))? {
        hart_host::target::Target::HartIp {
            address,
            tcp,
            secure: false,
        } => (address, tcp),
        _ => {
            return Err((
                format!(
                    "--port {}: the load generator talks to HART-IP servers: give \
                     udp://HOST[:PORT] or tcp://HOST[:PORT]",
                    a.port
                ),
                2,
            ))
        }
    };
    if !(a.duration > 0.0 && a.duration <= 86_400.0) {
        return Err((
            format!(
                "--duration {}: must be more than 0 and at most 86400 s",
                a.duration
            ),
            2,
        ));
    }
    if a.timeout_ms == 0 {
        return Err(("--timeout-ms 0: give a time-out of at least 1 ms".into(), 2));
    }
    let data = hartkit::fields::data_arg(a.command, &a.data, false)
        .map_err(|e| (format!("--data: {e}"), 2))?;
    let opts = hart_host::load::LoadOptions {
        address,
        tcp,
        sessions: a.sessions,
        duration: std::time::Duration::from_secs_f64(a.duration),
        command: a.command,
        data,
        poll: a.poll,
        timeout: std::time::Duration::from_millis(a.timeout_ms),
        threads: a.threads,
    };
    let report = hart_host::load::run_blocking(&opts).map_err(|e| {
        let code = e.exit_code();
        (e.to_string(), code)
    })?;
    if a.json {
        serde_json::to_string_pretty(&hartkit::ip_bench::report_json(&report))
            .map_err(|e| (e.to_string(), 5))
    } else {
        Ok(hartkit::ip_bench::report_text(&report))
    }
}

fn modem(cmd: &ModemCmd) -> Result<String, String> {
    use hartkit::modem;
    match cmd {
        ModemCmd::Tx {
            out,
            rate,
            amplitude_mvpp,
            preambles,
            gap_ms,
            volts_per_fs,
            float,
            snr_db,
            seed,
            input,
            frames,
        } => {
            let frames = modem::parse_frames(frames, input.as_deref())?;
            modem::tx(
                &frames,
                &modem::TxOptions {
                    out: out.clone(),
                    rate: *rate,
                    amplitude_mvpp: *amplitude_mvpp,
                    preambles: *preambles,
                    gap_ms: *gap_ms,
                    volts_per_fs: *volts_per_fs,
                    float: *float,
                    snr_db: *snr_db,
                    seed: *seed,
                },
            )
        }
        ModemCmd::Channel {
            rate,
            snr_db,
            signal_mvpp,
            rc_us,
            hum_hz,
            hum_mvpp,
            analog_ma,
            analog_sweep_hz,
            loop_ohm,
            volts_per_fs,
            seed,
        } => modem::channel(&modem::ChannelOptions {
            analog_ma: *analog_ma,
            analog_sweep_hz: *analog_sweep_hz,
            loop_ohm: *loop_ohm,
            rate: *rate,
            snr_db: *snr_db,
            signal_mvpp: *signal_mvpp,
            rc_us: *rc_us,
            hum_hz: *hum_hz,
            hum_mvpp: *hum_mvpp,
            volts_per_fs: *volts_per_fs,
            seed: *seed,
        }),
        ModemCmd::Rx {
            file,
            json,
            volts_per_fs,
            raw,
            rate,
            pcap,
            sound_card,
            list_sound_cards,
            live,
            jobs,
            chunk_samples,
        } => {
            if *list_sound_cards {
                return Ok(hartkit::sound::list()?.join("\n"));
            }
            let input = match (raw.as_deref(), sound_card) {
                (_, Some(name)) => modem::RxInput::SoundCard(name.clone()),
                (None, None) => modem::RxInput::Wav(
                    file.clone()
                        .ok_or("give a WAV file, or --raw s16le --rate R for raw samples")?,
                ),
                (Some("s16le"), None) => modem::RxInput::RawS16le {
                    path: file.clone().unwrap_or_else(|| "-".into()),
                    rate: rate.ok_or("--raw needs --rate (the sample rate in Hz)")?,
                },
                (Some(other), None) => {
                    return Err(format!("raw format {other:?} is not supported; use s16le"))
                }
            };
            let source = match sound_card {
                Some(name) => format!("modem rx --sound-card {name}"),
                None => format!(
                    "modem rx {}",
                    file.as_deref()
                        .map_or("-".into(), |p| p.display().to_string())
                ),
            };
            let mut capture = pcap
                .as_deref()
                .map(|p| hartkit::host::Capture::create(p, &source))
                .transpose()
                .map_err(|(e, _)| e)?;
            // With the capture on standard output, the listing goes to standard error.
            let mut out: Box<dyn std::io::Write> = if pcap.as_deref() == Some("-") {
                Box::new(std::io::stderr())
            } else {
                Box::new(std::io::stdout().lock())
            };
            if *jobs == Some(0) {
                return Err("--jobs: give 1 or more".into());
            }
            let options = modem::RxOptions {
                volts_per_fs: *volts_per_fs,
                json: *json,
                live: *live,
                jobs: jobs
                    .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get())),
                chunk_samples: *chunk_samples,
            };
            let n = modem::rx(&input, &options, &mut out, capture.as_mut())?;
            if !*json {
                eprintln!("{n} frame(s)");
            }
            Ok(String::new())
        }
        ModemCmd::Bench(a) => hartkit::modem_bench::run(&hartkit::modem_bench::Options {
            frames: a.frames,
            out: a.out.clone(),
            rate: a.rate,
            seed: a.seed,
            only: a.only.clone(),
            minimodem: a.minimodem,
        }),
    }
}

fn loop_cmd(cmd: &LoopCmd) -> Result<String, String> {
    match cmd {
        LoopCmd::Cable(a) => hartkit::cable::run(&hartkit::cable::CableOptions {
            pf_per_m: a.capacitance_pf_per_m,
            devices: a.devices,
            table: a.table || a.capacitance_pf_per_m.is_none(),
            simulate: a.simulate,
            transactions: a.transactions,
            resolution_m: a.resolution_m,
            csv: a.csv.clone(),
            sweep: a.sweep,
            json: a.json,
            seed: a.seed,
            analog: a.analog.clone(),
        }),
    }
}

/// Writes the manual pages of `cmd` and of every command under it into `dir`, named
/// `PREFIX-NAME.1`; returns the files written.
fn manual_pages(
    cmd: &clap::Command,
    dir: &std::path::Path,
    name: &str,
    out: &mut Vec<String>,
) -> std::io::Result<()> {
    let page = cmd.clone().name(name.to_string());
    let mut buf = vec![];
    clap_mangen::Man::new(page).render(&mut buf)?;
    let file = dir.join(format!("{name}.1"));
    std::fs::write(&file, buf)?;
    out.push(file.display().to_string());
    for sub in cmd.get_subcommands().filter(|c| c.get_name() != "help") {
        manual_pages(sub, dir, &format!("{name}-{}", sub.get_name()), out)?;
    }
    Ok(())
}

/// `hartkit completions` and `hartkit manual`: both from the command line's own
/// definitions.
fn self_description(top: &Top) -> Option<Result<String, (String, u8)>> {
    use clap::CommandFactory;
    match top {
        Top::Completions { shell } => {
            let mut cmd = Cli::command();
            let mut buf = vec![];
            clap_complete::generate(*shell, &mut cmd, "hartkit", &mut buf);
            Some(Ok(String::from_utf8_lossy(&buf).trim_end().to_string()))
        }
        Top::Manual { dir } => {
            let mut cmd = Cli::command();
            cmd.build();
            let mut files = vec![];
            let r = std::fs::create_dir_all(dir)
                .and_then(|_| manual_pages(&cmd, dir, "hartkit", &mut files));
            Some(match r {
                Ok(()) => Ok(format!("{} manual pages in {}", files.len(), dir.display())),
                Err(e) => Err((
                    format!(
                        "--dir {}: {e}; check the directory may be written",
                        dir.display()
                    ),
                    5,
                )),
            })
        }
        _ => None,
    }
}

/// Servers log their life at `info` with times; the rest warn only.
fn role(top: &Top) -> hartkit::logging::Role {
    use hartkit::logging::Role;
    use hartkit::wells::WellsCmd;
    match top {
        Top::Serve(_) | Top::Sim(SimCmd::Serve(_)) | Top::History(HistoryCmd::Ingest { .. }) => {
            Role::Server
        }
        Top::Wells(WellsCmd::Sensor(_) | WellsCmd::Concentrator(_) | WellsCmd::Handheld(_)) => {
            Role::Server
        }
        _ => Role::Command,
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if let Err(e) =
        hartkit::logging::init(cli.log_level.as_deref(), cli.log_format, role(&cli.command))
    {
        eprintln!("hartkit: error: {e}");
        return ExitCode::from(2);
    }
    if let Top::History(cmd) = &cli.command {
        return match history(cmd) {
            Ok(text) => {
                // A closed pipe (e.g. `| head`) is not an error worth a message.
                use std::io::Write as _;
                let _ = writeln!(std::io::stdout(), "{text}");
                ExitCode::SUCCESS
            }
            Err((e, code)) => {
                eprintln!("hartkit: error: {e}");
                ExitCode::from(code)
            }
        };
    }
    match self_description(&cli.command) {
        Some(Err((e, code))) => {
            eprintln!("hartkit: error: {e}");
            return ExitCode::from(code);
        }
        Some(Ok(text)) => {
            // A closed pipe (e.g. `| head`) is not an error worth a message.
            use std::io::Write as _;
            let _ = writeln!(std::io::stdout(), "{text}");
            return ExitCode::SUCCESS;
        }
        None => {}
    }
    if let Some(result) = run_host(&cli.command) {
        return match result {
            Ok(text) => {
                use std::io::Write as _;
                if !text.is_empty() {
                    let _ = writeln!(std::io::stdout(), "{text}");
                }
                ExitCode::SUCCESS
            }
            Err((e, code)) => {
                eprintln!("hartkit: error: {e}");
                ExitCode::from(code)
            }
        };
    }
    let result = match &cli.command {
        Top::Frame(FrameCmd::Decode { hex, json }) => decode(hex, *json),
        Top::Frame(FrameCmd::Encode(a)) => encode(a),
        Top::Sim(SimCmd::Bench(a)) => sim_bench(a),
        Top::Sim(SimCmd::Serve(a)) => sim_serve(a).map(|_| String::new()),
        Top::Modem(cmd) => modem(cmd),
        Top::Loop(cmd) => loop_cmd(cmd),
        Top::Wells(cmd) => hartkit::wells::run(cmd),
        Top::Wireless(cmd) => hartkit::wireless::run(cmd),
        _ => unreachable!("host commands are handled above"),
    };
    match result {
        Ok(text) => {
            // A closed pipe (e.g. `| head`) is not an error worth a message.
            use std::io::Write as _;
            if !text.is_empty() {
                let _ = writeln!(std::io::stdout(), "{text}");
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("hartkit: error: {e}");
            ExitCode::from(2)
        }
    }
}

/// Options of `hartkit serve`.
#[derive(Args)]
struct ServeCli {
    /// Gateway configuration file (TOML: [poll], [[loop]], [hart_ip], [modbus],
    /// [modbus_rtu], [profibus], [opcua], [history], [mqtt], [[device_commands]]; see
    /// docs/gateway.md).
    /// Options given here add to it.
    #[arg(long, value_name = "FILE")]
    config: Option<std::path::PathBuf>,
    /// Serve HART-IP here, e.g. 0.0.0.0 or 127.0.0.1:5094 (port 5094 by default).
    #[arg(long, value_name = "ADDR[:PORT]")]
    hart_ip: Option<String>,
    /// Serve HART-IP over UDP (with --tcp: only the ones given; default both).
    #[arg(long)]
    udp: bool,
    /// Serve HART-IP over TCP.
    #[arg(long)]
    tcp: bool,
    /// Serve Modbus TCP here (port 502 by default): each device is a unit, unit id 1 +
    /// its position in the device list (--print-map shows it).
    #[arg(long, value_name = "ADDR[:PORT]")]
    modbus: Option<String>,
    /// Be a Modbus RTU slave on this serial port (units as for --modbus).
    #[arg(long, value_name = "PORT")]
    modbus_rtu: Option<String>,
    /// Baud rate of --modbus-rtu (default 19200).
    #[arg(long, value_name = "BAUD")]
    modbus_baud: Option<u32>,
    /// Parity of --modbus-rtu: N, E (default) or O.
    #[arg(long, value_name = "N|E|O")]
    modbus_parity: Option<char>,
    /// Be a PROFIBUS DP slave on this serial port (8E1): each device is a module of
    /// 28 input and 6 output bytes, 8 devices per station (docs/profibus.md). Without a
    /// port, only with --print-map (the PROFIBUS map instead of the Modbus one).
    #[arg(long, value_name = "PORT", num_args = 0..=1, default_missing_value = "")]
    profibus: Option<String>,
    /// Station address of --profibus (default 5); devices beyond the 8th take the next
    /// addresses.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u8).range(0..=125))]
    profibus_address: Option<u8>,
    /// Bit rate of --profibus: 9600, 19200 (default), 45450 or 93750.
    #[arg(long, value_name = "BAUD")]
    profibus_baud: Option<u32>,
    /// Order of the bytes of Modbus floats and 32-bit integers: abcd (high word first,
    /// the default), cdab (low word first), badc, dcba.
    #[arg(long, value_name = "ORDER")]
    float_order: Option<hart_modbus::map::FloatOrder>,
    /// Serve OPC UA here (port 4840 by default): Objects/HART/<loop>/<device> with PV,
    /// SV, TV, QV, LoopCurrent, PercentRange and methods.
    #[arg(long, value_name = "ADDR[:PORT]")]
    opcua: Option<String>,
    /// OPC UA endpoint security: none, basic256sha256 or both (default: basic256sha256
    /// with --opcua-user, else none on a loopback address and basic256sha256 on any
    /// other). Basic256Sha256 lets in only clients whose certificate is trusted
    /// (`hartkit opcua trust`); with both, anonymous sessions on None only read.
    #[arg(long, value_name = "MODE")]
    opcua_security: Option<String>,
    /// A user of the secure OPC UA endpoint, NAME:PASSWORD (repeat for more): users may
    /// call methods, anonymous sessions then only read. Not with --opcua-security none
    /// (the password would travel in clear).
    #[arg(long = "opcua-user", value_name = "NAME:PASSWORD")]
    opcua_users: Vec<String>,
    /// Directory of the OPC UA certificate and key (made at the first start) and of the
    /// trust list of client certificates (trusted/, rejected/).
    #[arg(long, value_name = "DIR")]
    opcua_pki: Option<std::path::PathBuf>,
    /// Keep the history of every value (every change, and each device every 10 s) in
    /// this SQLite file, or a postgres://USER@HOST/DB database (see docs/history.md;
    /// query it with hartkit history query).
    #[arg(long, value_name = "FILE.sqlite|URL")]
    history: Option<String>,
    /// Publish every device to this MQTT broker as a Sparkplug B edge node:
    /// mqtt://HOST[:PORT] or mqtts://HOST[:PORT] (see docs/mqtt.md).
    #[arg(long, value_name = "URL")]
    mqtt: Option<String>,
    /// Sparkplug group ID of --mqtt (default hartkit).
    #[arg(long, value_name = "G")]
    group: Option<String>,
    /// Sparkplug edge node ID of --mqtt (default: this machine's host name).
    #[arg(long, value_name = "NAME")]
    edge_node: Option<String>,
    /// Publish only while this Sparkplug primary host application says it is online
    /// (spBv1.0/STATE/ID); data are kept meanwhile.
    #[arg(long, value_name = "ID")]
    primary_host: Option<String>,
    /// QoS of the births and data of --mqtt: 0 (Sparkplug's rule, the default) or 1
    /// (at least once, for a broker cluster feeding `hartkit history ingest`; see
    /// docs/mqtt.md).
    #[arg(long, value_name = "0|1", value_parser = clap::value_parser!(u8).range(0..=1))]
    mqtt_qos: Option<u8>,
    /// Serve the web dashboard here: plant, device pages, trends, traffic and a JSON
    /// API (see docs/web.md). A port alone listens on 127.0.0.1 only (default port 8080).
    #[arg(long, value_name = "ADDR[:PORT]")]
    web: Option<String>,
    /// The web dashboard's administrator password: the first line of this file. Without
    /// it the dashboard only reads; with it, writes need a login.
    #[arg(long, value_name = "FILE")]
    web_admin_password_file: Option<std::path::PathBuf>,
    /// Serve the web dashboard over HTTPS with this PEM certificate chain (with --web-key).
    #[arg(long, value_name = "FILE")]
    web_cert: Option<std::path::PathBuf>,
    /// The PEM private key of --web-cert.
    #[arg(long, value_name = "FILE")]
    web_key: Option<std::path::PathBuf>,
    /// A name the web dashboard answers to besides its own addresses and localhost
    /// (plant-gw.example, or plant-gw.example:8443 for that port only); repeat for more.
    /// Requests to any other Host are refused (DNS rebinding), as [web] hosts.
    #[arg(long = "web-host", value_name = "NAME")]
    web_hosts: Vec<String>,
    /// Print the Modbus map (units and registers) once the devices are found, and exit
    /// (with --profibus: the PROFIBUS stations and modules).
    #[arg(long)]
    print_map: bool,
    /// Print the GSD file of the PROFIBUS station (for the PLC's engineering tool) and
    /// exit.
    #[arg(long)]
    print_gsd: bool,
    /// JSON output (--print-map, and the terminal view).
    #[arg(long)]
    json: bool,
    /// Poll each device at most this often, seconds (default 1).
    #[arg(long, value_name = "SECONDS")]
    poll_period: Option<f64>,
    /// The longest a loop test (a fixed loop current, command 40) lasts, seconds,
    /// whichever front end asked for it: then the gateway releases it (default 600).
    #[arg(long, value_name = "SECONDS")]
    loop_test_limit: Option<f64>,
    /// A loop behind the gateway (any host --port target); repeat for several loops
    /// (a multiplexer: each loop is a channel).
    #[arg(long = "port", short = 'p', value_name = "TARGET")]
    ports: Vec<String>,
    /// A simulated plant behind the gateway: these profiles at polling addresses
    /// 1, 2, ... (none: the demo plant); `pressure x15` is 15 pressure transmitters.
    #[arg(long, num_args = 0.., value_name = "PROFILE")]
    sim: Option<Vec<String>>,
    /// Refuse every command not known to only read, on every front end and for every
    /// identity (HART-IP: "access restricted"; Modbus: "illegal function"; OPC UA
    /// methods: BadUserAccessDenied).
    #[arg(long)]
    read_only: bool,
    /// Most HART-IP sessions at once.
    #[arg(long, default_value_t = 64)]
    max_sessions: usize,
    /// Most HART-IP sessions at once from one client address (UDP and TCP together).
    #[arg(long, default_value_t = 16)]
    max_sessions_per_host: usize,
    /// Longest HART-IP inactivity timer granted, seconds (default 300): a session
    /// initiate asking for more is given this (status 8), so abandoned sessions free
    /// themselves.
    #[arg(long, value_name = "SECONDS")]
    max_inactivity: Option<f64>,
    /// Let a loop device at polling address 0 answer there (one loop only); by
    /// default the server itself, a HART I/O system, answers at polling address 0
    /// and reaches that device by its unique ID.
    #[arg(long)]
    transparent: bool,
    /// HART-IP version 2 security: serve TLS (TCP) and DTLS (UDP) with the
    /// pre-shared keys in FILE (lines IDENTITY:HEXKEY, optionally :read-only) at
    /// --hart-ip; plain HART-IP only where --plain asks for it.
    #[arg(long, value_name = "FILE")]
    psk_file: Option<std::path::PathBuf>,
    /// With --psk-file, also serve plain HART-IP (version 1) at this address.
    #[arg(long, value_name = "ADDR[:PORT]", requires = "psk_file")]
    plain: Option<String>,
    /// What plain (unauthenticated) HART-IP sessions may do: read-only (the default
    /// with --psk-file) or read-write (the default without).
    #[arg(long, value_name = "RIGHTS")]
    plain_rights: Option<hart_access::Rights>,
    /// Device-specific commands (128-253 and others not known to hartkit) that only
    /// read, per device type, in a TOML file of [[device]] tables (type = "26F1",
    /// reads = "128,130-131"); every other one counts as a write (docs/hart-ip.md).
    #[arg(long, value_name = "FILE")]
    device_commands: Option<std::path::PathBuf>,
    /// Modbus clients that may write, as addresses or networks (10.0.0.0/24); repeat
    /// for more. Default: loopback only. Others' writes get exception 01.
    #[arg(long = "modbus-write-from", value_name = "NET")]
    modbus_write_from: Vec<String>,
    /// Modbus clients (addresses or networks) whose connections are never closed to
    /// admit others nor limited per address: the SCADA hosts. Repeat for more.
    #[arg(long = "modbus-priority", value_name = "NET")]
    modbus_priority: Vec<String>,
    /// Only these commands may be sent over HART-IP (ranges, e.g. 0-22,48,74-84);
    /// others are answered "access restricted" (16). Every level of command 77 is
    /// checked.
    #[arg(long, value_name = "LIST")]
    allow_commands: Option<hart_ip_server::access::CommandAllowList>,
    /// Also append every write let through, by HART-IP or by an OPC UA method call, as
    /// a JSON line (time, front end, session, peer, identity, device, command, via,
    /// operation) to FILE; the log on standard error has it anyway.
    #[arg(long, value_name = "FILE")]
    audit_file: Option<std::path::PathBuf>,
    /// Scan polling addresses 0..=N of each loop for devices (63: all).
    #[arg(long, default_value_t = 63, value_parser = clap::value_parser!(u8).range(0..=63))]
    scan_to: u8,
    /// With --sim: the simulated devices answer at once, in memory, without the
    /// loop's 1200 bit/s timing, so a load generator measures the gateway itself.
    #[arg(long)]
    instant: bool,
    /// Stop after this many seconds.
    #[arg(long)]
    run_for: Option<f64>,
}

impl ServeCli {
    fn options(&self) -> hartkit::gateway::ServeOptions {
        hartkit::gateway::ServeOptions {
            config: self.config.clone(),
            hart_ip: self.hart_ip.clone(),
            udp: self.udp,
            tcp: self.tcp,
            ports: self.ports.clone(),
            sim: self.sim.clone(),
            instant: self.instant,
            read_only: self.read_only,
            max_sessions: self.max_sessions,
            max_sessions_per_host: self.max_sessions_per_host,
            max_inactivity: self.max_inactivity,
            transparent: self.transparent,
            scan_to: self.scan_to,
            psk_file: self.psk_file.clone(),
            plain: self.plain.clone(),
            plain_rights: self.plain_rights,
            device_commands: self.device_commands.clone(),
            modbus_write_from: self.modbus_write_from.clone(),
            modbus_priority: self.modbus_priority.clone(),
            allow_commands: self.allow_commands.clone(),
            audit_file: self.audit_file.clone(),
            modbus: self.modbus.clone(),
            modbus_rtu: self.modbus_rtu.clone(),
            modbus_baud: self.modbus_baud,
            modbus_parity: self.modbus_parity,
            profibus: self.profibus.clone(),
            profibus_address: self.profibus_address,
            profibus_baud: self.profibus_baud,
            float_order: self.float_order,
            opcua: self.opcua.clone(),
            opcua_security: self.opcua_security.clone(),
            opcua_users: self.opcua_users.clone(),
            opcua_pki: self.opcua_pki.clone(),
            poll_period: self.poll_period,
            loop_test_limit: self.loop_test_limit,
            history: self.history.clone(),
            mqtt: self.mqtt.clone(),
            mqtt_group: self.group.clone(),
            mqtt_edge_node: self.edge_node.clone(),
            mqtt_primary_host: self.primary_host.clone(),
            mqtt_qos: self.mqtt_qos,
            web: self.web.clone(),
            web_admin_password_file: self.web_admin_password_file.clone(),
            web_cert: self.web_cert.clone(),
            web_key: self.web_key.clone(),
            web_hosts: self.web_hosts.clone(),
            json: self.json,
        }
    }
}
