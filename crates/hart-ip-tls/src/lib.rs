//! # hart-ip-tls
//!
//! HART-IP version 2 security for the client (`hart-host`) and the server
//! (`hart-ip-server`): TLS 1.2 and 1.3 with pre-shared keys over TCP, DTLS 1.2 with
//! pre-shared keys over UDP. The cryptography is the system's OpenSSL, through the
//! `openssl` crate; nothing here encrypts by hand.
//!
//! * [`Psk`] and [`PskTable`]: keys and PSK files (lines `IDENTITY:HEXKEY`).
//! * [`server_context`] and [`client_context`]: OpenSSL contexts with HART-IP's PSK
//!   cipher suites.
//! * [`DatagramStream`]: one DTLS peer as a stream of whole datagrams, so the same
//!   `tokio_openssl::SslStream` carries TLS over TCP and DTLS over UDP.
//! * [`Refusal`]: why a handshake failed, in words for the log.

use std::fmt;
use std::io;
use std::net::SocketAddr;
use std::path::Path;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};

use openssl::ex_data::Index;
use openssl::ssl::{Ssl, SslContext, SslContextBuilder, SslMethod, SslOptions, SslVersion};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::UdpSocket;
use tokio::sync::mpsc;

pub use tokio_openssl::SslStream;

/// TLS 1.2 / DTLS 1.2 cipher suites offered: those of FieldComm's reference server
/// (hipserver), strongest first.
pub const PSK_CIPHERS: &str = "PSK-AES128-GCM-SHA256:PSK-AES128-CCM:PSK-AES128-CBC-SHA256";

/// TLS 1.3 cipher suites (PSK in TLS 1.3 needs a SHA-256 suite).
pub const TLS13_CIPHERS: &str = "TLS_AES_128_GCM_SHA256:TLS_AES_128_CCM_SHA256";

/// Largest DTLS datagram sent (leaves room for IP and UDP headers in a 1500-byte MTU).
pub const DTLS_MTU: u32 = 1400;

/// What an identity may do (hart-access's rights, the same for every front end).
pub use hart_access::Rights;

/// A pre-shared key and its identity.
#[derive(Clone, PartialEq, Eq)]
pub struct Psk {
    /// Identity, sent in the clear during the handshake.
    pub identity: String,
    /// The key (at least 16 bytes).
    pub key: Vec<u8>,
    /// What sessions with this identity may do.
    pub rights: Rights,
}

impl fmt::Debug for Psk {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // Never print the key.
        f.debug_struct("Psk")
            .field("identity", &self.identity)
            .field("key", &format_args!("<{} bytes>", self.key.len()))
            .field("rights", &self.rights)
            .finish()
    }
}

/// Shortest key accepted, bytes (128 bits, as the AES-128 suites use).
pub const MIN_KEY_LEN: usize = 16;

/// Longest key OpenSSL's PSK callbacks take, bytes.
pub const MAX_KEY_LEN: usize = 64;

fn hex_key(hex: &str) -> Result<Vec<u8>, String> {
    let hex = hex.trim();
    if hex.len() % 2 != 0 || !hex.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err("the key must be hexadecimal, two digits a byte".into());
    }
    let key: Vec<u8> = (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap_or(0))
        .collect();
    if key.len() < MIN_KEY_LEN || key.len() > MAX_KEY_LEN {
        return Err(format!(
            "the key has {} bytes; use {MIN_KEY_LEN} to {MAX_KEY_LEN} (32 to 128 hex digits), e.g. from `openssl rand -hex 16`",
            key.len()
        ));
    }
    Ok(key)
}

impl Psk {
    /// Reads `IDENTITY:HEXKEY`, optionally followed by `:read-only` (or `:ro`).
    pub fn parse(text: &str) -> Result<Psk, String> {
        let mut parts = text.trim().splitn(3, ':');
        let identity = parts.next().unwrap_or("").trim();
        let Some(hex) = parts.next() else {
            return Err("expected IDENTITY:HEXKEY".into());
        };
        if identity.is_empty() || identity.len() > 128 {
            return Err("the identity must have 1 to 128 characters".into());
        }
        let rights = match parts.next().map(str::trim) {
            None | Some("") | Some("read-write") | Some("rw") => Rights::ReadWrite,
            Some("read-only") | Some("ro") => Rights::ReadOnly,
            Some(other) => {
                return Err(format!(
                    "unknown rights {other:?} after the key (read-only or read-write)"
                ))
            }
        };
        Ok(Psk {
            identity: identity.to_string(),
            key: hex_key(hex)?,
            rights,
        })
    }
}

