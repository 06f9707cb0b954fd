//! Real-time setup of a process: SCHED_FIFO priority (thread-priority), CPU affinity and locked
//! memory (libc). Each step that the OS refuses (EPERM in a container, no CAP_SYS_NICE, RT
//! throttling) is reported with a clear warning and the process runs on without it, as
//! ros2_control and dora do; [`RtReport`] says exactly what was obtained.

use serde::{Deserialize, Serialize};
use std::fmt;

/// Real-time placement of a process (config `[rt]` and `[node.rt]`).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RtSettings {
    /// Request SCHED_FIFO for the cycle thread.
    #[serde(default)]
    pub sched_fifo: bool,
    /// SCHED_FIFO priority, 1..=99.
    #[serde(default = "default_priority")]
    pub priority: u8,
    /// CPUs the process may run on (empty: no pinning).
    #[serde(default)]
    pub cpus: Vec<usize>,
    /// mlockall(MCL_CURRENT | MCL_FUTURE): no page faults on the cycle path.
    #[serde(default)]
    pub lock_memory: bool,
}

fn default_priority() -> u8 {
    80
}

impl Default for RtSettings {
    fn default() -> Self {
        Self {
            sched_fifo: false,
            priority: default_priority(),
            cpus: Vec::new(),
            lock_memory: false,
        }
    }
}

/// Outcome of one setup step.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    NotRequested,
    Applied,
    /// Refused by the OS; the message says why (errno text).
    Refused(String),
}

impl fmt::Display for Outcome {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Outcome::NotRequested => write!(f, "not requested"),
            Outcome::Applied => write!(f, "ok"),
            Outcome::Refused(why) => write!(f, "REFUSED ({why})"),
        }
    }
}

/// What [`apply`] obtained.
#[derive(Debug, Clone, PartialEq)]
pub struct RtReport {
    pub sched_fifo: Outcome,
    pub priority: u8,
    pub affinity: Outcome,
    pub cpus: Vec<usize>,
    pub lock_memory: Outcome,
}

impl RtReport {
    /// Every requested step succeeded.
    pub fn fully_applied(&self) -> bool {
        ![&self.sched_fifo, &self.affinity, &self.lock_memory]
            .iter()
            .any(|o| matches!(o, Outcome::Refused(_)))
    }

    /// One-line warnings for the refused steps.
    pub fn warnings(&self) -> Vec<String> {
        let mut w = Vec::new();
        if let Outcome::Refused(why) = &self.sched_fifo {
            w.push(format!(
                "SCHED_FIFO priority {} refused ({why}): running with the normal scheduler, expect larger jitter",
                self.priority
            ));
        }
        if let Outcome::Refused(why) = &self.affinity {
            w.push(format!(
                "CPU affinity {:?} refused ({why}): running on any CPU",
                self.cpus
            ));
        }
        if let Outcome::Refused(why) = &self.lock_memory {
            w.push(format!("mlockall refused ({why}): pages may fault in the cycle"));
        }
        w
    }
}

impl fmt::Display for RtReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "SCHED_FIFO(prio {}): {}, affinity {:?}: {}, mlockall: {}",
            self.priority, self.sched_fifo, self.cpus, self.affinity, self.lock_memory
        )
    }
}

fn errno_text() -> String {
    std::io::Error::last_os_error().to_string()
}

/// Locks current and future pages in RAM.
pub fn lock_memory() -> Outcome {
    // SAFETY: plain syscall.
    if unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) } == 0 {
        Outcome::Applied
    } else {
        Outcome::Refused(errno_text())
    }
}

/// Pins the calling thread to `cpus`.
pub fn pin_to_cpus(cpus: &[usize]) -> Outcome {
    if cpus.is_empty() {
        return Outcome::NotRequested;
    }
    // SAFETY: a zeroed cpu_set_t is the empty set; CPU_SET bounds are checked below.
    unsafe {
        let mut set: libc::cpu_set_t = core::mem::zeroed();
        for &c in cpus {
            if c >= libc::CPU_SETSIZE as usize {
                return Outcome::Refused(format!("cpu {c} out of range"));
            }
            libc::CPU_SET(c, &mut set);
        }
        if libc::sched_setaffinity(0, core::mem::size_of::<libc::cpu_set_t>(), &set) == 0 {
            Outcome::Applied
        } else {
            Outcome::Refused(errno_text())
        }
    }
}

/// Puts the calling thread under SCHED_FIFO at `priority`.
pub fn set_fifo(priority: u8) -> Outcome {
    use thread_priority::unix::{
        set_thread_priority_and_policy, thread_native_id, RealtimeThreadSchedulePolicy, ThreadSchedulePolicy,
    };
    use thread_priority::{ThreadPriority, ThreadPriorityValue};
    let value = match ThreadPriorityValue::try_from(priority) {
        Ok(v) => v,
        Err(e) => return Outcome::Refused(format!("priority {priority}: {e}")),
    };
    match set_thread_priority_and_policy(
        thread_native_id(),
        ThreadPriority::Crossplatform(value),
        ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo),
    ) {
        Ok(()) => Outcome::Applied,
        Err(thread_priority::Error::OS(code)) => Outcome::Refused(std::io::Error::from_raw_os_error(code).to_string()),
        Err(e) => Outcome::Refused(format!("{e:?}")),
    }
}

/// Whether the calling thread currently runs under SCHED_FIFO.
pub fn is_fifo() -> bool {
    // SAFETY: plain syscall on the calling thread.
    unsafe { libc::sched_getscheduler(0) == libc::SCHED_FIFO }
}

/// Applies `s` to the calling thread/process: memory lock first (so later pages are resident),
/// then affinity, then priority. Never fails: refusals are in the report.
pub fn apply(s: &RtSettings) -> RtReport {
    // Absolute-deadline sleeps should end at the deadline, not up to 50 µs later (the default
    // timer slack of a normal thread).
    // SAFETY: plain prctl on the calling thread.
    unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong, 0, 0, 0) };
    let lock_memory = if s.lock_memory {
        self::lock_memory()
    } else {
        Outcome::NotRequested
    };
    let affinity = pin_to_cpus(&s.cpus);
    let sched_fifo = if s.sched_fifo {
        set_fifo(s.priority)
    } else {
        Outcome::NotRequested
    };
    RtReport {
        sched_fifo,
        priority: s.priority,
        affinity,
        cpus: s.cpus.clone(),
        lock_memory,
    }
}
