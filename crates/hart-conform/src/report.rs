//! The report in three forms: a terminal summary, JSON (one object per test per line)
//! and a self-contained HTML page (inline CSS and SVG, no external files).

use std::fmt::Write as _;

use crate::model::{Evidence, Report, TestResult, Verdict};

fn ms(us: u64) -> String {
    format!("{:.1} ms", us as f64 / 1000.0)
}

/// The terminal summary: one line per test, then the counts.
pub fn text(r: &Report) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "conformance of {} ({})", r.target, r.transport);
    if let Some(d) = &r.device {
        let _ = writeln!(
            s,
            "device {} HART {}{}{}",
            d.unique_id,
            d.universal_revision,
            d.polling_address
                .map(|p| format!(", polling address {p}"))
                .unwrap_or_default(),
            d.tag
                .as_ref()
                .map(|t| format!(", tag {t}"))
                .unwrap_or_default()
        );
    }
    for w in &r.warnings {
        let _ = writeln!(s, "warning: {w}");
    }
    // A run that found no device: one reason for every test, said once.
    let same_reason = r.device.is_none()
        && r.results.len() > 1
        && r.results
            .iter()
            .all(|t| t.verdict == Verdict::CouldNotRun && t.detail == r.results[0].detail);
    if same_reason {
        let _ = writeln!(
            s,
            "none of the {} tests could run: {}",
            r.results.len(),
            r.results[0].detail
        );
    } else {
        for t in &r.results {
            let _ = writeln!(s, "{:<10} {:<15} {}", t.id, t.verdict.name(), t.detail);
        }
    }
    let _ = writeln!(
        s,
        "{} passed, {} failed, {} not applicable, {} could not run ({:.1} s, {:.1} s of it on the line)",
        r.count(Verdict::Pass),
        r.count(Verdict::Fail),
        r.count(Verdict::NotApplicable),
        r.count(Verdict::CouldNotRun),
        r.duration_us as f64 / 1e6,
        r.line_time_us as f64 / 1e6
    );
    s
}

/// JSON: one object per test, one per line (field names in docs/conform.md).
pub fn json_lines(r: &Report) -> String {
    let mut s = String::new();
    for t in &r.results {
        s.push_str(
            &serde_json::to_string(t)
                .unwrap_or_else(|e| format!("{{\"id\":\"{}\",\"error\":\"{e}\"}}", t.id)),
        );
        s.push('\n');
    }
    s
}

fn esc(text: &str) -> String {
    let mut o = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '&' => o.push_str("&amp;"),
            '"' => o.push_str("&quot;"),
            _ => o.push(c),
        }
    }
    o
}

fn verdict_class(v: Verdict) -> &'static str {
    match v {
        Verdict::Pass => "pass",
        Verdict::Fail => "fail",
        Verdict::NotApplicable => "na",
        Verdict::CouldNotRun => "cnr",
    }
}

