//! The supervisor: starts the processes of a pipeline (`bowden node <name>` children, or the
//! external executable a config names), notices when one exits, restarts it if its policy says
//! so, and stops them all — SIGTERM, a grace period, then SIGKILL.

use crate::config::{PipelineConfig, ProcessSpec, RestartPolicy};
use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

/// How children are started.
#[derive(Debug, Clone)]
pub struct LaunchOptions {
    /// The `bowden` executable that hosts built-in nodes (`bowden node <name> ...`).
    pub exe: PathBuf,
    /// Pass `--quiet` to children (no exit summaries on stderr).
    pub quiet_children: bool,
    /// Where children's stdout/stderr go; `None` inherits the launcher's.
    pub log_dir: Option<PathBuf>,
}

impl LaunchOptions {
    /// Children are started from the running executable (the `bowden` binary).
    pub fn current_exe() -> std::io::Result<Self> {
        Ok(Self {
            exe: std::env::current_exe()?,
            quiet_children: false,
            log_dir: None,
        })
    }

    pub fn with_exe(exe: impl Into<PathBuf>) -> Self {
        Self {
            exe: exe.into(),
            quiet_children: false,
            log_dir: None,
        }
    }
}

/// A process could not be started.
#[derive(Debug, thiserror::Error)]
#[error("cannot start process `{process}` ({program}): {source}")]
pub struct SpawnError {
    pub process: String,
    pub program: String,
    pub source: std::io::Error,
}

/// Something the supervisor observed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ChildEvent {
    /// The process exited; `restarted` says whether a new instance was started.
    Exited {
        process: String,
        status: String,
        success: bool,
        restarted: bool,
    },
}

struct Managed {
    spec: ProcessSpec,
    child: Option<Child>,
    restarts: u32,
    last_status: Option<String>,
    /// Exited and will not be restarted.
    gone: bool,
}

/// Owns the child processes of one run.
pub struct Supervisor {
    opts: LaunchOptions,
    config_arg: String,
    override_args: Vec<String>,
    env: Vec<(String, String)>,
    procs: Vec<Managed>,
}

fn describe(status: ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match (status.code(), status.signal()) {
        (Some(c), _) => format!("exit code {c}"),
        (None, Some(s)) => format!("killed by signal {s}"),
        _ => "unknown status".into(),
    }
}

impl Supervisor {
    pub fn new(cfg: &PipelineConfig, opts: LaunchOptions) -> Self {
        let ipc = cfg.ipc();
        let env = vec![
            ("BOWDEN_PREFIX".to_string(), ipc.prefix.clone()),
            ("BOWDEN_NAMESPACE".to_string(), ipc.namespace.clone()),
            ("BOWDEN_MODE".to_string(), cfg.mode().as_str().to_string()),
            ("BOWDEN_CONFIG".to_string(), cfg.origin.arg()),
            ("BOWDEN_PERIOD_US".to_string(), cfg.runtime.period_us.to_string()),
        ];
        // Children must agree with the launcher on everything the launcher was told.
        let mut ov = cfg.overrides.clone();
        ov.mode = Some(cfg.mode());
        ov.prefix = Some(ipc.prefix.clone());
        ov.namespace = Some(ipc.namespace.clone());
        Self {
            opts,
            config_arg: cfg.origin.arg(),
            override_args: ov.to_args(),
            env,
            procs: cfg
                .processes
                .iter()
                .map(|p| Managed {
                    spec: p.clone(),
                    child: None,
                    restarts: 0,
                    last_status: None,
                    gone: false,
                })
                .collect(),
        }
    }

