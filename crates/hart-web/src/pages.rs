//! The pages: plant, device, traffic, login. Each is whole HTML from the server; the
//! script (assets/app.js) only keeps the values live.

use std::fmt::Write as _;

use hart_proto::command::Empty;
use hart_proto::Request;
use serde_json::Value;

use crate::html::{esc, fields_table, page, Visitor};
use crate::state::AppState;

/// A message at the top of a page: the result of a write.
pub(crate) struct Banner {
    pub ok: bool,
    pub text: String,
}

fn banner_html(b: &Option<Banner>) -> String {
    b.as_ref().map_or(String::new(), |b| {
        format!(
            "<div class=\"banner {}\" role=\"status\" id=\"banner\">{}</div>",
            if b.ok { "ok" } else { "bad" },
            esc(&b.text)
        )
    })
}

fn num(v: &Value, digits: usize) -> String {
    v.as_f64()
        .map_or("—".to_string(), |x| format!("{x:.digits$}"))
}

/// One row of the plant table (the script builds the same from the event stream).
fn plant_row(d: &Value) -> String {
    let unit = d["unit"].as_u64().unwrap_or(0);
    let pct = d["percent_of_range"].as_f64();
    let bar = pct.map_or(String::new(), |p| {
        format!(
            "<meter class=\"bar\" min=\"0\" max=\"100\" value=\"{:.1}\"></meter>",
            p.clamp(0.0, 100.0)
        )
    });
    let status: Vec<&str> = d["device_status_set"]
        .as_array()
        .map(|a| a.iter().filter_map(Value::as_str).collect())
        .unwrap_or_default();
    format!(
        "<tr id=\"dev-{unit}\" data-unit=\"{unit}\"><td>{unit}</td><td><a href=\"/device/{unit}\" class=\"tag\">{name}</a><div class=\"muted small\">{long}</div></td>\
<td>{loop_}</td><td>{poll}</td><td class=\"muted small\">{uid}</td>\
<td class=\"num pv\">{pv}</td><td class=\"units\">{units}</td><td class=\"pct\">{bar}<span class=\"small\">{pcts}</span></td>\
<td class=\"num current\">{current}</td><td class=\"status\">{status}</td><td><span class=\"q q-{q}\">{q}</span></td><td class=\"num age\">{age}</td></tr>",
        name = esc(d["name"].as_str().unwrap_or("")),
        long = esc(d["descriptor"].as_str().unwrap_or("")),
        loop_ = esc(d["loop"].as_str().unwrap_or("")),
        poll = d["polling_address"].as_u64().map_or("—".into(), |p| p.to_string()),
        uid = esc(d["unique_id"].as_str().unwrap_or("")),
        pv = num(&d["pv"]["value"], 3),
        units = esc(d["pv"]["units_symbol"].as_str().unwrap_or("")),
        pcts = pct.map_or(String::new(), |p| format!("{p:.1} %")),
        current = d["loop_current"].as_f64().map_or("—".into(), |c| format!("{c:.3} mA")),
        status = esc(&if status.is_empty() { "ok".to_string() } else { status.join(", ") }),
        q = esc(d["quality"].as_str().unwrap_or("")),
        age = d["age_s"].as_u64().map_or("—".into(), |a| format!("{a} s")),
    )
}

/// The plant view.
pub(crate) fn plant(state: &AppState, visitor: &Visitor<'_>) -> String {
    let p = state.plant_json();
    let mut body = String::from("<h1>Plant</h1>");
    for l in p["loops"].as_array().into_iter().flatten() {
        for (key, what) in [("port_failed", "port down"), ("disturbed", "disturbed")] {
            if let Some(why) = l[key].as_str() {
                let _ = write!(
                    body,
                    "<div class=\"banner bad\">loop {}: {what}: {}</div>",
                    esc(l["name"].as_str().unwrap_or("?")),
                    esc(why)
                );
            }
        }
    }
    body.push_str(
        "<table class=\"plant\" id=\"plant\"><thead><tr><th>Unit</th><th>Tag</th><th>Loop</th><th>Address</th>\
<th>Unique ID</th><th>PV</th><th>Units</th><th>% of range</th><th>Loop current</th><th>Status</th><th>Quality</th><th>Age</th></tr></thead><tbody>",
    );
    for d in p["devices"].as_array().into_iter().flatten() {
        body.push_str(&plant_row(d));
    }
    let _ = write!(
        body,
        "</tbody></table><p class=\"muted small\">Live: <span id=\"live\">connecting…</span> · updated <span id=\"updated\">{}</span></p>",
        esc(p["time"].as_str().unwrap_or(""))
    );
    page("Plant", "plant", visitor, &body)
}

