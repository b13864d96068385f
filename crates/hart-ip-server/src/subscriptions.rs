//! Publish subscriptions (commands 532 and 533).

use hart_proto::command::{ClientSubscription, SubscriptionSelect, SubscriptionTarget};
use hart_proto::frame::Frame;
use hart_proto::wire::{Reader, Wire, Writer};

use crate::Shared;

/// Publish-message subscription flags (command 533), from hart-proto's table.
pub use hart_proto::command::subscription;

/// A session's publish subscriptions: `None` until the client writes one with command
/// 533 (every burst message is published to it then, as HART-IP clients that predate
/// subscriptions expect); then the list of (target, flags), where the all-zero unique
/// ID stands for every device and excludes entries for single devices.
pub(crate) type Subscriptions = Option<Vec<(SubscriptionTarget, u16)>>;

/// Whether a burst frame goes to a session with `subs`.
pub(crate) fn subscribed(subs: &Subscriptions, pdu: &[u8]) -> bool {
    let Some(list) = subs else {
        return true;
    };
    let Ok(f) = Frame::parse_pdu(pdu) else {
        return false;
    };
    let id = match f.address {
        hart_proto::frame::Address::Long(a) => Some(SubscriptionTarget::from(a.id)),
        hart_proto::frame::Address::Short(_) => None,
    };
    list.iter()
        .any(|(t, _)| *t == SubscriptionTarget::ALL || Some(*t) == id)
}

/// Commands 532 (read client subscription summary) and 533 (write client subscription
/// flags), answered by the server for the session: request data is the target unique
/// ID (5 bytes, all zero for every device), for 533 followed by the flags (u16); the
/// reply data is the unique ID and the flags ([`ClientSubscription`]). Response codes:
/// 5 too few data bytes, 9 individual subscription not allowed (a subscription to
/// every device is in place), 65 unknown unique ID (no such sub-device, or no
/// subscription to read).
pub(crate) async fn subscription_command(
    shared: &Shared,
    subs: &mut Subscriptions,
    command: u16,
    data: &[u8],
) -> (u8, Vec<u8>) {
    use hart_proto::tables::rc;
    let request = if command == 533 {
        ClientSubscription::decode(&mut Reader::new(data))
    } else {
        SubscriptionSelect::decode(&mut Reader::new(data)).map(|r| ClientSubscription {
            unique_id: r.unique_id,
            flags: 0,
        })
    };
    let Ok(ClientSubscription { unique_id, flags }) = request else {
        return (rc::TOO_FEW_DATA_BYTES, vec![]);
    };
    // The burst and master bits are not part of the device's identity.
    let target = SubscriptionTarget::from(unique_id.unique_id());
    let all = target == SubscriptionTarget::ALL;
    let list =
        subs.get_or_insert_with(|| vec![(SubscriptionTarget::ALL, subscription::PROCESS_DATA)]);
    let broadcast_in_place = list.iter().any(|(t, _)| *t == SubscriptionTarget::ALL);
    if command == 532 {
        if broadcast_in_place && !all {
            return (INDIVIDUAL_SUBSCRIPTION_NOT_ALLOWED, vec![]);
        }
        return match list
            .iter()
            .find(|(t, _)| *t == target || *t == SubscriptionTarget::ALL)
        {
            Some(&(unique_id, flags)) => (rc::SUCCESS, reply(unique_id, flags)),
            None => (UNKNOWN_UNIQUE_ID, vec![]),
        };
    }
    if all {
        list.clear();
        if flags != 0 {
            list.push((SubscriptionTarget::ALL, flags));
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
            .any(|s| SubscriptionTarget::from(s.info.unique_id()) == target);
        if !known && !list.iter().any(|(t, _)| *t == target) {
            return (UNKNOWN_UNIQUE_ID, vec![]);
        }
        list.retain(|(t, _)| *t != target);
        if flags != 0 {
            list.push((target, flags));
        }
    }
    (rc::SUCCESS, reply(target, flags))
}

/// The reply data of commands 532 and 533.
fn reply(unique_id: SubscriptionTarget, flags: u16) -> Vec<u8> {
    let r = ClientSubscription { unique_id, flags };
    let mut buf = vec![0u8; r.encoded_len()];
    // The buffer has the layout's own length.
    let _ = r.encode(&mut Writer::new(&mut buf));
    buf
}

/// Response code of commands 532/533: a subscription to every device is in place.
pub(crate) const INDIVIDUAL_SUBSCRIPTION_NOT_ALLOWED: u8 = 9;
/// Response code of commands 532/533: no such sub-device, or no subscription to read.
pub(crate) const UNKNOWN_UNIQUE_ID: u8 = 65;
