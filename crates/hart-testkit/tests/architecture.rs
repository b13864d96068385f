//! docs/architecture.md against the workspace: its diagram and its table of crates
//! name every crate of the workspace (and no other), each with its layer, and the
//! table lists each crate's workspace dependencies as its Cargo.toml has them. No
//! dependency points to a higher layer.
//!
//! The table, in the section "Crates and layers", has a row per crate:
//! `| layer | `crate` | what it is for | `dep`, `dep` | `dev-dep` |` ("—" for none); the
//! last column lists the crates only the tests use (dev-dependencies that are not
//! dependencies). The diagram is the first code block of that section: a line starting
//! with a layer's number names its crates; a line without a number continues the layer
//! above it.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

const DOC: &str = "docs/architecture.md";
const SECTION: &str = "## Crates and layers";

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .canonicalize()
        .unwrap()
}

/// A crate of the workspace as its Cargo.toml describes it.
struct Krate {
    /// Its directory under the workspace root (`crates/hart-proto`).
    dir: String,
    /// Workspace crates it depends on (normal and build dependencies, optional ones
    /// included).
    deps: BTreeSet<String>,
    /// Workspace crates only its tests, examples and benchmarks use.
    dev_deps: BTreeSet<String>,
}

fn read_toml(path: &Path) -> toml::Table {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.parse()
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The names (the `package` key when renamed) of a dependency table.
fn dependency_names(table: Option<&toml::Value>) -> Vec<String> {
    let Some(table) = table.and_then(|t| t.as_table()) else {
        return Vec::new();
    };
    table
        .iter()
        .map(|(key, value)| {
            value
                .get("package")
                .and_then(|p| p.as_str())
                .unwrap_or(key)
                .to_string()
        })
        .collect()
}

/// Every crate of the workspace by package name.
fn workspace() -> BTreeMap<String, Krate> {
    let root = workspace_root();
    let manifest = read_toml(&root.join("Cargo.toml"));
    let mut dirs = Vec::new();
    for member in manifest["workspace"]["members"].as_array().unwrap() {
        let member = member.as_str().unwrap();
        if let Some(dir) = member.strip_suffix("/*") {
            for entry in std::fs::read_dir(root.join(dir)).unwrap() {
                let entry = entry.unwrap();
                if entry.path().join("Cargo.toml").exists() {
                    dirs.push(format!("{dir}/{}", entry.file_name().to_str().unwrap()));
                }
            }
        } else {
            dirs.push(member.to_string());
        }
    }
    let manifests: Vec<(String, toml::Table)> = dirs
        .into_iter()
        .map(|dir| {
            let m = read_toml(&root.join(&dir).join("Cargo.toml"));
            (dir, m)
        })
        .collect();
    let names: BTreeSet<String> = manifests
        .iter()
        .map(|(_, m)| m["package"]["name"].as_str().unwrap().to_string())
        .collect();
    let mut crates = BTreeMap::new();
    for (dir, m) in manifests {
        let mut deps = BTreeSet::new();
        let mut dev_deps = BTreeSet::new();
        let mut tables = vec![m.clone()];
        if let Some(targets) = m.get("target").and_then(|t| t.as_table()) {
            tables.extend(targets.values().filter_map(|t| t.as_table().cloned()));
        }
        for t in &tables {
            for key in ["dependencies", "build-dependencies"] {
                deps.extend(dependency_names(t.get(key)));
            }
            for key in ["dev-dependencies", "dev_dependencies"] {
                dev_deps.extend(dependency_names(t.get(key)));
            }
        }
        deps.retain(|d| names.contains(d));
        dev_deps.retain(|d| names.contains(d) && !deps.contains(d));
        let name = m["package"]["name"].as_str().unwrap().to_string();
        crates.insert(
            name,
            Krate {
                dir,
                deps,
                dev_deps,
            },
        );
    }
    crates
}

/// Words in `text` that name a crate: backticked `hart…` names (`hart_x::y` read as
/// `hart-x`), file names (`hart-ip.md`) left out.
fn crate_names_in(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let chars: Vec<char> = text.chars().collect();
    let mut i = 0;
    while i < chars.len() {
        let starts = chars[i..].starts_with(&['h', 'a', 'r', 't'])
            && (i == 0 || !(chars[i - 1].is_alphanumeric() || "_-./".contains(chars[i - 1])));
        if !starts {
            i += 1;
            continue;
        }
        let start = i;
        while i < chars.len() && (chars[i].is_ascii_alphanumeric() || "_-".contains(chars[i])) {
            i += 1;
        }
        let file_name =
            chars.get(i) == Some(&'.') && chars.get(i + 1).is_some_and(|c| c.is_ascii_alphabetic());
        let word: String = chars[start..i].iter().collect();
        let word = word.trim_end_matches('-').replace('_', "-");
        if !file_name
            && (word == "hartkit" || word.starts_with("hart-") || word.starts_with("hartkit-"))
        {
            out.push(word);
        }
    }
    out
}

/// The backticked spans of a line.
fn backticked(line: &str) -> Vec<&str> {
    line.split('`').skip(1).step_by(2).collect()
}

/// A row of the table.
struct Row {
    layer: u32,
    purpose: String,
    deps: BTreeSet<String>,
    dev_deps: BTreeSet<String>,
}

/// What docs/architecture.md says: the table's rows, the diagram's layers, and any
/// complaint about its form.
struct Doc {
    rows: BTreeMap<String, Row>,
    diagram: BTreeMap<String, Vec<u32>>,
    problems: Vec<String>,
    text: String,
}

fn names_of(cell: &str) -> BTreeSet<String> {
    backticked(cell)
        .into_iter()
        .flat_map(crate_names_in)
        .collect()
}

fn read_doc() -> Doc {
    let text = std::fs::read_to_string(workspace_root().join(DOC)).unwrap();
    let mut doc = Doc {
        rows: BTreeMap::new(),
        diagram: BTreeMap::new(),
        problems: Vec::new(),
        text: text.clone(),
    };
    let Some(start) = text.find(&format!("\n{SECTION}\n")) else {
        doc.problems.push(format!(
            "{DOC} has no section \"{SECTION}\": add it, with the layered diagram in a code \
             block and the table of crates (see crates/hart-testkit/tests/architecture.rs)"
        ));
        return doc;
    };
    let section = &text[start + 1..];
    let section = match section[SECTION.len()..].find("\n## ") {
        Some(end) => &section[..SECTION.len() + end],
        None => section,
    };
    // The diagram: the first code block.
    let mut in_block = false;
    let mut seen_block = false;
    let mut layer = None;
    for line in section.lines() {
        if line.trim_start().starts_with("```") {
            if in_block {
                seen_block = true;
            }
            in_block = !in_block && !seen_block;
            continue;
        }
        if !in_block {
            continue;
        }
        let trimmed = line.trim_start();
        let digits: String = trimmed.chars().take_while(|c| c.is_ascii_digit()).collect();
        if !digits.is_empty() {
            layer = digits.parse().ok();
        }
        for name in crate_names_in(line) {
            match layer {
                Some(l) => doc.diagram.entry(name).or_default().push(l),
                None => doc.problems.push(format!(
                    "the diagram in {DOC} names {name} before any layer's number: start \
                     its line with the number of its layer"
                )),
            }
        }
    }
    if !seen_block {
        doc.problems.push(format!(
            "the section \"{SECTION}\" of {DOC} has no diagram: add the layers in a code \
             block, one line per layer starting with its number"
        ));
    }
    // The table: rows whose second cell is a backticked crate name.
    for line in section.lines().filter(|l| l.starts_with('|')) {
        let cells: Vec<&str> = line
            .trim()
            .trim_matches('|')
            .split('|')
            .map(str::trim)
            .collect();
        if cells.len() < 2 || !cells[1].starts_with('`') {
            continue;
        }
        let name = cells[1].trim_matches('`').to_string();
        if cells.len() != 5 {
            doc.problems.push(format!(
                "the row of {name} in the table of {DOC} has {} columns: write \
                 | layer | `crate` | what it is for | dependencies | test-only dependencies |",
                cells.len()
            ));
            continue;
        }
        let Ok(layer) = cells[0].split_whitespace().next().unwrap_or("").parse() else {
            doc.problems.push(format!(
                "the row of {name} in the table of {DOC} has no layer number in its first \
                 column: write the number of its layer there"
            ));
            continue;
        };
        let row = Row {
            layer,
            purpose: cells[2].to_string(),
            deps: names_of(cells[3]),
            dev_deps: names_of(cells[4]),
        };
        if doc.rows.insert(name.clone(), row).is_some() {
            doc.problems.push(format!(
                "the table of {DOC} has two rows for {name}: remove one"
            ));
        }
    }
    doc
}

fn list(names: &BTreeSet<String>) -> String {
    if names.is_empty() {
        "—".to_string()
    } else {
        names
            .iter()
            .map(|n| format!("`{n}`"))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

#[test]
fn architecture_document_matches_the_workspace() {
    let crates = workspace();
    let doc = read_doc();
    let mut problems = doc.problems.clone();
    for (name, krate) in &crates {
        let Some(row) = doc.rows.get(name) else {
            problems.push(format!(
                "{name} ({}) is missing from the table of {DOC}: add the row\n    | <layer> | \
                 `{name}` | <what it is for, in one line> | {} | {} |\n  and name it on the \
                 line of its layer in the diagram above the table",
                krate.dir,
                list(&krate.deps),
                list(&krate.dev_deps)
            ));
            continue;
        };
        if row.purpose.is_empty() {
            problems.push(format!(
                "the row of {name} in {DOC} says nothing of what it is for: write it in one \
                 line in its third column"
            ));
        }
        if row.deps != krate.deps {
            problems.push(format!(
                "{name}'s dependencies in {DOC} are {}, but {}/Cargo.toml has {}: write \
                 {} in the fourth column of its row",
                list(&row.deps),
                krate.dir,
                list(&krate.deps),
                list(&krate.deps)
            ));
        }
        if row.dev_deps != krate.dev_deps {
            problems.push(format!(
                "{name}'s test-only dependencies in {DOC} are {}, but {}/Cargo.toml has {}: \
                 write {} in the fifth column of its row",
                list(&row.dev_deps),
                krate.dir,
                list(&krate.dev_deps),
                list(&krate.dev_deps)
            ));
        }
        match doc.diagram.get(name).map(Vec::as_slice) {
            None | Some([]) => problems.push(format!(
                "{name} is missing from the diagram of {DOC}: name it on the line of layer {}",
                row.layer
            )),
            Some([layer]) if *layer == row.layer => {}
            Some([layer]) => problems.push(format!(
                "the diagram of {DOC} shows {name} in layer {layer} but the table in layer \
                 {}: make them the same",
                row.layer
            )),
            Some(_) => problems.push(format!(
                "the diagram of {DOC} names {name} more than once: keep it on the line of \
                 layer {} only",
                row.layer
            )),
        }
        for (dep, dev) in krate
            .deps
            .iter()
            .map(|d| (d, false))
            .chain(krate.dev_deps.iter().map(|d| (d, true)))
        {
            let Some(dep_row) = doc.rows.get(dep) else {
                continue; // reported as missing
            };
            if dep_row.layer > row.layer {
                problems.push(format!(
                    "{name} (layer {}) depends{} on {dep} (layer {}), a higher layer: \
                     dependencies point down (or within a layer) only; move {name} to layer \
                     {} or higher in the table and the diagram of {DOC}, or {dep} down, if \
                     that is where it belongs, or drop the dependency",
                    row.layer,
                    if dev { " in its tests" } else { "" },
                    dep_row.layer,
                    dep_row.layer
                ));
            }
        }
    }
    for name in doc.rows.keys() {
        if !crates.contains_key(name) {
            problems.push(format!(
                "the table of {DOC} has a row for {name}, which is no crate of the workspace: \
                 remove the row (or correct the name)"
            ));
        }
    }
    for name in doc.diagram.keys() {
        if !crates.contains_key(name) && !doc.rows.contains_key(name) {
            problems.push(format!(
                "the diagram of {DOC} names {name}, which is no crate of the workspace: \
                 remove it (or correct the name)"
            ));
        }
    }
    // Crates named anywhere else: in code spans and as crates/<name>.
    let mut named = BTreeSet::new();
    for line in doc.text.lines() {
        for span in backticked(line) {
            named.extend(crate_names_in(span));
        }
        for part in line.split("crates/").skip(1) {
            let word: String = part
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '-' || *c == '_')
                .collect();
            if !word.is_empty() {
                named.insert(word);
            }
        }
    }
    for name in named {
        if !crates.contains_key(&name) && !doc.rows.contains_key(&name) {
            problems.push(format!(
                "{DOC} names `{name}`, which is no crate of the workspace: correct or remove it"
            ));
        }
    }
    assert!(
        problems.is_empty(),
        "\n{DOC} does not match the workspace:\n- {}\n",
        problems.join("\n- ")
    );
}

/// The crate names the checks read from text.
#[test]
fn crate_names_are_read_from_text() {
    assert_eq!(
        crate_names_in("hart_host::Transport, hartkit wells, hart-ip.md, (hart-ip-server)"),
        ["hart-host", "hartkit", "hart-ip-server"]
    );
    assert_eq!(crate_names_in("HART-IP and chart-x"), Vec::<String>::new());
}
