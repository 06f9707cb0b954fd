//! The Python client (`clients/python`) against the real pipeline: a venv from PyPI
//! (`target/py-venv`, reused while `clients/python/pyproject.toml` is unchanged) with the package
//! installed as an integrator installs it (`pip install -e clients/python`, which brings
//! iceoryx2 0.10); its unit tests (layouts, type names, service names and QoS parsed from the
//! Rust sources; ports over shared memory); then `configs/sim.toml` with the plant replaced by
//! `clients/python/examples/plant_node.py` (`exec = [...]`) in lockstep — every stage handles
//! every tick, the camera renders the Python plant's state and the estimator recovers it — and
//! in real time with `examples/monitor.py` printing the compensator's commands beside it.
//!
//! Skipped, with a message, only where there is no `python3`. Nothing is left in /dev/shm.

use crate::runtime_support;

use bowden_interfaces::{JointEstimate, PlantState};
use bowden_runtime::record::LogReader;
use bowden_runtime::replay::summarize;
use runtime_support::*;
use std::collections::BTreeMap;
use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn client_dir() -> PathBuf {
    repo().join("clients/python")
}

/// `target/` (or `$CARGO_TARGET_DIR`): the parent of the integration tests' scratch directory.
fn target_dir() -> PathBuf {
    Path::new(env!("CARGO_TARGET_TMPDIR"))
        .parent()
        .expect("CARGO_TARGET_TMPDIR has a parent")
        .to_path_buf()
}

/// `python3` if it runs, else a message saying the test is skipped.
fn python3() -> Option<String> {
    let ok = Command::new("python3")
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .map(|s| s.success())
        .unwrap_or(false);
    if !ok {
        eprintln!(
            "python_client: SKIPPED: no `python3` on PATH. The Python client tests need Python 3.9+ \
             with venv and pip (they install iceoryx2 0.10 from PyPI into target/py-venv)."
        );
        return None;
    }
    Some("python3".into())
}

/// A child process in its own process group, killed with its whole group unless it has exited
/// (a failing assertion or a timeout never leaves a pipeline behind).
struct Group(Child);

impl Group {
    fn spawn(mut cmd: Command) -> Group {
        use std::os::unix::process::CommandExt;
        cmd.process_group(0);
        Group(cmd.spawn().unwrap_or_else(|e| panic!("cannot start {cmd:?}: {e}")))
    }

