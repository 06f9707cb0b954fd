//! A motor driver on a serial line: the second implementation of [`Drive`] beside the IPC
//! drive of the actuator node, and the skeleton of a real one. Many motor controllers take
//! ASCII setpoints over a UART (or a USB CDC-ACM device); this drive speaks a minimal line
//! protocol on a character device (`/dev/ttyUSB0`, a pty in the tests):
//!
//! ```text
//! E\n                                    activate: enable the amplifiers
//! S <tick> <flags> <n> <d1> … <dn>\n     one setpoint: cable displacements, mm, 4 decimals
//! H\n                                    deactivate: hold position
//! ```
//!
//! `flags` are [`MotorCommand`]'s (e-stop 1, hold 2, clamped 4). The device is opened
//! non-blocking and each line is formatted into a fixed buffer: `write` never blocks and never
//! allocates. A line the device cannot take whole (its buffer is full: the controller stopped
//! reading) is an error, so the actuator reports it instead of sending setpoints into a void.
//! A real controller needs its own framing, checksums and acknowledgement on top: replace
//! `format_line` and read the replies in a helper thread.

use crate::{Drive, DriveError};
use bowden_interfaces::{MotorCommand, MAX_CABLES};
use std::fs::File;
use std::io::Write;
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};

/// Longest line: "S", a u64 tick, flags, n and 16 displacements of up to 12 characters.
pub const LINE_MAX: usize = 16 + 2 * 21 + MAX_CABLES * 14;

/// The setpoint line of `cmd` in `buf`; returns its length.
pub fn format_line(cmd: &MotorCommand, buf: &mut [u8; LINE_MAX]) -> Result<usize, std::io::Error> {
    let n = (cmd.n_cables as usize).min(MAX_CABLES);
    let mut w: &mut [u8] = &mut buf[..];
    let cap = w.len();
    write!(w, "S {} {} {}", cmd.header.tick, cmd.flags, n)?;
    for d in &cmd.cable_disp_mm[..n] {
        write!(w, " {d:.4}")?;
    }
    w.write_all(b"\n")?;
    Ok(cap - w.len())
}

/// A terminal device goes to raw mode (no line editing, no "\n" → "\r\n"), as a serial link
/// to a controller must be; the baud rate is left as the system set it (`stty`, udev). Any
/// other character device (a FIFO, a file for a dry run) is written as it is.
fn raw_mode(dev: &File) -> std::io::Result<()> {
    use std::os::fd::AsRawFd;
    let fd = dev.as_raw_fd();
    // SAFETY: `fd` is open for the lifetime of `dev`; `termios` is plain data that tcgetattr
    // fills before it is read.
    unsafe {
        if libc::isatty(fd) != 1 {
            return Ok(());
        }
        let mut t: libc::termios = std::mem::zeroed();
        if libc::tcgetattr(fd, &mut t) != 0 {
            return Err(std::io::Error::last_os_error());
        }
        libc::cfmakeraw(&mut t);
        if libc::tcsetattr(fd, libc::TCSANOW, &t) != 0 {
            return Err(std::io::Error::last_os_error());
        }
    }
    Ok(())
}

/// [`Drive`] over a serial character device.
pub struct SerialLineDrive {
    path: PathBuf,
    name: String,
    dev: File,
    buf: [u8; LINE_MAX],
    /// Lines written whole.
    sent: u64,
}

impl SerialLineDrive {
    /// Opens `path` for writing, non-blocking, without making it the controlling terminal.
    pub fn open(path: impl AsRef<Path>) -> Result<Self, DriveError> {
        let path = path.as_ref().to_path_buf();
        let name = format!("serial {}", path.display());
        let dev = std::fs::OpenOptions::new()
            .write(true)
            .custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY)
            .open(&path)
            .map_err(|e| DriveError {
                drive: name.clone(),
                message: format!("cannot open: {e}"),
            })?;
        raw_mode(&dev).map_err(|e| DriveError {
            drive: name.clone(),
            message: format!("cannot set raw mode: {e}"),
        })?;
        Ok(Self {
            path,
            name,
            dev,
            buf: [0; LINE_MAX],
            sent: 0,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Setpoint lines written so far.
    pub fn sent(&self) -> u64 {
        self.sent
    }

    fn line(&mut self, len: usize) -> Result<(), DriveError> {
        match self.dev.write(&self.buf[..len]) {
            Ok(n) if n == len => Ok(()),
            Ok(n) => Err(self.err(format!(
                "the device took {n} of {len} bytes: is the controller reading?"
            ))),
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                Err(self.err("the device's buffer is full: is the controller reading?"))
            }
            Err(e) => Err(self.err(format!("write: {e}"))),
        }
    }

    fn err(&self, message: impl Into<String>) -> DriveError {
        DriveError {
            drive: self.name.clone(),
            message: message.into(),
        }
    }

    fn control(&mut self, c: u8) -> Result<(), DriveError> {
        self.buf[0] = c;
        self.buf[1] = b'\n';
        self.line(2)
    }
}

impl Drive for SerialLineDrive {
    fn name(&self) -> &str {
        &self.name
    }

    fn activate(&mut self) -> Result<(), DriveError> {
        self.control(b'E')
    }

    fn write(&mut self, cmd: &MotorCommand) -> Result<(), DriveError> {
        let len = format_line(cmd, &mut self.buf).map_err(|e| DriveError {
            drive: self.name.clone(),
            message: format!("format: {e}"),
        })?;
        self.line(len)?;
        self.sent += 1;
        Ok(())
    }

    fn deactivate(&mut self) -> Result<(), DriveError> {
        self.control(b'H')
    }
}
