//! # hart-recorder
//!
//! The historian on the polling engine: every change of the engine's image (only the
//! values that changed) and a sample of every device at a configurable period become
//! hart-history's [`Sample`](hart_history::Sample)s, handed to its writer thread.
//! The store, its queries and its configuration are hart-history's; this crate is the
//! engine-facing part only the gateway links.

mod feed;
mod samples;

pub use feed::{run, Handle, Recorder, CHANGES_CAPACITY, DRAIN_LIMIT};
pub use samples::{device_key, samples_of};
