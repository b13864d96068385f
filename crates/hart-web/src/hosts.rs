//! The names the dashboard answers to, against DNS rebinding and cross-site writes.
//!
//! A page of another site whose name an attacker points at the gateway's address (DNS
//! rebinding) reaches the dashboard with its own name in `Host`; a browser's write
//! from another site's page carries that site in `Origin`. So:
//!
//! * a request's `Host` (or, in HTTP/2, its `:authority`) must be one of the
//!   dashboard's names, else it is answered 421 Misdirected Request with what to do:
//!   `localhost`, the address it listens on, the address the client reached (on a
//!   wildcard listener, `0.0.0.0` or `[::]`, each local address), any port for these
//!   (a tunnel or a port forward changes it; a name is what rebinding needs), and the
//!   names of `[web] hosts` / `--web-host` (with the port given, only that port);
//! * a request that changes something (any method but GET, HEAD and OPTIONS) whose
//!   `Origin` is present must come from an allowed origin: the `Host` it was sent to
//!   (already checked above), same scheme's default port counted as none, or a name
//!   of `[web] hosts` given with its port; else 403.

use std::net::{IpAddr, SocketAddr};
use std::str::FromStr;

/// A name the dashboard answers to (`[web] hosts`, `--web-host`): a DNS name or an IP
/// address, and a port or none (none: any port).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HostName {
    /// The name, in lower case without a final dot, or the address (IPv6 without
    /// brackets).
    pub host: String,
    /// The only port it is allowed with; `None`: any.
    pub port: Option<u16>,
}

/// A `[web] hosts` entry that is not a name, an address, or one of them with a port.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BadHostName(pub String);

impl std::fmt::Display for BadHostName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{:?} is not a host name: give a name (plant-gw.example), an address \
             (10.0.0.5, [fd00::5]), or one with a port (plant-gw.example:8443), without \
             a scheme or a path",
            self.0
        )
    }
}

impl std::error::Error for BadHostName {}

impl FromStr for HostName {
    type Err = BadHostName;

    fn from_str(s: &str) -> Result<Self, BadHostName> {
        let bad = || BadHostName(s.to_string());
        let t = s.trim();
        // A bare IPv6 address has colons of its own.
        if let Ok(ip) = t.parse::<IpAddr>() {
            return Ok(HostName {
                host: canonical_ip(ip),
                port: None,
            });
        }
        let (host, port) = split_authority(t).ok_or_else(bad)?;
        if host.is_empty() {
            return Err(bad());
        }
        Ok(HostName { host, port })
    }
}

impl std::fmt::Display for HostName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.host.contains(':') {
            write!(f, "[{}]", self.host)?;
        } else {
            f.write_str(&self.host)?;
        }
        match self.port {
            Some(p) => write!(f, ":{p}"),
            None => Ok(()),
        }
    }
}

/// An address as the names compare it (an IPv4-mapped IPv6 address as IPv4).
fn canonical_ip(ip: IpAddr) -> String {
    match ip {
        IpAddr::V6(v6) => match v6.to_ipv4_mapped() {
            Some(v4) => v4.to_string(),
            None => v6.to_string(),
        },
        v4 => v4.to_string(),
    }
}

/// `host[:port]` as (host in lower case without a final dot, or an IP address in its
/// canonical form; port); `None` when it is not an authority.
pub(crate) fn split_authority(s: &str) -> Option<(String, Option<u16>)> {
    let (host, port) = if let Some(rest) = s.strip_prefix('[') {
        let (v6, after) = rest.split_once(']')?;
        let ip: std::net::Ipv6Addr = v6.parse().ok()?;
        let port = match after {
            "" => None,
            p => Some(p.strip_prefix(':')?),
        };
        (canonical_ip(IpAddr::V6(ip)), port)
    } else {
        let (h, port) = match s.rsplit_once(':') {
            Some((h, p)) => (h, Some(p)),
            None => (s, None),
        };
        let h = h.strip_suffix('.').unwrap_or(h).to_ascii_lowercase();
        let ok = !h.is_empty()
            && h.len() <= 253
            && h.bytes()
                .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'-' | b'.' | b'_'));
        if !ok {
            return None;
        }
        let h = match h.parse::<IpAddr>() {
            Ok(ip) => canonical_ip(ip),
            Err(_) => h,
        };
        (h, port)
    };
    let port = match port {
        None => None,
        Some(p) if !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit()) => {
            Some(p.parse::<u16>().ok()?)
        }
        Some(_) => return None,
    };
    Some((host, port))
}

/// What a request's names are checked against.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Allowed<'a> {
    /// `[web] hosts`.
    pub names: &'a [HostName],
    /// Where the dashboard listens.
    pub bind: SocketAddr,
    /// The address the client reached, when known.
    pub local: Option<SocketAddr>,
}

