//! The WirelessHART network PDU: control byte, TTL, ASN snippet, graph ID, addresses
//! (big-endian here, unlike the 802.15.4 header), proxy and source routes, the security
//! sub-layer (join: 4-byte counter; session: 1-byte counter), the MIC and the AES-CCM*
//! encrypted transport PDU.

use alloc::vec::Vec;
use core::fmt;

use crate::crypto::{self, Key};
use crate::mac::Address;

/// The manager's nickname.
pub const MANAGER: u16 = 0xF980;
/// The gateway's nickname.
pub const GATEWAY: u16 = 0xF981;

/// Why a network PDU could not be parsed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NlError {
    /// The header is cut short.
    TooShort {
        /// Bytes the header needs.
        needed: usize,
        /// Bytes present.
        available: usize,
    },
    /// A security type other than session (0) and join (1).
    SecurityType(u8),
}

impl fmt::Display for NlError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NlError::TooShort { needed, available } => write!(
                f,
                "header needs {needed} bytes (with its routes and security sub-layer), has {available}"
            ),
            NlError::SecurityType(t) => write!(
                f,
                "security type {t} is reserved (0 session-keyed and 1 join-keyed are defined)"
            ),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for NlError {}

/// The security sub-layer's kind and counter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Security {
    /// Session-keyed: the low byte of the sender's nonce counter.
    Session(u8),
    /// Join-keyed: a 4-byte nonce counter.
    Join(u32),
}

impl Security {
    /// `"session"` or `"join"`.
    pub fn name(&self) -> &'static str {
        match self {
            Security::Session(_) => "session",
            Security::Join(_) => "join",
        }
    }
    /// The counter as carried.
    pub fn counter(&self) -> u32 {
        match *self {
            Security::Session(c) => c as u32,
            Security::Join(c) => c,
        }
    }
}

/// A network PDU (its payload still encrypted).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Npdu {
    /// Control byte bits 5-3 (reserved).
    pub reserved: u8,
    /// Time to live.
    pub ttl: u8,
    /// The low 16 bits of the ASN when the packet was created (latency).
    pub asn_snippet: u16,
    /// Graph ID (or the route's destination).
    pub graph_id: u16,
    /// Final destination.
    pub dst: Address,
    /// Original source.
    pub src: Address,
    /// Proxy (control bit 2): the nickname of the joining device's proxy.
    pub proxy: Option<u16>,
    /// First source-route segment (control bit 0): four nicknames.
    pub route1: Option<[u16; 4]>,
    /// Second source-route segment (control bit 1): four nicknames.
    pub route2: Option<[u16; 4]>,
    /// Security byte bits 7-4 (reserved).
    pub security_reserved: u8,
    /// Security type and counter.
    pub security: Security,
    /// Network MIC.
    pub mic: [u8; 4],
    /// The encrypted transport PDU.
    pub payload: Vec<u8>,
}

fn addr(b: &[u8], long: bool) -> Address {
    if long {
        let mut a = [0u8; 8];
        a.copy_from_slice(&b[..8]);
        Address::Long(u64::from_be_bytes(a))
    } else {
        Address::Short(u16::from_be_bytes([b[0], b[1]]))
    }
}

fn put_addr(v: &mut Vec<u8>, a: Address) {
    match a {
        Address::Long(l) => v.extend_from_slice(&l.to_be_bytes()),
        Address::Short(s) => v.extend_from_slice(&s.to_be_bytes()),
        Address::None => v.extend_from_slice(&[0, 0]),
    }
}

impl Npdu {
    /// Parses a network PDU.
    pub fn parse(b: &[u8]) -> Result<Self, NlError> {
        let too_short = |needed: usize| NlError::TooShort {
            needed,
            available: b.len(),
        };
        if b.is_empty() {
            return Err(too_short(1));
        }
        let c = b[0];
        let (dl, sl) = (c & 0x80 != 0, c & 0x40 != 0);
        let alen = |l: bool| if l { 8 } else { 2 };
        let mut need = 6 + alen(dl) + alen(sl);
        need += if c & 4 != 0 { 2 } else { 0 };
        need += if c & 1 != 0 { 8 } else { 0 };
        need += if c & 2 != 0 { 8 } else { 0 };
        if b.len() < need + 1 {
            return Err(too_short(need + 1));
        }
        let mut p = 6;
        let dst = addr(&b[p..], dl);
        p += alen(dl);
        let src = addr(&b[p..], sl);
        p += alen(sl);
        let u16at = |p: usize| u16::from_be_bytes([b[p], b[p + 1]]);
        let proxy = (c & 4 != 0).then(|| {
            p += 2;
            u16at(p - 2)
        });
        let mut seg = |bit: u8| {
            (c & bit != 0).then(|| {
                p += 8;
                let s = p - 8;
                [u16at(s), u16at(s + 2), u16at(s + 4), u16at(s + 6)]
            })
        };
        let route1 = seg(1);
        let route2 = seg(2);
        let sec = b[p];
        let (security, clen) = match sec & 0x0F {
            0 => (Security::Session(0), 1),
            1 => (Security::Join(0), 4),
            t => return Err(NlError::SecurityType(t)),
        };
        if b.len() < p + 1 + clen + 4 {
            return Err(too_short(p + 1 + clen + 4));
        }
        let security = match security {
            Security::Session(_) => Security::Session(b[p + 1]),
            Security::Join(_) => {
                Security::Join(u32::from_be_bytes([b[p + 1], b[p + 2], b[p + 3], b[p + 4]]))
            }
        };
        p += 1 + clen;
        let mic = [b[p], b[p + 1], b[p + 2], b[p + 3]];
        p += 4;
        Ok(Npdu {
            reserved: (c >> 3) & 7,
            ttl: b[1],
            asn_snippet: u16at(2),
            graph_id: u16at(4),
            dst,
            src,
            proxy,
            route1,
            route2,
            security_reserved: sec >> 4,
            security,
            mic,
            payload: b[p..].to_vec(),
        })
    }