/// An SVG timing diagram of exchanges with a measured reply: the request, the reply,
/// the slave time-out after the request, aligned at each request's end.
pub fn timing_svg(r: &Report, sto_us: u64) -> String {
    let rows: Vec<(&TestResult, &Evidence)> = r
        .results
        .iter()
        .filter(|t| t.id.starts_with("LINK"))
        .flat_map(|t| t.evidence.iter().map(move |e| (t, e)))
        .filter(|(_, e)| e.reply_delay_us.is_some() && !e.received.is_empty())
        .take(10)
        .collect();
    if rows.is_empty() {
        return "<p>No reply timing was measured (the transport hides timing, or no link test ran).</p>".into();
    }
    // Time axis: from the longest request before its end to the longest reply after it.
    let before = rows
        .iter()
        .map(|(_, e)| e.sent_end_us - e.sent_start_us.min(e.sent_end_us))
        .max()
        .unwrap_or(0);
    let after = rows
        .iter()
        .flat_map(|(_, e)| {
            e.received
                .iter()
                .map(move |f| f.end_us.saturating_sub(e.sent_end_us))
        })
        .max()
        .unwrap_or(0)
        .max(sto_us + sto_us / 10);
    let span = (before + after).max(1) as f64;
    let (left, width, row_h) = (190.0, 760.0, 26.0);
    let x = |t_rel: i64| left + (t_rel + before as i64) as f64 / span * width;
    let h = 40.0 + row_h * rows.len() as f64;
    let mut s = String::new();
    let _ = write!(
        s,
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{}\" height=\"{h}\" font-family=\"sans-serif\" font-size=\"11\">",
        left + width + 20.0
    );
    let sto_x = x(sto_us as i64);
    let zero = x(0);
    let _ = write!(
        s,
        "<line x1=\"{zero}\" y1=\"10\" x2=\"{zero}\" y2=\"{}\" stroke=\"#555\"/><text x=\"{}\" y=\"10\">end of request</text>",
        h - 5.0,
        zero + 3.0
    );
    let _ = write!(
        s,
        "<line x1=\"{sto_x}\" y1=\"10\" x2=\"{sto_x}\" y2=\"{}\" stroke=\"#c00\" stroke-dasharray=\"4 3\"/><text x=\"{}\" y=\"22\" fill=\"#c00\">STO {}</text>",
        h - 5.0,
        sto_x + 3.0,
        ms(sto_us)
    );
    for (i, (t, e)) in rows.iter().enumerate() {
        let y = 30.0 + row_h * i as f64;
        let label = format!("{} {}", t.id, e.what);
        let label: String = label.chars().take(30).collect();
        let _ = write!(s, "<text x=\"4\" y=\"{}\">{}</text>", y + 13.0, esc(&label));
        let rs = x(e.sent_start_us as i64 - e.sent_end_us as i64);
        let _ = write!(
            s,
            "<rect x=\"{rs}\" y=\"{y}\" width=\"{}\" height=\"16\" fill=\"#4a7bd0\"><title>request {}</title></rect>",
            (zero - rs).max(1.0),
            ms(e.sent_end_us - e.sent_start_us.min(e.sent_end_us))
        );
        for f in &e.received {
            let fs = x(f.start_us as i64 - e.sent_end_us as i64);
            let fe = x(f.end_us as i64 - e.sent_end_us as i64);
            let _ = write!(
                s,
                "<rect x=\"{fs}\" y=\"{y}\" width=\"{}\" height=\"16\" fill=\"{}\"><title>{} starts {} after the request; longest gap {}</title></rect>",
                (fe - fs).max(1.0),
                if f.start_us.saturating_sub(e.sent_end_us) > sto_us || f.max_gap_us > 0 { "#d0704a" } else { "#3a9d5d" },
                esc(&f.summary),
                ms(f.start_us.saturating_sub(e.sent_end_us)),
                ms(f.max_gap_us)
            );
        }
    }
    s.push_str("</svg>");
    s
}

