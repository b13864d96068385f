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

use std::time::Duration;

use rumqttc::{ConnectionError, Event, EventLoop, MqttOptions, Outgoing};
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
            loop {
                let ev = eventloop.poll().await;
                let pause = matches!(ev, Err(_) | Ok(Event::Outgoing(Outgoing::Disconnect)));
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
