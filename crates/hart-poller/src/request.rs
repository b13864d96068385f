//! Requests that other clients (HART-IP sessions, SCADA writes) hand to a loop, and
//! what became of them.

use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::Arc;

use tokio::sync::{mpsc, oneshot};

use crate::lease::LeaseTerms;

/// A request for a loop: a PDU, and where to send what became of it.
pub struct LoopRequest {
    /// The frame (delimiter through check byte).
    pub pdu: Vec<u8>,
    /// Retries on the loop after no reply: the loop's full count for a device the
    /// gateway knows, one for an address where it found no device (so an absent
    /// device is reported after two slave time-outs, not four).
    pub retries: u8,
    /// Set when the loop takes the request ([`LoopRequest::start`]) or when its
    /// requester stops waiting for that: whichever comes first wins, so a request is
    /// either carried out or answered "busy", never both.
    pub state: Arc<AtomicU8>,
    /// The outcome. A request whose receiver is gone (its session ended) is dropped
    /// unsent.
    pub reply: oneshot::Sender<LoopOutcome>,
    /// What the lease of a fixed current it starts (command 40 accepted) asks for
    /// ([`crate::lease`]): the engine's limit and no holder by default.
    pub lease: LeaseTerms,
}

/// [`LoopRequest::state`]: waiting in the queue.
const QUEUED: u8 = 0;
/// [`LoopRequest::state`]: taken by the loop.
const STARTED: u8 = 1;
/// [`LoopRequest::state`]: given up by its requester.
const ABANDONED: u8 = 2;

impl LoopRequest {
    /// A request for `pdu` with `retries`, and the receiver of its outcome.
    pub fn new(pdu: Vec<u8>, retries: u8) -> (Self, oneshot::Receiver<LoopOutcome>) {
        let (tx, rx) = oneshot::channel();
        (
            LoopRequest {
                pdu,
                retries,
                state: Arc::new(AtomicU8::new(QUEUED)),
                reply: tx,
                lease: LeaseTerms::default(),
            },
            rx,
        )
    }

    /// The loop takes the request; `false` if its requester has given up on it (or
    /// gone), so the line is not spent on it.
    pub fn start(&self) -> bool {
        !self.reply.is_closed()
            && self
                .state
                .compare_exchange(QUEUED, STARTED, Ordering::AcqRel, Ordering::Acquire)
                .is_ok()
    }
}

/// What became of a request for a loop.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LoopOutcome {
    /// The device's reply frame.
    Reply(Vec<u8>),
    /// No reply after the loop's retries.
    NoReply,
    /// Not sent: the loop's queue was full, or the request waited there too long.
    Busy,
}

/// Requests queued for a real (or simulated) 1200 bit/s loop at most; more are answered
/// "busy" at once. A few seconds of line time: longer queues only serve clients that
/// have given up.
pub const LOOP_QUEUE: usize = 16;

/// Longest a request waits in a loop's queue before it is answered "busy" unsent: with
/// a transaction's own time (up to about 2 s with retries on an FSK loop) the answer
/// still comes within the 5 s clients wait (hartkit's, hartip-py's).
pub const MAX_QUEUE_WAIT: std::time::Duration = std::time::Duration::from_millis(2500);

/// Queues `pdu` on `queue` and waits for its outcome. Never waits for room in the
/// queue: a full queue answers [`LoopOutcome::Busy`], and so does a request still
/// queued after [`MAX_QUEUE_WAIT`] (it is then given up, never sent late).
pub(crate) async fn submit(
    queue: &mpsc::Sender<LoopRequest>,
    pdu: Vec<u8>,
    retries: u8,
    lease: LeaseTerms,
) -> LoopOutcome {
    let (mut request, mut rx) = LoopRequest::new(pdu, retries);
    request.lease = lease;
    let state = request.state.clone();
    match queue.try_send(request) {
        Ok(()) => {}
        Err(mpsc::error::TrySendError::Full(_)) => return LoopOutcome::Busy,
        Err(mpsc::error::TrySendError::Closed(_)) => return LoopOutcome::NoReply,
    }
    match tokio::time::timeout(MAX_QUEUE_WAIT, &mut rx).await {
        Ok(r) => r.unwrap_or(LoopOutcome::NoReply),
        Err(_) => {
            // Still queued: give it up ("busy"). Taken meanwhile: wait for it.
            let gave_up = state
                .compare_exchange(QUEUED, ABANDONED, Ordering::AcqRel, Ordering::Acquire)
                .is_ok();
            if gave_up {
                LoopOutcome::Busy
            } else {
                rx.await.unwrap_or(LoopOutcome::NoReply)
            }
        }
    }
}
