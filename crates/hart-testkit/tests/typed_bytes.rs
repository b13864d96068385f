//! Every HART command's bytes come from hart-proto's typed layouts (issue 38): this
//! test reads the non-test code of the crates above hart-proto and fails on command
//! data built or read by hand (a command number with literal data, numbers turned
//! into bytes, offsets into reply data, strings' raw arrays, a request builder of its
//! own).
//!
//! What is deliberately raw is allowed explicitly, here, so that a change shows in
//! review: whole files whose bytes are another protocol's ([`OTHER_LAYERS`]), and a
//! line marked `// raw: <why>` (at its end or on the line above).

use std::path::{Path, PathBuf};

use regex::Regex;

/// Crates whose bytes are not this test's business: hart-proto holds the layouts,
/// hart-wireless its own WirelessHART layouts.
const SKIPPED_CRATES: &[&str] = &["hart-proto", "hart-wireless"];

/// Files (or folders, ending in `/`) whose bytes are another layer's, with the rules
/// that do not apply there and why. The rules `extended_by_number` and
/// `primary_request` apply everywhere.
const OTHER_LAYERS: &[(&str, &[&str], &str)] = &[
    (
        "crates/hart-ip/src/lib.rs",
        &["be_bytes", "data_offset"],
        "HART-IP message header and bodies",
    ),
    (
        "crates/hart-capture/src/",
        &["be_bytes", "data_offset"],
        "pcap/pcapng, IP/UDP/TCP headers",
    ),
    (
        "crates/hart-modbus/src/",
        &["be_bytes", "data_offset"],
        "Modbus PDUs and registers",
    ),
    (
        "crates/hart-profibus/src/",
        &["be_bytes", "data_offset"],
        "PROFIBUS DP telegrams, process image",
    ),
    (
        "crates/hart-opcua/src/sessions.rs",
        &["data_offset"],
        "OPC UA binary chunk header",
    ),
    (
        "crates/hart-ip-server/src/audit.rs",
        &["be_bytes", "data_offset"],
        "HART-IP audit log record",
    ),
    (
        "crates/hart-ip-server/src/stream.rs",
        &["be_bytes"],
        "HART-IP header length",
    ),
    (
        "crates/hart-ip-server/src/session.rs",
        &["be_bytes", "data_offset"],
        "HART-IP session initiate, audit log and direct PDU bodies (hart-ip's layer)",
    ),
    (
        "crates/hart-host/src/hartip.rs",
        &["be_bytes", "data_offset"],
        "HART-IP direct PDU body",
    ),
    (
        "crates/hart-wells/src/proto.rs",
        &["be_bytes", "data_offset", "literal_command_data"],
        "the well network's own commands 1, 14, 144, 160, 161: their layouts, defined once here",
    ),
];

/// The rules: an id and a pattern over one logical line.
fn rules() -> Vec<(&'static str, Regex)> {
    let r = |s: &str| Regex::new(s).expect("rule pattern");
    vec![
        (
            // `FrameSpec` derives the command-31 form itself.
            "extended_by_number",
            r(r"extended\s*:\s*[\w.]*command\s*>\s*255"),
        ),
        (
            // A command number with non-empty literal data: `(9, vec![246, ..])`,
            // `self.cmd(109, &[0, 0])`. Empty data (`&[]`, `vec![]`) is no bytes.
            "literal_command_data",
            r(r"\b\d{1,3}\s*,\s*(?:&\s*\[\s*[^\]\s]|vec!\s*\[\s*[^\]\s]|\[\s*vec!|&\[\s*&)"),
        ),
        (
            // Numbers serialized by hand.
            "be_bytes",
            r(r"\.to_be_bytes\(\)|\bfrom_be_bytes\("),
        ),
        (
            // Offsets into command data: `data[6]`, `f.data[2..]`, `d.get(..6)`,
            // `data.first()`, `let [a, b, ..] = *data`.
            "data_offset",
            r(concat!(
                r"(?:^|[^\w.])(?:data|d|raw|body|original|before)\s*\[\s*(?:\d+\s*(?:\.\.=?\s*\d*)?|\.\.=?\s*\d+)\s*\]",
                r"|\w+\.data\s*\[\s*(?:\d+\s*(?:\.\.=?\s*\d*)?|\.\.=?\s*\d+)\s*\]",
                r"|(?:^|[^\w.])(?:data|d|raw|original|before|\w+\.data)\.get\(\s*(?:\d+|\d*\s*\.\.=?\s*\d*)\s*\)",
                r"|\b(?:data|\w+\.data)\.(?:first|last|split_first|split_at)\(",
                r"|let\s*\[[^\]]*\.\.\s*\]\s*=\s*\*?\s*(?:data|\w+\.data)\b",
            )),
        ),
        (
            // Data pieced together.
            "concat_bytes",
            r(r"\[\s*(?:&?\s*\[|vec!|&\w+\.to_be_bytes)[^;]*\]\s*\.concat\(\)"),
        ),
        (
            // A typed string's raw array used as data.
            "string_bytes",
            r(
                r"&\s*\w*(?:tag|message|descriptor)\.0\b|\w*(?:tag|message|descriptor)\.0\s*\[|\)\??\s*\.0\s*\.to_vec\(\)",
            ),
        ),
        (
            // Another request builder: requests for an image position come from one
            // function in hart-poller.
            "primary_request",
            r(r"Address::long\([^)]*\)\s*\.with_master\(\s*(?:[\w:]+::)?MasterKind::Primary\s*\)"),
        ),
    ]
}

