//! The console view: with no front end, `hartkit serve` shows the image in the
//! terminal.

use hart_poller::Engine;

use crate::ConsoleConfig;

/// With no front end, `hartkit serve` shows the image: every few seconds a table
/// (or, with `--json`, one JSON line per device, with its poll and failure counts).
pub async fn view(engine: Engine, config: ConsoleConfig) {
    let json = config.json;
    use std::io::Write as _;
    let mut tick = tokio::time::interval(config.every);
    loop {
        tick.tick().await;
        let now = engine.clock().now();
        let mut out = std::io::stdout();
        let image = engine.image().snapshot();
        // A loop whose port is down says so first.
        for channel in 0..engine.loop_count() {
            if let Some(why) = engine.loop_failure(channel) {
                let name = engine.loop_name(channel).unwrap_or("?");
                let _ = if json {
                    writeln!(
                        out,
                        "{}",
                        serde_json::json!({"loop": name, "port_failed": why})
                    )
                } else {
                    writeln!(
                        out,
                        "loop {name}: the port is down ({why}); opening it again"
                    )
                };
            }
            if let Some(why) = engine.loop_disturbed(channel) {
                let name = engine.loop_name(channel).unwrap_or("?");
                let _ = if json {
                    writeln!(
                        out,
                        "{}",
                        serde_json::json!({"loop": name, "disturbed": why})
                    )
                } else {
                    writeln!(out, "loop {name}: disturbed: {why}")
                };
            }
        }
        if !json {
            let _ = writeln!(
                out,
                "{:>4}  {:<24} {:>12} {:<8} {:>9}  quality",
                "unit", "device", "PV", "units", "current"
            );
        }
        for d in &image {
            let pv = d.variables[0];
            let units = pv
                .and_then(|v| hart_proto::tables::unit_symbol(v.units))
                .unwrap_or("");
            if json {
                let line = serde_json::json!({
                    "unit": d.position + 1,
                    "loop": d.loop_name,
                    "name": d.display_name(),
                    "pv": pv.map(|v| v.value),
                    "pv_units": pv.map(|v| v.units),
                    "pv_units_symbol": units,
                    "loop_current": d.loop_current,
                    "device_status": d.device_status,
                    "quality": d.quality(now).name(),
                    "polls": d.polls,
                    "failures": d.failures,
                });
                let _ = writeln!(out, "{line}");
            } else {
                let _ = writeln!(
                    out,
                    "{:>4}  {:<24} {:>12} {:<8} {:>9}  {}",
                    d.position + 1,
                    d.display_name(),
                    pv.map_or("-".to_string(), |v| format!("{:.3}", v.value)),
                    units,
                    d.loop_current
                        .map_or("-".to_string(), |c| format!("{c:.3} mA")),
                    d.quality(now)
                );
            }
        }
        let _ = out.flush();
    }
}
