//! What `hartkit conform` does once its arguments are parsed: the run, the outputs,
//! the exit status. The command line itself (argument parsing, opening the transport)
//! stays in the `hartkit` crate.

use std::path::Path;

use hart_host::transport::Transport;

use crate::model::{Group, Report};
use crate::run::{DeviceAddress, Options};

/// The parsed arguments of `hartkit conform -p TARGET ...`.
#[derive(Debug, Clone, Default)]
pub struct Args {
    /// The `-p` target, for the report.
    pub target: String,
    /// `--poll N`.
    pub poll: Option<u8>,
    /// `--unique-id HEX`.
    pub unique_id: Option<String>,
    /// `--only link,commands,...`.
    pub only: Option<String>,
    /// `--expect DEVICE.toml`.
    pub expect: Option<std::path::PathBuf>,
    /// `--json`.
    pub json: bool,
    /// `--report FILE.html`.
    pub report: Option<std::path::PathBuf>,
    /// `--allow-writes`.
    pub allow_writes: bool,
}

/// The run's options from the arguments; errors name the option and what it takes.
pub fn options(a: &Args) -> Result<Options, String> {
    let address = match (&a.poll, &a.unique_id) {
        (Some(_), Some(_)) => return Err("give --poll or --unique-id, not both".into()),
        (Some(p), None) if *p > 63 => {
            return Err(format!("--poll {p}: polling addresses are 0-63"))
        }
        (Some(p), None) => DeviceAddress::Poll(*p),
        (None, Some(h)) => DeviceAddress::UniqueId(
            hart_proto::frame::UniqueId::parse_hex(h)
                .map_err(|e| format!("--unique-id {h}: {e} (10 hex digits, e.g. 26F1010001)"))?,
        ),
        (None, None) => DeviceAddress::Poll(0),
    };
    let mut o = Options::new(&a.target, address);
    if let Some(only) = &a.only {
        o.groups = Group::parse_list(only)?;
    }
    if let Some(path) = &a.expect {
        o.expect = Some(crate::expect::Expect::load(path)?);
    }
    o.allow_writes = a.allow_writes;
    Ok(o)
}

/// Runs the tests on `t` and writes the outputs: the terminal summary or JSON lines
/// (returned, for standard output) and the HTML report (`--report`).
pub async fn run<T: Transport>(t: &mut T, a: &Args) -> Result<(Report, String), String> {
    let o = options(a)?;
    let sto = t.profile().sto;
    let report = crate::run::run(t, &o).await;
    let text = outputs(&report, a.json, a.report.as_deref(), sto)?;
    Ok((report, text))
}

/// The text for standard output (summary or JSON lines), and the HTML file written
/// when asked for.
pub fn outputs(r: &Report, json: bool, html: Option<&Path>, sto_us: u64) -> Result<String, String> {
    if let Some(path) = html {
        std::fs::write(path, crate::report::html(r, sto_us)).map_err(|e| {
            format!(
                "--report {}: {e} (check the directory exists and may be written)",
                path.display()
            )
        })?;
    }
    Ok(if json {
        crate::report::json_lines(r)
    } else {
        crate::report::text(r)
    })
}

/// `hartkit conform phy FILE.wav`: the physical-layer tests on a recording.
pub fn phy(file: &Path, json: bool, html: Option<&Path>) -> Result<(Report, String), String> {
    let bytes = std::fs::read(file).map_err(|e| format!("{}: {e}", file.display()))?;
    let r = crate::phy::run(
        &bytes,
        &file.display().to_string(),
        &crate::phy::Limits::default(),
    );
    let text = outputs(&r, json, html, hart_link::TimingProfile::fsk().sto)?;
    Ok((r, text))
}

/// The exit status of a run: 0 when nothing failed, 1 when a test failed, 2 when the
/// device could not be tested at all (no device, unreadable recording).
pub fn exit_code(r: &Report) -> u8 {
    use crate::model::Verdict;
    if r.count(Verdict::Fail) > 0 {
        1
    } else if r.results.iter().all(|t| t.verdict == Verdict::CouldNotRun) {
        2
    } else {
        0
    }
}
