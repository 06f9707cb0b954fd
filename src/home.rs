//! Where bowden finds its shipped files — the robot, plant, camera, markers, controller,
//! pipeline and trajectory configs (`configs/**`) and the trained models (`models/**`) — so
//! every command works from any directory, with or without a checkout.
//!
//! One resolution order for every file a command reads by name (docs/architecture.md,
//! "Finding the shipped files"):
//!
//! 1. the path as given: absolute, or relative to the working directory;
//! 2. a relative path under `$BOWDEN_HOME` (a directory laid out like the repository:
//!    `configs/`, `models/`);
//! 3. the copy built into the binary (`configs/**` and `models/**` at build time, see build.rs),
//!    extracted once to `$XDG_CACHE_HOME/bowden/` (else `~/.cache/bowden/`, else the temporary
//!    directory), because pipelines and node processes, and tract, read real files. The
//!    extracted tree keeps the repository's layout, so the relative paths inside the shipped
//!    files (a pipeline's `config = "plant.toml"`, a controller's `models/...onnx`) resolve as
//!    in a checkout.
//!
//! Paths written *inside* a config file resolve against that file's directory (pipelines) or
//! its directory and parent (controller configs), as before: once a file is found, its
//! neighbours are found beside it.

use anyhow::{anyhow, bail, Context, Result};
use std::path::{Component, Path, PathBuf};
use std::sync::OnceLock;

include!(concat!(env!("OUT_DIR"), "/shipped.rs"));

/// The environment variable naming a data directory laid out like the repository.
pub const HOME_ENV: &str = "BOWDEN_HOME";

/// Where a file was found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Origin {
    /// As given: absolute, or relative to the working directory.
    Given,
    /// Under `$BOWDEN_HOME`.
    Home,
    /// The copy built into the binary (extracted to the cache).
    Builtin,
}

/// A file or directory found by [`resolve`].
#[derive(Debug, Clone)]
pub struct Resolved {
    /// The path to open.
    pub path: PathBuf,
    /// The path as the user (or a default) gave it.
    pub given: PathBuf,
    pub origin: Origin,
}

impl Resolved {
    /// How messages and reports name it: as given, with where it was found when that is not
    /// the working directory (so a report does not name the machine's cache).
    pub fn shown(&self) -> String {
        match self.origin {
            Origin::Given => self.given.display().to_string(),
            Origin::Home => format!("{} (from ${HOME_ENV})", self.given.display()),
            Origin::Builtin => format!("{} (built-in)", self.given.display()),
        }
    }
}

/// `p` as a key of [`SHIPPED`] (`configs/robot.toml`), when it is a plain relative path.
fn shipped_key(p: &Path) -> Option<String> {
    let mut parts = Vec::new();
    for c in p.components() {
        match c {
            Component::Normal(s) => parts.push(s.to_str()?.to_string()),
            Component::CurDir => {}
            _ => return None,
        }
    }
    (!parts.is_empty()).then(|| parts.join("/"))
}

/// Whether `key` is a shipped file or a directory holding shipped files.
fn is_shipped(key: &str) -> bool {
    let dir = format!("{key}/");
    SHIPPED.iter().any(|(f, _)| *f == key || f.starts_with(&dir))
}

fn home_dir() -> Option<PathBuf> {
    std::env::var_os(HOME_ENV).filter(|v| !v.is_empty()).map(PathBuf::from)
}

/// Finds `p` (a file or a directory) by the resolution order of this module.
pub fn resolve(p: &Path) -> Result<Resolved> {
    let found = |path: PathBuf, origin| Resolved {
        path,
        given: p.to_path_buf(),
        origin,
    };
    if p.exists() {
        return Ok(found(p.to_path_buf(), Origin::Given));
    }
    if p.is_relative() {
        if let Some(home) = home_dir() {
            let h = home.join(p);
            if h.exists() {
                return Ok(found(h, Origin::Home));
            }
        }
        if let Some(key) = shipped_key(p).filter(|k| is_shipped(k)) {
            let root = builtin_root()?;
            return Ok(found(root.join(key), Origin::Builtin));
        }
    }
    let cwd = std::env::current_dir()
        .map(|d| d.display().to_string())
        .unwrap_or_else(|_| "?".into());
    let home = match home_dir() {
        Some(h) => format!("not under ${HOME_ENV} ({})", h.display()),
        None => format!("${HOME_ENV} unset"),
    };
    if p.is_absolute() {
        bail!("{}: no such file or directory", p.display());
    }
    bail!(
        "{}: not found: not in the working directory ({cwd}), {home}, and not a shipped file \
         (the built-in configs/... and models/...: `bowden shipped` lists them)",
        p.display()
    )
}

