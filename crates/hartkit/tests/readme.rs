//! The examples of the README and of every document in docs/ run as written: every
//! `hartkit` command in their console and shell blocks that needs no hardware, network
//! server or minutes of real time (the simulated plant in virtual time, `frame`, `sim
//! bench`, `loop cable`, the modem on files) is run in document order in a scratch
//! directory of its own per document. A command shown with
//! `hartkit: error` after it must fail; any other must succeed; and every line of
//! output the README shows under a command must be in what it prints (but one-line
//! JSON, which the tool pretty-prints, and wall-clock times).

mod common;

/// One command of the README with the output shown under it.
struct Example {
    line: usize,
    args: Vec<String>,
    shown: Vec<String>,
}

/// Splits a shell command line: words, single and double quotes, a `#` comment after
/// white space. `None` for a line with pipes, redirections or background jobs.
fn shell_words(line: &str) -> Option<Vec<String>> {
    let mut words = vec![];
    let mut word = String::new();
    let mut in_word = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '\'' | '"' => {
                in_word = true;
                for q in chars.by_ref() {
                    if q == c {
                        break;
                    }
                    word.push(q);
                }
            }
            '#' if !in_word => break,
            '|' | '&' | '<' | '>' | ';' | '$' | '`' => return None,
            c if c.is_whitespace() => {
                if in_word {
                    words.push(std::mem::take(&mut word));
                    in_word = false;
                }
            }
            c => {
                in_word = true;
                word.push(c);
            }
        }
    }
    if in_word {
        words.push(word);
    }
    Some(words)
}

/// Whether a line goes on in the next (a shell's trailing backslash).
fn block_continues(line: &str) -> bool {
    line.ends_with('\\') && !line.starts_with("```")
}

/// The commands of a document's ```console and ```sh blocks, in order.
fn examples(doc: &str) -> Vec<Example> {
    let mut out: Vec<Example> = vec![];
    let mut block: Option<&str> = None;
    // A line ending in a backslash goes on in the next one, as in a shell.
    let mut lines: Vec<(usize, String)> = vec![];
    let mut pending: Option<(usize, String)> = None;
    for (i, raw) in doc.lines().enumerate() {
        let (start, mut text) = match pending.take() {
            Some((n, t)) => (n, t + " " + raw.trim_start()),
            None => (i, raw.to_string()),
        };
        if block_continues(&text) {
            text.pop();
            pending = Some((start, text));
        } else {
            lines.push((start, text));
        }
    }
    for (i, line) in lines.iter().map(|(i, l)| (*i, l.as_str())) {
        if let Some(kind) = line.strip_prefix("```") {
            block = match block {
                Some(_) => None,
                None => Some(kind.trim()),
            };
            continue;
        }
        let Some(kind) = block else { continue };
        let command = match kind {
            "console" => line.strip_prefix("$ "),
            "sh" | "bash" | "shell" => Some(line),
            _ => None,
        };
        match command.map(str::trim_start) {
            Some(c) if c.starts_with("hartkit ") => {
                let args = shell_words(c);
                out.push(Example {
                    line: i + 1,
                    args: args.map(|w| w[1..].to_vec()).unwrap_or_default(),
                    shown: vec![],
                });
            }
            Some(_) => {}
            None if kind == "console" => {
                if let Some(last) = out.last_mut() {
                    last.shown.push(line.trim_end().to_string());
                }
            }
            None => {}
        }
    }
    out
}