/// Rules no file is excused from.
const EVERYWHERE: &[&str] = &["extended_by_number", "primary_request"];

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let mut entries: Vec<_> = entries.flatten().map(|e| e.path()).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// The non-test source files of the crates above hart-proto, as paths relative to the
/// workspace root (`crates/NAME/src/...`).
fn source_files() -> Vec<String> {
    let root = root();
    let mut crates: Vec<_> = std::fs::read_dir(root.join("crates"))
        .expect("crates/")
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.join("src").is_dir())
        .collect();
    crates.sort();
    let mut files = vec![];
    for c in crates {
        let name = c.file_name().unwrap().to_string_lossy().to_string();
        if SKIPPED_CRATES.contains(&name.as_str()) {
            continue;
        }
        let mut found = vec![];
        rust_files(&c.join("src"), &mut found);
        // `mod tests;` files: `src/tests.rs`, `src/tests/**`, `*/tests.rs`.
        for f in found {
            let rel = f
                .strip_prefix(&root)
                .unwrap()
                .to_string_lossy()
                .replace('\\', "/");
            let rel = rel.trim_start_matches("./").to_string();
            if rel.ends_with("/tests.rs") || rel.contains("/tests/") {
                continue;
            }
            files.push(rel);
        }
    }
    files
}

/// A logical line: where it starts, and its text (continuation lines appended).
struct Logical {
    line: usize,
    text: String,
    /// The reason of a `// raw:` marker at its end or on the line above.
    raw: Option<String>,
}

/// The text before a trailing `//` comment that is not inside a string, and the
/// comment.
fn split_comment(line: &str) -> (&str, Option<&str>) {
    let b = line.as_bytes();
    let mut in_str = false;
    let mut i = 0;
    while i < b.len() {
        match b[i] {
            b'\\' if in_str => i += 1,
            b'"' => in_str = !in_str,
            b'\'' if !in_str => {
                // A char literal such as '"' must not open a string.
                if b.get(i + 2) == Some(&b'\'') {
                    i += 2;
                } else if b.get(i + 1) == Some(&b'\\') && b.get(i + 3) == Some(&b'\'') {
                    i += 3;
                }
            }
            b'/' if !in_str && b.get(i + 1) == Some(&b'/') => {
                return (&line[..i], Some(&line[i + 2..]));
            }
            _ => {}
        }
        i += 1;
    }
    (line, None)
}

fn raw_reason(comment: &str) -> Option<String> {
    comment
        .trim()
        .strip_prefix("raw:")
        .map(|r| r.trim().to_string())
}

