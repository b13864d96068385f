//! No circles between files: within each crate of the workspace, no source file may use
//! (directly or through other files) an item of a file that uses one of its own items,
//! unless the circle is on [`ALLOWED`] with a reason.
//!
//! The scan reads each crate's module tree from `src/lib.rs`, `src/main.rs` and
//! `src/bin/*.rs` along its `mod x;` declarations, and finds which file uses which
//! other file's items from the source text:
//!
//! * a private `use` of an item (or a trait) defined in another file is an edge to that
//!   file; a `use` of a module itself is not (the paths through it are);
//! * a `pub use` only re-exports: it is an edge only when the file itself names what it
//!   re-exports; resolution looks through re-exports to the file that defines the item,
//!   so `crate::Y` re-exported by `pub use x::Y` in `lib.rs` is an edge to `x.rs`;
//! * `mod x;` is no edge; a file using an item defined in `lib.rs` (or a `mod.rs`) has
//!   an edge to it, and so has `lib.rs` when its own code uses `x::f`;
//! * paths in code (`crate::a::B`, `super::f`, `self::m::C`, `child::D`) and `name!`
//!   calls of a `macro_rules!` macro of another file are edges;
//! * a glob import (`use super::*`) is an edge to the file of each name the file uses
//!   from it.
//!
//! Code only compiled for unit tests (`#[cfg(test)]` modules, inline or in files of their
//! own) is left out: a unit test may use whatever it tests.
//!
//! Comments (including intra-doc links), strings and character literals are skipped.

use std::cell::RefCell;
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::{Path, PathBuf};

/// Circles between files that are known and accepted for now: the crate, the files of
/// the circle (paths under the crate's `src/`, all of them, any order) and why it stays.
const ALLOWED: &[(&str, &[&str], &str)] = &[
    (
        "hart-proto",
        &["types.rs", "wire.rs"],
        "wire.rs's `Value` carries types.rs's `Date` while types.rs builds its values with \
         wire.rs's codec; to be broken by moving `Date`'s place in `Value` (or the codec \
         helpers types.rs uses) so that one of them no longer names the other",
    ),
    (
        "hart-ip-server",
        &[
            "dtls.rs",
            "lib.rs",
            "session.rs",
            "stream.rs",
            "subscriptions.rs",
            "udp.rs",
        ],
        "lib.rs holds the server's shared state and helpers (`Shared`, `lock`, `message`, \
         `local_frame`, `AbortOnDrop`) next to the code that starts the front ends; to be \
         broken by moving the shared items into a module of their own",
    ),
    (
        "hart-poller",
        &["gate.rs", "lib.rs", "task.rs", "write.rs"],
        "lib.rs defines `Engine` and `Shared`, used by task.rs and write.rs, and uses \
         their items in turn; to be broken by moving the engine's shared state into a \
         module of its own",
    ),
    (
        "hart-sim",
        &["analog.rs", "lib.rs"],
        "lib.rs defines `Sim`, which analog.rs runs on the analog loop, and uses \
         analog.rs's `Air`; to be broken by moving `Sim` into a module of its own",
    ),
    (
        "hart-web",
        &[
            "api.rs", "auth.rs", "html.rs", "lib.rs", "pages.rs", "state.rs", "svg.rs",
        ],
        "lib.rs defines `Error` and `WebConfig`, used by auth.rs and state.rs, and builds \
         the router from api.rs, auth.rs and state.rs; to be broken by moving those items \
         out of lib.rs",
    ),
    (
        "hartkit-py",
        &["host.rs", "lib.rs", "sim.rs"],
        "lib.rs defines `to_py` and `thread_runtime`, used by host.rs and sim.rs, and \
         registers their classes; to be broken by moving the helpers into a module of \
         their own",
    ),
];

// ---------------------------------------------------------------------------------------
// Tokens
// ---------------------------------------------------------------------------------------

#[derive(Clone, Debug, PartialEq, Eq)]
enum Tok {
    Ident(String),
    /// `::`
    Sep,
    /// Any other punctuation; literals are `P('L')`, `$name` is `P('$')`.
    P(char),
}

fn is_ident_start(c: char) -> bool {
    c == '_' || c.is_alphabetic()
}

fn is_ident_char(c: char) -> bool {
    c == '_' || c.is_alphanumeric()
}

