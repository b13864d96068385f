//! rumqttc's event loop on a task of its own.
//!
//! `EventLoop::poll` must not be cancelled: dropped while it connects (TCP and CONNECT
//! done, CONNACK not read yet), the next poll opens a second connection with the same
//! client ID, the broker closes the first and publishes its will (an NDEATH before the
//! NBIRTH); dropped while it writes, part of a packet may go out twice. A `select!`
//! over `poll()` and anything else (the engine's changes, a timer) drops it whenever
//! the other branch wins. [`Driver`] polls it in a loop on its own task and hands the
//! events over a channel, whose `recv` may be cancelled freely. After a connection
//! error (or a DISCONNECT the client asked for) the loop waits for a [`Resume`]: the
//! owner decides what the next connection carries (its will, another broker of a
//! cluster, nothing of the old session) and when it is tried.
//!
//! A message longer than the client takes (`MqttOptions::set_max_packet_size`) ends
//! the connection before it is read, and a persistent session or a retained message
//! brings it back at every connection: a loop of reconnections that stops everything
//! behind it. So after such an error the next connection alone takes messages up to
//! that length (MQTT's own limit at most), for the owner to acknowledge and drop; the
//! one after it is back to the usual limit.

use std::time::Duration;

use rumqttc::{ConnectionError, Event, EventLoop, MqttOptions, Outgoing, StateError};

/// The longest packet the edge node and the ingest send, bytes (a page of backfill
/// is well under it); set with the incoming limit on the options given to
/// [`Driver::spawn`] and [`Resume`].
pub const MAX_OUTGOING: usize = 1 << 20;

/// The longest remaining length an MQTT packet can have (a 4-byte variable integer).
pub const MQTT_MAX_PACKET: usize = 268_435_455;

/// The length of the message that ended the connection for being longer than the
/// client takes, if that was the cause.
pub fn oversized(e: &ConnectionError) -> Option<usize> {
    match e {
        ConnectionError::MqttState(StateError::Deserialization(
            rumqttc::mqttbytes::Error::PayloadSizeLimitExceeded(n),
        )) => Some(*n),
        _ => None,
    }
}
use tokio::sync::mpsc;

/// What the event loop does before it connects again.
#[derive(Debug, Default)]
pub struct Resume {
    /// New options (another broker of a cluster, a new will); `None` keeps them.
    pub options: Option<MqttOptions>,
    /// Forget the requests of the old session still queued in the event loop (a
    /// clean session carries nothing over).
    pub clear: bool,
    /// Wait this long first.
    pub after: Duration,
}

/// rumqttc's event loop, polled on a task of its own.
pub struct Driver {
    events: mpsc::Receiver<Result<Event, ConnectionError>>,
    control: mpsc::UnboundedSender<Resume>,
    task: tokio::task::JoinHandle<()>,
}

impl Driver {
    /// Polls `eventloop` on a new task (call inside a tokio runtime).
    pub fn spawn(mut eventloop: EventLoop) -> Driver {
        let (tx, events) = mpsc::channel(256);
        let (control, mut control_rx) = mpsc::unbounded_channel::<Resume>();
        let task = tokio::spawn(async move {
            // The usual incoming limit while one connection takes a longer message.
            let mut raised: Option<usize> = None;
            let mut too_long: Option<usize> = None;
            loop {
                let ev = eventloop.poll().await;
                let pause = matches!(ev, Err(_) | Ok(Event::Outgoing(Outgoing::Disconnect)));
                if let Err(e) = &ev {
                    too_long = oversized(e);
                }
                if tx.send(ev).await.is_err() {
                    return;
                }
                if !pause {
                    continue;
                }
                // The connection is over: nothing more until the owner says how to go on.
                let Some(r) = control_rx.recv().await else {
                    return;
                };
                // After a DISCONNECT the client asked for, rumqttc still holds the
                // network: the next poll must connect anew.
                eventloop.network = None;
                if r.clear {
                    eventloop.pending.clear();
                    eventloop.state.events.clear();
                }
                if let Some(o) = r.options {
                    eventloop.mqtt_options = o;
                } else if let Some(usual) = raised.take() {
                    eventloop
                        .mqtt_options
                        .set_max_packet_size(usual, MAX_OUTGOING);
                }
                if let Some(n) = too_long.take().filter(|n| *n <= MQTT_MAX_PACKET) {
                    let usual = eventloop.mqtt_options.max_packet_size();
                    tracing::warn!(
                        "mqtt: the broker sent a message of {n} bytes, more than the {usual} this \
                         client takes; the next connection takes it once, to acknowledge and drop \
                         it (the broker's message_size_limit keeps such messages out)"
                    );
                    eventloop.mqtt_options.set_max_packet_size(n, MAX_OUTGOING);
                    raised.get_or_insert(usual);
                }
                if !r.after.is_zero() {
                    tokio::time::sleep(r.after).await;
                }
            }
        });
        Driver {
            events,
            control,
            task,
        }
    }

    /// The next event, or the error that ended the connection (then the loop waits
    /// for [`Driver::resume`]); `None` once the task has ended. Cancel-safe.
    pub async fn recv(&mut self) -> Option<Result<Event, ConnectionError>> {
        self.events.recv().await
    }

    /// Lets the event loop connect again after an error or a DISCONNECT.
    pub fn resume(&self, r: Resume) {
        let _ = self.control.send(r);
    }
}

impl Drop for Driver {
    fn drop(&mut self) {
        self.task.abort();
    }
}
