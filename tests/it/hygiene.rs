//! Workspace hygiene that `cargo test` can check on its own, so CI holds it without any tool
//! installed by hand: every dependency a crate declares is used by that crate (what
//! `cargo machete` checks), in the targets that can use it.
//!
//! A dependency is "used" when its crate name appears as a path or import in the sources of
//! the targets that see it: `[dependencies]` in `src/` (and `build.rs`), `[dev-dependencies]`
//! in `src/`, `tests/`, `benches/` and `examples/`, `[build-dependencies]` in `build.rs`. A
//! dependency declared only to switch on a feature of another one is listed, with its reason,
//! under `[package.metadata.cargo-machete] ignored = [...]`, the key `cargo machete` reads too.

use std::path::{Path, PathBuf};

fn workspace_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// True when `text` names the crate `ident` as the start of a path (`ident::`), in a `use` or
/// an `extern crate`: a word boundary on both sides, so `rand` is not found in `rand_chacha`.
fn names_crate(text: &str, ident: &str) -> bool {
    let bytes = text.as_bytes();
    let is_word = |b: u8| b.is_ascii_alphanumeric() || b == b'_';
    let mut from = 0;
    while let Some(i) = text[from..].find(ident) {
        let start = from + i;
        let end = start + ident.len();
        from = end;
        if start > 0 && (is_word(bytes[start - 1]) || bytes[start - 1] == b':') {
            continue;
        }
        if end < bytes.len() && is_word(bytes[end]) {
            continue;
        }
        let after = &text[end..];
        let before = text[..start].trim_end();
        if after.starts_with("::") || before.ends_with("use") || before.ends_with("crate") {
            return true;
        }
    }
    false
}

fn sources(crate_dir: &Path, targets: &[&str]) -> Vec<PathBuf> {
    let mut files = Vec::new();
    for t in targets {
        let p = crate_dir.join(t);
        if p.is_file() {
            files.push(p);
        } else {
            rust_files(&p, &mut files);
        }
    }
    files
}

/// (crate dir, section, dependency) for every declared dependency no source of its targets uses.
fn unused_dependencies() -> Vec<String> {
    let root = workspace_root();
    let ws: toml::Table = toml::from_str(&std::fs::read_to_string(root.join("Cargo.toml")).unwrap()).unwrap();
    let members = ws["workspace"]["members"].as_array().unwrap();
    let mut unused = Vec::new();
    for m in members {
        let dir = root.join(m.as_str().unwrap());
        let manifest_path = dir.join("Cargo.toml");
        let manifest: toml::Table = toml::from_str(&std::fs::read_to_string(&manifest_path).unwrap())
            .unwrap_or_else(|e| panic!("{}: {e}", manifest_path.display()));
        let ignored: Vec<String> = manifest
            .get("package")
            .and_then(|p| p.get("metadata"))
            .and_then(|m| m.get("cargo-machete"))
            .and_then(|m| m.get("ignored"))
            .and_then(|i| i.as_array())
            .map(|a| a.iter().filter_map(|v| v.as_str().map(String::from)).collect())
            .unwrap_or_default();
        let sections: [(&str, &[&str]); 3] = [
            ("dependencies", &["src", "build.rs"]),
            ("dev-dependencies", &["src", "tests", "benches", "examples"]),
            ("build-dependencies", &["build.rs"]),
        ];
        for (section, targets) in sections {
            let Some(deps) = manifest.get(section).and_then(|d| d.as_table()) else {
                continue;
            };
            let texts: Vec<String> = sources(&dir, targets)
                .iter()
                .map(|f| std::fs::read_to_string(f).unwrap())
                .collect();
            for name in deps.keys() {
                if ignored.iter().any(|i| i == name) {
                    continue;
                }
                let ident = name.replace('-', "_");
                if !texts.iter().any(|t| names_crate(t, &ident)) {
                    unused.push(format!("{}: [{section}] {name}", manifest_path.display()));
                }
            }
        }
    }
    unused
}

#[test]
fn the_check_finds_a_crate_name_only_as_a_path_or_import() {
    assert!(names_crate("use rand::Rng;", "rand"));
    assert!(names_crate("let x = serde_json::to_string(&v);", "serde_json"));
    assert!(names_crate("extern crate libc;", "libc"));
    assert!(names_crate("use {\n    rand_chacha::ChaCha8Rng };", "rand_chacha"));
    // Not a use: another crate whose name starts the same, a word in a comment, a field path.
    assert!(!names_crate("use rand_chacha::ChaCha8Rng;", "rand"));
    assert!(!names_crate("// a rand number", "rand"));
    assert!(!names_crate("bowden_rand::x", "rand"));
}

