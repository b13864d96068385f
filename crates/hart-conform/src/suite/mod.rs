//! The tests' implementations, one file per catalogue group; each file runs its
//! group's tests on the [`Runner`](crate::runner::Runner) with an exhaustive match.

mod burst;
mod commands;
mod link;