impl Allowed<'_> {
    /// Whether `host` (with `port`, if given) is one of the dashboard's names.
    pub(crate) fn host(&self, host: &str, port: Option<u16>) -> bool {
        if host == "localhost" {
            return true;
        }
        let own = [Some(self.bind.ip()), self.local.map(|l| l.ip())];
        if own
            .iter()
            .flatten()
            .any(|ip| !ip.is_unspecified() && canonical_ip(*ip) == host)
        {
            return true;
        }
        self.names
            .iter()
            .any(|n| n.host == host && n.port.is_none_or(|p| Some(p) == port))
    }

    /// Whether a `Host` value is one of the dashboard's names.
    pub(crate) fn authority(&self, authority: &str) -> bool {
        split_authority(authority.trim()).is_some_and(|(h, p)| self.host(&h, p))
    }

    /// Whether `origin` (scheme://host[:port]) may send a write to `host` (the
    /// request's `Host`, already allowed).
    pub(crate) fn origin(&self, origin: &str, host: &str) -> bool {
        let Some((scheme, authority)) = origin.trim().split_once("://") else {
            return false;
        };
        let default = match scheme.to_ascii_lowercase().as_str() {
            "http" => 80,
            "https" => 443,
            _ => return false,
        };
        let Some((oh, op)) = split_authority(authority) else {
            return false;
        };
        let op = op.unwrap_or(default);
        // The site it was sent to.
        if let Some((hh, hp)) = split_authority(host.trim()) {
            if hh == oh && hp.unwrap_or(default) == op {
                return true;
            }
        }
        // A name given with its port (the origin behind a proxy).
        self.names
            .iter()
            .any(|n| n.host == oh && n.port == Some(op))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(list: &[&str]) -> Vec<HostName> {
        list.iter().map(|n| n.parse().unwrap()).collect()
    }

    #[test]
    fn names_parse_with_and_without_ports() {
        let n: HostName = "Plant-GW.example.:8443".parse().unwrap();
        assert_eq!(n.host, "plant-gw.example");
        assert_eq!(n.port, Some(8443));
        assert_eq!(n.to_string(), "plant-gw.example:8443");
        let n: HostName = "[FD00::5]".parse().unwrap();
        assert_eq!((n.host.as_str(), n.port), ("fd00::5", None));
        assert_eq!(n.to_string(), "[fd00::5]");
        let n: HostName = "fd00::5".parse().unwrap();
        assert_eq!(n.host, "fd00::5");
        for bad in [
            "",
            "http://gw",
            "gw/",
            "gw:",
            "gw:99999",
            "gw:x",
            "g w",
            "[::1",
            "[x]:1",
            "a@b",
        ] {
            let e = bad.parse::<HostName>().unwrap_err();
            assert!(e.to_string().contains("not a host name"), "{bad}: {e}");
        }
    }

    #[test]
    fn hosts_are_the_listeners_addresses_localhost_and_the_configured_names() {
        let configured = names(&["plant-gw.example", "proxy.example:443"]);
        let specific = Allowed {
            names: &configured,
            bind: "10.0.0.5:8080".parse().unwrap(),
            local: Some("10.0.0.5:8080".parse().unwrap()),
        };
        for ok in [
            "10.0.0.5:8080",
            "10.0.0.5",
            "10.0.0.5:9000",
            "localhost:8080",
            "LOCALHOST",
            "plant-gw.example",
            "plant-gw.example.:8080",
            "proxy.example:443",
        ] {
            assert!(specific.authority(ok), "{ok}");
        }
        for refused in [
            "evil.example:8080",
            "10.0.0.6:8080",
            "proxy.example",
            "proxy.example:8080",
            "",
            "10.0.0.5:8080/x",
            "0.0.0.0:8080",
        ] {
            assert!(!specific.authority(refused), "{refused}");
        }
        // A wildcard listener: the address the client reached, IPv4-mapped or not.
        let wildcard = Allowed {
            names: &[],
            bind: "[::]:8080".parse().unwrap(),
            local: Some("[::ffff:192.168.1.10]:8080".parse().unwrap()),
        };
        assert!(wildcard.authority("192.168.1.10:8080"));
        assert!(!wildcard.authority("[::]:8080"));
        assert!(!wildcard.authority("192.168.1.11:8080"));
        let wildcard = Allowed {
            local: Some("[fd00::5]:8080".parse().unwrap()),
            ..wildcard
        };
        assert!(wildcard.authority("[FD00::5]:8080"));
    }

    #[test]
    fn an_origin_must_be_the_host_it_writes_to_or_a_name_with_its_port() {
        let configured = names(&["plant-gw.example:443"]);
        let a = Allowed {
            names: &configured,
            bind: "127.0.0.1:8080".parse().unwrap(),
            local: None,
        };
        assert!(a.origin("http://127.0.0.1:8080", "127.0.0.1:8080"));
        assert!(a.origin("http://LOCALHOST:8080", "localhost:8080"));
        assert!(a.origin("http://gw", "gw:80"));
        assert!(a.origin("https://gw", "gw"));
        // Behind a TLS proxy that passes its own Host on.
        assert!(a.origin("https://plant-gw.example", "127.0.0.1:8080"));
        for (origin, host) in [
            ("http://evil.example:8080", "127.0.0.1:8080"),
            ("http://127.0.0.1:3000", "127.0.0.1:8080"),
            ("null", "127.0.0.1:8080"),
            ("ftp://127.0.0.1:8080", "127.0.0.1:8080"),
            ("http://plant-gw.example", "127.0.0.1:8080"),
            ("http://127.0.0.1:8080/", "127.0.0.1:8080"),
        ] {
            assert!(!a.origin(origin, host), "{origin} to {host}");
        }
    }
}
