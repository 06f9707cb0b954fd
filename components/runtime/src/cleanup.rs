//! Stale iceoryx2 resources: a process killed with SIGKILL (or a crashed one) leaves its node,
//! ports and shared memory behind; with one publisher allowed per data service, its successor
//! could not even start. The launcher removes the resources of dead nodes before it starts
//! anything ([`remove_stale_nodes`]) and after a child dies, and removes the last per-prefix
//! bookkeeping files when a run ends with no node left ([`remove_prefix_files`]).

use crate::ports::{Ipc, IpcSettings, PortError};
use iceoryx2::node::{Node, NodeState};
use iceoryx2::prelude::CallbackProgression;
use std::path::{Path, PathBuf};

/// Outcome of [`remove_stale_nodes`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CleanupReport {
    /// Dead nodes whose resources were removed.
    pub dead_removed: usize,
    /// Dead nodes whose cleanup failed (another process may be cleaning them).
    pub dead_failed: usize,
    /// Nodes still alive under the prefix.
    pub alive: usize,
    /// Nodes in an undefined or inaccessible state.
    pub other: usize,
}

/// Removes the resources of every dead node under `settings.prefix`.
pub fn remove_stale_nodes(settings: &IpcSettings) -> Result<CleanupReport, PortError> {
    crate::ports::quiet_iceoryx2_log();
    let cfg = settings.iox_config()?;
    let mut report = CleanupReport::default();
    let mut dead = Vec::new();
    Node::<Ipc>::list(&cfg, |state| {
        match state {
            NodeState::Alive(_) => report.alive += 1,
            NodeState::Dead(v) => dead.push(v),
            NodeState::Inaccessible(_) | NodeState::Undefined(_) => report.other += 1,
        }
        CallbackProgression::Continue
    })
    .map_err(|e| PortError::Node {
        node: "<list>".into(),
        prefix: settings.prefix.clone(),
        message: format!("cannot list nodes: {e:?}"),
    })?;
    for v in dead {
        match v.try_remove_stale_resources() {
            Ok(()) => report.dead_removed += 1,
            Err(_) => report.dead_failed += 1,
        }
    }
    Ok(report)
}

/// Nodes currently alive under the prefix.
pub fn alive_nodes(settings: &IpcSettings) -> Result<usize, PortError> {
    let cfg = settings.iox_config()?;
    let mut n = 0;
    Node::<Ipc>::list(&cfg, |state| {
        if matches!(state, NodeState::Alive(_)) {
            n += 1;
        }
        CallbackProgression::Continue
    })
    .map_err(|e| PortError::Node {
        node: "<list>".into(),
        prefix: settings.prefix.clone(),
        message: format!("cannot list nodes: {e:?}"),
    })?;
    Ok(n)
}

/// Where iceoryx2 keeps files: shared memory and its root directory.
pub fn resource_dirs(settings: &IpcSettings) -> Vec<PathBuf> {
    let root = settings
        .iox_config()
        .map(|c| PathBuf::from(c.global.root_path().to_string()))
        .unwrap_or_else(|_| PathBuf::from("/tmp/iceoryx2"));
    vec![PathBuf::from("/dev/shm"), root]
}

fn walk(dir: &Path, prefix: &str, out: &mut Vec<PathBuf>) {
    let Ok(rd) = std::fs::read_dir(dir) else { return };
    for e in rd.flatten() {
        let p = e.path();
        let is_dir = e.file_type().map(|t| t.is_dir()).unwrap_or(false);
        let matches = e.file_name().to_string_lossy().starts_with(prefix);
        if is_dir {
            walk(&p, prefix, out);
        } else if matches {
            out.push(p);
        }
    }
}

/// Files under the iceoryx2 directories whose name starts with the prefix.
pub fn prefix_files(settings: &IpcSettings) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for d in resource_dirs(settings) {
        walk(&d, &settings.prefix, &mut out);
    }
    out.sort();
    out
}

/// Removes the prefix's remaining files if no node is alive under it (a clean exit still leaves
/// a small global-management segment per prefix). Returns how many files were removed.
pub fn remove_prefix_files(settings: &IpcSettings) -> Result<usize, PortError> {
    if alive_nodes(settings)? > 0 {
        return Ok(0);
    }
    let mut n = 0;
    for f in prefix_files(settings) {
        if std::fs::remove_file(&f).is_ok() {
            n += 1;
        }
    }
    Ok(n)
}

/// A prefix file another user owns: a pipeline must not share its shared memory with it.
#[derive(Debug, thiserror::Error)]
#[error(
    "{path}: owned by uid {owner}, not by this user (uid {me}): another user created or took a file \
     of prefix `{prefix}`; refusing to run the pipeline over it (choose another prefix, or have the \
     file removed: see docs/deployment.md, \"Security\")"
)]
pub struct ForeignFile {
    pub path: String,
    pub prefix: String,
    pub owner: u32,
    pub me: u32,
}

/// Keeps the prefix's shared memory private to this user. iceoryx2 0.10 creates its per-prefix
/// node-management file (`…global_mgmt`) with mode 0666 whatever the umask; any local user
/// could then empty it and make `bowden estop` and the launcher's stale-node clean-up hang.
/// This refuses a prefix with a file of another user (a squatter who created it first) and
/// takes group and other access away from ours. Returns how many modes were changed.
///
/// Call it before the first node of a run exists (to find squatters) and right after (the
/// management file is created with the first node): the window in between is the node's
/// creation, and an attacker who opened the file in it keeps the descriptor — the complete fix
/// is a private /dev/shm (the systemd unit's `PrivateIPC`/`TemporaryFileSystem`, see
/// docs/deployment.md).
pub fn secure_prefix_files(settings: &IpcSettings) -> Result<usize, ForeignFile> {
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    // SAFETY: geteuid has no preconditions.
    let me = unsafe { libc::geteuid() };
    let mut changed = 0;
    for f in prefix_files(settings) {
        let Ok(meta) = std::fs::symlink_metadata(&f) else {
            continue;
        };
        if meta.uid() != me {
            return Err(ForeignFile {
                path: f.display().to_string(),
                prefix: settings.prefix.clone(),
                owner: meta.uid(),
                me,
            });
        }
        if meta.file_type().is_file() && meta.mode() & 0o077 != 0 {
            let mode = meta.mode() & 0o700;
            if std::fs::set_permissions(&f, std::fs::Permissions::from_mode(mode)).is_ok() {
                changed += 1;
            }
        }
    }
    Ok(changed)
}
