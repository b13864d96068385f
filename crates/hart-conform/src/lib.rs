//! # hart-conform
//!
//! Conformance tests for HART field devices, run from a host over any transport
//! `hart-host` opens (HART modem, RS-485, HART-IP, simulated plants): the data link
//! (addressing, framing, timing, communication errors), the universal and
//! common-practice commands, burst mode, and the FSK physical layer from a recording.
//!
//! * [`catalog::TESTS`]: every test once, with its stable ID, rule and source.
//! * [`run::run`]: runs the catalogue against a device ([`run::Options`]).
//! * [`phy::run`]: the physical-layer tests on a WAV recording.
//! * [`report`]: terminal summary, JSON lines and a self-contained HTML report.
//!
//! Every wait is bounded; a device that stops answering ends the run with
//! could-not-run verdicts, and nothing the device sends makes the tester panic.
//! Tests that write run only with [`run::Options::allow_writes`] and restore what they
//! change. See docs/conform.md.

#![warn(missing_docs)]

pub mod catalog;
pub mod cli;
pub mod expect;
pub mod frames;
pub mod model;
pub mod phy;
pub mod probe;
pub mod report;
pub mod run;
mod runner;
mod suite;

pub use catalog::{TestDef, TESTS};
pub use model::{Group, Report, TestResult, Verdict};
pub use run::{run, DeviceAddress, Options};