/// The device page: what the image knows, live reads, the trend, the forms.
pub(crate) async fn device(
    state: &AppState,
    position: usize,
    visitor: &Visitor<'_>,
    banner: Option<Banner>,
    window: &str,
) -> String {
    let engine = &state.engine;
    let Some(d) = engine
        .image()
        .with(position, |d| crate::device::device_json(d, engine))
    else {
        return page(
            "No such device",
            "error",
            visitor,
            "<h1>No such device</h1>",
        );
    };
    let unit = position + 1;
    let name = d["name"].as_str().unwrap_or("").to_string();
    let mut body = banner_html(&banner);
    let _ = write!(
        body,
        "<h1>{} <span class=\"q q-{q}\" data-field=\"quality\">{q}</span></h1><p class=\"muted\">unit {unit} · loop {} · polling address {} · unique ID {}</p>",
        esc(&name),
        esc(d["loop"].as_str().unwrap_or("")),
        d["polling_address"].as_u64().map_or("—".into(), |p| p.to_string()),
        esc(d["unique_id"].as_str().unwrap_or("not known yet")),
        q = esc(d["quality"].as_str().unwrap_or("")),
    );
    // The values, kept live by the script.
    body.push_str("<section class=\"values\" id=\"values\" data-unit=\"");
    let _ = write!(body, "{unit}\">");
    for (key, label) in [("pv", "PV"), ("sv", "SV"), ("tv", "TV"), ("qv", "QV")] {
        let _ = write!(
            body,
            "<div class=\"value\"><div class=\"label\">{label}</div><div class=\"big\" data-field=\"{key}\">{}</div><div class=\"muted\" data-field=\"{key}_units\">{}</div></div>",
            num(&d[key]["value"], 3),
            esc(d[key]["units_symbol"].as_str().unwrap_or(""))
        );
    }
    let _ = write!(
        body,
        "<div class=\"value\"><div class=\"label\">Loop current</div><div class=\"big\" data-field=\"loop_current\">{}</div><div class=\"muted\">mA</div></div>\
<div class=\"value\"><div class=\"label\">% of range</div><div class=\"big\" data-field=\"percent_of_range\">{}</div><div class=\"muted\">%</div></div></section>",
        num(&d["loop_current"], 3),
        num(&d["percent_of_range"], 1),
    );
    let status: Vec<&str> = d["device_status_set"]
        .as_array()
        .map(|a| a.iter().filter_map(Value::as_str).collect())
        .unwrap_or_default();
    let _ = write!(
        body,
        "<p>Device status: <span data-field=\"status\">{}</span></p>",
        esc(&if status.is_empty() {
            "ok".to_string()
        } else {
            status.join(", ")
        })
    );
    // The trend.
    let _ = write!(
        body,
        "<h2>Trend</h2><form method=\"get\" class=\"inline\" id=\"trend-form\">Window <select name=\"window\" id=\"window\">{}</select> <button type=\"submit\">Show</button> <span class=\"muted small\">{}</span></form>\
<div class=\"trend\"><img id=\"trend\" alt=\"trend of PV and loop current\" src=\"/device/{unit}/trend.svg?window={}\" width=\"900\" height=\"320\"></div>",
        ["5m", "15m", "1h", "6h", "24h", "7d"]
            .iter()
            .map(|w| format!(
                "<option{}>{w}</option>",
                if *w == window { " selected" } else { "" }
            ))
            .collect::<String>(),
        if state.config.history.is_some() {
            "from the historian"
        } else {
            "from memory (the last hour; run a historian with --history for more)"
        },
        esc(window),
    );
    // Configuration and live reads.
    let _ = write!(
        body,
        "<h2>Configuration</h2>{}",
        d["range"].as_object().map_or(
            "<p class=\"muted\">range not read yet</p>".to_string(),
            |r| format!(
                "<p>Range {} to {} {} · damping {} s · write protect {}</p>",
                num(&r["lower"], 3),
                num(&r["upper"], 3),
                esc(r["units_symbol"].as_str().unwrap_or("")),
                num(&r["damping"], 2),
                r["write_protect"]
            )
        )
    );
    let revision = d["universal_revision"].as_u64().unwrap_or(5) as u8;
    let reads: [(&str, Request); 5] = [
        (
            "Identity (command 0)",
            Request::ReadUniqueIdentifier(Empty {}),
        ),
        ("Long tag (command 20)", Request::ReadLongTag(Empty {})),
        (
            "Device variables (command 9)",
            crate::device::variables_request(engine, position),
        ),
        (
            "Additional status (command 48)",
            Request::ReadAdditionalStatus(Default::default()),
        ),
        (
            "Burst configuration (command 105)",
            crate::device::burst_request(engine, position, 0),
        ),
    ];
    body.push_str("<div class=\"reads\">");
    for (title, request) in reads {
        let command = request.command();
        if command == 20 && revision < 6 {
            continue;
        }
        let inner = match crate::device::read(engine, position, &request).await {
            Ok(v) => reply_html(&v),
            Err(e) => format!("<p class=\"muted\">{}</p>", esc(&e.message)),
        };
        let _ = write!(
            body,
            "<section class=\"read\" id=\"cmd-{command}\"><h3>{title}</h3>{inner}</section>"
        );
    }
    body.push_str("</div>");
    body.push_str(&forms(state, unit, &d, visitor));
    page(&name, "device", visitor, &body)
}

