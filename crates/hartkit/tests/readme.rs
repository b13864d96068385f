//! The README's examples run as written: every `hartkit` command in its console and
//! shell blocks that needs no hardware, network server or minutes of real time (the
//! simulated plant in virtual time, `frame`, `sim bench`, `loop cable`, the modem on
//! files) is run in document order in a scratch directory. A command shown with
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

/// The commands of the README's ```console and ```sh blocks, in order.
fn examples(readme: &str) -> Vec<Example> {
    let mut out: Vec<Example> = vec![];
    let mut block: Option<&str> = None;
    for (i, line) in readme.lines().enumerate() {
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
        ["frame", ..] | ["sim", "bench", ..] | ["loop", "cable", ..] => true,
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

#[test]
fn the_readme_examples_run_as_written() {
    let readme = std::fs::read_to_string(common::workspace().join("README.md")).unwrap();
    let all = examples(&readme);
    let scratch = tempfile::tempdir().unwrap();
    let mut ran = 0;
    let mut failures = vec![];
    for ex in all.iter().filter(|e| runs_offline(&e.args)) {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_hartkit"))
            .args(&ex.args)
            .current_dir(scratch.path())
            .output()
            .unwrap();
        ran += 1;
        let printed = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        let should_fail = ex.shown.iter().any(|l| l.starts_with("hartkit: error"));
        let what = format!("README.md:{} hartkit {}", ex.line, ex.args.join(" "));
        if out.status.success() == should_fail {
            failures.push(format!(
                "{what}: exit status {:?}, expected {}\n{printed}",
                out.status.code(),
                if should_fail { "failure" } else { "success" }
            ));
            continue;
        }
        let lines: Vec<&str> = printed.lines().map(str::trim_end).collect();
        for shown in ex.shown.iter().filter(|l| compared(l)) {
            if !lines.contains(&shown.as_str()) {
                failures.push(format!(
                    "{what}: the README shows\n  {shown}\nwhich it does not print:\n{printed}"
                ));
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
    assert!(ran >= 15, "only {ran} README examples ran");
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
