//! `hartkit wireless ...`: WirelessHART captures decoded whole (the logic is in the
//! hart-wireless crate; this is the command-line shell around it).

use std::io::Write;

use clap::{Args, Subcommand};
use hart_wireless::{capture, crypto, decoder};

/// `hartkit wireless ...`.
#[derive(Subcommand)]
pub enum WirelessCmd {
    /// Decode a pcap or pcapng capture of IEEE 802.15.4 frames (link types 195, 230
    /// or 283): one line per frame, then a summary. Keys learned from the traffic
    /// (commands 961 and 963) are used for what follows.
    Decode(DecodeArgs),
    /// Build frames from their fields and write them as a pcap file (link type 195,
    /// with FCS): an example join exchange, or every frame of a capture rebuilt from
    /// its decoded fields (--from).
    Encode(EncodeArgs),
}

/// Options of `hartkit wireless decode`.
#[derive(Args)]
pub struct DecodeArgs {
    /// The capture.
    pub file: std::path::PathBuf,
    /// A join key, 32 hex digits (repeatable).
    #[arg(long = "join-key", value_name = "HEX")]
    pub join_keys: Vec<String>,
    /// A network key, 32 hex digits, for captures that do not hold the join.
    #[arg(long = "network-key", value_name = "HEX")]
    pub network_keys: Vec<String>,
    /// One JSON object per frame, one per line (the summary too, as the last line).
    #[arg(long)]
    pub json: bool,
    /// Only the summary.
    #[arg(long)]
    pub stats: bool,
}

/// Options of `hartkit wireless encode`.
#[derive(Args)]
pub struct EncodeArgs {
    /// Where to write the pcap file.
    #[arg(long, value_name = "FILE")]
    pub pcap: std::path::PathBuf,
    /// Rebuild every frame of this capture from its decoded fields instead.
    #[arg(long, value_name = "CAPTURE")]
    pub from: Option<std::path::PathBuf>,
    /// The join key of the example exchange (default 41424344 × 4).
    #[arg(long = "join-key", value_name = "HEX")]
    pub join_key: Option<String>,
}

fn key(text: &str, what: &str) -> Result<crypto::Key, String> {
    crypto::parse_key(text).ok_or_else(|| {
        format!("{what} {text:?} is not a key: give 32 hex digits (16 bytes), e.g. 41424344414243444142434441424344")
    })
}

fn read(path: &std::path::Path) -> Result<Vec<u8>, String> {
    std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))
}

/// Runs a `hartkit wireless` command; what it returns is printed.
pub fn run(cmd: &WirelessCmd) -> Result<String, String> {
    match cmd {
        WirelessCmd::Decode(a) => decode(a),
        WirelessCmd::Encode(a) => encode(a),
    }
}

fn decode(a: &DecodeArgs) -> Result<String, String> {
    let mut d = decoder::Decoder::new();
    for k in &a.join_keys {
        d.add_join_key(key(k, "--join-key")?);
    }
    for k in &a.network_keys {
        d.add_network_key(key(k, "--network-key")?);
    }
    let bytes = read(&a.file)?;
    let packets = capture::read(&bytes).map_err(|e| format!("{}: {e}", a.file.display()))?;
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    for (i, p) in packets.iter().enumerate() {
        let r = d.decode(i, p);
        if a.stats {
            continue;
        }
        let line = if a.json {
            r.to_json().to_string()
        } else {
            r.to_line()
        };
        // A closed pipe (`| head`) ends the listing quietly.
        if writeln!(out, "{line}").is_err() {
            return Ok(String::new());
        }
    }
    let _ = out.flush();
    if a.json {
        let s = serde_json::json!({ "summary": d.stats.to_json() });
        Ok(s.to_string())
    } else {
        Ok(d.stats.summary().trim_end().to_string())
    }
}

fn encode(a: &EncodeArgs) -> Result<String, String> {
    let frames: Vec<(u64, Vec<u8>)> = match &a.from {
        Some(path) => {
            let bytes = read(path)?;
            let packets = capture::read(&bytes).map_err(|e| format!("{}: {e}", path.display()))?;
            let mut out = Vec::with_capacity(packets.len());
            for (i, p) in packets.iter().enumerate() {
                let d = hart_wireless::Dlpdu::parse(&p.frame)
                    .map_err(|e| format!("{} frame {i}: {e}", path.display()))?;
                out.push((p.time_ns, d.encode()));
            }
            out
        }
        None => {
            let join = match &a.join_key {
                Some(k) => key(k, "--join-key")?,
                None => *b"ABCDABCDABCDABCD",
            };
            let keys = hart_wireless::build::ExampleKeys {
                join,
                network: [0x5A; 16],
            };
            // Frames 10 ms apart per slot, starting at a whole second.
            hart_wireless::build::example_exchange(&keys, 0x04CD, 1000)
                .into_iter()
                .map(|(asn, f)| (1_700_000_000_000_000_000 + asn * 10_000_000, f))
                .collect()
        }
    };
    let refs: Vec<(u64, &[u8])> = frames.iter().map(|(t, f)| (*t, f.as_slice())).collect();
    std::fs::write(&a.pcap, capture::write_pcap(&refs))
        .map_err(|e| format!("cannot write {}: {e}", a.pcap.display()))?;
    Ok(format!(
        "{} frames written to {}",
        frames.len(),
        a.pcap.display()
    ))
}
