//! The loop side: one task per loop that forwards requests, scans in the background
//! and collects burst frames, and the in-memory backend for benchmarks.

use std::sync::Arc;
use std::time::{Duration, Instant};

use hart_host::target::AnyTransport;
use hart_host::Client;
use hart_link::master::RetryPolicy;
use hart_proto::frame::{Frame, FrameSpec, FrameType};
use tokio::sync::{broadcast, mpsc, Mutex};

use crate::io_system::{LoopOutcome, LoopRequest, SubDevice};
use crate::pdu;

/// The loop of [`crate::start_in_memory`]: requests answered by the devices at once,
/// without line timing, one after another as on a loop; burst messages published when
/// due. Like a loop's backend, it lists the devices a scan of polling addresses
/// `0..=scan_to` would find (none for `None`) and learns the others from the identity
/// replies that clients' requests bring back.
pub(crate) async fn memory_backend(
    mut devices: Vec<hart_device::Device>,
    scan_to: Option<u8>,
    subs: Arc<Mutex<Vec<SubDevice>>>,
    mut requests: mpsc::Receiver<LoopRequest>,
    bursts: broadcast::Sender<Vec<u8>>,
) {
    use hart_link::slave::Handler;
    use hart_proto::frame::Address;
    let start = Instant::now();
    let now = || start.elapsed().as_micros() as u64;
    {
        let mut s = subs.lock().await;
        for d in &devices {
            let c = d.config();
            if scan_to.is_none_or(|last| c.polling_address > last) {
                continue;
            }
            s.push(SubDevice {
                channel: 0,
                info: hart_host::DeviceInfo {
                    polling_address: Some(c.polling_address),
                    identity: d.identity(),
                    tag: Some(c.tag.clone()),
                    descriptor: Some(c.descriptor.clone()),
                    long_tag: Some(c.long_tag.clone()),
                    io_channel: None,
                },
            });
        }
    }
    loop {
        // A queued request is taken at once; only an idle loop arms the timer that
        // wakes it for burst messages (a timer per request costs more than the answer).
        let req = match requests.try_recv() {
            Ok(r) => Some(r),
            Err(mpsc::error::TryRecvError::Disconnected) => return,
            Err(mpsc::error::TryRecvError::Empty) => tokio::select! {
                r = requests.recv() => match r { Some(r) => Some(r), None => return },
                _ = tokio::time::sleep(Duration::from_millis(20)) => None,
            },
        };
        let t = now();
        if let Some(r) = req {
            if !r.start() {
                continue;
            }
            let reply = answer(&mut devices, &r.pdu, t);
            if let Some(reply) = &reply {
                learn(&subs, 0, &r.pdu, reply).await;
            }
            let _ = r
                .reply
                .send(reply.map_or(LoopOutcome::NoReply, LoopOutcome::Reply));
        }
        // Burst messages that are due; the master bit alternates as on a line.
        for d in &mut devices {
            if d.burst_mode() && d.burst_due(t).is_some_and(|due| due <= t) {
                let mut reply = hart_link::slave::Reply::default();
                let master = d.burst_master();
                let command = d.burst(&mut reply, t);
                let id = d.unique_id();
                let _ = bursts.send(pdu(&FrameSpec {
                    frame_type: FrameType::Back,
                    status: Some((reply.response_code, reply.device_status)),
                    extended: command > 255,
                    ..FrameSpec::request(
                        Address::long(id).with_burst(true).with_master(master),
                        command,
                        reply.data(),
                    )
                }));
                d.set_burst_master(master.other());
            }
        }
    }
}

/// The reply of the device a request frame addresses, as its data-link slave would
/// accept it (polling address; unique ID; the broadcast address for commands 11 and 21,
/// which only the device with that tag answers), or `None` when none answers.
fn answer(devices: &mut [hart_device::Device], request: &[u8], t: u64) -> Option<Vec<u8>> {
    use hart_proto::frame::Address;
    let f = Frame::parse_pdu(request).ok()?;
    devices
        .iter_mut()
        .filter(|d| match f.address {
            Address::Short(a) => a.polling_address == d.config().polling_address,
            Address::Long(a) => {
                a.id == d.unique_id() || (a.id.is_broadcast() && matches!(f.command_byte, 11 | 21))
            }
        })
        .find_map(|d| {
            let (code, status, data) = d.handle(&f, t)?;
            Some(pdu(&FrameSpec {
                frame_type: FrameType::Ack,
                extended: f.extended,
                status: Some((code, status)),
                ..FrameSpec::request(f.address.with_burst(d.burst_mode()), f.command, &data)
            }))
        })
}

