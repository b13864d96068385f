//! Access control: the server asks hart-access's [`Policy`](hart_access::Policy) about
//! every request on every path (token-passing PDUs, Direct PDU entries, command 77 at
//! any depth, subscriptions) with the session's rights, and records every write it lets
//! through in the [`Audit`](hart_access::Audit). The rules are in docs/hart-ip.md.

pub use hart_access::{CommandAllowList, DeviceCommands, Rights};
