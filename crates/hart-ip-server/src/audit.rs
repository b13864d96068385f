//! The session audit log (Read Audit Log, message ID 5).

use std::net::SocketAddr;

/// Audit records kept: the newest sessions, oldest dropped first. Read Audit Log
/// addresses records with one byte, so a client can reach at most 256 anyway.
pub const AUDIT_RECORDS: usize = 128;

/// The newest [`AUDIT_RECORDS`] session records; record 0 of a read is the oldest kept.
#[derive(Default)]
pub(crate) struct AuditLog {
    pub(crate) records: std::collections::VecDeque<AuditRecord>,
    /// Number of the oldest record kept (records are numbered from 0 at power-up).
    first: u64,
}

impl AuditLog {
    pub(crate) fn push(&mut self, r: AuditRecord) -> u64 {
        if self.records.len() == AUDIT_RECORDS {
            self.records.pop_front();
            self.first += 1;
        }
        self.records.push_back(r);
        self.first + self.records.len() as u64 - 1
    }

    /// The record numbered `n`, while it is still kept.
    pub(crate) fn get_mut(&mut self, n: u64) -> Option<&mut AuditRecord> {
        let i = usize::try_from(n.checked_sub(self.first)?).ok()?;
        self.records.get_mut(i)
    }
}

/// One session in the audit log (58 bytes on the wire).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AuditRecord {
    /// Client address.
    pub client: SocketAddr,
    /// Server port.
    pub server_port: u16,
    /// Connect time, s since 1970.
    pub connected: u64,
    /// Disconnect time, s since 1970 (0 while open).
    pub disconnected: u64,
    /// Session status bits: 0x0001 writes occurred, 0x0002 bad session initialization,
    /// 0x0004 aborted session, 0x0008 session timeout, 0x0010 insecure session.
    pub status: u16,
    /// Publish PDUs sent.
    pub publishes: u32,
    /// Request PDUs received.
    pub requests: u32,
    /// Response PDUs sent.
    pub responses: u32,
}

impl AuditRecord {
    pub(crate) fn bytes(&self) -> [u8; 58] {
        let mut b = [0u8; 58];
        match self.client.ip() {
            std::net::IpAddr::V4(a) => b[0..4].copy_from_slice(&a.octets()),
            std::net::IpAddr::V6(a) => b[4..20].copy_from_slice(&a.octets()),
        }
        b[20..22].copy_from_slice(&self.client.port().to_be_bytes());
        b[22..24].copy_from_slice(&self.server_port.to_be_bytes());
        b[24..32].copy_from_slice(&self.connected.to_be_bytes());
        b[32..40].copy_from_slice(&self.disconnected.to_be_bytes());
        b[40..42].copy_from_slice(&self.status.to_be_bytes());
        // 42..46: configuration change counts at start and end (not tracked: 0).
        b[46..50].copy_from_slice(&self.publishes.to_be_bytes());
        b[50..54].copy_from_slice(&self.requests.to_be_bytes());
        b[54..58].copy_from_slice(&self.responses.to_be_bytes());
        b
    }
}