/// After the first pass, one more address of the scan is visited whenever the loop has
/// had no request for this long, so the sub-device list stays current.
pub(crate) const RESCAN_IDLE: Duration = Duration::from_secs(2);

/// During the first pass the scan waits this long after a request before it takes the
/// line again, so a client's next request (which follows its reply within
/// milliseconds) does not queue behind a scan step.
pub(crate) const SCAN_GRACE: Duration = Duration::from_millis(150);

/// Rescan visits without a reply after which a known sub-device is dropped.
pub(crate) const MISSES_TO_FORGET: u8 = 2;

/// The one task that talks to a loop: requests in turn (each with the retries its
/// route asks for); between them, one polling address of the scan at a time (so
/// requests never wait long for the line), then the scan again, slowly, to learn
/// devices that were connected and forget those that were removed; and listening for
/// burst frames.
pub(crate) async fn backend(
    mut client: Client<AnyTransport>,
    channel: u8,
    scan_to: Option<u8>,
    subs: Arc<Mutex<Vec<SubDevice>>>,
    mut requests: mpsc::Receiver<LoopRequest>,
    bursts: broadcast::Sender<Vec<u8>>,
) {
    let last = scan_to.unwrap_or(0).min(63);
    let mut next_scan = scan_to.map(|_| 0u8);
    let mut first_pass = true;
    // Rescan visits without a reply, per polling address of a known device.
    let mut misses = [0u8; 64];
    // The last request, or after the first pass the last scan step: the rescan takes
    // one address per RESCAN_IDLE of quiet.
    let mut quiet_since: Option<Instant> = None;
    loop {
        // A loop in virtual time never waits: let the sessions run between steps.
        tokio::task::yield_now().await;
        let idle = quiet_since.map_or(Duration::MAX, |t| t.elapsed());
        let scan_wait = if first_pass { SCAN_GRACE } else { RESCAN_IDLE };
        let scan_due = next_scan.is_some() && idle >= scan_wait;
        let req = match requests.try_recv() {
            Ok(r) => Some(r),
            Err(mpsc::error::TryRecvError::Disconnected) => return,
            Err(mpsc::error::TryRecvError::Empty) if scan_due => None,
            Err(mpsc::error::TryRecvError::Empty) => {
                let wait = match next_scan {
                    Some(_) => scan_wait
                        .saturating_sub(idle)
                        .min(Duration::from_millis(20)),
                    None => Duration::from_millis(20),
                };
                tokio::select! {
                    r = requests.recv() => match r { Some(r) => Some(r), None => return },
                    _ = tokio::time::sleep(wait) => None,
                }
            }
        };
        let idle = quiet_since.map_or(Duration::MAX, |t| t.elapsed());
        let scan_due = next_scan.is_some() && idle >= scan_wait;
        match (req, next_scan) {
            (Some(r), _) => {
                // Given up by its requester (answered "busy"), or its session ended:
                // the line is not spent on it.
                if !r.start() {
                    continue;
                }
                client.set_policy(RetryPolicy {
                    retries: r.retries,
                    ..RetryPolicy::default()
                });
                let outcome = match client.forward(&r.pdu).await {
                    Ok(reply) => {
                        learn(&subs, channel, &r.pdu, &reply).await;
                        LoopOutcome::Reply(reply)
                    }
                    Err(_) => LoopOutcome::NoReply,
                };
                let _ = r.reply.send(outcome);
                quiet_since = Some(Instant::now());
            }
            (None, Some(poll)) if scan_due => {
                match scan_address(&mut client, poll).await {
                    Some(info) => {
                        misses[usize::from(poll)] = 0;
                        remember(&subs, SubDevice { channel, info }).await;
                    }
                    None => {
                        let m = &mut misses[usize::from(poll)];
                        *m = m.saturating_add(1);
                        if *m >= MISSES_TO_FORGET {
                            subs.lock().await.retain(|s| {
                                s.channel != channel || s.info.polling_address != Some(poll)
                            });
                        }
                    }
                }
                if poll >= last {
                    first_pass = false;
                }
                if !first_pass {
                    quiet_since = Some(Instant::now());
                }
                next_scan = Some(if poll >= last { 0 } else { poll + 1 });
            }
            (None, _) => {
                let _ = client.listen(20_000).await;
            }
        }
        for b in client.take_bursts() {
            let _ = bursts.send(b);
        }
    }
}