    fn spawn_one(&mut self, i: usize) -> Result<(), SpawnError> {
        let m = &self.procs[i];
        let (program, args): (PathBuf, Vec<String>) = match &m.spec.exec {
            Some(e) => (PathBuf::from(&e[0]), e[1..].to_vec()),
            None => {
                let mut a = vec![
                    "node".to_string(),
                    m.spec.name.clone(),
                    "--config".to_string(),
                    self.config_arg.clone(),
                ];
                a.extend(self.override_args.iter().cloned());
                if self.opts.quiet_children {
                    a.push("--quiet".into());
                }
                (self.opts.exe.clone(), a)
            }
        };
        let mut cmd = Command::new(&program);
        cmd.args(&args).stdin(Stdio::null());
        for (k, v) in &self.env {
            cmd.env(k, v);
        }
        cmd.env("BOWDEN_NODE", &m.spec.name);
        let err = |source| SpawnError {
            process: m.spec.name.clone(),
            program: program.display().to_string(),
            source,
        };
        if let Some(dir) = &self.opts.log_dir {
            std::fs::create_dir_all(dir).map_err(err)?;
            let f = std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(dir.join(format!("{}.log", m.spec.name)))
                .map_err(err)?;
            let f2 = f.try_clone().map_err(err)?;
            cmd.stdout(f).stderr(f2);
        }
        // A child must not outlive a launcher that was killed: it gets SIGTERM and shuts down
        // cleanly (the actuator holds) instead of running unsupervised.
        // SAFETY: prctl is async-signal-safe and touches only the child.
        unsafe {
            use std::os::unix::process::CommandExt;
            cmd.pre_exec(|| {
                libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM as libc::c_ulong, 0, 0, 0);
                Ok(())
            });
        }
        let child = cmd.spawn().map_err(err)?;
        self.procs[i].child = Some(child);
        self.procs[i].gone = false;
        Ok(())
    }

    /// Starts every process of the pipeline.
    pub fn spawn_all(&mut self) -> Result<(), SpawnError> {
        for i in 0..self.procs.len() {
            self.spawn_one(i)?;
        }
        Ok(())
    }

    /// Process ids by process name, for diagnostics and tests.
    pub fn pids(&self) -> Vec<(String, u32)> {
        self.procs
            .iter()
            .filter_map(|m| m.child.as_ref().map(|c| (m.spec.name.clone(), c.id())))
            .collect()
    }

    /// Checks every child without blocking. Exited ones are reported; the caller decides about
    /// restarts with [`Supervisor::restart`] (lockstep restarts only between ticks).
    pub fn poll_exits(&mut self) -> Vec<(usize, String, bool)> {
        let mut out = Vec::new();
        for (i, m) in self.procs.iter_mut().enumerate() {
            let Some(c) = m.child.as_mut() else { continue };
            if let Ok(Some(status)) = c.try_wait() {
                let text = describe(status);
                m.last_status = Some(text.clone());
                m.child = None;
                out.push((i, text, status.success()));
            }
        }
        out
    }

    /// Whether process `i` should be restarted after an exit with `success`.
    pub fn wants_restart(&self, i: usize, success: bool) -> bool {
        let m = &self.procs[i];
        let policy = match m.spec.restart {
            RestartPolicy::Never => false,
            RestartPolicy::OnFailure => !success,
            RestartPolicy::Always => true,
        };
        policy && m.restarts < m.spec.max_restarts
    }

    /// Starts a new instance of process `i`.
    pub fn restart(&mut self, i: usize) -> Result<(), SpawnError> {
        self.procs[i].restarts += 1;
        self.spawn_one(i)
    }

    /// Marks process `i` as finished for good.
    pub fn mark_gone(&mut self, i: usize) {
        self.procs[i].gone = true;
    }

    pub fn spec(&self, i: usize) -> &ProcessSpec {
        &self.procs[i].spec
    }

    pub fn len(&self) -> usize {
        self.procs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.procs.is_empty()
    }

    pub fn running(&self, i: usize) -> bool {
        self.procs[i].child.is_some()
    }

    pub fn restarts(&self, i: usize) -> u32 {
        self.procs[i].restarts
    }

    pub fn last_status(&self, i: usize) -> Option<&str> {
        self.procs[i].last_status.as_deref()
    }

    /// Sends `sig` to every running child.
    pub fn signal_all(&self, sig: i32) {
        for m in &self.procs {
            if let Some(c) = &m.child {
                // SAFETY: signalling a child we spawned and have not reaped.
                unsafe { libc::kill(c.id() as libc::pid_t, sig) };
            }
        }
    }

    /// Waits up to `grace` for every child to exit on its own (after the shutdown tick), then
    /// SIGTERMs the rest, waits `grace` again and SIGKILLs what is left. Returns the processes
    /// that had to be signalled, with how.
    pub fn stop_all(&mut self, grace: Duration) -> Vec<(String, &'static str)> {
        let mut forced = Vec::new();
        let wait = |procs: &mut Vec<Managed>, until: Instant| loop {
            let mut left = 0;
            for m in procs.iter_mut() {
                if let Some(c) = m.child.as_mut() {
                    match c.try_wait() {
                        Ok(Some(s)) => {
                            m.last_status = Some(describe(s));
                            m.child = None;
                        }
                        _ => left += 1,
                    }
                }
            }
            if left == 0 || Instant::now() >= until {
                return left;
            }
            std::thread::sleep(Duration::from_millis(5));
        };
        if wait(&mut self.procs, Instant::now() + grace) == 0 {
            return forced;
        }
        for m in &self.procs {
            if let Some(c) = &m.child {
                forced.push((m.spec.name.clone(), "SIGTERM"));
                // SAFETY: signalling our own unreaped child.
                unsafe { libc::kill(c.id() as libc::pid_t, libc::SIGTERM) };
            }
        }
        if wait(&mut self.procs, Instant::now() + grace) == 0 {
            return forced;
        }
        for m in self.procs.iter_mut() {
            if let Some(c) = m.child.as_mut() {
                forced.push((m.spec.name.clone(), "SIGKILL"));
                let _ = c.kill();
                if let Ok(s) = c.wait() {
                    m.last_status = Some(describe(s));
                }
                m.child = None;
            }
        }
        forced
    }
}

impl Drop for Supervisor {
    fn drop(&mut self) {
        // Never leave children behind, whatever path the launcher took out.
        if self.procs.iter().any(|m| m.child.is_some()) {
            self.stop_all(Duration::from_millis(500));
        }
    }
}