/// Whether an example runs here: nothing outside the process but files it makes.
fn runs_offline(args: &[String]) -> bool {
    let a: Vec<&str> = args.iter().map(String::as_str).collect();
    let on_sim = a.contains(&"sim?virtual");
    match a.as_slice() {
        ["scan" | "read" | "write" | "command", ..] => on_sim,
        ["frame", ..] | ["sim", "bench", ..] => true,
        // Conformance runs on the simulated plant in virtual time, and on recordings
        // the document makes first.
        ["conform", "phy", ..] => true,
        ["conform", ..] => on_sim,
        // Simulating the cable takes minutes in a test build.
        ["loop", "cable", ..] => !a.contains(&"--simulate"),
        // WirelessHART on the files the document makes (the captures of the repository
        // are read from its root, not from the scratch directory).
        ["wireless", "encode", ..] => !a.contains(&"--from"),
        ["wireless", "decode", file, ..] => !file.contains('/'),
        ["modem", "tx", ..] => !a.contains(&"-"),
        ["modem", "rx", ..] => !a.contains(&"-") && !a.iter().any(|w| w.contains("sound")),
        _ => false,
    }
}

/// Whether a line the README shows under a command is compared with the output: not
/// blank, not an ellipsis or a comment continuing the command, not one-line JSON (the
/// tool pretty-prints), not a wall-clock time.
fn compared(shown: &str) -> bool {
    let t = shown.trim_start();
    !(t.is_empty()
        || t == "..."
        || t.starts_with('#')
        || t.starts_with('{')
        || t.contains(" wall ("))
}

/// A gateway a document starts (`hartkit serve --sim ...` with a front end on
/// loopback): run in the background until the next one replaces it or the document
/// ends, so the client commands after it run against it.
fn gateway_on_loopback(args: &[String]) -> bool {
    let a: Vec<&str> = args.iter().map(String::as_str).collect();
    let front_end = [
        "--hart-ip",
        "--modbus",
        "--opcua",
        "--history",
        "--mqtt",
        "--web",
    ]
    .iter()
    .any(|f| a.contains(f));
    a.first() == Some(&"serve")
        && a.contains(&"--sim")
        && front_end
        && !a.contains(&"--print-map")
        && !a.contains(&"--port")
        && !a.contains(&"--config")
        && !a.iter().any(|w| w.starts_with("0.0.0.0"))
}

/// A client command against a gateway the document started on loopback; one that runs
/// until stopped (a monitor without --duration) is left out.
fn against_the_gateway(args: &[String]) -> bool {
    let a: Vec<&str> = args.iter().map(String::as_str).collect();
    let local = a
        .iter()
        .any(|w| w.starts_with("udp://127.0.0.1") || w.starts_with("tcp://127.0.0.1"));
    let ends = a.first() != Some(&"monitor") || a.contains(&"--duration");
    local
        && ends
        && matches!(
            a.first(),
            Some(&("scan" | "read" | "write" | "command" | "burst" | "monitor"))
        )
}

/// A query of the historian file a gateway the document started writes (not a
/// database server).
fn reads_its_history(args: &[String]) -> bool {
    let a: Vec<&str> = args.iter().map(String::as_str).collect();
    matches!(a.as_slice(), ["history", "query" | "devices", ..])
        && !a.iter().any(|w| w.contains("://"))
}

/// Kills a background gateway when dropped.
struct Background(std::process::Child);

