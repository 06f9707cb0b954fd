//! Thin, allocation-free wrappers over the Linux calls the scheduler needs: the monotonic clock,
//! absolute-deadline sleep, termination signals and an epoll reactor with an absolute timer.

use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};
use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};

/// CLOCK_MONOTONIC in nanoseconds: the time base of every `t_origin_ns` in real-time mode (the
/// same clock in every process of the machine).
#[inline]
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: valid out pointer; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

fn timespec_of(t_ns: u64) -> libc::timespec {
    libc::timespec {
        tv_sec: (t_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (t_ns % 1_000_000_000) as libc::c_long,
    }
}

/// Sleeps until the absolute monotonic time `t_ns` (clock_nanosleep, TIMER_ABSTIME: no drift
/// accumulates over cycles). Returns `false` if a signal interrupted the sleep.
pub fn sleep_until_ns(t_ns: u64) -> bool {
    let ts = timespec_of(t_ns);
    // SAFETY: valid timespec; remaining-time pointer unused with TIMER_ABSTIME.
    let rc = unsafe { libc::clock_nanosleep(libc::CLOCK_MONOTONIC, libc::TIMER_ABSTIME, &ts, core::ptr::null_mut()) };
    rc != libc::EINTR
}

static TERMINATE: AtomicBool = AtomicBool::new(false);
static LAST_SIGNAL: AtomicI32 = AtomicI32::new(0);
static SIGNAL_EVENTFD: AtomicI32 = AtomicI32::new(-1);

extern "C" fn on_termination_signal(sig: libc::c_int) {
    TERMINATE.store(true, Ordering::SeqCst);
    LAST_SIGNAL.store(sig, Ordering::SeqCst);
    let fd = SIGNAL_EVENTFD.load(Ordering::SeqCst);
    if fd >= 0 {
        let one: u64 = 1;
        // SAFETY: write(2) is async-signal-safe; an eventfd accepts 8-byte writes.
        unsafe { libc::write(fd, &one as *const u64 as *const libc::c_void, 8) };
    }
}

/// Installs SIGINT/SIGTERM handlers that set a flag and wake every [`Reactor`] of the process
/// (through an eventfd), and ignores SIGPIPE. Idempotent.
pub fn install_termination_handlers() -> io::Result<()> {
    if SIGNAL_EVENTFD.load(Ordering::SeqCst) < 0 {
        // SAFETY: plain syscall.
        let fd = unsafe { libc::eventfd(0, libc::EFD_NONBLOCK | libc::EFD_CLOEXEC) };
        if fd < 0 {
            return Err(io::Error::last_os_error());
        }
        if SIGNAL_EVENTFD
            .compare_exchange(-1, fd, Ordering::SeqCst, Ordering::SeqCst)
            .is_err()
        {
            // SAFETY: we own `fd` and lost the race: close it.
            unsafe { libc::close(fd) };
        }
    }
    for sig in [libc::SIGINT, libc::SIGTERM] {
        // SAFETY: a zeroed sigaction with a valid handler; no SA_RESTART, so blocking waits return EINTR.
        unsafe {
            let mut sa: libc::sigaction = core::mem::zeroed();
            sa.sa_sigaction = on_termination_signal as *const () as usize;
            libc::sigemptyset(&mut sa.sa_mask);
            sa.sa_flags = 0;
            if libc::sigaction(sig, &sa, core::ptr::null_mut()) != 0 {
                return Err(io::Error::last_os_error());
            }
        }
    }
    // SAFETY: ignoring SIGPIPE is always valid.
    unsafe { libc::signal(libc::SIGPIPE, libc::SIG_IGN) };
    Ok(())
}

/// A SIGINT/SIGTERM arrived (or [`request_termination`] was called).
#[inline]
pub fn termination_requested() -> bool {
    TERMINATE.load(Ordering::Relaxed)
}

/// The signal that requested termination (0 if none or programmatic).
pub fn termination_signal() -> i32 {
    LAST_SIGNAL.load(Ordering::Relaxed)
}

/// Requests termination from inside the process (same effect as SIGTERM).
pub fn request_termination() {
    on_termination_signal(0);
}

fn cvt(rc: libc::c_int) -> io::Result<libc::c_int> {
    if rc < 0 {
        Err(io::Error::last_os_error())
    } else {
        Ok(rc)
    }
}

/// A non-blocking eventfd another thread (or a library's callback) signals to wake a stage's
/// event-driven process: [`crate::stage::Stage::wake_fd`] hands its fd to the process's
/// [`Reactor`]. `signal` and `drain` allocate nothing and never block.
pub struct EventFd(OwnedFd);

impl EventFd {
    pub fn new() -> io::Result<Self> {
        // SAFETY: plain syscall; the fd is owned right away.
        let fd = cvt(unsafe { libc::eventfd(0, libc::EFD_NONBLOCK | libc::EFD_CLOEXEC) })?;
        Ok(Self(unsafe { OwnedFd::from_raw_fd(fd) }))
    }

    /// Makes the fd readable (adds 1 to its counter). Safe to call from any thread.
    pub fn signal(&self) {
        let one: u64 = 1;
        // SAFETY: writing 8 bytes from a valid u64 to our eventfd; a full counter (EAGAIN)
        // already means "readable", so the result does not matter.
        unsafe { libc::write(self.0.as_raw_fd(), &one as *const u64 as *const libc::c_void, 8) };
    }

    /// Resets the counter; returns how many signals it held (0 if none).
    pub fn drain(&self) -> u64 {
        let mut v: u64 = 0;
        // SAFETY: reading the 8-byte counter of a non-blocking eventfd into a valid u64.
        let n = unsafe { libc::read(self.0.as_raw_fd(), &mut v as *mut u64 as *mut libc::c_void, 8) };
        if n == 8 {
            v
        } else {
            0
        }
    }

    pub fn fd(&self) -> RawFd {
        self.0.as_raw_fd()
    }
}

/// What woke a [`Reactor::wait`].
#[derive(Debug, Clone, Copy, Default)]
pub struct Wake {
    /// Bit i set: the fd registered with token i is readable.
    pub ready_mask: u64,
    /// The absolute deadline armed with [`Reactor::wait`] has passed.
    pub timer: bool,
    /// Termination was requested.
    pub terminate: bool,
}

const TOKEN_TIMER: u64 = 62;
const TOKEN_SIGNAL: u64 = 63;

/// epoll over listener file descriptors, a timerfd armed at absolute deadlines, and the
/// termination eventfd. Waiting allocates nothing.
pub struct Reactor {
    epoll: OwnedFd,
    timer: OwnedFd,
    tokens: u32,
}

impl Reactor {
    pub fn new() -> io::Result<Self> {
        // SAFETY: plain syscalls; the fds are owned right away.
        let epoll = unsafe { OwnedFd::from_raw_fd(cvt(libc::epoll_create1(libc::EPOLL_CLOEXEC))?) };
        let timer = unsafe {
            OwnedFd::from_raw_fd(cvt(libc::timerfd_create(
                libc::CLOCK_MONOTONIC,
                libc::TFD_NONBLOCK | libc::TFD_CLOEXEC,
            ))?)
        };
        let r = Self {
            epoll,
            timer,
            tokens: 0,
        };
        r.register(r.timer.as_raw_fd(), TOKEN_TIMER)?;
        let sig = SIGNAL_EVENTFD.load(Ordering::SeqCst);
        if sig >= 0 {
            r.register(sig, TOKEN_SIGNAL)?;
        }
        Ok(r)
    }

    fn register(&self, fd: RawFd, token: u64) -> io::Result<()> {
        let mut ev = libc::epoll_event {
            events: libc::EPOLLIN as u32,
            u64: token,
        };
        // SAFETY: valid epoll fd and event pointer.
        cvt(unsafe { libc::epoll_ctl(self.epoll.as_raw_fd(), libc::EPOLL_CTL_ADD, fd, &mut ev) })?;
        Ok(())
    }

    /// Watches `fd` for readability; returns its token (bit index in [`Wake::ready_mask`]).
    pub fn add(&mut self, fd: RawFd) -> io::Result<u32> {
        if self.tokens >= 60 {
            return Err(io::Error::other("reactor: more than 60 file descriptors"));
        }
        let token = self.tokens;
        self.register(fd, token as u64)?;
        self.tokens += 1;
        Ok(token)
    }

    /// Blocks until a registered fd is readable, `deadline_ns` (absolute, monotonic) passes, or
    /// termination is requested. `None` waits without a deadline.
    pub fn wait(&self, deadline_ns: Option<u64>) -> io::Result<Wake> {
        let mut wake = Wake::default();
        if termination_requested() {
            wake.terminate = true;
            return Ok(wake);
        }
        let spec = libc::itimerspec {
            it_interval: timespec_of(0),
            // A zero it_value disarms; deadline 0 would disarm, so use 1 ns (already past).
            it_value: timespec_of(deadline_ns.map(|d| d.max(1)).unwrap_or(0)),
        };
        // SAFETY: valid timerfd and spec.
        cvt(unsafe {
            libc::timerfd_settime(
                self.timer.as_raw_fd(),
                libc::TFD_TIMER_ABSTIME,
                &spec,
                core::ptr::null_mut(),
            )
        })?;
        let mut events = [libc::epoll_event { events: 0, u64: 0 }; 16];
        // SAFETY: valid epoll fd and buffer.
        let n = unsafe { libc::epoll_wait(self.epoll.as_raw_fd(), events.as_mut_ptr(), events.len() as i32, -1) };
        if n < 0 {
            let e = io::Error::last_os_error();
            if e.kind() == io::ErrorKind::Interrupted {
                wake.terminate = termination_requested();
                return Ok(wake);
            }
            return Err(e);
        }
        for ev in &events[..n as usize] {
            match ev.u64 {
                TOKEN_TIMER => {
                    let mut buf = 0u64;
                    // SAFETY: draining the 8-byte expiry counter of a non-blocking timerfd.
                    unsafe { libc::read(self.timer.as_raw_fd(), &mut buf as *mut u64 as *mut libc::c_void, 8) };
                    wake.timer = true;
                }
                TOKEN_SIGNAL => wake.terminate = true,
                t => wake.ready_mask |= 1 << t,
            }
        }
        if let Some(d) = deadline_ns {
            if !wake.timer && monotonic_ns() >= d {
                wake.timer = true;
            }
        }
        wake.terminate |= termination_requested();
        Ok(wake)
    }
}
