//! Publish subscriptions (commands 532 and 533).

use hart_proto::frame::Frame;

use crate::Shared;

/// Publish-message subscription flags (command 533).
pub mod subscription {
    /// Process data (burst messages).
    pub const PROCESS_DATA: u16 = 0x0001;
    /// Event notifications.
    pub const EVENT_NOTIFICATION: u16 = 0x0002;
    /// Device status.
    pub const DEVICE_STATUS: u16 = 0x0004;
    /// Device configuration.
    pub const DEVICE_CONFIGURATION: u16 = 0x0008;
}

/// A session's publish subscriptions: `None` until the client writes one with command
/// 533 (every burst message is published to it then, as HART-IP clients that predate
/// subscriptions expect); then the list of (target, flags), where the all-zero unique
/// ID stands for every device and excludes entries for single devices.
pub(crate) type Subscriptions = Option<Vec<([u8; 5], u16)>>;

/// Whether a burst frame goes to a session with `subs`.
pub(crate) fn subscribed(subs: &Subscriptions, pdu: &[u8]) -> bool {
    let Some(list) = subs else {
        return true;
    };
    let Ok(f) = Frame::parse_pdu(pdu) else {
        return false;
    };
    let id = match f.address {
        hart_proto::frame::Address::Long(a) => Some(a.id.to_bytes()),
        hart_proto::frame::Address::Short(_) => None,
    };
    list.iter().any(|(t, _)| *t == [0; 5] || Some(*t) == id)
}

/// Commands 532 (read client subscription summary) and 533 (write client subscription
/// flags), answered by the server for the session: request data is the target unique
/// ID (5 bytes, all zero for every device), for 533 followed by the flags (u16); the
/// reply data is the unique ID and the flags. Response codes: 5 too few data bytes, 9
/// individual subscription not allowed (a subscription to every device is in place),
/// 65 unknown unique ID (no such sub-device, or no subscription to read).
pub(crate) async fn subscription_command(
    shared: &Shared,
    subs: &mut Subscriptions,
    command: u16,
    data: &[u8],
) -> (u8, Vec<u8>) {
    use hart_proto::tables::rc;
    let need = if command == 533 { 7 } else { 5 };
    if data.len() < need {
        return (rc::TOO_FEW_DATA_BYTES, vec![]);
    }
    let mut target = [0u8; 5];
    target.copy_from_slice(&data[..5]);
    // The burst and master bits are not part of the device's identity.
    target[0] &= 0x3F;
    let all = target == [0; 5];
    let same = |t: &[u8; 5]| *t == target;
    let list = subs.get_or_insert_with(|| vec![([0; 5], subscription::PROCESS_DATA)]);
    let broadcast_in_place = list.iter().any(|(t, _)| *t == [0; 5]);
    if command == 532 {
        if broadcast_in_place && !all {
            return (INDIVIDUAL_SUBSCRIPTION_NOT_ALLOWED, vec![]);
        }
        return match list.iter().find(|(t, _)| same(t) || *t == [0; 5]) {
            Some((t, flags)) => {
                let mut d = t.to_vec();
                d.extend(flags.to_be_bytes());
                (rc::SUCCESS, d)
            }
            None => (UNKNOWN_UNIQUE_ID, vec![]),
        };
    }
    let flags = u16::from_be_bytes([data[5], data[6]]);
    if all {
        list.clear();
        if flags != 0 {
            list.push(([0; 5], flags));
        }
    } else {
        if broadcast_in_place {
            return (INDIVIDUAL_SUBSCRIPTION_NOT_ALLOWED, vec![]);
        }
        let known = shared
            .io
            .subs
            .lock()
            .await
            .iter()
            .any(|s| same(&s.info.unique_id().to_bytes()));
        if !known && !list.iter().any(|(t, _)| same(t)) {
            return (UNKNOWN_UNIQUE_ID, vec![]);
        }
        list.retain(|(t, _)| !same(t));
        if flags != 0 {
            list.push((target, flags));
        }
    }
    let mut d = target.to_vec();
    d.extend(flags.to_be_bytes());
    (rc::SUCCESS, d)
}

/// Response code of commands 532/533: a subscription to every device is in place.
pub(crate) const INDIVIDUAL_SUBSCRIPTION_NOT_ALLOWED: u8 = 9;
/// Response code of commands 532/533: no such sub-device, or no subscription to read.
pub(crate) const UNKNOWN_UNIQUE_ID: u8 = 65;
