//! Frames built from their fields: a small join exchange with every data-link packet
//! type, sealed with the right keys, for `hartkit wireless encode` and the tests.

use alloc::vec;
use alloc::vec::Vec;

use crate::crypto::{Key, WELL_KNOWN_KEY};
use crate::dll::{Ack, AdvLink, AdvSuperframe, Advertise, DlBody, Dlpdu};
use crate::mac::Address;
use crate::nl::{Npdu, Security, MANAGER};
use crate::tl::{Command, Tpdu};

/// The keys of [`example_exchange`].
#[derive(Debug, Clone, Copy)]
pub struct ExampleKeys {
    /// The join key.
    pub join: Key,
    /// The network key the join response hands out (command 961).
    pub network: Key,
}

/// A transport PDU of commands.
pub fn tpdu(response: bool, seq: u8, commands: &[(u16, &[u8])]) -> Tpdu {
    Tpdu {
        acknowledged: true,
        response,
        broadcast: false,
        seq: seq & 0x1F,
        device_status: 0,
        extended_status: 0,
        commands: commands
            .iter()
            .map(|(n, d)| Command {
                number: *n,
                data: d.to_vec(),
            })
            .collect(),
    }
}

/// A join-keyed network PDU carrying `plain`, sealed with `key`.
pub fn join_npdu(dst: Address, src: Address, counter: u32, key: &Key, plain: &[u8]) -> Npdu {
    let mut n = Npdu {
        reserved: 0,
        ttl: 127,
        asn_snippet: 0,
        graph_id: 0,
        dst,
        src,
        proxy: None,
        route1: None,
        route2: None,
        security_reserved: 0,
        security: Security::Join(counter),
        mic: [0; 4],
        payload: Vec::new(),
    };
    n.seal(key, counter, plain);
    n
}

/// Six frames (without FCS), each sealed at its ASN: an advertisement, a join request
/// (command 787) under the join key, its ACK, the join response (963, 961, 962), a
/// keep-alive and a disconnect under the network key it hands out.
pub fn example_exchange(
    keys: &ExampleKeys,
    network_id: u16,
    start_asn: u64,
) -> Vec<(u64, Vec<u8>)> {
    let ap = Address::Short(0x0001);
    let joiner = Address::Long(0x0017_0D00_0032_D368);
    let mut out = Vec::new();
    let mut push = |asn: u64, mut d: Dlpdu, key: &Key| {
        d.seq = asn as u8;
        d.seal(key, asn);
        out.push((asn, d.encode()));
    };
    let adv = Advertise {
        asn: start_asn,
        join_control: 0x11,
        channel_count: 15,
        channel_map: 0x0004,
        graph_id: 0,
        superframes: vec![AdvSuperframe {
            id: 0,
            slots: 1024,
            links: vec![AdvLink {
                slot: 17,
                flags: 0x41,
            }],
        }],
        extra: Vec::new(),
    };
    let bcast = Address::Short(0xFFFF);
    push(
        start_asn,
        Dlpdu::new(0, network_id, bcast, ap, 0, false, DlBody::Advertise(adv)),
        &WELL_KNOWN_KEY,
    );
    let req = tpdu(true, 0, &[(787, &[0, 0, 1, 1, 0, 1, 0xF1])]).encode();
    let n = join_npdu(Address::Short(MANAGER), joiner, 7, &keys.join, &req);
    push(
        start_asn + 17,
        Dlpdu::new(0, network_id, ap, joiner, 3, false, DlBody::Data(n)),
        &WELL_KNOWN_KEY,
    );
    let ack = Ack {
        response_code: 0,
        time_adjustment: -32,
        extra: Vec::new(),
    };
    push(
        start_asn + 17,
        Dlpdu::new(0, network_id, joiner, ap, 0, false, DlBody::Ack(ack)),
        &WELL_KNOWN_KEY,
    );
    let mut session = vec![0u8, 0xF9, 0x80, 0xF9, 0x80, 0, 0, 1, 0, 0, 0, 1];
    session.extend_from_slice(&[0x5A; 16]);
    session.push(0);
    let resp = tpdu(
        false,
        10,
        &[(963, &session), (961, &keys.network), (962, &[0, 2])],
    )
    .encode();
    let n = join_npdu(joiner, Address::Short(MANAGER), 7, &keys.join, &resp);
    push(
        start_asn + 90,
        Dlpdu::new(0, network_id, joiner, ap, 3, false, DlBody::Data(n)),
        &WELL_KNOWN_KEY,
    );
    let me = Address::Short(0x0002);
    push(
        start_asn + 1024,
        Dlpdu::new(
            0,
            network_id,
            ap,
            me,
            0,
            true,
            DlBody::KeepAlive(Vec::new()),
        ),
        &keys.network,
    );
    push(
        start_asn + 2048,
        Dlpdu::new(
            0,
            network_id,
            ap,
            me,
            0,
            true,
            DlBody::Disconnect(Vec::new()),
        ),
        &keys.network,
    );
    out
}
