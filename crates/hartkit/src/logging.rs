//! The log: every diagnostic of the command line and its libraries goes through
//! `tracing` to standard error (standard output stays for results).
//!
//! The level comes from `--log-level`, else `RUST_LOG`, else `HARTKIT_LOG` (both take
//! `tracing`'s filter syntax, e.g. `hart_ip_server=debug`), else the command's default
//! (`info` for servers, `warn` for the others). A bare level applies to hartkit's own
//! crates; other libraries stay at `warn`. `--log-format json` writes one JSON object
//! a line (time, level, target, fields) for a plant's log collector; text lines carry
//! the time only for servers. At `debug` the host commands log every raw transfer, at
//! `trace` each frame decoded field by field.

use std::sync::atomic::{AtomicU8, Ordering};

/// How log lines look.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum LogFormat {
    /// One line of text an event.
    #[default]
    Text,
    /// One JSON object an event.
    Json,
}

/// What kind of command runs: a server logs its life (`info`, with times).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// Runs until stopped: `serve`, `sim serve`, the well network's roles.
    Server,
    /// Does one job and ends.
    Command,
}

/// How much of the raw traffic the host commands log: 0 none, 1 transfers (debug),
/// 2 frames decoded too (trace).
static TRAFFIC: AtomicU8 = AtomicU8::new(0);

/// The levels `--log-level` takes.
pub const LEVELS: [&str; 5] = ["error", "warn", "info", "debug", "trace"];

/// Sets up the log once for the process. `level` is `--log-level`; a bad one is an
/// error that names the levels.
pub fn init(level: Option<&str>, format: LogFormat, role: Role) -> Result<(), String> {
    use tracing_subscriber::EnvFilter;
    static DONE: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    if DONE.load(Ordering::Acquire) {
        // The command line set it up; a library's later call changes nothing.
        return Ok(());
    }
    let from_env = || {
        ["RUST_LOG", "HARTKIT_LOG"]
            .iter()
            .find_map(|v| std::env::var(v).ok().filter(|s| !s.trim().is_empty()))
    };
    let directive = match level {
        Some(l) if !LEVELS.contains(&l) => {
            return Err(format!(
                "--log-level {l}: expected error, warn, info, debug or trace"
            ))
        }
        Some(l) => own_crates(l),
        None => from_env().unwrap_or_else(|| {
            own_crates(match role {
                Role::Server => "info",
                Role::Command => "warn",
            })
        }),
    };
    let filter = EnvFilter::try_new(&directive)
        .map_err(|e| format!("log filter {directive:?}: {e} (RUST_LOG, HARTKIT_LOG)"))?;
    let traffic = if directive_enables(&directive, "trace") {
        2
    } else if directive_enables(&directive, "debug") {
        1
    } else {
        0
    };
    TRAFFIC.store(traffic, Ordering::Relaxed);
    use std::io::IsTerminal;
    let builder = tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .with_env_filter(filter);
    let _ = match (format, role) {
        (LogFormat::Json, _) => builder.json().with_current_span(false).try_init(),
        (LogFormat::Text, Role::Server) => builder.with_target(false).try_init(),
        (LogFormat::Text, Role::Command) => builder.with_target(false).without_time().try_init(),
    };
    DONE.store(true, Ordering::Release);
    Ok(())
}

/// A bare level for hartkit's crates (`hart...`), `warn` for every other library.
fn own_crates(level: &str) -> String {
    // async-opcua logs an error for every connection that ends before its secure
    // channel opens, unbounded: a flood would fill the disk. The gateway's front logs
    // each refused or closed connection itself, with the peer and the reason, at most
    // 20 lines a second (hart_opcua::connections); RUST_LOG can still ask for them.
    const QUIET: &str = "opcua_server::session::controller=off";
    match level {
        "error" | "warn" => format!("{level},{QUIET}"),
        l => format!("warn,hart={l},{QUIET}"),
    }
}

/// Whether a filter directive lets `level` through for hartkit's crates (roughly: it
/// names that level or a more verbose one).
fn directive_enables(directive: &str, level: &str) -> bool {
    let order = |l: &str| LEVELS.iter().position(|x| x.eq_ignore_ascii_case(l));
    let want = order(level).unwrap_or(4);
    directive.split(',').any(|d| {
        let l = d.rsplit('=').next().unwrap_or(d).trim();
        order(l).is_some_and(|o| o >= want)
    })
}

/// How much of the raw traffic to log (set by [`init`]): 0 none, 1 transfers, 2
/// frames decoded too.
pub fn traffic() -> u8 {
    TRAFFIC.load(Ordering::Relaxed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_and_filters() {
        assert_eq!(
            own_crates("debug"),
            "warn,hart=debug,opcua_server::session::controller=off"
        );
        assert_eq!(
            own_crates("error"),
            "error,opcua_server::session::controller=off"
        );
        assert!(directive_enables("warn,hart=debug", "debug"));
        assert!(!directive_enables("warn,hart=debug", "trace"));
        assert!(directive_enables("hart_host=trace", "debug"));
        assert!(!directive_enables("info", "debug"));
        assert!(init(Some("loud"), LogFormat::Text, Role::Command).is_err());
    }
}