#[test]
fn no_crate_declares_a_dependency_it_does_not_use() {
    let unused = unused_dependencies();
    assert!(
        unused.is_empty(),
        "declared but unused (remove them, or list them with the reason under \
         [package.metadata.cargo-machete] ignored):\n{}",
        unused.join("\n")
    );
}

/// A function longer than this many lines needs a stated reason (issue #40): a `// Long:`
/// comment within the six lines above its `fn`.
const LONG_FN_LINES: usize = 120;

/// Whether `line` (trimmed) starts a function: `fn`, after any of `pub`, `pub(..)`, `const`,
/// `async`, `unsafe`.
fn starts_fn(line: &str) -> bool {
    let mut t = line;
    loop {
        let before = t;
        for kw in ["pub(crate) ", "pub(super) ", "pub ", "const ", "async ", "unsafe "] {
            t = t.strip_prefix(kw).unwrap_or(t);
        }
        if t == before {
            return t.starts_with("fn ");
        }
    }
}

/// `file:line: N lines` of every function over [`LONG_FN_LINES`] without a `// Long:` reason
/// in `text`. rustfmt's layout is assumed: a body ends at a `}` line with the `fn`'s indent.
fn long_functions(name: &str, text: &str) -> Vec<String> {
    let lines: Vec<&str> = text.lines().collect();
    let mut found = Vec::new();
    for (i, l) in lines.iter().enumerate() {
        let t = l.trim_start();
        if !starts_fn(t) {
            continue;
        }
        // The signature ends at the first line ending in `{` (a body) or `;` (a declaration).
        let Some(sig_end) = lines[i..]
            .iter()
            .position(|x| x.trim_end().ends_with('{') || x.trim_end().ends_with(';') || x.trim_end().ends_with('}'))
        else {
            continue;
        };
        let sig = lines[i + sig_end].trim_end();
        if !sig.ends_with('{') {
            continue; // a declaration, or a body on one line
        }
        let close = format!("{}}}", &l[..l.len() - t.len()]);
        let Some(end) = lines[i + sig_end..].iter().position(|x| *x == close) else {
            continue;
        };
        let n = sig_end + end + 1;
        let reason = lines[i.saturating_sub(6)..i].iter().any(|x| x.contains("// Long:"));
        if n > LONG_FN_LINES && !reason {
            found.push(format!("{name}:{}: {n} lines", i + 1));
        }
    }
    found
}

#[test]
fn the_long_function_check_counts_bodies_and_reads_reasons() {
    let body = |n: usize| "    let x = 1;\n".repeat(n);
    let long = format!("pub fn f(\n    a: u8,\n) -> u8 {{\n{}    a\n}}\n", body(LONG_FN_LINES));
    assert_eq!(
        long_functions("a.rs", &long),
        vec![format!("a.rs:1: {} lines", LONG_FN_LINES + 5)]
    );
    let reasoned = format!("// Long: a list of checks.\n{long}");
    assert!(long_functions("a.rs", &reasoned).is_empty());
    let short = format!("fn g() {{\n{}}}\n", body(LONG_FN_LINES - 2));
    assert!(long_functions("a.rs", &short).is_empty());
    // Declarations and one-line bodies are not functions to measure.
    assert!(long_functions("a.rs", "trait T {\n    fn h(&self)\n        -> u8;\n}\nfn k() { }\n").is_empty());
}

#[test]
fn no_function_is_over_120_lines_without_a_stated_reason() {
    let root = workspace_root();
    let mut files = Vec::new();
    for d in ["src", "components", "interfaces", "tests", "benches", "build.rs"] {
        let p = root.join(d);
        if p.is_file() {
            files.push(p);
        } else {
            rust_files(&p, &mut files);
        }
    }
    files.retain(|f| !f.components().any(|c| c.as_os_str() == "target"));
    let mut found = Vec::new();
    for f in &files {
        let text = std::fs::read_to_string(f).unwrap();
        let name = f.strip_prefix(&root).unwrap_or(f).display().to_string();
        found.extend(long_functions(&name, &text));
    }
    assert!(
        found.is_empty(),
        "functions over {LONG_FN_LINES} lines without a `// Long:` reason above them (split them, or say why \
         not):\n{}",
        found.join("\n")
    );
}
