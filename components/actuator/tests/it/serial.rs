//! The serial-line drive against a pseudo-terminal, as a motor controller on a UART would see
//! it: enable, one line per setpoint, hold; a controller that stops reading is an error, not a
//! blocked control cycle.

use bowden_actuator::serial::{format_line, SerialLineDrive};
use bowden_actuator::Drive;
use bowden_interfaces::MotorCommand;
use std::fs::File;
use std::io::Read;
use std::os::fd::FromRawFd;

/// A pty pair: the controller's end (master, non-blocking reads) and the device path.
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

fn read_all(master: &mut File) -> String {
    let mut out = Vec::new();
    let mut buf = [0u8; 4096];
    for _ in 0..50 {
        match master.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => out.extend_from_slice(&buf[..n]),
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                if !out.is_empty() {
                    break;
                }
                std::thread::sleep(std::time::Duration::from_millis(10));
            }
            Err(e) => panic!("read: {e}"),
        }
    }
    String::from_utf8(out).unwrap()
}

fn command(tick: u64) -> MotorCommand {
    let mut m = MotorCommand {
        n_cables: 10,
        flags: MotorCommand::FLAG_CLAMPED,
        ..Default::default()
    };
    m.header.tick = tick;
    for (i, d) in m.cable_disp_mm[..10].iter_mut().enumerate() {
        *d = i as f64 * 0.5 - 2.25;
    }
    m
}

#[test]
fn setpoints_reach_the_controller_as_lines() {
    let (mut master, path) = pty();
    let mut d = SerialLineDrive::open(&path).unwrap();
    d.activate().unwrap();
    d.write(&command(7)).unwrap();
    d.write(&command(8)).unwrap();
    d.deactivate().unwrap();
    let text = read_all(&mut master);
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 4, "{text:?}");
    assert_eq!(lines[0], "E");
    assert_eq!(
        lines[1],
        "S 7 4 10 -2.2500 -1.7500 -1.2500 -0.7500 -0.2500 0.2500 0.7500 1.2500 1.7500 2.2500"
    );
    assert!(lines[2].starts_with("S 8 4 10 -2.2500"), "{}", lines[2]);
    assert_eq!(lines[3], "H");
    assert!(!text.contains('\r'), "raw mode: no CR added");
    assert_eq!(d.sent(), 2);
}

#[test]
fn a_controller_that_stops_reading_is_an_error_not_a_block() {
    let (_master, path) = pty();
    let mut d = SerialLineDrive::open(&path).unwrap();
    // Nobody reads the master: the pty's buffer fills and the drive must say so.
    let mut failed = None;
    for k in 0..100_000 {
        if let Err(e) = d.write(&command(k)) {
            failed = Some((k, e));
            break;
        }
    }
    let (k, e) = failed.expect("a full device buffer is reported");
    assert!(k > 10, "lines fit before the buffer is full: {k}");
    assert!(e.to_string().contains("is the controller reading"), "{e}");
    assert!(e.to_string().contains(&path), "{e}");
}

#[test]
fn a_missing_device_names_itself_and_lines_stay_bounded() {
    let e = SerialLineDrive::open("/dev/bowden-no-such-tty")
        .err()
        .expect("no device");
    assert!(
        e.to_string().contains("/dev/bowden-no-such-tty") && e.to_string().contains("cannot open"),
        "{e}"
    );
    // A value too large for the line is an error, never a longer write.
    let mut m = command(1);
    m.cable_disp_mm[0] = 1e300;
    let mut buf = [0u8; bowden_actuator::serial::LINE_MAX];
    assert!(format_line(&m, &mut buf).is_err());
}
