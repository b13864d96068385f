//! `hartkit serve`: the gateway. The gateway is assembled by the hart-gateway crate
//! from one configuration value; this module only turns the command line into that
//! value and runs it, and manages the OPC UA trust list (`hartkit opcua trust`).

use std::path::PathBuf;

pub use hart_gateway::config::default_pki_dir;
pub use hart_gateway::{GatewayFile, ServeOptions};

/// A failure: the message and the process exit code (2 usage, 5 I/O).
pub type Failure = (String, u8);

fn failure(e: hart_gateway::Error) -> Failure {
    let code = e.exit_code();
    (e.message, code)
}

/// `ADDR[:PORT]` (`port` when none) as a socket address; `what` names the option.
pub fn socket_addr(what: &str, text: &str, port: u16) -> Result<std::net::SocketAddr, Failure> {
    hart_gateway::socket_addr(what, text, port).map_err(failure)
}

/// Sets up the log for a server when the command line has not ([`crate::logging`]).
pub(crate) fn init_log() {
    let _ = crate::logging::init(
        None,
        crate::logging::LogFormat::Text,
        crate::logging::Role::Server,
    );
}

/// How `hartkit serve` runs besides the gateway's options.
#[derive(Debug, Clone, Copy, Default)]
pub struct RunMode {
    /// `--print-map`: print the Modbus map (JSON with `--json`) and exit.
    pub print_map: bool,
    /// `--print-gsd`: print the PROFIBUS station's GSD file and exit.
    pub print_gsd: bool,
    /// `--run-for` seconds; until Ctrl-C when `None`.
    pub run_for: Option<f64>,
}

/// Runs `hartkit serve` until interrupted (or `--run-for`).
pub fn run(opts: ServeOptions, mode: RunMode) -> Result<String, Failure> {
    if mode.print_gsd {
        return hart_gateway::print_gsd(&opts)
            .map(|g| g.trim_end().to_string())
            .map_err(failure);
    }
    let config = hart_gateway::GatewayConfig::from_options(&opts).map_err(failure)?;
    if mode.print_map {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(|e| (e.to_string(), 5))?;
        return tokio::task::LocalSet::new()
            .block_on(&rt, hart_gateway::print_map(config, opts.json))
            .map_err(failure);
    }
    init_log();
    hart_gateway::run_until(config, hart_gateway::interrupted_or(mode.run_for)).map_err(failure)?;
    Ok(String::new())
}

/// What `hartkit opcua trust` does.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TrustAction {
    /// `FILE`: a certificate file, or a rejected one by file name or thumbprint.
    File(String),
    /// `--all`: every rejected certificate.
    All,
    /// `--list`: show the rejected and trusted certificates.
    List,
}

/// `hartkit opcua trust [--opcua-pki DIR] [FILE | --all | --list]`: moves client
/// certificates into the gateway's trust list, or lists it; `pki` defaults to
/// [`default_pki_dir`].
pub fn opcua_trust(pki: Option<PathBuf>, action: TrustAction) -> Result<String, Failure> {
    let pki = pki.unwrap_or_else(default_pki_dir);
    let show = |c: &hart_opcua::trust::CertInfo| {
        format!(
            "{}  {}{}",
            c.thumbprint,
            c.subject,
            c.not_after
                .as_ref()
                .map_or(String::new(), |t| format!("  (valid until {t})"))
        )
    };
    let what = match action {
        TrustAction::List => {
            let l = hart_opcua::trust::list(&pki).map_err(|e| (e, 5))?;
            let mut out = vec![];
            for (name, dir, certs) in [
                ("rejected", &l.rejected_dir, &l.rejected),
                ("trusted", &l.trusted_dir, &l.trusted),
            ] {
                out.push(format!("{name} ({}):", dir.display()));
                if certs.is_empty() {
                    out.push("  none".into());
                }
                for c in certs {
                    out.push(format!("  {}", show(c)));
                    out.push(format!(
                        "      {}",
                        c.path.file_name().unwrap_or_default().to_string_lossy()
                    ));
                }
            }
            for (f, e) in &l.unreadable {
                out.push(format!("not a certificate: {} ({e})", f.display()));
            }
            return Ok(out.join("\n"));
        }
        TrustAction::All => hart_opcua::trust::Trust::AllRejected,
        TrustAction::File(f) => hart_opcua::trust::Trust::File(f),
    };
    let done = hart_opcua::trust::trust(&pki, &what).map_err(|e| (e, 2))?;
    Ok(done
        .iter()
        .map(|c| format!("trusted {} -> {}", show(c), c.path.display()))
        .collect::<Vec<_>>()
        .join("\n"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The complete example of docs/gateway.md is a configuration the gateway reads.
    #[test]
    fn the_documented_example_reads() {
        let doc = include_str!("../../../docs/gateway.md");
        let start = doc
            .find("```toml\n# Poll defaults")
            .expect("the example in docs/gateway.md");
        let body = &doc[start + "```toml\n".len()..];
        let example = &body[..body.find("```").unwrap()];
        let file: GatewayFile = toml::from_str(example).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(file.loops.len(), 2);
        let history = file.history.clone().unwrap();
        assert_eq!(
            history.retention,
            Some(std::time::Duration::from_secs(90 * 86_400))
        );
        let mqtt = file.mqtt.clone().unwrap();
        assert_eq!(
            (mqtt.group.as_str(), mqtt.edge_node.as_str()),
            ("Plant", "hart-gw1")
        );
        mqtt.check().unwrap();
        assert_eq!(
            file.hart_ip.unwrap().plain_rights,
            Some(hart_access::Rights::ReadOnly)
        );
        let commands = hart_access::DeviceCommands::from_entries(&file.device_commands).unwrap();
        assert!(commands.reads(0x26F3, 128) && !commands.reads(0x26F3, 129));
        let nets = file.modbus.unwrap().write_from.unwrap();
        assert!(hart_access::NetList::parse(&nets)
            .unwrap()
            .contains("10.0.0.9".parse().unwrap()));
    }
}