impl Drop for Background {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts a gateway in `dir` and waits for its first line (its addresses).
fn start_gateway(args: &[String], dir: &std::path::Path) -> Result<Background, String> {
    use std::io::BufRead;
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_hartkit"))
        .args(args)
        .current_dir(dir)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .map_err(|e| e.to_string())?;
    let mut out = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    let _ = out.read_line(&mut line);
    let gw = Background(child);
    if line.is_empty() {
        return Err("the gateway did not start".into());
    }
    // Keep reading its output so it never blocks on a full pipe.
    std::thread::spawn(move || {
        let mut sink = String::new();
        while out.read_line(&mut sink).is_ok_and(|n| n > 0) {
            sink.clear();
        }
    });
    // Let it find the plant's devices before the first client asks (and, for a
    // historian, store the last of them: the demo plant's third device is read about
    // 6 s after the start, on its 1200 bit/s line).
    let settle = if args.iter().any(|a| a == "--history") {
        10
    } else {
        3
    };
    std::thread::sleep(std::time::Duration::from_secs(settle));
    Ok(gw)
}

/// Runs `args` in `dir`, stopped after `limit`: (success, standard output and error).
fn run_limited(
    args: &[String],
    dir: &std::path::Path,
    limit: std::time::Duration,
) -> (bool, String) {
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_hartkit"))
        .args(args)
        .current_dir(dir)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let end = std::time::Instant::now() + limit;
    while child.try_wait().unwrap().is_none() {
        if std::time::Instant::now() > end {
            let _ = child.kill();
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let out = child.wait_with_output().unwrap();
    (
        out.status.success(),
        format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ),
    )
}

/// Runs the offline examples of one document in a scratch directory; the failures.
/// With `servers`, the gateways it starts on loopback run in the background for the
/// client commands that follow.
fn run_examples(name: &str, text: &str, servers: bool) -> (usize, Vec<String>) {
    let scratch = tempfile::tempdir().unwrap();
    let mut ran = 0;
    let mut failures = vec![];
    let mut gateway: Option<Background> = None;
    for ex in examples(text) {
        let what = format!("{name}:{} hartkit {}", ex.line, ex.args.join(" "));
        if servers && gateway_on_loopback(&ex.args) {
            drop(gateway.take());
            match start_gateway(&ex.args, scratch.path()) {
                Ok(g) => gateway = Some(g),
                Err(e) => failures.push(format!("{what}: {e}")),
            }
            ran += 1;
            continue;
        }
        let runs = runs_offline(&ex.args)
            || (gateway.is_some()
                && (against_the_gateway(&ex.args) || reads_its_history(&ex.args)));
        if !runs {
            continue;
        }
        let (success, printed) = run_limited(
            &ex.args,
            scratch.path(),
            std::time::Duration::from_secs(120),
        );
        ran += 1;
        let should_fail = ex.shown.iter().any(|l| l.starts_with("hartkit: error"));
        if success == should_fail {
            failures.push(format!(
                "{what}: {}, expected {}\n{printed}",
                if success { "succeeded" } else { "failed" },
                if should_fail { "failure" } else { "success" }
            ));
            continue;
        }
        let lines: Vec<&str> = printed.lines().map(str::trim_end).collect();
        for shown in ex.shown.iter().filter(|l| compared(l)) {
            if !lines.contains(&shown.as_str()) {
                failures.push(format!(
                    "{what}: the document shows\n  {shown}\nwhich it does not print:\n{printed}"
                ));
            }
        }
    }
    (ran, failures)
}

#[test]
fn the_readme_examples_run_as_written() {
    let readme = std::fs::read_to_string(common::workspace().join("README.md")).unwrap();
    let (ran, failures) = run_examples("README.md", &readme, false);
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
    assert!(ran >= 15, "only {ran} README examples ran");
}

#[test]
fn the_docs_examples_run_as_written() {
    let dir = common::workspace().join("docs");
    let mut names: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".md"))
        .collect();
    names.sort();
    let (mut ran, mut failures) = (0, vec![]);
    for name in &names {
        let text = std::fs::read_to_string(dir.join(name)).unwrap();
        let (n, f) = run_examples(&format!("docs/{name}"), &text, true);
        ran += n;
        failures.extend(f);
    }
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
    assert!(ran >= 15, "only {ran} examples of docs/ ran");
}

#[test]
fn shell_words_split_as_a_shell_does() {
    assert_eq!(
        shell_words(r#"hartkit command -p "sim?virtual" 44 '{"a": 1}'   # comment"#).unwrap(),
        [
            "hartkit",
            "command",
            "-p",
            "sim?virtual",
            "44",
            r#"{"a": 1}"#
        ]
    );
    assert_eq!(shell_words("hartkit x | y"), None);
    assert_eq!(shell_words("hartkit a#b").unwrap(), ["hartkit", "a#b"]);
}
