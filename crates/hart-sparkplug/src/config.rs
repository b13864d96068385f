//! The `[mqtt]` section of the gateway's configuration file, and the broker URL.

use std::path::PathBuf;

/// The `[mqtt]` section (`--mqtt`, `--group`, `--edge-node`, `--primary-host` are its
/// command-line shortcuts).
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MqttConfig {
    /// The broker: `mqtt://HOST[:PORT]` (port 1883 by default) or
    /// `mqtts://HOST[:PORT]` (TLS, port 8883 by default); the nodes of a broker
    /// cluster separated by commas, `mqtt://h1:1883,h2:1883,h3:1883`, tried in turn
    /// (the next one when the connection to one is lost).
    pub url: String,
    /// Sparkplug group ID (default [`DEFAULT_GROUP`]).
    #[serde(default = "default_group")]
    pub group: String,
    /// Sparkplug edge node ID (default: this machine's host name,
    /// [`default_edge_node`]).
    #[serde(default = "default_edge_node")]
    pub edge_node: String,
    /// The primary host application's ID: births wait for its `spBv1.0/STATE/ID`
    /// to say online, and data are kept while it says offline.
    #[serde(default)]
    pub primary_host: Option<String>,
    /// User name for the broker.
    #[serde(default)]
    pub username: Option<String>,
    /// A file whose first line is the broker password (a password on the command
    /// line would show in the process list).
    #[serde(default)]
    pub password_file: Option<PathBuf>,
    /// PEM file of the certificate authorities that sign the broker's certificate
    /// (`mqtts://`); without it, the system's roots.
    #[serde(default)]
    pub ca_file: Option<PathBuf>,
    /// Samples kept at most while the broker or the primary host is away.
    #[serde(default = "default_backlog")]
    pub backlog: usize,
    /// Refuse every DCMD write (the gateway's `--read-only` does too).
    #[serde(default)]
    pub read_only: bool,
    /// MQTT client ID (default `hartkit-GROUP-EDGE_NODE`).
    #[serde(default)]
    pub client_id: Option<String>,
    /// QoS of births, data and device deaths: 0 (Sparkplug 3.0's rule, the default)
    /// or 1 (at-least-once, for a clustered broker feeding a historian: a message
    /// not acknowledged by the broker is kept and sent again, marked historical,
    /// after reconnecting). `--mqtt-qos` on the command line.
    #[serde(default)]
    pub data_qos: u8,
}

/// The Sparkplug group of a gateway that names none.
pub const DEFAULT_GROUP: &str = "hartkit";

fn default_group() -> String {
    DEFAULT_GROUP.into()
}

/// The edge node ID of a gateway that names none: this machine's host name, with the
/// characters a Sparkplug ID may not hold (`+`, `/`, `#`, control characters) turned
/// into `-`; `hartkit-gateway` when the host name cannot be read.
pub fn default_edge_node() -> String {
    let name = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .or_else(|_| std::fs::read_to_string("/etc/hostname"))
        .unwrap_or_default();
    let name: String = name
        .trim()
        .chars()
        .map(|c| {
            if matches!(c, '+' | '/' | '#') || c.is_control() {
                '-'
            } else {
                c
            }
        })
        .collect();
    if name.is_empty() {
        "hartkit-gateway".into()
    } else {
        name
    }
}

/// The default store-and-forward bound: 100 000 samples (a few tens of MB).
pub const DEFAULT_BACKLOG: usize = 100_000;

fn default_backlog() -> usize {
    DEFAULT_BACKLOG
}

impl MqttConfig {
    /// A configuration with the defaults.
    pub fn new(url: &str, group: &str, edge_node: &str) -> Self {
        MqttConfig {
            url: url.into(),
            group: group.into(),
            edge_node: edge_node.into(),
            primary_host: None,
            username: None,
            password_file: None,
            ca_file: None,
            backlog: DEFAULT_BACKLOG,
            read_only: false,
            client_id: None,
            data_qos: 0,
        }
    }

    /// Checks the IDs, the QoS and the URL; the brokers in the order to try them.
    pub fn check(&self) -> Result<Vec<Broker>, crate::Error> {
        check_id("group", "--group", &self.group)?;
        check_id("edge node", "--edge-node", &self.edge_node)?;
        if let Some(h) = &self.primary_host {
            check_id("primary host", "--primary-host", h)?;
        }
        if self.password_file.is_some() && self.username.is_none() {
            return Err(crate::Error::Config(
                "[mqtt] password_file is given without username".into(),
            ));
        }
        if self.data_qos > 1 {
            return Err(crate::Error::Config(format!(
                "[mqtt] data_qos {} (--mqtt-qos): give 0 (Sparkplug's default) or 1 (at least once, for a historian behind a broker cluster)",
                self.data_qos
            )));
        }
        Broker::parse_list(&self.url)
    }
}

/// A Sparkplug ID is a UTF-8 string without `+`, `/` and `#` (Sparkplug 3.0
/// section 4.1); control characters are refused too.
fn check_id(what: &str, option: &str, id: &str) -> Result<(), crate::Error> {
    if id.is_empty() || id.contains(['+', '/', '#']) || id.chars().any(char::is_control) {
        return Err(crate::Error::Config(format!(
            "{option} {id:?}: a Sparkplug {what} ID must be non-empty, without '+', '/', '#' or control characters"
        )));
    }
    Ok(())
}

/// Where the broker is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Broker {
    /// TLS (`mqtts://`).
    pub tls: bool,
    /// Host name or address.
    pub host: String,
    /// TCP port.
    pub port: u16,
}