/// Identifies the device at `poll` (one retry only: an empty address must not hold the
/// line, and the requests queued behind it, for four slave time-outs), then reads its
/// tag and descriptor (command 13) and, from HART 6 on, its long tag (command 20).
async fn scan_address(
    client: &mut Client<AnyTransport>,
    poll: u8,
) -> Option<hart_host::DeviceInfo> {
    use hart_proto::wire::{Reader, Wire};
    client.set_policy(RetryPolicy {
        retries: 1,
        ..RetryPolicy::default()
    });
    let found = client.identify(poll).await;
    client.set_policy(RetryPolicy::default());
    let mut info = found.ok()?;
    if let Ok(r) = client.command(&info, 13, &[]).await {
        if let Ok(t) = hart_proto::command::TagDescriptorDate::decode(&mut Reader::new(&r.data)) {
            info.tag = Some(t.tag.to_string().trim_end().to_string());
            info.descriptor = Some(t.descriptor.to_string().trim_end().to_string());
        }
    }
    if info.revision() >= 6 {
        if let Ok(r) = client.command(&info, 20, &[]).await {
            if let Ok(t) = hart_proto::command::LongTag::decode(&mut Reader::new(&r.data)) {
                info.long_tag = Some(t.long_tag.to_string());
            }
        }
    }
    Some(info)
}

/// Adds a sub-device, or updates the one with the same unique ID.
pub(crate) async fn remember(subs: &Mutex<Vec<SubDevice>>, sub: SubDevice) {
    let mut subs = subs.lock().await;
    // A different device now answering at a polling address replaces the one seen
    // there before.
    if let Some(p) = sub.info.polling_address {
        subs.retain(|s| {
            s.channel != sub.channel
                || s.info.polling_address != Some(p)
                || s.info.unique_id() == sub.info.unique_id()
        });
    }
    match subs
        .iter_mut()
        .find(|s| s.info.unique_id() == sub.info.unique_id())
    {
        Some(s) => {
            let old = std::mem::replace(s, sub);
            // Keep what the new sighting did not learn.
            s.info.polling_address = s.info.polling_address.or(old.info.polling_address);
            s.info.tag = s.info.tag.take().or(old.info.tag);
            s.info.descriptor = s.info.descriptor.take().or(old.info.descriptor);
            s.info.long_tag = s.info.long_tag.take().or(old.info.long_tag);
        }
        None => subs.push(sub),
    }
}

/// Learns sub-devices from the identity replies (commands 0, 11 and 21) that clients'
/// requests bring back, so devices connected after the start-up scan are routed too.
pub(crate) async fn learn(subs: &Mutex<Vec<SubDevice>>, channel: u8, request: &[u8], reply: &[u8]) {
    use hart_proto::wire::{Reader, Wire};
    let (Ok(req), Ok(rep)) = (Frame::parse_pdu(request), Frame::parse_pdu(reply)) else {
        return;
    };
    if !matches!(rep.command, 0 | 11 | 21) || rep.response_code.unwrap_or(0xFF) != 0 {
        return;
    }
    let Ok(identity) = hart_proto::command::Identity::decode(&mut Reader::new(rep.data)) else {
        return;
    };
    let polling_address = match req.address {
        hart_proto::frame::Address::Short(a) => Some(a.polling_address),
        hart_proto::frame::Address::Long(_) => None,
    };
    let info = hart_host::DeviceInfo {
        polling_address,
        identity,
        tag: None,
        descriptor: None,
        long_tag: None,
        io_channel: None,
    };
    remember(subs, SubDevice { channel, info }).await;
}
