//! `hartkit hart-ip bench`: the report of the HART-IP load generator
//! (`hart_host::load`) as text and JSON.

use hart_host::load::LoadReport;
use serde_json::json;

fn transport(r: &LoadReport) -> &'static str {
    if r.tcp {
        "tcp"
    } else {
        "udp"
    }
}

/// The `--json` object: `transactions`, `transactions_per_s`, `latency_us` (`p50`,
/// `p99`, `max`, `mean`), `errors` (the total) and `error_kinds`, with the set-up.
pub fn report_json(r: &LoadReport) -> serde_json::Value {
    json!({
        "server": r.server.to_string(),
        "transport": transport(r),
        "sessions": r.sessions,
        "sessions_open": r.sessions_open,
        "device": r.device.to_string(),
        "poll": r.poll,
        "command": r.command,
        "seconds": r.seconds,
        "transactions": r.transactions,
        "transactions_per_s": r.transactions_per_second(),
        "latency_us": {
            "p50": r.latency.p50_us,
            "p99": r.latency.p99_us,
            "max": r.latency.max_us,
            "mean": r.latency.mean_us,
        },
        "errors": r.errors.total(),
        "error_kinds": {
            "timeouts": r.errors.timeouts,
            "refused": r.errors.refused,
            "closed": r.errors.closed,
            "bad_replies": r.errors.bad_replies,
        },
        "publish_messages": r.publish_messages,
    })
}

/// The summary.
pub fn report_text(r: &LoadReport) -> String {
    let e = &r.errors;
    format!(
        "HART-IP {} {}: {} session(s) ({} open), command {} to {} (polling address {}), {:.2} s\n\
         transactions: {} ({:.0}/s)\n\
         latency: p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs, mean {:.0} µs\n\
         errors: {} (time-outs {}, refused sessions {}, closed sessions {}, bad replies {})",
        transport(r),
        r.server,
        r.sessions,
        r.sessions_open,
        r.command,
        r.device,
        r.poll,
        r.seconds,
        r.transactions,
        r.transactions_per_second(),
        r.latency.p50_us,
        r.latency.p99_us,
        r.latency.max_us,
        r.latency.mean_us,
        e.total(),
        e.timeouts,
        e.refused,
        e.closed,
        e.bad_replies,
    )
}