impl Broker {
    /// Parses one broker URL or several separated by commas
    /// (`mqtt://h1:p1,h2:p2,h3:p3`: the nodes of a cluster): a scheme given once
    /// applies to every host after it; each part may repeat it.
    pub fn parse_list(url: &str) -> Result<Vec<Broker>, crate::Error> {
        let scheme = if url.starts_with("mqtts://") {
            "mqtts://"
        } else {
            "mqtt://"
        };
        let mut out = Vec::new();
        for (i, part) in url.split(',').enumerate() {
            let part = part.trim();
            if part.is_empty() {
                return Err(crate::Error::Config(format!(
                    "--mqtt {url:?}: an empty broker in the list; give mqtt://HOST[:PORT],HOST[:PORT],..."
                )));
            }
            let b = if i == 0 || part.contains("://") {
                Broker::parse(part)?
            } else {
                Broker::parse(&format!("{scheme}{part}"))?
            };
            if out.first().is_some_and(|f: &Broker| f.tls != b.tls) {
                return Err(crate::Error::Config(format!(
                    "--mqtt {url:?}: mqtt:// and mqtts:// mixed; the nodes of one cluster take one scheme"
                )));
            }
            out.push(b);
        }
        Ok(out)
    }

    /// Parses `mqtt://HOST[:PORT]` or `mqtts://HOST[:PORT]` (IPv6 in brackets).
    pub fn parse(url: &str) -> Result<Broker, crate::Error> {
        let bad = |why: &str| {
            crate::Error::Config(format!(
                "--mqtt {url:?}: {why}; give mqtt://HOST[:PORT] or mqtts://HOST[:PORT]"
            ))
        };
        let (tls, rest) = if let Some(r) = url.strip_prefix("mqtt://") {
            (false, r)
        } else if let Some(r) = url.strip_prefix("mqtts://") {
            (true, r)
        } else {
            return Err(bad("unknown scheme"));
        };
        let rest = rest.strip_suffix('/').unwrap_or(rest);
        if rest.contains(['/', '@', '?']) {
            return Err(bad("only a host and a port may follow the scheme (credentials go in username and password_file)"));
        }
        let (host, port) = if let Some(r) = rest.strip_prefix('[') {
            let (h, after) = r.split_once(']').ok_or_else(|| bad("unclosed '['"))?;
            (h, after.strip_prefix(':'))
        } else {
            match rest.rsplit_once(':') {
                Some((h, p)) => (h, Some(p)),
                None => (rest, None),
            }
        };
        if host.is_empty() {
            return Err(bad("no host"));
        }
        let port = match port {
            Some(p) => p
                .parse()
                .map_err(|_| bad("the port is not a number 1-65535"))?,
            None if tls => 8883,
            None => 1883,
        };
        if port == 0 {
            return Err(bad("port 0"));
        }
        Ok(Broker {
            tls,
            host: host.to_string(),
            port,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls() {
        let b = Broker::parse("mqtt://localhost").unwrap();
        assert_eq!((b.tls, b.host.as_str(), b.port), (false, "localhost", 1883));
        let b = Broker::parse("mqtts://broker.plant:9883/").unwrap();
        assert_eq!(
            (b.tls, b.host.as_str(), b.port),
            (true, "broker.plant", 9883)
        );
        assert_eq!(Broker::parse("mqtts://[::1]").unwrap().port, 8883);
        assert_eq!(Broker::parse("mqtt://[::1]:1884").unwrap().host, "::1");
        for bad in [
            "tcp://x",
            "mqtt://",
            "mqtt://h:x",
            "mqtt://u:p@h",
            "mqtt://h:0",
            "mqtt://h/t",
        ] {
            assert!(Broker::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn broker_lists() {
        let l = Broker::parse_list("mqtt://a:1,b:2, mqtt://c").unwrap();
        let hp: Vec<_> = l.iter().map(|b| (b.host.as_str(), b.port)).collect();
        assert_eq!(hp, [("a", 1), ("b", 2), ("c", 1883)]);
        assert!(Broker::parse_list("mqtts://a,b")
            .unwrap()
            .iter()
            .all(|b| b.tls && b.port == 8883));
        for bad in [
            "mqtt://a,",
            "mqtt://a,,b",
            "mqtt://a,mqtts://b",
            "mqtt://a,b:x",
        ] {
            assert!(Broker::parse_list(bad).is_err(), "{bad}");
        }
        let mut c = MqttConfig::new("mqtt://a,b", "g", "e");
        assert_eq!(c.check().unwrap().len(), 2);
        c.data_qos = 2;
        assert!(c.check().unwrap_err().to_string().contains("data_qos"));
    }

    #[test]
    fn toml_section() {
        let c: MqttConfig = toml::from_str(
            r#"
            url = "mqtt://127.0.0.1:1883"
            group = "Plant"
            edge_node = "gw1"
            primary_host = "scada"
            username = "gw"
            password_file = "/etc/hartkit/mqtt-password"
            backlog = 500
            data_qos = 1
            "#,
        )
        .unwrap();
        assert_eq!(c.backlog, 500);
        assert_eq!(c.data_qos, 1);
        assert!(c.check().is_ok());
        assert!(toml::from_str::<MqttConfig>(
            "url = \"mqtt://h\"\ngroup = \"g\"\nedge_node = \"e\"\nqos = 1"
        )
        .is_err());
        let mut c = MqttConfig::new("mqtt://h", "a/b", "e");
        assert!(c.check().is_err());
        c.group = "a".into();
        c.edge_node = "e#".into();
        assert!(c.check().is_err());
    }
}
