//! The actuator's drive chosen in the pipeline file: `drive = { serial = "<device>" }` sends
//! every setpoint the actuator publishes to a motor controller on a serial line too (here a
//! pseudo-terminal read by the test), line for line, in a lockstep run of configs/sim.toml; a
//! device that cannot be opened stops the node at start with its path named.

use crate::runtime_support::*;
use bowden_interfaces::{services, MotorCommand};
use std::fs::File;
use std::io::Read;
use std::os::fd::FromRawFd;
use std::path::{Path, PathBuf};

fn pty() -> (File, String) {
    // SAFETY: plain libc pty calls; the returned fd is owned by the File.
    unsafe {
        let fd = libc::posix_openpt(libc::O_RDWR | libc::O_NOCTTY | libc::O_NONBLOCK);
        assert!(fd >= 0, "posix_openpt: {}", std::io::Error::last_os_error());
        assert_eq!(libc::grantpt(fd), 0);
        assert_eq!(libc::unlockpt(fd), 0);
        let mut name = [0 as libc::c_char; 128];
        assert_eq!(libc::ptsname_r(fd, name.as_mut_ptr(), name.len()), 0);
        let path = std::ffi::CStr::from_ptr(name.as_ptr()).to_string_lossy().into_owned();
        (File::from_raw_fd(fd), path)
    }
}

fn pipeline(dir: &Path, drive: toml::Value) -> PathBuf {
    let out = dir.join("serial.toml");
    bowden_evaluation::pipeline_variant(&sim_toml(), &[("actuator", "drive", drive)], &out).unwrap();
    out
}

#[test]
fn the_serial_drive_gets_every_setpoint_the_actuator_publishes() {
    let dir = tempfile::tempdir().unwrap();
    let (mut master, dev) = pty();
    let mut drive = toml::Table::new();
    drive.insert("serial".into(), toml::Value::String(dev.clone()));
    let file = pipeline(dir.path(), toml::Value::Table(drive));
    let (mut s, _guard) = lockstep_session(&file, "drs", &[services::MOTOR_COMMAND]);
    let (mut published, mut text, mut buf) = (Vec::new(), String::new(), [0u8; 8192]);
    for _ in 0..300 {
        let out = s.step().unwrap();
        assert!(out.events.is_empty(), "{:?}", out.events);
        published.extend(out.get::<MotorCommand>(services::MOTOR_COMMAND));
        // The controller reads as it goes (a pty holds a few kB).
        while let Ok(n) = master.read(&mut buf) {
            if n == 0 {
                break;
            }
            text.push_str(std::str::from_utf8(&buf[..n]).unwrap());
        }
    }
    s.shutdown().unwrap();
    while let Ok(n) = master.read(&mut buf) {
        if n == 0 {
            break;
        }
        text.push_str(std::str::from_utf8(&buf[..n]).unwrap());
    }
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.first(), Some(&"E"), "enabled first");
    assert_eq!(lines.last(), Some(&"H"), "held at the end: {:?}", lines.last());
    let setpoints: Vec<&str> = lines.iter().copied().filter(|l| l.starts_with("S ")).collect();
    assert_eq!(published.len(), 300, "a motor command every tick");
    assert_eq!(setpoints.len(), published.len(), "one line per published setpoint");
    for (line, m) in setpoints.iter().zip(&published) {
        let f: Vec<&str> = line.split(' ').collect();
        assert_eq!(f[1].parse::<u64>().unwrap(), m.header.tick, "{line}");
        assert_eq!(f[2].parse::<u32>().unwrap(), m.flags, "{line}");
        assert_eq!(f[3].parse::<usize>().unwrap(), m.n_cables as usize);
        for (j, v) in f[4..].iter().enumerate() {
            let d: f64 = v.parse().unwrap();
            assert!((d - m.cable_disp_mm[j]).abs() <= 0.5e-4 + 1e-12, "{line}: cable {j}");
        }
    }
    assert!(
        published
            .iter()
            .any(|m| m.cable_disp_mm[..10].iter().any(|d| d.abs() > 0.1)),
        "the robot moved"
    );
}

#[test]
fn a_device_that_cannot_be_opened_stops_the_node_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let mut drive = toml::Table::new();
    drive.insert("serial".into(), toml::Value::String("/dev/bowden-no-such-tty".into()));
    let file = pipeline(dir.path(), toml::Value::Table(drive));
    let (p, _g) = guarded_prefix("drm");
    let out = bowden()
        .args(["node", "actuator", "--config"])
        .arg(&file)
        .args(["--mode", "lockstep", "--prefix", &p])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("/dev/bowden-no-such-tty") && err.contains("cannot open"),
        "{err}"
    );
    // A drive that is not one of the two is refused on load, with what is accepted.
    let file = pipeline(dir.path(), toml::Value::String("can".into()));
    let out = bowden()
        .args(["node", "actuator", "--config"])
        .arg(&file)
        .args(["--mode", "lockstep", "--prefix", &p])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("drive") && err.contains("serial"),
        "{err}"
    );
}