    /// The control byte.
    pub fn control(&self) -> u8 {
        (matches!(self.dst, Address::Long(_)) as u8) << 7
            | (matches!(self.src, Address::Long(_)) as u8) << 6
            | (self.reserved & 7) << 3
            | (self.proxy.is_some() as u8) << 2
            | (self.route2.is_some() as u8) << 1
            | self.route1.is_some() as u8
    }

    /// The header through the MIC; with `zeroed`, TTL, counter and MIC are zero (the
    /// authenticated data of the network MIC).
    pub fn header(&self, zeroed: bool) -> Vec<u8> {
        let mut v = Vec::with_capacity(40);
        v.push(self.control());
        v.push(if zeroed { 0 } else { self.ttl });
        v.extend_from_slice(&self.asn_snippet.to_be_bytes());
        v.extend_from_slice(&self.graph_id.to_be_bytes());
        put_addr(&mut v, self.dst);
        put_addr(&mut v, self.src);
        if let Some(p) = self.proxy {
            v.extend_from_slice(&p.to_be_bytes());
        }
        for seg in [self.route1, self.route2].into_iter().flatten() {
            for n in seg {
                v.extend_from_slice(&n.to_be_bytes());
            }
        }
        match self.security {
            Security::Session(c) => {
                v.push(self.security_reserved << 4);
                v.push(if zeroed { 0 } else { c });
            }
            Security::Join(c) => {
                v.push(self.security_reserved << 4 | 1);
                v.extend_from_slice(&(if zeroed { 0 } else { c }).to_be_bytes());
            }
        }
        v.extend_from_slice(if zeroed { &[0; 4] } else { &self.mic });
        v
    }

    /// The whole PDU.
    pub fn encode(&self) -> Vec<u8> {
        let mut v = self.header(false);
        v.extend_from_slice(&self.payload);
        v
    }

    /// The nonce: flag, the 4-byte nonce counter, the address (8 bytes, big-endian).
    /// For join-keyed packets from the manager the flag is 1 and the address is the
    /// destination (the joining device); otherwise 0 and the source.
    pub fn nonce(&self, counter: u32) -> [u8; 13] {
        let from_manager_to_joiner =
            matches!(self.security, Security::Join(_)) && self.src == Address::Short(MANAGER);
        let (flag, a) = if from_manager_to_joiner {
            (1, self.dst)
        } else {
            (0, self.src)
        };
        let mut n = [0u8; 13];
        n[0] = flag;
        n[1..5].copy_from_slice(&counter.to_be_bytes());
        n[5..].copy_from_slice(&a.nonce_bytes());
        n
    }

    /// Decrypts the payload with `key` and the full nonce counter (for join-keyed
    /// packets the carried counter; for session-keyed ones the sender's counter whose
    /// low byte is carried); `None` when the MIC does not verify.
    pub fn decrypt(&self, key: &Key, counter: u32) -> Option<Vec<u8>> {
        let mut data = self.payload.clone();
        crypto::decrypt(
            key,
            &self.nonce(counter),
            &self.header(true),
            &mut data,
            &self.mic,
        )
        .then_some(data)
    }

    /// Encrypts `plain` into the payload and sets the MIC (the counter as given; for a
    /// session-keyed packet its low byte is what is carried).
    pub fn seal(&mut self, key: &Key, counter: u32, plain: &[u8]) {
        self.security = match self.security {
            Security::Session(_) => Security::Session(counter as u8),
            Security::Join(_) => Security::Join(counter),
        };
        let mut data = plain.to_vec();
        self.mic = [0; 4];
        self.mic = crypto::encrypt(key, &self.nonce(counter), &self.header(true), &mut data);
        self.payload = data;
    }
}