/// The keys a server accepts (or the key a client uses: the first).
#[derive(Debug, Clone, Default)]
pub struct PskTable {
    /// The entries, in file order.
    pub keys: Vec<Psk>,
}

impl PskTable {
    /// Reads a PSK file: one `IDENTITY:HEXKEY[:read-only]` a line; blank lines and
    /// lines starting with `#` are skipped.
    pub fn parse(text: &str) -> Result<PskTable, String> {
        let mut keys: Vec<Psk> = vec![];
        for (n, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let psk = Psk::parse(line).map_err(|e| format!("line {}: {e}", n + 1))?;
            if keys.iter().any(|k| k.identity == psk.identity) {
                return Err(format!(
                    "line {}: identity {:?} appears twice",
                    n + 1,
                    psk.identity
                ));
            }
            keys.push(psk);
        }
        if keys.is_empty() {
            return Err("no key in the file (lines IDENTITY:HEXKEY)".into());
        }
        Ok(PskTable { keys })
    }

    /// Reads a PSK file from disk.
    pub fn load(path: &Path) -> Result<PskTable, String> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("PSK file {}: {e}", path.display()))?;
        PskTable::parse(&text).map_err(|e| format!("PSK file {}: {e}", path.display()))
    }

    /// The entry for `identity`.
    pub fn find(&self, identity: &str) -> Option<&Psk> {
        self.keys.iter().find(|k| k.identity == identity)
    }
}

/// What the server's PSK callback saw during one handshake, for the log line of a
/// refusal and for the session's rights.
#[derive(Debug, Clone, Default)]
pub struct HandshakeNote {
    /// The identity the client sent, if it got that far.
    pub identity: Option<String>,
    /// Whether that identity is in the table.
    pub known: bool,
}

/// Where a server `Ssl` keeps its [`HandshakeNote`].
fn note_index() -> Index<Ssl, Arc<Mutex<HandshakeNote>>> {
    static INDEX: std::sync::OnceLock<Index<Ssl, Arc<Mutex<HandshakeNote>>>> =
        std::sync::OnceLock::new();
    *INDEX.get_or_init(|| Ssl::new_ex_index().expect("OpenSSL ex-data index"))
}

/// The OpenSSL context of a HART-IP server: TLS 1.2-1.3 (`dtls` false) or DTLS 1.2,
/// PSK suites only, keys from `table`.
pub fn server_context(table: Arc<PskTable>, dtls: bool) -> Result<SslContext, String> {
    let method = if dtls {
        SslMethod::dtls_server()
    } else {
        SslMethod::tls_server()
    };
    let mut b = SslContextBuilder::new(method).map_err(|e| format!("OpenSSL: {e}"))?;
    common(&mut b, dtls)?;
    b.set_psk_server_callback(move |ssl, identity, key_out| {
        let identity = identity.map(|i| String::from_utf8_lossy(i).into_owned());
        let found = identity.as_deref().and_then(|i| table.find(i));
        if let Some(note) = ssl.ex_data(note_index()) {
            if let Ok(mut n) = note.lock() {
                n.identity = identity.clone();
                n.known = found.is_some();
            }
        }
        match found {
            Some(psk) if psk.key.len() <= key_out.len() => {
                key_out[..psk.key.len()].copy_from_slice(&psk.key);
                Ok(psk.key.len())
            }
            // Unknown identity: no key, the handshake fails.
            _ => Ok(0),
        }
    });
    Ok(b.build())
}

/// The OpenSSL context of a HART-IP client with `psk`: TLS 1.2-1.3 or DTLS 1.2.
pub fn client_context(psk: &Psk, dtls: bool) -> Result<SslContext, String> {
    let method = if dtls {
        SslMethod::dtls_client()
    } else {
        SslMethod::tls_client()
    };
    let mut b = SslContextBuilder::new(method).map_err(|e| format!("OpenSSL: {e}"))?;
    common(&mut b, dtls)?;
    let (identity, key) = (psk.identity.clone(), psk.key.clone());
    b.set_psk_client_callback(move |_ssl, _hint, identity_out, key_out| {
        let id = identity.as_bytes();
        if id.len() + 1 > identity_out.len() || key.len() > key_out.len() {
            return Ok(0);
        }
        identity_out[..id.len()].copy_from_slice(id);
        identity_out[id.len()] = 0;
        key_out[..key.len()].copy_from_slice(&key);
        Ok(key.len())
    });
    Ok(b.build())
}