/// [`resolve`]'s path.
pub fn path(p: &Path) -> Result<PathBuf> {
    Ok(resolve(p)?.path)
}

/// How a path that came out of [`resolve`] (possibly made absolute since) is named in a report:
/// relative to the built-in copy, the working directory or `$BOWDEN_HOME` (said) when inside
/// one, else as it is.
pub fn describe(p: &Path) -> String {
    if let Some(Ok(root)) = BUILTIN.get() {
        if let Ok(rel) = p.strip_prefix(root) {
            return format!("{} (built-in)", rel.display());
        }
    }
    if let Ok(cwd) = std::env::current_dir() {
        if let Ok(rel) = p.strip_prefix(&cwd) {
            return rel.display().to_string();
        }
    }
    if let Some(home) = home_dir().and_then(|h| std::fs::canonicalize(h).ok()) {
        if let Ok(rel) = p.strip_prefix(&home) {
            return format!("{} (from ${HOME_ENV})", rel.display());
        }
    }
    p.display().to_string()
}

/// Candidate parents of the extracted copy, in order.
fn cache_bases() -> Vec<PathBuf> {
    let mut v = Vec::new();
    if let Some(x) = std::env::var_os("XDG_CACHE_HOME").map(PathBuf::from) {
        if x.is_absolute() {
            v.push(x.join("bowden"));
        }
    }
    if let Some(h) = std::env::var_os("HOME").map(PathBuf::from) {
        if h.is_absolute() {
            v.push(h.join(".cache").join("bowden"));
        }
    }
    // SAFETY: getuid has no preconditions.
    let uid = unsafe { libc::getuid() };
    v.push(std::env::temp_dir().join(format!("bowden-{uid}")));
    v
}

static BUILTIN: OnceLock<Result<PathBuf, String>> = OnceLock::new();

/// The extracted built-in copy (extracted, or repaired, on first use in a process).
pub fn builtin_root() -> Result<&'static Path> {
    BUILTIN
        .get_or_init(|| {
            let name = format!("shipped-{}-{SHIPPED_HASH}", env!("CARGO_PKG_VERSION"));
            let mut errors = Vec::new();
            for base in cache_bases() {
                let dir = base.join(&name);
                match extract(&dir) {
                    // Canonical, so paths made absolute later (pipeline copies) still share it.
                    Ok(()) => return Ok(std::fs::canonicalize(&dir).unwrap_or(dir)),
                    Err(e) => errors.push(format!("{e:#}")),
                }
            }
            Err(errors.join("; "))
        })
        .as_deref()
        .map_err(|e| anyhow!("extracting the built-in configs and models: {e}"))
}

/// Writes every shipped file under `dir` whose copy there is missing or differs (an edited
/// copy is restored: the built-in files are what the binary was built with). Each file is
/// written to a temporary name and renamed, so processes extracting at once never see a
/// partial file.
pub fn extract(dir: &Path) -> Result<()> {
    for (i, (rel, bytes)) in SHIPPED.iter().enumerate() {
        let dest = dir.join(rel);
        if std::fs::read(&dest).is_ok_and(|b| b == *bytes) {
            continue;
        }
        let parent = dest.parent().unwrap_or(dir);
        std::fs::create_dir_all(parent).with_context(|| format!("creating {}", parent.display()))?;
        let tmp = parent.join(format!(".{i}.{}.tmp", std::process::id()));
        std::fs::write(&tmp, bytes).with_context(|| format!("writing {}", tmp.display()))?;
        std::fs::rename(&tmp, &dest).with_context(|| format!("renaming {} to {}", tmp.display(), dest.display()))?;
    }
    Ok(())
}