/// The index after the string literal whose opening quote is at `i`.
fn skip_string(c: &[char], mut i: usize) -> usize {
    i += 1;
    while i < c.len() {
        match c[i] {
            '\\' => i += 2,
            '"' => return i + 1,
            _ => i += 1,
        }
    }
    c.len()
}

/// The index after the raw string whose first `#` (or quote) is at `i`.
fn skip_raw_string(c: &[char], mut i: usize) -> usize {
    let mut hashes = 0;
    while i < c.len() && c[i] == '#' {
        hashes += 1;
        i += 1;
    }
    i += 1; // the opening quote
    while i < c.len() {
        if c[i] == '"'
            && c[i + 1..]
                .iter()
                .take(hashes)
                .filter(|&&h| h == '#')
                .count()
                == hashes
        {
            return i + 1 + hashes;
        }
        i += 1;
    }
    c.len()
}

fn tokenize(src: &str) -> Vec<Tok> {
    let c: Vec<char> = src.chars().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < c.len() {
        let ch = c[i];
        let next = c.get(i + 1).copied();
        if ch.is_whitespace() {
            i += 1;
        } else if ch == '/' && next == Some('/') {
            while i < c.len() && c[i] != '\n' {
                i += 1;
            }
        } else if ch == '/' && next == Some('*') {
            let mut depth = 0;
            while i < c.len() {
                if c[i] == '/' && c.get(i + 1) == Some(&'*') {
                    depth += 1;
                    i += 2;
                } else if c[i] == '*' && c.get(i + 1) == Some(&'/') {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
        } else if ch == '"' {
            i = skip_string(&c, i);
            out.push(Tok::P('L'));
        } else if ch == '\'' {
            if next == Some('\\') {
                // '\n', '\'', '\u{..}'
                i += 3;
                while i < c.len() && c[i] != '\'' {
                    i += 1;
                }
                i += 1;
                out.push(Tok::P('L'));
            } else if c.get(i + 2) == Some(&'\'') {
                i += 3;
                out.push(Tok::P('L'));
            } else {
                // A lifetime or a label.
                i += 1;
                while i < c.len() && is_ident_char(c[i]) {
                    i += 1;
                }
            }
        } else if ch.is_ascii_digit() {
            while i < c.len()
                && (is_ident_char(c[i])
                    || (c[i] == '.' && c.get(i + 1).is_some_and(|d| d.is_ascii_digit())))
            {
                i += 1;
            }
            out.push(Tok::P('L'));
        } else if is_ident_start(ch) {
            let start = i;
            while i < c.len() && is_ident_char(c[i]) {
                i += 1;
            }
            let word: String = c[start..i].iter().collect();
            let here = c.get(i).copied();
            let prefix = matches!(word.as_str(), "r" | "b" | "br" | "c" | "cr");
            if prefix && word.contains('r') && here == Some('#') {
                let mut k = i;
                while k < c.len() && c[k] == '#' {
                    k += 1;
                }
                if c.get(k) == Some(&'"') {
                    i = skip_raw_string(&c, i);
                    out.push(Tok::P('L'));
                } else {
                    // A raw identifier: r#type.
                    i += 1;
                    let start = i;
                    while i < c.len() && is_ident_char(c[i]) {
                        i += 1;
                    }
                    out.push(Tok::Ident(c[start..i].iter().collect()));
                }
            } else if prefix && here == Some('"') {
                i = if word.contains('r') {
                    skip_raw_string(&c, i)
                } else {
                    skip_string(&c, i)
                };
                out.push(Tok::P('L'));
            } else if word == "b" && here == Some('\'') {
                i += 1;
                if c.get(i) == Some(&'\\') {
                    i += 2;
                }
                while i < c.len() && c[i] != '\'' {
                    i += 1;
                }
                i += 1;
                out.push(Tok::P('L'));
            } else {
                out.push(Tok::Ident(word));
            }
        } else if ch == '$' {
            i += 1;
            let start = i;
            while i < c.len() && is_ident_char(c[i]) {
                i += 1;
            }
            let word: String = c[start..i].iter().collect();
            if word == "crate" {
                out.push(Tok::Ident(word));
            } else {
                out.push(Tok::P('$'));
            }
        } else if ch == ':' && next == Some(':') {
            out.push(Tok::Sep);
            i += 2;
        } else {
            out.push(Tok::P(ch));
            i += 1;
        }
    }
    out
}

// ---------------------------------------------------------------------------------------
// Module trees
// ---------------------------------------------------------------------------------------

/// A module's path from the crate root (empty for the root).
type ModPath = Vec<String>;

/// What a path names: the file that defines it, and whether it is a module.
type Target = (usize, bool);

/// A path as written in a module.
type Lookup = (ModPath, Vec<String>);

struct Import {
    /// The name it brings in (`None` for a glob, `_` for `as _`).
    name: Option<String>,
    path: Vec<String>,
    public: bool,
    test: bool,
    module: ModPath,
    file: usize,
}

struct Ref {
    path: Vec<String>,
    macro_call: bool,
    test: bool,
    module: ModPath,
    file: usize,
}

struct Module {
    file: usize,
    /// The items defined here, and whether each is public (`pub` or `pub(..)`).
    defs: BTreeMap<String, bool>,
    /// The modules declared here, and whether each is public.
    children: BTreeMap<String, (ModPath, bool)>,
    imports: Vec<usize>,
}

struct File {
    /// The path under the crate's directory (`src/store.rs`).
    rel: String,
    test: bool,
    /// Every identifier outside `use` declarations and unit-test code.
    idents: BTreeSet<String>,
}

#[derive(Default)]
struct Tree {
    files: Vec<File>,
    modules: BTreeMap<ModPath, Module>,
    imports: Vec<Import>,
    refs: Vec<Ref>,
    macros: BTreeMap<String, BTreeSet<usize>>,
    /// What [`Tree::resolve`] has found so far.
    resolved: RefCell<HashMap<Lookup, Option<Target>>>,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Scope {
    /// The body of an inline module (and whether it is test-only).
    Module(bool),
    /// A macro call's braces: items inside are items of the enclosing scope.
    Transparent,
    /// Any other block (and whether it is test-only): items inside are local.
    Block(bool),
}

const ITEM_KEYWORDS: &[&str] = &[
    "fn", "struct", "enum", "trait", "type", "const", "static", "union",
];

impl Tree {
    /// Reads the module tree rooted at `root` (a path under `krate`).
    fn load(krate: &Path, root: &str) -> Tree {
        let mut tree = Tree::default();
        tree.load_file(krate, root, Vec::new(), false);
        tree
    }

    fn load_file(&mut self, krate: &Path, rel: &str, module: ModPath, test: bool) {
        let text = std::fs::read_to_string(krate.join(rel))
            .unwrap_or_else(|e| panic!("{}: {e}", krate.join(rel).display()));
        let file = self.files.len();
        self.files.push(File {
            rel: rel.to_string(),
            test,
            idents: BTreeSet::new(),
        });
        self.modules.insert(
            module.clone(),
            Module {
                file,
                defs: BTreeMap::new(),
                children: BTreeMap::new(),
                imports: Vec::new(),
            },
        );
        // Child files are in the directory of a lib.rs, main.rs or mod.rs, and in
        // `x/` for `x.rs`.
        let path = Path::new(rel);
        let stem = path.file_stem().unwrap().to_str().unwrap();
        let dir = path.parent().unwrap();
        let child_dir = if matches!(stem, "lib" | "main" | "mod") || module.is_empty() {
            dir.to_path_buf()
        } else {
            dir.join(stem)
        };
        let children = self.scan(file, &module, test, &tokenize(&text));
        for (name, inline_path, child_test) in children {
            let flat = child_dir.join(&inline_path).join(format!("{name}.rs"));
            let nested = child_dir.join(&inline_path).join(&name).join("mod.rs");
            let rel = if krate.join(&flat).exists() {
                flat
            } else if krate.join(&nested).exists() {
                nested
            } else {
                panic!("{}: mod {name}; has no file", krate.join(rel).display());
            };
            let mut child = module.clone();
            child.extend(inline_path.iter().map(|p| p.to_str().unwrap().to_string()));
            child.push(name);
            self.load_file(krate, &to_slash(&rel), child, child_test);
        }
    }

    /// Scans one file's tokens; returns its `mod x;` children: name, the inline modules
    /// it is declared in, and whether it is test-only.
    fn scan(
        &mut self,
        file: usize,
        file_module: &ModPath,
        file_test: bool,
        t: &[Tok],
    ) -> Vec<(String, PathBuf, bool)> {
        let mut children = Vec::new();
        let ident = |j: usize| match t.get(j) {
            Some(Tok::Ident(s)) => Some(s.as_str()),
            _ => None,
        };
        let is = |j: usize, tok: Tok| t.get(j) == Some(&tok);
        // The scopes entered; the inline modules among them name the current module.
        let mut scopes: Vec<Scope> = Vec::new();
        let mut inline: Vec<String> = Vec::new();
        let mut pending_test = false;
        let mut pending_pub = false;
        let mut j = 0;
        while j < t.len() {
            let module: ModPath = file_module.iter().chain(inline.iter()).cloned().collect();
            let test = file_test
                || scopes
                    .iter()
                    .any(|s| matches!(s, Scope::Module(true) | Scope::Block(true)))
                || pending_test;
            let items_here = scopes
                .iter()
                .rev()
                .find(|s| **s != Scope::Transparent)
                .is_none_or(|s| matches!(s, Scope::Module(_)));
            match &t[j] {
                Tok::P('#') => {
                    // An attribute: `#[cfg(test)]` makes the next item test-only.
                    let mut k = j + 1;
                    if is(k, Tok::P('!')) {
                        k += 1;
                    }
                    if is(k, Tok::P('[')) {
                        let mut depth = 0;
                        let start = k;
                        while k < t.len() {
                            match t[k] {
                                Tok::P('[') => depth += 1,
                                Tok::P(']') => {
                                    depth -= 1;
                                    if depth == 0 {
                                        break;
                                    }
                                }
                                _ => {}
                            }
                            k += 1;
                        }
                        let attr = &t[start..k];
                        let has = |w: &str| attr.contains(&Tok::Ident(w.to_string()));
                        if has("cfg") && has("test") && !has("not") {
                            pending_test = true;
                        }
                        j = k + 1;
                        continue;
                    }
                    j += 1;
                }
                Tok::P('{') => {
                    let macro_call = j >= 2 && is(j - 1, Tok::P('!')) && ident(j - 2).is_some();
                    scopes.push(if macro_call {
                        Scope::Transparent
                    } else {
                        Scope::Block(test)
                    });
                    pending_test = false;
                    pending_pub = false;
                    j += 1;
                }
                Tok::P('}') => {
                    if scopes.pop().is_some_and(|s| matches!(s, Scope::Module(_))) {
                        inline.pop();
                    }
                    pending_test = false;
                    pending_pub = false;
                    j += 1;
                }
                Tok::P(';') => {
                    pending_test = false;
                    pending_pub = false;
                    j += 1;
                }
                Tok::Ident(w) if w == "pub" => {
                    pending_pub = true;
                    j += 1;
                    if is(j, Tok::P('(')) {
                        while j < t.len() && !is(j, Tok::P(')')) {
                            j += 1;
                        }
                        j += 1;
                    }
                }
                Tok::Ident(w) if w == "use" => {
                    j += 1;
                    let mut leaves = Vec::new();
                    use_tree(t, &mut j, Vec::new(), &mut leaves);
                    for (path, name) in leaves {
                        let index = self.imports.len();
                        self.imports.push(Import {
                            name,
                            path,
                            public: pending_pub,
                            test,
                            module: module.clone(),
                            file,
                        });
                        self.modules.get_mut(&module).unwrap().imports.push(index);
                    }
                    pending_test = false;
                    pending_pub = false;
                }
                Tok::Ident(w) if w == "mod" && ident(j + 1).is_some() => {
                    let name = ident(j + 1).unwrap().to_string();
                    let mut child = module.clone();
                    child.push(name.clone());
                    self.modules
                        .get_mut(&module)
                        .unwrap()
                        .children
                        .insert(name.clone(), (child.clone(), pending_pub));
                    if is(j + 2, Tok::P('{')) {
                        self.modules.insert(
                            child,
                            Module {
                                file,
                                defs: BTreeMap::new(),
                                children: BTreeMap::new(),
                                imports: Vec::new(),
                            },
                        );
                        scopes.push(Scope::Module(test));
                        inline.push(name);
                        j += 3;
                    } else {
                        children.push((name, inline.iter().collect::<PathBuf>(), test));
                        j += 2;
                    }
                    pending_test = false;
                    pending_pub = false;
                }
                Tok::Ident(w) if w == "macro_rules" && is(j + 1, Tok::P('!')) => {
                    if let Some(name) = ident(j + 2) {
                        self.macros
                            .entry(name.to_string())
                            .or_default()
                            .insert(file);
                    }
                    j += 3;
                }
                Tok::Ident(w) if ITEM_KEYWORDS.contains(&w.as_str()) => {
                    if let Some(name) = ident(j + 1) {
                        if items_here && !ITEM_KEYWORDS.contains(&name) {
                            self.modules
                                .get_mut(&module)
                                .unwrap()
                                .defs
                                .insert(name.to_string(), pending_pub);
                        }
                    }
                    j += 1;
                }
                Tok::Ident(_) => {
                    // A path in code: `a::b::c`, `name!`.
                    let mut path = Vec::new();
                    while let Some(seg) = ident(j) {
                        path.push(seg.to_string());
                        if !test {
                            self.files[file].idents.insert(seg.to_string());
                        }
                        if is(j + 1, Tok::Sep) && ident(j + 2).is_some() {
                            j += 2;
                        } else {
                            break;
                        }
                    }
                    j += 1;
                    let macro_call = is(j, Tok::P('!')) && !is(j + 1, Tok::P('='));
                    if path.len() > 1 || macro_call {
                        self.refs.push(Ref {
                            path,
                            macro_call,
                            test,
                            module: module.clone(),
                            file,
                        });
                    }
                }
                Tok::Sep => {
                    // A global path (`::std::x`): skip it.
                    j += 1;
                    while ident(j).is_some() && is(j + 1, Tok::Sep) {
                        j += 2;
                    }
                    j += 1;
                }
                _ => j += 1,
            }
        }
        children
    }

    fn parent(module: &ModPath) -> Option<ModPath> {
        (!module.is_empty()).then(|| module[..module.len() - 1].to_vec())
    }

    /// The file that defines what `path` names when written in `module`, and whether it
    /// is a module; `None` for what is outside the crate (or not found).
    fn resolve(&self, module: &ModPath, path: &[String], depth: u32) -> Option<Target> {
        if depth > 12 || path.is_empty() {
            return None;
        }
        let key = (module.clone(), path.to_vec());
        if let Some(known) = self.resolved.borrow().get(&key) {
            return *known;
        }
        // Whatever is being resolved already is not found again through a circle of
        // imports.
        self.resolved.borrow_mut().insert(key.clone(), None);
        let found = self.resolve_uncached(module, path, depth);
        self.resolved.borrow_mut().insert(key, found);
        found
    }

    fn resolve_uncached(&self, module: &ModPath, path: &[String], depth: u32) -> Option<Target> {
        let mut m = module.clone();
        let mut rest = path;
        match path[0].as_str() {
            "crate" => {
                m = Vec::new();
                rest = &path[1..];
            }
            "self" => rest = &path[1..],
            "super" => {
                while rest.first().is_some_and(|s| s == "super") {
                    m = Tree::parent(&m)?;
                    rest = &rest[1..];
                }
            }
            _ => {}
        }
        if rest.is_empty() {
            return Some((self.modules.get(&m)?.file, true));
        }
        // What is private to a module is seen from it and the modules inside it only
        // (which matters to glob imports: `pub use x::*` passes on x's public items).
        let seen = |owner: &ModPath, public: bool| public || module.starts_with(owner);
        for (k, seg) in rest.iter().enumerate() {
            let last = k + 1 == rest.len();
            let here = self.modules.get(&m)?;
            if let Some((child, _)) = here.children.get(seg).filter(|(_, p)| seen(&m, *p)) {
                m = child.clone();
                if last {
                    return Some((self.modules.get(&m)?.file, true));
                }
                continue;
            }
            if here.defs.get(seg).is_some_and(|p| seen(&m, *p)) {
                return Some((here.file, false));
            }
            let imports = here
                .imports
                .iter()
                .map(|&i| &self.imports[i])
                .filter(|i| seen(&m, i.public));
            if let Some(import) = imports
                .clone()
                .find(|i| i.name.as_deref() == Some(seg.as_str()) && seg != "_")
            {
                let mut p = import.path.clone();
                p.extend(rest[k + 1..].iter().cloned());
                return self.resolve(&m, &p, depth + 1);
            }
            for glob in imports.filter(|i| i.name.is_none()) {
                let mut p = glob.path.clone();
                p.extend(rest[k..].iter().cloned());
                if let Some(found) = self.resolve(&m, &p, depth + 1) {
                    return Some(found);
                }
            }
            if m.is_empty() && last {
                if let Some(files) = self.macros.get(seg) {
                    if files.len() == 1 {
                        return Some((*files.iter().next().unwrap(), false));
                    }
                }
            }
            return None;
        }
        None
    }

    /// Which file uses which other file's items: (from, to) -> an example of the use.
    fn edges(&self) -> BTreeMap<(usize, usize), String> {
        let mut edges = BTreeMap::new();
        let mut add = |from: usize, to: usize, why: String| {
            if from != to {
                edges.entry((from, to)).or_insert(why);
            }
        };
        for import in &self.imports {
            if import.test || self.files[import.file].test {
                continue;
            }
            let shown = format!("use {}", import.path.join("::"));
            match &import.name {
                Some(name) => {
                    if import.public && !self.files[import.file].idents.contains(name) {
                        continue; // a re-export only
                    }
                    if let Some((to, false)) = self.resolve(&import.module, &import.path, 0) {
                        add(import.file, to, shown);
                    }
                }
                None => {
                    if import.public {
                        continue;
                    }
                    for name in &self.files[import.file].idents {
                        let mut p = import.path.clone();
                        p.push(name.clone());
                        if let Some((to, false)) = self.resolve(&import.module, &p, 0) {
                            add(import.file, to, format!("{shown}::* ({name})"));
                        }
                    }
                }
            }
        }
        for r in &self.refs {
            if r.test || self.files[r.file].test {
                continue;
            }
            let shown = format!(
                "{}{}",
                r.path.join("::"),
                if r.macro_call { "!" } else { "" }
            );
            if r.macro_call && r.path.len() == 1 {
                if let Some(files) = self.macros.get(&r.path[0]) {
                    if !files.contains(&r.file) && files.len() == 1 {
                        add(r.file, *files.iter().next().unwrap(), shown);
                    }
                }
                continue;
            }
            if let Some((to, _)) = self.resolve(&r.module, &r.path, 0) {
                add(r.file, to, shown);
            }
        }
        edges
    }
}

fn to_slash(p: &Path) -> String {
    p.to_str().unwrap().replace('\\', "/")
}

/// Parses a `use` tree after `use` (up to and including its `;`): each leaf's path and
/// the name it binds (`None` for a glob).
fn use_tree(
    t: &[Tok],
    j: &mut usize,
    mut path: Vec<String>,
    out: &mut Vec<(Vec<String>, Option<String>)>,
) {
    if t.get(*j) == Some(&Tok::Sep) {
        path.push("::".to_string()); // a global path: outside the crate
        *j += 1;
    }
    loop {
        match t.get(*j) {
            Some(Tok::Ident(seg)) => {
                path.push(seg.clone());
                *j += 1;
                if t.get(*j) == Some(&Tok::Sep) {
                    *j += 1;
                    continue;
                }
                let mut name = None;
                if t.get(*j) == Some(&Tok::Ident("as".to_string())) {
                    if let Some(Tok::Ident(alias)) = t.get(*j + 1) {
                        name = Some(alias.clone());
                    }
                    *j += 2;
                }
                if path.last().is_some_and(|s| s == "self") {
                    path.pop();
                }
                let name = name.or_else(|| path.last().cloned());
                out.push((path, name));
                break;
            }
            Some(Tok::P('*')) => {
                *j += 1;
                out.push((path, None));
                break;
            }
            Some(Tok::P('{')) => {
                *j += 1;
                loop {
                    match t.get(*j) {
                        Some(Tok::P('}')) => {
                            *j += 1;
                            break;
                        }
                        Some(Tok::P(',')) => *j += 1,
                        None => return,
                        _ => {
                            let before = *j;
                            use_tree(t, j, path.clone(), out);
                            if *j == before {
                                *j += 1;
                            }
                        }
                    }
                }
                break;
            }
            _ => break,
        }
    }
    // Only the outermost call ends the declaration.
    if t.get(*j) == Some(&Tok::P(';')) {
        *j += 1;
    }
}

// ---------------------------------------------------------------------------------------
// Circles
// ---------------------------------------------------------------------------------------

/// The strongly connected components of more than one node (Tarjan's algorithm).
fn circles(n: usize, edges: &BTreeMap<(usize, usize), String>) -> Vec<Vec<usize>> {
    let mut next: Vec<Vec<usize>> = vec![Vec::new(); n];
    for &(a, b) in edges.keys() {
        next[a].push(b);
    }
    struct State<'a> {
        next: &'a [Vec<usize>],
        index: Vec<Option<usize>>,
        low: Vec<usize>,
        on_stack: Vec<bool>,
        stack: Vec<usize>,
        counter: usize,
        out: Vec<Vec<usize>>,
    }
    fn visit(s: &mut State, v: usize) {
        s.index[v] = Some(s.counter);
        s.low[v] = s.counter;
        s.counter += 1;
        s.stack.push(v);
        s.on_stack[v] = true;
        for k in 0..s.next[v].len() {
            let w = s.next[v][k];
            match s.index[w] {
                None => {
                    visit(s, w);
                    s.low[v] = s.low[v].min(s.low[w]);
                }
                Some(i) if s.on_stack[w] => s.low[v] = s.low[v].min(i),
                _ => {}
            }
        }
        if Some(s.low[v]) == s.index[v] {
            let mut component = Vec::new();
            loop {
                let w = s.stack.pop().unwrap();
                s.on_stack[w] = false;
                component.push(w);
                if w == v {
                    break;
                }
            }
            if component.len() > 1 {
                component.sort();
                s.out.push(component);
            }
        }
    }
    let mut s = State {
        next: &next,
        index: vec![None; n],
        low: vec![0; n],
        on_stack: vec![false; n],
        stack: Vec::new(),
        counter: 0,
        out: Vec::new(),
    };
    for v in 0..n {
        if s.index[v].is_none() {
            visit(&mut s, v);
        }
    }
    s.out
}

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .canonicalize()
        .unwrap()
}

/// The workspace's members (directories under the root), from its Cargo.toml.
fn members(root: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(root.join("Cargo.toml")).unwrap();
    let manifest: toml::Table = text.parse().unwrap();
    let members = manifest["workspace"]["members"].as_array().unwrap();
    let mut out = Vec::new();
    for m in members {
        let m = m.as_str().unwrap();
        if let Some(dir) = m.strip_suffix("/*") {
            for entry in std::fs::read_dir(root.join(dir)).unwrap() {
                let entry = entry.unwrap();
                if entry.path().join("Cargo.toml").exists() {
                    out.push(format!("{dir}/{}", entry.file_name().to_str().unwrap()));
                }
            }
        } else {
            out.push(m.to_string());
        }
    }
    out.sort();
    out
}

/// The crate's roots: its library, its binary and `src/bin/*.rs`.
fn roots(krate: &Path) -> Vec<String> {
    let mut roots: Vec<String> = ["src/lib.rs", "src/main.rs"]
        .into_iter()
        .filter(|r| krate.join(r).exists())
        .map(String::from)
        .collect();
    if let Ok(dir) = std::fs::read_dir(krate.join("src/bin")) {
        let mut bins: Vec<String> = dir
            .map(|e| e.unwrap().path())
            .filter_map(|p| {
                if p.extension().is_some_and(|e| e == "rs") {
                    Some(format!("src/bin/{}", p.file_name()?.to_str()?))
                } else if p.join("main.rs").exists() {
                    Some(format!("src/bin/{}/main.rs", p.file_name()?.to_str()?))
                } else {
                    None
                }
            })
            .collect();
        bins.sort();
        roots.extend(bins);
    }
    roots
}

/// A circle found in one crate: the crate's directory name, its files (under `src/`,
/// sorted) and the uses that close it.
struct Circle {
    krate: String,
    files: Vec<String>,
    uses: Vec<String>,
}

fn find_circles() -> Vec<Circle> {
    let root = workspace_root();
    let mut found = Vec::new();
    for member in members(&root) {
        let krate = root.join(&member);
        let name = Path::new(&member)
            .file_name()
            .unwrap()
            .to_str()
            .unwrap()
            .to_string();
        for start in roots(&krate) {
            let tree = Tree::load(&krate, &start);
            let edges = tree.edges();
            for component in circles(tree.files.len(), &edges) {
                let short = |f: usize| {
                    tree.files[f]
                        .rel
                        .strip_prefix("src/")
                        .unwrap_or(&tree.files[f].rel)
                        .to_string()
                };
                let mut files: Vec<String> = component.iter().map(|&f| short(f)).collect();
                files.sort();
                let uses = edges
                    .iter()
                    .filter(|((a, b), _)| component.contains(a) && component.contains(b))
                    .map(|((a, b), why)| format!("{} -> {}: {why}", short(*a), short(*b)))
                    .collect();
                found.push(Circle {
                    krate: name.clone(),
                    files,
                    uses,
                });
            }
        }
    }
    found
}

fn allowed(circle: &Circle) -> bool {
    ALLOWED.iter().any(|(krate, files, _)| {
        let mut listed: Vec<&str> = files.to_vec();
        listed.sort();
        *krate == circle.krate && listed == circle.files
    })
}

#[test]
fn no_circles_between_files() {
    let found = find_circles();
    let mut failures = Vec::new();
    for circle in found.iter().filter(|c| !allowed(c)) {
        failures.push(format!(
            "crates/{}: a circle between {}; each file uses the next:\n    {}\n  \
             Move the shared items into the file they belong to (or a small module of \
             their own) so that the uses point one way.",
            circle.krate,
            circle.files.join(", "),
            circle.uses.join("\n    ")
        ));
    }
    for (krate, files, _) in ALLOWED {
        let mut listed: Vec<&str> = files.to_vec();
        listed.sort();
        if !found.iter().any(|c| c.krate == *krate && c.files == listed) {
            failures.push(format!(
                "crates/{krate}: the allowed circle between {} is gone (or has other files \
                 now): remove its entry from ALLOWED in {}",
                listed.join(", "),
                file!()
            ));
        }
    }
    eprintln!(
        "{} circles between files, {} of them allowed",
        found.len(),
        found.iter().filter(|c| allowed(c)).count()
    );
    assert!(failures.is_empty(), "\n{}\n", failures.join("\n\n"));
}

/// The scan's rules on a small crate written to a temporary directory: re-exports and
/// `mod` declarations are no uses, an item defined in lib.rs is, and so are paths, glob
/// imports and macros; code for unit tests is left out.
#[test]
fn the_scan_finds_uses_between_files() {
    let dir = std::env::temp_dir().join(format!("hartkit-file-cycles-{}", std::process::id()));
    let files: &[(&str, &str)] = &[
        (
            "src/lib.rs",
            "mod a;\nmod b;\npub mod c;\nmod t;\npub use a::A;\npub use b::*;\n\
             /// Shared.\npub struct Root;\n",
        ),
        // a.rs uses lib.rs's Root, and b.rs through a path in code.
        (
            "src/a.rs",
            "use crate::Root;\npub struct A(Root);\nfn f() { crate::b::g(); }\n",
        ),
        // b.rs: a glob import of c (its `C` only); a string and a comment name a.
        (
            "src/b.rs",
            "use crate::c::*;\npub fn g() -> C { let _ = \"crate::a::A\"; // crate::a::A\n C }\n\
             #[cfg(test)]\nmod tests { use crate::a::A; }\n",
        ),
        // c.rs calls t.rs's macro; c/d.rs uses super's item, c.rs none of d's.
        ("src/c.rs", "mod d;\npub struct C;\nfn h() { m!(); }\n"),
        ("src/c/d.rs", "use super::C;\n"),
        (
            "src/t.rs",
            "#[macro_export]\nmacro_rules! m { () => { $crate::a::A(crate::Root) } }\n",
        ),
    ];
    for (path, text) in files {
        let path = dir.join(path);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, text).unwrap();
    }
    let tree = Tree::load(&dir, "src/lib.rs");
    let name = |f: usize| tree.files[f].rel.clone();
    let edges: BTreeSet<(String, String)> = tree
        .edges()
        .keys()
        .map(|&(a, b)| (name(a), name(b)))
        .collect();
    let _ = std::fs::remove_dir_all(&dir);
    let expected: BTreeSet<(String, String)> = [
        ("src/a.rs", "src/lib.rs"),
        ("src/a.rs", "src/b.rs"),
        ("src/b.rs", "src/c.rs"),
        ("src/c.rs", "src/t.rs"),
        ("src/c/d.rs", "src/c.rs"),
        ("src/t.rs", "src/a.rs"),
        ("src/t.rs", "src/lib.rs"),
    ]
    .into_iter()
    .map(|(a, b)| (a.to_string(), b.to_string()))
    .collect();
    assert_eq!(edges, expected);
    let edge_map = tree.edges();
    let found: Vec<Vec<String>> = circles(tree.files.len(), &edge_map)
        .into_iter()
        .map(|c| c.into_iter().map(name).collect())
        .collect();
    assert_eq!(found, [["src/a.rs", "src/b.rs", "src/c.rs", "src/t.rs"]]);
}
