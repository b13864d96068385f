//! The loop side: one task per loop that forwards requests, scans in the background
//! and collects burst frames, and the in-memory backend for benchmarks.

use std::sync::Arc;
use std::time::{Duration, Instant};

use hart_host::target::AnyTransport;
use hart_host::Client;
use hart_link::master::RetryPolicy;
use hart_proto::frame::{Frame, FrameSpec, FrameType};
use tokio::sync::{broadcast, mpsc, Mutex};

use crate::mux::{LoopRequest, SubDevice};
use crate::pdu;

pub(crate) async fn memory_backend(
    mut devices: Vec<hart_device::Device>,
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
            let identity = d.identity();
            s.push(SubDevice {
                channel: 0,
                info: hart_host::DeviceInfo {
                    polling_address: Some(c.polling_address),
                    identity,
                    tag: Some(c.tag.clone()),
                    descriptor: Some(c.descriptor.clone()),
                    long_tag: Some(c.long_tag.clone()),
                },
            });
        }
    }
    loop {
        let req = tokio::select! {
            r = requests.recv() => match r { Some(r) => Some(r), None => return },
            _ = tokio::time::sleep(Duration::from_millis(20)) => None,
        };
        let t = now();
        if let Some(r) = req {
            let reply = Frame::parse_pdu(&r.pdu).ok().and_then(|f| {
                let d = devices.iter_mut().find(|d| {
                    let c = d.config();
                    match f.address {
                        Address::Short(a) => a.polling_address == c.polling_address,
                        Address::Long(a) => {
                            a.id == d.unique_id()
                                || (a.id.is_broadcast() && matches!(f.command, 11 | 21))
                        }
                    }
                })?;
                let (code, status, data) = d.handle(&f, t)?;
                Some(pdu(&FrameSpec {
                    frame_type: FrameType::Ack,
                    extended: f.extended,
                    status: Some((code, status)),
                    ..FrameSpec::request(f.address.with_burst(d.burst_mode()), f.command, &data)
                }))
            });
            let _ = r.reply.send(reply);
        }
        // Burst messages that are due.
        for d in &mut devices {
            if d.burst_mode() && d.burst_due(t).is_some_and(|due| due <= t) {
                let mut reply = hart_link::slave::Reply::default();
                let command = d.burst(&mut reply, t);
                let id = d.unique_id();
                let _ = bursts.send(pdu(&FrameSpec {
                    frame_type: FrameType::Back,
                    status: Some((reply.response_code, reply.device_status)),
                    extended: command > 255,
                    ..FrameSpec::request(Address::long(id).with_burst(true), command, reply.data())
                }));
            }
        }
    }
}

/// The one task that talks to a loop: requests in turn; between them, one polling
/// address of the scan at a time (so requests never wait long) and listening for
/// burst frames.
pub(crate) async fn backend(
    mut client: Client<AnyTransport>,
    channel: u8,
    scan_to: Option<u8>,
    subs: Arc<Mutex<Vec<SubDevice>>>,
    mut requests: mpsc::Receiver<LoopRequest>,
    bursts: broadcast::Sender<Vec<u8>>,
) {
    let mut next_scan = scan_to.map(|_| 0u8);
    loop {
        let req = match requests.try_recv() {
            Ok(r) => Some(r),
            Err(mpsc::error::TryRecvError::Disconnected) => return,
            Err(mpsc::error::TryRecvError::Empty) if next_scan.is_some() => None,
            Err(mpsc::error::TryRecvError::Empty) => tokio::select! {
                r = requests.recv() => match r { Some(r) => Some(r), None => return },
                _ = tokio::time::sleep(Duration::from_millis(20)) => None,
            },
        };
        match (req, next_scan) {
            (Some(r), _) => {
                let reply = client.forward(&r.pdu).await.ok();
                if let Some(reply) = &reply {
                    learn(&subs, channel, &r.pdu, reply).await;
                }
                let _ = r.reply.send(reply);
            }
            (None, Some(poll)) => {
                // One retry only: an empty address must not hold the line (and the
                // requests queued behind it) for four slave time-outs.
                client.set_policy(RetryPolicy {
                    retries: 1,
                    ..RetryPolicy::default()
                });
                let found = client.identify(poll).await;
                client.set_policy(RetryPolicy::default());
                if let Ok(mut info) = found {
                    if info.revision() >= 6 {
                        if let Ok(r) = client.command(&info, 20, &[]).await {
                            info.long_tag = Some(
                                hart_proto::types::Latin1String::<32>(
                                    r.data
                                        .get(..32)
                                        .and_then(|b| b.try_into().ok())
                                        .unwrap_or([0; 32]),
                                )
                                .to_string(),
                            );
                        }
                    }
                    remember(&subs, SubDevice { channel, info }).await;
                }
                next_scan = (poll < scan_to.unwrap_or(0).min(63)).then_some(poll + 1);
            }
            (None, None) => {
                let _ = client.listen(20_000).await;
            }
        }
        for b in client.take_bursts() {
            let _ = bursts.send(b);
        }
    }
}

/// Adds a sub-device, or updates the one with the same unique ID.
pub(crate) async fn remember(subs: &Mutex<Vec<SubDevice>>, sub: SubDevice) {
    let mut subs = subs.lock().await;
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
    };
    remember(subs, SubDevice { channel, info }).await;
}