/// The non-test logical lines of `text` (rustfmt's layout is relied on: a
/// `#[cfg(test)]` item ends at the first `}` at its own indentation).
fn logical_lines(text: &str) -> Vec<Logical> {
    let lines: Vec<&str> = text.lines().collect();
    let mut out: Vec<Logical> = vec![];
    let mut pending_raw: Option<String> = None;
    let mut i = 0;
    while i < lines.len() {
        let line = lines[i];
        let trimmed = line.trim();
        if trimmed == "#[cfg(test)]" {
            let indent = &line[..line.len() - line.trim_start().len()];
            let mut j = i + 1;
            while j < lines.len() && lines[j].trim().starts_with("#[") {
                j += 1;
            }
            if j < lines.len() && lines[j].trim_end().ends_with(';') {
                i = j + 1;
                continue;
            }
            let close = format!("{indent}}}");
            while j < lines.len() && lines[j].trim_end() != close {
                j += 1;
            }
            i = j + 1;
            pending_raw = None;
            continue;
        }
        if trimmed.starts_with("//") {
            if let Some(r) = raw_reason(trimmed.trim_start_matches('/')) {
                pending_raw = Some(r);
            }
            i += 1;
            continue;
        }
        let start = i;
        let (code, comment) = split_comment(line);
        let mut raw = comment.and_then(raw_reason).or(pending_raw.take());
        let mut text = code.to_string();
        let depth = |s: &str| -> i64 {
            s.chars()
                .map(|c| match c {
                    '(' | '[' => 1,
                    ')' | ']' => -1,
                    _ => 0,
                })
                .sum()
        };
        let mut d = depth(code);
        while i + 1 < lines.len() {
            let next = lines[i + 1].trim();
            if next.starts_with("#[cfg(test)]") {
                break;
            }
            if d > 0 || next.starts_with('.') || next.starts_with('?') {
                i += 1;
                if next.starts_with("//") {
                    continue;
                }
                let (code, comment) = split_comment(lines[i]);
                if raw.is_none() {
                    raw = comment.and_then(raw_reason);
                }
                text.push(' ');
                text.push_str(code.trim());
                d += depth(code);
            } else {
                break;
            }
        }
        out.push(Logical {
            line: start + 1,
            text,
            raw,
        });
        i += 1;
    }
    out
}

/// A rule's hit on a logical line.
struct Hit {
    file: String,
    line: usize,
    rule: &'static str,
    text: String,
}

/// A `// raw:` marker: file, line, reason, and whether a rule matched its line.
type Marker = (String, usize, String, bool);

fn excused(file: &str, rule: &str) -> bool {
    !EVERYWHERE.contains(&rule)
        && OTHER_LAYERS.iter().any(|(path, rules, _)| {
            (file == *path || (path.ends_with('/') && file.starts_with(path)))
                && rules.contains(&rule)
        })
}

/// Every hit of every rule, and the `// raw:` markers with their reasons and whether
/// a rule matched their line.
fn scan() -> (Vec<Hit>, Vec<Marker>) {
    let rules = rules();
    let root = root();
    let mut hits = vec![];
    let mut markers = vec![];
    for file in source_files() {
        let text = std::fs::read_to_string(root.join(&file)).expect("source file");
        for l in logical_lines(&text) {
            let mut matched = false;
            for (id, re) in &rules {
                if re.is_match(&l.text) {
                    matched = true;
                    let raw_ok =
                        l.raw.as_ref().is_some_and(|r| r.len() >= 10) && !EVERYWHERE.contains(id);
                    if !raw_ok && !excused(&file, id) {
                        hits.push(Hit {
                            file: file.clone(),
                            line: l.line,
                            rule: id,
                            text: l.text.trim().to_string(),
                        });
                    }
                }
            }
            if let Some(r) = &l.raw {
                markers.push((file.clone(), l.line, r.clone(), matched));
            }
        }
    }
    (hits, markers)
}

#[test]
fn hand_built_command_bytes_stay_out() {
    let (hits, _) = scan();
    let problems: Vec<String> = hits
        .iter()
        .map(|h| format!("  {}:{}: [{}] {}", h.file, h.line, h.rule, h.text))
        .collect();
    assert!(
        problems.is_empty(),
        "hand-built HART command bytes:\n{}\n\nbuild the data with hart-proto's typed layouts \
         (`hart_proto::Request`, `hart_proto::command::*`, `Wire::decode`); for deliberately \
         raw bytes add `// raw: <why>`",
        problems.join("\n")
    );
}