/// The HTML report: summary, every test, each failed rule with its evidence, and the
/// timing diagram. Self-contained (inline CSS and SVG).
pub fn html(r: &Report, sto_us: u64) -> String {
    let mut s = String::new();
    s.push_str("<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>HART conformance report</title><style>");
    s.push_str(
        "body{font-family:sans-serif;margin:2em;color:#222}table{border-collapse:collapse}\
         td,th{border:1px solid #ccc;padding:3px 6px;text-align:left;vertical-align:top;font-size:13px}\
         .pass{background:#dff3e3}.fail{background:#f8d7d3}.na{background:#eee}.cnr{background:#fff3cd}\
         code,pre{font-family:monospace;font-size:12px}pre{white-space:pre-wrap}\
         .summary span{display:inline-block;padding:4px 10px;margin-right:6px;border-radius:4px}",
    );
    s.push_str("</style></head><body>");
    let _ = write!(
        s,
        "<h1>HART conformance report</h1><p>Target <code>{}</code> ({})</p>",
        esc(&r.target),
        esc(&r.transport)
    );
    if let Some(d) = &r.device {
        let _ = write!(
            s,
            "<p>Device unique ID <code>{}</code>, HART {}, expanded device type 0x{:04X}, device ID 0x{:06X}{}{}</p>",
            d.unique_id,
            d.universal_revision,
            d.expanded_device_type,
            d.device_id,
            d.polling_address.map(|p| format!(", polling address {p}")).unwrap_or_default(),
            d.tag.as_ref().map(|t| format!(", tag {}", esc(t))).unwrap_or_default()
        );
    }
    for w in &r.warnings {
        let _ = write!(s, "<p class=\"cnr\">Warning: {}</p>", esc(w));
    }
    let _ = write!(
        s,
        "<p class=\"summary\"><span class=\"pass\">{} passed</span><span class=\"fail\">{} failed</span><span class=\"na\">{} not applicable</span><span class=\"cnr\">{} could not run</span> in {:.1} s ({:.1} s on the line)</p>",
        r.count(Verdict::Pass),
        r.count(Verdict::Fail),
        r.count(Verdict::NotApplicable),
        r.count(Verdict::CouldNotRun),
        r.duration_us as f64 / 1e6,
        r.line_time_us as f64 / 1e6
    );
    s.push_str("<h2>Link timing</h2>");
    s.push_str(&timing_svg(r, sto_us));
    s.push_str("<h2>Tests</h2><table><tr><th>ID</th><th>Verdict</th><th>Rule</th><th>Source</th><th>Finding</th></tr>");
    for t in &r.results {
        let _ = write!(
            s,
            "<tr class=\"{}\"><td><a href=\"#{}\">{}</a></td><td>{}</td><td>{}</td><td>{}{}</td><td>{}</td></tr>",
            verdict_class(t.verdict),
            t.id,
            t.id,
            t.verdict.name(),
            esc(t.rule),
            esc(t.source),
            if t.single_source { " (single source)" } else { "" },
            esc(&t.detail)
        );
    }
    s.push_str("</table>");
    let failed: Vec<&TestResult> = r
        .results
        .iter()
        .filter(|t| t.verdict == Verdict::Fail)
        .collect();
    if !failed.is_empty() {
        s.push_str("<h2>Failed rules and their evidence</h2>");
    }
    for t in failed {
        let _ = write!(
            s,
            "<h3 id=\"{}\">{}: {}</h3><p>{}</p><p>Source: {}</p>",
            t.id,
            t.id,
            esc(t.rule),
            esc(&t.detail),
            esc(t.source)
        );
        for e in &t.evidence {
            let _ = write!(s, "<pre>{}", esc(&e.what));
            if !e.sent_hex.is_empty() {
                let _ = write!(
                    s,
                    "\n  sent {} – {}: {}",
                    ms(e.sent_start_us),
                    ms(e.sent_end_us),
                    esc(&e.sent_hex)
                );
            }
            for f in &e.received {
                let _ = write!(
                    s,
                    "\n  received {} – {} ({} after the request, longest gap {}): {}\n    {}",
                    ms(f.start_us),
                    ms(f.end_us),
                    ms(f.start_us.saturating_sub(e.sent_end_us)),
                    ms(f.max_gap_us),
                    esc(&f.hex),
                    esc(&f.summary)
                );
            }
            if e.received.is_empty() && !e.sent_hex.is_empty() {
                s.push_str("\n  no reply");
            }
            if let Some(err) = &e.error {
                let _ = write!(s, "\n  error: {}", esc(err));
            }
            s.push_str("</pre>");
        }
    }
    s.push_str("<p>Made by <code>hartkit conform</code>; rules and sources in docs/conform.md.</p></body></html>\n");
    s
}