/// A live read's reply as HTML: an error's response code in words, or the fields.
fn reply_html(v: &Value) -> String {
    let rc = v["response_code"].as_u64().unwrap_or(0);
    let mut out = String::new();
    if v["communication_error"].as_bool() == Some(true) {
        return "<p class=\"bad\">the device reports a communication error</p>".to_string();
    }
    if rc != 0 {
        let _ = write!(
            out,
            "<p class=\"muted\">response code {rc}: {}</p>",
            esc(v["response_code_name"].as_str().unwrap_or(""))
        );
    }
    if let Some(d) = v.get("decoded") {
        out.push_str(&fields_table(d));
    } else if let Some(e) = v["decode_error"].as_str() {
        let _ = write!(out, "<p class=\"bad\">{}</p>", esc(e));
    }
    out
}

/// The write forms, or why there are none.
fn forms(state: &AppState, unit: usize, d: &Value, visitor: &Visitor<'_>) -> String {
    let mut out = String::from("<h2>Change</h2>");
    if state.read_only() {
        out.push_str("<p class=\"muted\">The gateway is read only (--read-only).</p>");
        return out;
    }
    let Some(session) = visitor.session else {
        out.push_str(if visitor.writes {
            "<p class=\"muted\"><a href=\"/login\">Log in</a> to change the device's configuration.</p>"
        } else {
            "<p class=\"muted\">Writes are off: start the gateway with --web-admin-password-file FILE.</p>"
        });
        return out;
    };
    let csrf = format!(
        "<input type=\"hidden\" name=\"csrf\" value=\"{}\">",
        esc(&session.csrf)
    );
    let text = |k: &str| esc(d[k].as_str().unwrap_or(""));
    let form = |id: &str, label: &str, fields: String, button: &str| {
        format!(
            "<form method=\"post\" action=\"/device/{unit}/write\" class=\"write\" id=\"form-{id}\">{csrf}<label>{label}</label>{fields}<button type=\"submit\">{button}</button></form>"
        )
    };
    let input = |name: &str, value: &str, size: usize, extra: &str| {
        format!("<input name=\"{name}\" value=\"{value}\" size=\"{size}\" {extra}>")
    };
    out.push_str("<div class=\"forms\">");
    out.push_str(&form(
        "tag",
        "Tag (8)",
        input("tag", &text("tag"), 10, "maxlength=\"8\""),
        "Write",
    ));
    out.push_str(&form(
        "long_tag",
        "Long tag (32)",
        input("long_tag", &text("long_tag"), 32, "maxlength=\"32\""),
        "Write",
    ));
    out.push_str(&form(
        "descriptor",
        "Descriptor (16)",
        input("descriptor", &text("descriptor"), 18, "maxlength=\"16\""),
        "Write",
    ));
    out.push_str(&form(
        "message",
        "Message (32)",
        input("message", "", 32, "maxlength=\"32\""),
        "Write",
    ));
    out.push_str(&form(
        "date",
        "Date",
        input("date", "", 12, "type=\"date\""),
        "Write",
    ));
    let r = &d["range"];
    out.push_str(&form(
        "range",
        "Range",
        format!(
            "{} to {} {}",
            input("lower_range", &num(&r["lower"], 3).replace('—', ""), 8, ""),
            input("upper_range", &num(&r["upper"], 3).replace('—', ""), 8, ""),
            input(
                "range_units",
                &esc(r["units_symbol"].as_str().unwrap_or("")),
                6,
                "title=\"units symbol or code\""
            )
        ),
        "Write",
    ));
    out.push_str(&form(
        "damping",
        "Damping (s)",
        input("damping", &num(&r["damping"], 2).replace('—', ""), 6, ""),
        "Write",
    ));
    out.push_str("</div>");
    let t = &d["loop_test"];
    let running = if t.is_null() {
        String::new()
    } else if t["failed_releases"].as_u64().unwrap_or(0) > 0 {
        format!(
            "<p class=\"warn\">⚠ ALARM: the loop test at {} mA ({}) could not be ended \
             ({} tries); the gateway keeps trying. Check the device and its loop.</p>",
            num(&t["current"], 3),
            esc(t["by"].as_str().unwrap_or("")),
            t["failed_releases"]
        )
    } else {
        format!(
            "<p class=\"warn\">Loop test running: {} mA, asked by {}, released at {}.</p>",
            num(&t["current"], 3),
            esc(t["by"].as_str().unwrap_or("")),
            esc(t["release_at"].as_str().unwrap_or(""))
        )
    };
    out.push_str(&format!(
        "<h3>Loop test</h3><p class=\"warn\">⚠ A loop test drives the 4-20 mA output to a fixed current: the control system sees a false value. Put the loop in manual first. The device is released automatically after the time given, and when the gateway stops.</p>{running}\
{}{}",
        form(
            "loop_test",
            "Fixed current (mA)",
            format!(
                "{} for {} s",
                input("loop_test_ma", "12", 6, ""),
                input("release_after_s", "60", 4, "")
            ),
            "Start loop test"
        ),
        form(
            "loop_release",
            "",
            "<input type=\"hidden\" name=\"loop_test_ma\" value=\"0\">".to_string(),
            "End loop test"
        )
    ));
    out
}