fn common(b: &mut SslContextBuilder, dtls: bool) -> Result<(), String> {
    let e = |e: openssl::error::ErrorStack| format!("OpenSSL: {e}");
    b.set_cipher_list(PSK_CIPHERS).map_err(e)?;
    if dtls {
        b.set_min_proto_version(Some(SslVersion::DTLS1_2))
            .map_err(e)?;
        b.set_options(SslOptions::NO_QUERY_MTU);
    } else {
        b.set_min_proto_version(Some(SslVersion::TLS1_2))
            .map_err(e)?;
        b.set_ciphersuites(TLS13_CIPHERS).map_err(e)?;
    }
    // No session tickets: every session starts with a full PSK handshake.
    b.set_options(SslOptions::NO_TICKET);
    Ok(())
}

/// A server-side `Ssl` for one connection, with a note for its handshake.
pub fn server_ssl(
    ctx: &SslContext,
    dtls: bool,
) -> Result<(Ssl, Arc<Mutex<HandshakeNote>>), String> {
    let mut ssl = Ssl::new(ctx).map_err(|e| format!("OpenSSL: {e}"))?;
    let note = Arc::new(Mutex::new(HandshakeNote::default()));
    ssl.set_ex_data(note_index(), note.clone());
    if dtls {
        ssl.set_mtu(DTLS_MTU).map_err(|e| format!("OpenSSL: {e}"))?;
    }
    Ok((ssl, note))
}

/// A client-side `Ssl`.
pub fn client_ssl(ctx: &SslContext, dtls: bool) -> Result<Ssl, String> {
    let mut ssl = Ssl::new(ctx).map_err(|e| format!("OpenSSL: {e}"))?;
    if dtls {
        ssl.set_mtu(DTLS_MTU).map_err(|e| format!("OpenSSL: {e}"))?;
    }
    Ok(ssl)
}

/// Why a server handshake failed, named for the log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Refusal {
    /// The client named an identity the server has no key for.
    UnknownIdentity(String),
    /// The identity is known, but the handshake failed after the key was used: the
    /// client has another key for it.
    WrongKey(String),
    /// The peer sent something that is not a TLS handshake (plain HART-IP on a secure
    /// port, say).
    NotTls,
    /// Anything else (no shared cipher suite, a protocol version not offered, a peer
    /// that went away), with OpenSSL's words.
    Handshake(String),
}

impl fmt::Display for Refusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Refusal::UnknownIdentity(i) => write!(f, "unknown PSK identity {i:?} (not in the PSK file)"),
            Refusal::WrongKey(i) => write!(f, "wrong key for PSK identity {i:?} (the handshake failed when the key was checked)"),
            Refusal::NotTls => f.write_str("not a TLS/DTLS handshake: plain HART-IP on a secure port? (use the --plain port, or tls:// / dtls:// with a key)"),
            Refusal::Handshake(e) => write!(f, "handshake failed: {e}"),
        }
    }
}

/// Names a failed server handshake from its note and OpenSSL's error.
pub fn refusal(note: &HandshakeNote, error: &dyn fmt::Display, first_byte: Option<u8>) -> Refusal {
    match (&note.identity, note.known) {
        (Some(i), false) => Refusal::UnknownIdentity(i.clone()),
        (Some(i), true) => Refusal::WrongKey(i.clone()),
        (None, _) if first_byte.is_some_and(|b| b != 0x16) => Refusal::NotTls,
        (None, _) => Refusal::Handshake(error.to_string()),
    }
}

/// What a datagram from a peer without a DTLS association is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Datagram {
    /// A DTLS handshake record (a ClientHello starts an association).
    Handshake,
    /// Another DTLS record (an alert or late data of an association that ended).
    OtherDtls,
    /// Not DTLS at all (plain HART-IP on a secure port, noise).
    NotDtls,
}

/// Sorts a datagram by its first DTLS record header: content type (20-23), version
/// DTLS 1.x (first byte 0xFE), 13 bytes in all.
pub fn classify(datagram: &[u8]) -> Datagram {
    match datagram {
        [22, 0xFE, ..] if datagram.len() >= 13 => Datagram::Handshake,
        [20..=23, 0xFE, ..] if datagram.len() >= 13 => Datagram::OtherDtls,
        _ => Datagram::NotDtls,
    }
}