    /// Waits for the exit, killing the group after `timeout`.
    fn wait(&mut self, timeout: Duration, what: &str) -> std::process::ExitStatus {
        let t0 = Instant::now();
        loop {
            if let Some(s) = self.0.try_wait().expect("try_wait") {
                return s;
            }
            if t0.elapsed() > timeout {
                self.kill();
                panic!("{what}: still running after {timeout:?}; killed its process group");
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    fn kill(&mut self) {
        // SAFETY: signalling the process group we created for our own child.
        unsafe { libc::kill(-(self.0.id() as libc::pid_t), libc::SIGKILL) };
        let _ = self.0.wait();
    }
}

impl Drop for Group {
    fn drop(&mut self) {
        if matches!(self.0.try_wait(), Ok(None)) {
            self.kill();
        }
    }
}

/// Runs `cmd` to completion within `timeout`, returning (success, stdout, stderr).
fn run(mut cmd: Command, timeout: Duration, what: &str) -> (bool, String, String) {
    let dir = tempfile::tempdir().unwrap();
    let (o, e) = (dir.path().join("stdout"), dir.path().join("stderr"));
    cmd.stdin(Stdio::null())
        .stdout(File::create(&o).unwrap())
        .stderr(File::create(&e).unwrap());
    let status = Group::spawn(cmd).wait(timeout, what);
    let read = |p: &Path| std::fs::read_to_string(p).unwrap_or_default();
    (status.success(), read(&o), read(&e))
}

fn must(cmd: Command, timeout: Duration, what: &str) -> String {
    let (ok, out, err) = run(cmd, timeout, what);
    assert!(ok, "{what} failed:\nstdout:\n{out}\nstderr:\n{err}");
    out + &err
}

/// An exclusive lock on a file, released when dropped (another `cargo test` sharing the target
/// directory waits instead of installing into the same venv at the same time).
struct FileLock(#[allow(dead_code)] File);

fn lock(path: &Path) -> FileLock {
    use std::os::fd::AsRawFd;
    let f = File::create(path).unwrap();
    // SAFETY: flock on a descriptor we own; released when the file is closed.
    let rc = unsafe { libc::flock(f.as_raw_fd(), libc::LOCK_EX) };
    assert_eq!(rc, 0, "flock {}", path.display());
    FileLock(f)
}

/// The venv's python with the client installed: `target/py-venv`, created with `python3 -m
/// venv` and `pip install -e clients/python` the first time, reused while the stamp (the
/// package's path and pyproject.toml) matches and both packages import.
fn venv_python() -> Option<PathBuf> {
    static VENV: Mutex<Option<PathBuf>> = Mutex::new(None);
    let mut done = VENV.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(p) = done.as_ref() {
        return Some(p.clone());
    }
    let py3 = python3()?;
    let target = target_dir();
    std::fs::create_dir_all(&target).unwrap();
    let _lock = lock(&target.join("py-venv.lock"));
    let venv = target.join("py-venv");
    let python = venv.join("bin/python");
    let stamp_path = venv.join(".bowden-client-stamp");
    let stamp = format!(
        "{}\n{}",
        client_dir().display(),
        std::fs::read_to_string(client_dir().join("pyproject.toml")).unwrap()
    );
    let t0 = Instant::now();
    let runs = |args: &[&str]| {
        Command::new(&python)
            .args(args)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .map(|s| s.success())
            .unwrap_or(false)
    };
    if !runs(&["-c", "import sys"]) {
        let mut c = Command::new(&py3);
        c.args(["-m", "venv", "--clear"]).arg(&venv);
        must(
            c,
            Duration::from_secs(300),
            "python3 -m venv target/py-venv (Debian/Ubuntu: apt-get install python3-venv)",
        );
    }
    let imports = || runs(&["-c", "import iceoryx2, bowden_client.ports"]);
    if std::fs::read_to_string(&stamp_path).ok().as_deref() != Some(stamp.as_str()) || !imports() {
        let mut c = Command::new(&python);
        c.args(["-m", "pip", "install", "-q", "-e"])
            .arg(client_dir())
            .env("PIP_DISABLE_PIP_VERSION_CHECK", "1")
            .env("PIP_NO_INPUT", "1");
        must(
            c,
            Duration::from_secs(600),
            "pip install -e clients/python (needs PyPI: iceoryx2==0.10.*)",
        );
        assert!(imports(), "iceoryx2 and bowden_client do not import after pip install");
        std::fs::write(&stamp_path, &stamp).unwrap();
        eprintln!(
            "python_client: venv {} ready in {:.1} s",
            venv.display(),
            t0.elapsed().as_secs_f64()
        );
    }
    *done = Some(python.clone());
    Some(python)
}

/// One pipeline at a time: the two runs would compete for the machine's 2 cores.
static PIPELINE: Mutex<()> = Mutex::new(());

/// configs/sim.toml with the plant replaced by the Python plant node.
fn sim_with_python_plant(python: &Path) -> String {
    let sim = std::fs::read_to_string(sim_toml()).unwrap();
    let plant = client_dir().join("examples/plant_node.py");
    let exec = format!(
        "[[node]]\nname = \"plant\"\nexec = [{:?}, {:?}]\nreports_status = true\n",
        python.display().to_string(),
        plant.display().to_string()
    );
    let out = sim.replace("[[node]]\nname = \"plant\"\n", &exec);
    assert_ne!(out, sim, "configs/sim.toml has no `name = \"plant\"` node to replace");
    out
}

fn bowden_run(args: &[&str]) -> Command {
    let mut c = Command::new(bowden_exe());
    c.args(args).current_dir(repo());
    c
}

#[test]
fn python_unit_tests_pass() {
    let Some(python) = venv_python() else { return };
    let mut c = Command::new(&python);
    c.args(["-m", "unittest", "discover", "-v", "-s"])
        .arg(client_dir().join("tests"))
        .current_dir(repo());
    let out = must(c, Duration::from_secs(120), "python -m unittest (clients/python/tests)");
    assert!(out.contains("\nOK"), "{out}");
    // Every test ran: the shared-memory ones are skipped only without iceoryx2.
    assert!(!out.contains("skipped"), "{out}");
    assert!(out.contains("test_qos_matches_ports_rs") && out.contains("test_a_mismatched_type_is_refused"));
}

#[test]
fn python_plant_closes_the_loop_in_lockstep() {
    let Some(python) = venv_python() else { return };
    let _one = PIPELINE.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let (p, _guard) = guarded_prefix("pyls");
    let cfg = write_config(dir.path(), "python-plant.toml", &sim_with_python_plant(&python));
    let log = dir.path().join("run.blog");
    let t0 = Instant::now();
    let (ok, out, err) = run(
        bowden_run(&[
            "run",
            cfg.to_str().unwrap(),
            "--mode",
            "lockstep",
            "--ticks",
            "600",
            "--prefix",
            &p,
            "--record",
            log.to_str().unwrap(),
            "--quiet",
        ]),
        Duration::from_secs(180),
        "bowden run (lockstep, Python plant)",
    );
    assert!(ok, "bowden run failed:\nstdout:\n{out}\nstderr:\n{err}");
    eprintln!("python_client: lockstep run in {:.1} s", t0.elapsed().as_secs_f64());
    assert!(err.contains("plant [plant] external `"), "{err}");
    assert!(err.contains("[plant] python plant (lockstep): 600 cycles"), "{err}");
    for stage in [
        "trajectory",
        "compensator",
        "actuator",
        "plant",
        "camera",
        "estimator",
        "recorder",
    ] {
        assert!(
            out.contains(&format!("| {stage} | stopped | 600 | 0 | 0 | 0 |")),
            "stage {stage} did not handle 600 ticks cleanly:\n{out}\n{err}"
        );
    }
    assert_clean(&p);

    // The Python plant's states, one per tick, lagging the commands.
    let s = summarize(&log).unwrap();
    let svc = |name: &str| s.services.iter().find(|v| v.service == name).unwrap();
    let ps = svc("bowden/plant_state");
    assert_eq!((ps.records, ps.seq_gaps, ps.last_tick), (600, 0, Some(599)));
    assert!(
        s.plant_mean_abs_error_deg.iter().all(|&e| e > 0.1 && e < 20.0),
        "{:?}",
        s.plant_mean_abs_error_deg
    );
    // The camera rendered them and the estimator recovered them: the loop is closed.
    assert!(svc("bowden/joint_estimate").records >= 15);
    assert!(
        s.estimate_valid_fraction.unwrap() > 0.9,
        "{:?}",
        s.estimate_valid_fraction
    );
    let mut r = LogReader::open(&log).unwrap();
    let mut buf = Vec::new();
    let mut states = BTreeMap::new();
    let mut estimates = Vec::new();
    for i in 0..r.entries.len() {
        if let Some(st) = r.sample::<PlantState>(i, &mut buf).unwrap() {
            states.insert(st.header.tick, st);
        } else if let Some(e) = r.sample::<JointEstimate>(i, &mut buf).unwrap() {
            estimates.push(e);
        }
    }
    let mut worst = 0.0f64;
    let mut compared = 0;
    for e in estimates.iter().filter(|e| e.quality == JointEstimate::QUALITY_VALID) {
        let st = states[&e.header.tick];
        for j in 0..5 {
            worst = worst.max((e.q_phy_deg[j] - st.q_phy_deg[j]).abs());
        }
        compared += 1;
    }
    assert!(compared >= 15, "{compared} valid estimates");
    eprintln!("python_client: {compared} valid estimates, within {worst:.3} deg of the Python plant's q_phy");
    assert!(
        worst < 1.5,
        "estimates differ from the Python plant's q_phy by up to {worst:.2} deg"
    );
}

#[test]
fn python_plant_and_monitor_run_in_real_time() {
    let Some(python) = venv_python() else { return };
    let _one = PIPELINE.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let (p, _guard) = guarded_prefix("pyrt");
    let cfg = write_config(dir.path(), "python-plant.toml", &sim_with_python_plant(&python));
    let log = dir.path().join("run.blog");
    let (out_f, err_f) = (dir.path().join("stdout"), dir.path().join("stderr"));
    let mut c = bowden_run(&[
        "run",
        cfg.to_str().unwrap(),
        "--seconds",
        "3",
        "--prefix",
        &p,
        "--record",
        log.to_str().unwrap(),
        "--quiet",
    ]);
    c.stdin(Stdio::null())
        .stdout(File::create(&out_f).unwrap())
        .stderr(File::create(&err_f).unwrap());
    let t0 = Instant::now();
    let mut launcher = Group::spawn(c);

    // The monitor beside it, on the same prefix: a few commands, then it exits by itself.
    let mut m = Command::new(&python);
    m.arg(client_dir().join("examples/monitor.py")).args([
        "--prefix",
        &p,
        "--count",
        "5",
        "--every",
        "10",
        "--timeout-s",
        "30",
    ]);
    let (mon_ok, mon_out, mon_err) = run(m, Duration::from_secs(60), "monitor.py");

    let status = launcher.wait(Duration::from_secs(120), "bowden run (real time, Python plant)");
    let out = std::fs::read_to_string(&out_f).unwrap();
    let err = std::fs::read_to_string(&err_f).unwrap();
    assert!(status.success(), "bowden run failed:\nstdout:\n{out}\nstderr:\n{err}");
    eprintln!("python_client: real-time run in {:.1} s", t0.elapsed().as_secs_f64());
    assert!(mon_ok, "monitor failed:\n{mon_out}\n{mon_err}");
    let lines: Vec<&str> = mon_out.lines().filter(|l| l.starts_with("JointCommand seq=")).collect();
    assert_eq!(lines.len(), 5, "monitor output:\n{mon_out}\n{mon_err}");
    assert!(lines.iter().all(|l| l.contains("mode=uncalibrated")), "{mon_out}");

    // The plant answered the launcher's shutdown tick (no SIGTERM needed) and reported a
    // status; it and every stage after it ran.
    assert!(!out.contains("did not exit in time"), "{out}\n{err}");
    let cycles = |stage: &str| -> u64 {
        let row = out
            .lines()
            .find(|l| l.starts_with(&format!("| {stage} | stopped | ")))
            .unwrap_or_else(|| panic!("no stopped row for {stage}:\n{out}\n{err}"));
        row.split('|').nth(3).unwrap().trim().parse().unwrap()
    };
    assert!(cycles("plant") > 300, "{out}\n{err}");
    for stage in ["actuator", "camera", "estimator", "recorder"] {
        assert!(cycles(stage) > 0, "{stage}:\n{out}\n{err}");
    }
    let s = summarize(&log).unwrap();
    let svc = |name: &str| s.services.iter().find(|v| v.service == name).map(|v| v.records);
    assert!(svc("bowden/plant_state").unwrap_or(0) > 100, "{s:?}");
    assert!(svc("bowden/joint_estimate").unwrap_or(0) > 0, "{s:?}");
    assert!(s.estimate_valid_fraction.unwrap_or(0.0) > 0.5, "{s:?}");
    assert_clean(&p);
}