/// The traffic view: filters, the live frame table and the capture download.
pub(crate) fn traffic(state: &AppState, visitor: &Visitor<'_>) -> String {
    let engine = &state.engine;
    let loops: String = (0..engine.loop_count())
        .map(|c| {
            format!(
                "<option value=\"{c}\">{}</option>",
                esc(engine.loop_name(c).unwrap_or("?"))
            )
        })
        .collect();
    let devices: String = engine
        .image()
        .snapshot()
        .iter()
        .map(|d| {
            format!(
                "<option value=\"{}\">{} · {}</option>",
                d.position + 1,
                d.position + 1,
                esc(&d.display_name())
            )
        })
        .collect();
    let body = format!(
        "<h1>Traffic</h1><form id=\"traffic-filter\" class=\"inline\">Loop <select name=\"loop\"><option value=\"\">all</option>{loops}</select> \
Device <select name=\"device\"><option value=\"\">all</option>{devices}</select> \
Command <input name=\"command\" size=\"4\" inputmode=\"numeric\"> \
<button type=\"button\" id=\"pause\">Pause</button> <a id=\"download\" href=\"/api/traffic.pcapng\" download=\"hartkit-traffic.pcapng\">Download pcapng</a></form>\
<p class=\"muted small\">The last {} frames the gateway sent and heard, newest at the bottom; a request retried is shown once. <span id=\"traffic-state\"></span></p>\
<table class=\"traffic\" id=\"traffic\"><thead><tr><th>#</th><th>Time (UTC)</th><th>Loop</th><th></th><th>Frame</th><th>Command</th></tr></thead><tbody></tbody></table>",
        crate::state::TRAFFIC_KEPT
    );
    page("Traffic", "traffic", visitor, &body)
}

/// The login page (`token`: the form's CSRF token, also in a cookie).
pub(crate) fn login(token: &str, error: Option<&str>, writes: bool, identities: bool) -> String {
    let visitor = Visitor {
        session: None,
        writes,
    };
    let body = format!(
        "<h1>Log in</h1>{}{}<form method=\"post\" action=\"/login\" class=\"login-form\"><input type=\"hidden\" name=\"csrf\" value=\"{}\">\
{}<label for=\"password\">Password</label> <input type=\"password\" name=\"password\" id=\"password\" autocomplete=\"current-password\" autofocus> <button type=\"submit\">Log in</button></form>",
        error.map_or(String::new(), |e| format!("<div class=\"banner bad\">{}</div>", esc(e))),
        if writes {
            ""
        } else {
            "<p class=\"muted\">Writes are off on this gateway: there is nothing to log in to.</p>"
        },
        esc(token),
        if identities {
            "<p class=\"muted small\">The administrator leaves the identity empty and gives the password; a HART-IP PSK identity with write rights gives its name and its key (hex).</p>\
<label for=\"identity\">Identity</label> <input name=\"identity\" id=\"identity\" autocomplete=\"username\" size=\"16\"> "
        } else {
            ""
        }
    );
    page("Log in", "login", &visitor, &body)
}

/// A page that says what went wrong.
pub(crate) fn error(title: &str, message: &str, visitor: &Visitor<'_>) -> String {
    page(
        title,
        "error",
        visitor,
        &format!("<h1>{}</h1><p>{}</p>", esc(title), esc(message)),
    )
}