#[test]
fn markers_and_allowances_are_current() {
    let root = root();
    let mut problems = vec![];
    for (path, rules_named, why) in OTHER_LAYERS {
        if !root.join(path).exists() {
            problems.push(format!("OTHER_LAYERS names {path}, which does not exist"));
        }
        if why.is_empty() {
            problems.push(format!("OTHER_LAYERS entry {path} gives no reason"));
        }
        for r in *rules_named {
            if !rules().iter().any(|(id, _)| id == r) || EVERYWHERE.contains(r) {
                problems.push(format!("OTHER_LAYERS entry {path}: no excusable rule {r}"));
            }
        }
    }
    let (_, markers) = scan();
    for (file, line, reason, matched) in markers {
        if reason.len() < 10 {
            problems.push(format!(
                "{file}:{line}: `// raw:` needs a reason (at least 10 characters)"
            ));
        }
        if !matched {
            problems.push(format!(
                "{file}:{line}: `// raw:` marks a line no rule matches; remove it"
            ));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn the_rules_see_what_they_are_meant_to() {
    let rules = rules();
    let hit = |text: &str| -> Vec<&str> {
        let lines = logical_lines(text);
        rules
            .iter()
            .filter(|(_, re)| {
                lines
                    .iter()
                    .any(|l| l.raw.is_none() && re.is_match(&l.text))
            })
            .map(|(id, _)| *id)
            .collect()
    };
    assert_eq!(hit("let x = (9, vec![1]);"), ["literal_command_data"]);
    assert_eq!(
        hit("self.cmd(109, &[0, 0]).await"),
        ["literal_command_data"]
    );
    assert!(hit("self.cmd(13, &[]).await").is_empty());
    assert!(hit("(3, vec![])").is_empty());
    assert_eq!(hit("let v = u16::from_be_bytes([a, b]);"), ["be_bytes"]);
    assert_eq!(hit("let e = data.get(6);"), ["data_offset"]);
    assert_eq!(hit("let e = f.data[2..].to_vec();"), ["data_offset"]);
    assert!(hit("let e = st.ad[1][0];").is_empty());
    assert_eq!(
        hit("let d = [&[m][..], &p.to_be_bytes()].concat();"),
        ["be_bytes", "concat_bytes"]
    );
    assert_eq!(hit("c.command(&d, 11, &tag.0)"), ["string_bytes"]);
    assert_eq!(
        hit("FrameSpec { extended: command > 255, ..x }"),
        ["extended_by_number"]
    );
    assert_eq!(
        hit("Address::long(id).with_master(MasterKind::Primary)"),
        ["primary_request"]
    );
    // Continuation lines join; comments and test items do not count.
    assert_eq!(
        hit("let r = self\n    .cmd(\n        9,\n        vec![246],\n    );"),
        ["literal_command_data"]
    );
    assert!(hit("// (9, vec![1])\nlet a = 1;").is_empty());
    assert!(hit("#[cfg(test)]\nmod tests {\n    fn f() { (9, vec![1]); }\n}").is_empty());
    assert!(hit("let x = (9, vec![1]); // raw: a malformed request on purpose").is_empty());
    assert!(hit("// raw: a malformed request on purpose\nlet x = (9, vec![1]);").is_empty());
    assert!(
        hit("let s = \"// (9, vec![1])\"; let x = (9, vec![1]);").contains(&"literal_command_data")
    );
}

/// The Python package's pass: a `Device` method sends a command it has a layout for
/// with `self.request(commands.X, ...)`, not `self.command(N, bytes(...))`, so its
/// data also comes from hart-proto's layouts (through the native module).
#[test]
fn python_uses_typed_requests() {
    let raw = Regex::new(r#"\.command\(\s*\d+\s*,\s*(?:bytes\(|b["'])"#).unwrap();
    assert!(raw.is_match("return self.command(9, bytes(codes))"));
    assert!(!raw.is_match("return self.command(cls.number, cls.encode_request(fields))"));
    let dir = root().join("crates/hartkit-py/python/hartkit");
    let mut found = vec![];
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "py"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no Python files under {}", dir.display());
    for file in files {
        let text = std::fs::read_to_string(&file).unwrap();
        for (n, line) in text.lines().enumerate() {
            if raw.is_match(line) && !line.contains("# raw:") {
                found.push(format!("{}:{}: {}", file.display(), n + 1, line.trim()));
            }
        }
    }
    assert!(
        found.is_empty(),
        "command data built by hand in the Python package; send it with \
         self.request(commands.<Name>, ...) (or mark a deliberate one `# raw: <why>`):\n{}",
        found.join("\n")
    );
}
