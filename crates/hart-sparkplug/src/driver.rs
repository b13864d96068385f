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
//! behind it. So after such an error the client takes messages up to that length from
//! then on (up to [`MAX_RAISED_PACKET`]), for the owner to acknowledge and drop: one
//! reconnection per new, longer message, never a loop. Longer still is beyond what it
//! will hold in memory: that is logged as an error naming the broker's
//! `message_size_limit`, which keeps such messages out.

use std::time::Duration;

use rumqttc::{ConnectionError, Event, EventLoop, MqttOptions, Outgoing, StateError};

/// The longest packet the edge node and the ingest send, bytes (a page of backfill
/// is well under it); set with the incoming limit on the options given to
/// [`Driver::spawn`] and [`Resume`].
pub const MAX_OUTGOING: usize = 1 << 20;

/// The longest message the client is ever raised to take after one ended a
/// connection for being too long (64 MiB): the memory one message may cost.
pub const MAX_RAISED_PACKET: usize = 64 << 20;

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
            // The incoming limit raised after a longer message (kept for every later
            // connection, whatever options the owner gives).
            let mut floor: usize = 0;
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
                }
                if let Some(n) = too_long.take() {
                    let usual = eventloop.mqtt_options.max_packet_size();
                    if n <= MAX_RAISED_PACKET {
                        tracing::warn!(
                            "mqtt: the broker sent a message of {n} bytes, more than the {usual} this \
                             client took; from now on it takes messages up to that length, to \
                             acknowledge and drop them (the broker's message_size_limit keeps such \
                             messages out)"
                        );
                        floor = floor.max(n);
                    } else {
                        tracing::error!(
                            "mqtt: the broker sent a message of {n} bytes, more than the \
                             {MAX_RAISED_PACKET} this client will ever hold; it ends every connection \
                             it is delivered on: set the broker's message_size_limit (mosquitto) \
                             below {MAX_RAISED_PACKET}, or remove the message (a retained one: publish \
                             an empty retained message on its topic)"
                        );
                    }
                }
                if floor > eventloop.mqtt_options.max_packet_size() {
                    eventloop
                        .mqtt_options
                        .set_max_packet_size(floor, MAX_OUTGOING);
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
