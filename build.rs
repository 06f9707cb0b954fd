//! Embeds the shipped files (`configs/**`, `models/**`) in the `bowden` binary, so an installed
//! binary finds them without a checkout (src/home.rs). Writes `$OUT_DIR/shipped.rs`: the list
//! of `(relative path, include_bytes!(...))` and a hash of the whole set.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

const ROOTS: [&str; 2] = ["configs", "models"];

fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    let mut entries: Vec<_> = entries.flatten().map(|e| e.path()).collect();
    entries.sort();
    for p in entries {
        let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
        // Hidden files, editor swap and backup files are not part of what ships.
        if name.starts_with('.') || name.ends_with(".swp") || name.ends_with('~') {
            continue;
        }
        if p.is_dir() {
            walk(&p, out);
        } else if p.is_file() {
            out.push(p);
        }
    }
}

fn main() {
    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").expect("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    for r in ROOTS {
        // A directory: Cargo re-runs this script when anything under it changes.
        println!("cargo:rerun-if-changed={r}");
        walk(&root.join(r), &mut files);
    }
    let mut code = String::from("/// Every shipped file: path relative to the repository root, contents.\n");
    code.push_str("pub static SHIPPED: &[(&str, &[u8])] = &[\n");
    // FNV-1a 64 over names and contents: names the extracted copy, so two builds with different
    // files never share a cache directory.
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    let mut feed = |bytes: &[u8]| {
        for b in bytes {
            hash ^= u64::from(*b);
            hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
        }
    };
    for f in &files {
        let rel = f.strip_prefix(&root).expect("under the root");
        let rel: Vec<String> = rel
            .components()
            .map(|c| c.as_os_str().to_string_lossy().into_owned())
            .collect();
        let rel = rel.join("/");
        let bytes = std::fs::read(f).unwrap_or_else(|e| panic!("reading {}: {e}", f.display()));
        feed(rel.as_bytes());
        feed(&[0]);
        feed(&(bytes.len() as u64).to_le_bytes());
        feed(&bytes);
        writeln!(code, "    ({rel:?}, include_bytes!({:?})),", f.display().to_string()).expect("write to a String");
    }
    code.push_str("];\n");
    writeln!(
        code,
        "/// FNV-1a 64 of the shipped files' names and contents.\npub const SHIPPED_HASH: &str = \"{hash:016x}\";"
    )
    .expect("write to a String");
    let out = PathBuf::from(std::env::var("OUT_DIR").expect("OUT_DIR")).join("shipped.rs");
    std::fs::write(&out, code).unwrap_or_else(|e| panic!("writing {}: {e}", out.display()));
}
