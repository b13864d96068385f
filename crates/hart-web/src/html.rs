//! HTML building: escaping, the page frame, and tables of decoded replies.

use std::fmt::Write as _;

use serde_json::Value;

use crate::auth::SessionView;

/// `text` safe inside HTML text and attribute values.
pub fn esc(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// What the page frame shows of the visitor: logged in (with the logout form's
/// token), or whether logging in is possible at all.
pub(crate) struct Visitor<'a> {
    pub session: Option<&'a SessionView>,
    /// Writes are possible on this dashboard (a password is set, not read only).
    pub writes: bool,
}

/// A whole page: head, navigation, `body`. `page` names it for the script.
pub(crate) fn page(title: &str, page: &str, visitor: &Visitor<'_>, body: &str) -> String {
    let login = match visitor.session {
        Some(s) => format!(
            r#"<form method="post" action="/logout" class="inline"><input type="hidden" name="csrf" value="{}"><span class="who">{}</span> <button type="submit">Log out</button></form>"#,
            esc(&s.csrf),
            esc(&s.who)
        ),
        None if visitor.writes => r#"<a href="/login">Log in</a>"#.to_string(),
        None => r#"<span class="who" title="start the gateway with --web-admin-password-file to allow writes">read only</span>"#.to_string(),
    };
    format!(
        r#"<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title} · hartkit</title><link rel="stylesheet" href="/assets/style.css"><script src="/assets/app.js" defer></script></head>
<body data-page="{page}"><header><a class="brand" href="/">hartkit</a><nav><a href="/">Plant</a><a href="/traffic">Traffic</a></nav><div class="login">{login}</div></header>
<main>{body}</main><footer>hartkit gateway · <a href="/api/devices">JSON API</a></footer></body></html>
"#,
        title = esc(title),
        page = esc(page),
    )
}

/// A value of a decoded reply as text.
fn value_text(v: &Value) -> String {
    match v {
        Value::Null => "—".to_string(),
        Value::String(s) => s.clone(),
        Value::Array(a) if a.iter().all(|x| !x.is_object()) => {
            a.iter().map(value_text).collect::<Vec<_>>().join(", ")
        }
        other => other.to_string(),
    }
}

/// The fields of a decoded reply as table rows (lists of objects as numbered rows),
/// with the meaning of codes (`_name`, `_symbol`, `_set`) beside them.
pub(crate) fn fields_table(v: &Value) -> String {
    let mut rows = String::new();
    rows_of(v, "", &mut rows);
    if rows.is_empty() {
        return "<p class=\"muted\">no data</p>".to_string();
    }
    format!("<table class=\"fields\"><tbody>{rows}</tbody></table>")
}

fn rows_of(v: &Value, prefix: &str, rows: &mut String) {
    let Some(obj) = v.as_object() else { return };
    for (k, x) in obj {
        // The meanings are shown beside their code.
        if ["_name", "_symbol", "_set"].iter().any(|s| k.ends_with(s))
            && obj.contains_key(k.rsplit_once('_').map_or("", |(a, _)| a))
        {
            continue;
        }
        let name = format!("{prefix}{k}");
        match x {
            Value::Array(items) if items.iter().any(Value::is_object) => {
                for (i, item) in items.iter().enumerate() {
                    rows_of(item, &format!("{name}[{i}]."), rows);
                }
            }
            Value::Object(_) => rows_of(x, &format!("{name}."), rows),
            _ => {
                let mut meaning = String::new();
                for suffix in ["_symbol", "_name"] {
                    if let Some(m) = obj.get(&format!("{k}{suffix}")).and_then(Value::as_str) {
                        if !meaning.is_empty() {
                            meaning.push_str(" · ");
                        }
                        meaning.push_str(m);
                    }
                }
                if let Some(Value::Array(set)) = obj.get(&format!("{k}_set")) {
                    let words: Vec<&str> = set.iter().filter_map(Value::as_str).collect();
                    meaning = if words.is_empty() {
                        "none set".to_string()
                    } else {
                        words.join(", ")
                    };
                }
                let _ = write!(
                    rows,
                    "<tr><th>{}</th><td>{}</td><td class=\"muted\">{}</td></tr>",
                    esc(&name.replace('_', " ")),
                    esc(&value_text(x)),
                    esc(&meaning)
                );
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn escapes_everything_that_matters() {
        assert_eq!(
            esc(r#"<a href="x">'&'</a>"#),
            "&lt;a href=&quot;x&quot;&gt;&#39;&amp;&#39;&lt;/a&gt;"
        );
    }

    #[test]
    fn tables_show_codes_with_their_meaning() {
        let t = fields_table(&json!({
            "pv_units": 12, "pv_units_symbol": "kPa", "pv_units_name": "kilopascals",
            "slots": [{"code": 0}, {"code": 1}],
            "flags": 3, "flags_set": ["a", "b"],
        }));
        assert!(t.contains("pv units</th><td>12</td><td class=\"muted\">kPa · kilopascals"));
        assert!(t.contains("slots[1].code"));
        assert!(t.contains("a, b"));
        assert!(!t.contains("pv units symbol"));
    }
}
