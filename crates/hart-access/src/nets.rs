//! Client addresses as networks, for the front ends that admit writers by address.

use std::net::IpAddr;
use std::str::FromStr;

use ipnet::IpNet;

/// A list of networks (`10.0.0.0/24`, `192.168.1.7`, `::1`); a client is on it when
/// its address is in one of them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NetList(Vec<IpNet>);

impl NetList {
    /// Loopback only (`127.0.0.0/8`, `::1`): the default for writes.
    pub fn loopback() -> Self {
        NetList(vec![
            "127.0.0.0/8".parse().expect("a network"),
            "::1/128".parse().expect("a network"),
        ])
    }

    /// No network: nobody is on it.
    pub fn empty() -> Self {
        NetList(vec![])
    }

    /// Whether it lists no network.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// Reads networks, each `ADDR/PREFIX` or a single address.
    pub fn parse<S: AsRef<str>>(items: &[S]) -> Result<Self, String> {
        let mut nets = vec![];
        for item in items {
            let t = item.as_ref().trim();
            let net = IpNet::from_str(t)
                .or_else(|_| IpAddr::from_str(t).map(IpNet::from))
                .map_err(|_| {
                    format!("{t:?} is not an address or a network (e.g. 10.0.0.0/24, 192.168.1.7)")
                })?;
            nets.push(net);
        }
        Ok(NetList(nets))
    }

    /// Whether `ip` is on the list (an IPv4 client seen as `::ffff:a.b.c.d` counts as
    /// its IPv4 address).
    pub fn contains(&self, ip: IpAddr) -> bool {
        let ip = match ip {
            IpAddr::V6(v6) => v6.to_ipv4_mapped().map_or(ip, IpAddr::V4),
            v4 => v4,
        };
        self.0.iter().any(|n| n.contains(&ip))
    }

    /// The networks, as given.
    pub fn nets(&self) -> Vec<String> {
        self.0.iter().map(|n| n.to_string()).collect()
    }
}

impl Default for NetList {
    fn default() -> Self {
        NetList::loopback()
    }
}