/// One DTLS peer as a stream: each read returns one whole datagram from the peer (they
/// arrive on `inbound`, put there by whoever owns the socket), each write sends one
/// datagram to it. DTLS needs its records kept in their datagrams; the server's UDP
/// socket is shared by every peer, so datagrams are sorted by source address before
/// they reach here.
pub struct DatagramStream {
    socket: Arc<UdpSocket>,
    peer: SocketAddr,
    inbound: mpsc::Receiver<Vec<u8>>,
    /// The socket is connected to the peer (a client's own socket): read it directly.
    connected: bool,
}

impl DatagramStream {
    /// A server's view of `peer` on a shared `socket`, fed by `inbound`.
    pub fn shared(
        socket: Arc<UdpSocket>,
        peer: SocketAddr,
        inbound: mpsc::Receiver<Vec<u8>>,
    ) -> Self {
        DatagramStream {
            socket,
            peer,
            inbound,
            connected: false,
        }
    }

    /// A client's own socket, connected to the server.
    pub fn connected(socket: UdpSocket, peer: SocketAddr) -> Self {
        let (_, inbound) = mpsc::channel(1);
        DatagramStream {
            socket: Arc::new(socket),
            peer,
            inbound,
            connected: true,
        }
    }

    /// The peer.
    pub fn peer(&self) -> SocketAddr {
        self.peer
    }
}

impl AsyncRead for DatagramStream {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        if self.connected {
            return self.socket.poll_recv(cx, buf);
        }
        match self.inbound.poll_recv(cx) {
            Poll::Ready(Some(d)) => {
                // A datagram longer than the buffer is cut, as a UDP read would cut it.
                let n = d.len().min(buf.remaining());
                buf.put_slice(&d[..n]);
                Poll::Ready(Ok(()))
            }
            // The owner dropped the peer: end of stream.
            Poll::Ready(None) => Poll::Ready(Ok(())),
            Poll::Pending => Poll::Pending,
        }
    }
}

impl AsyncWrite for DatagramStream {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        if self.connected {
            self.socket.poll_send(cx, buf)
        } else {
            self.socket.poll_send_to(cx, buf, self.peer)
        }
    }

    fn poll_flush(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }

    fn poll_shutdown(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psk_lines() {
        let p = Psk::parse("plant-1:00112233445566778899aabbccddeeff").unwrap();
        assert_eq!(p.identity, "plant-1");
        assert_eq!(p.key.len(), 16);
        assert_eq!(p.rights, Rights::ReadWrite);
        let ro = Psk::parse("viewer:00112233445566778899AABBCCDDEEFF:read-only").unwrap();
        assert_eq!(ro.rights, Rights::ReadOnly);
        assert!(
            !format!("{ro:?}").contains("0011"),
            "the key is never printed"
        );
        for bad in [
            "nokey",
            ":00112233445566778899aabbccddeeff",
            "id:0011",
            "id:zz112233445566778899aabbccddeeff",
            "id:00112233445566778899aabbccddeeff:admin",
        ] {
            assert!(Psk::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn psk_files() {
        let t = PskTable::parse(
            "# plant keys\n\nhost:00112233445566778899aabbccddeeff\nscada:ffeeddccbbaa99887766554433221100:ro\n",
        )
        .unwrap();
        assert_eq!(t.keys.len(), 2);
        assert_eq!(t.find("scada").unwrap().rights, Rights::ReadOnly);
        assert!(t.find("nobody").is_none());
        let e = PskTable::parse(
            "a:00112233445566778899aabbccddeeff\na:00112233445566778899aabbccddeeff",
        )
        .unwrap_err();
        assert!(e.contains("line 2") && e.contains("twice"), "{e}");
        assert!(PskTable::parse("# only a comment\n").is_err());
    }

    #[test]
    fn datagrams_sorted() {
        let mut hello = vec![22, 0xFE, 0xFD];
        hello.resize(13, 0);
        assert_eq!(classify(&hello), Datagram::Handshake);
        hello[0] = 21;
        assert_eq!(classify(&hello), Datagram::OtherDtls);
        assert_eq!(classify(&[1, 0, 0, 0, 0, 1, 0, 13]), Datagram::NotDtls);
        assert_eq!(classify(&hello[..12]), Datagram::NotDtls);
        assert_eq!(classify(&[]), Datagram::NotDtls);
    }

    #[test]
    fn contexts_build() {
        let t = Arc::new(PskTable::parse("a:00112233445566778899aabbccddeeff").unwrap());
        server_context(t.clone(), false).unwrap();
        server_context(t.clone(), true).unwrap();
        client_context(&t.keys[0], false).unwrap();
        client_context(&t.keys[0], true).unwrap();
    }
}
