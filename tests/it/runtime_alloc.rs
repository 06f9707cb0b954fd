//! The control cycle allocates nothing from the system allocator. This test binary installs its
//! own counting global allocator (`RtAlloc`, per-thread counters, iceoryx2's per-loan `Rc` served
//! from a pre-faulted pool) and checks:
//! 1. in process: one cycle of the real components over the real ports — trajectory target →
//!    compensator (Algorithm 1 on the shipped fixture models) → actuator (with its robot-state
//!    monitor reading the plant state back) → plant, with event
//!    wake-ups, the reactor, status samples and latency histograms — after a warm-up makes zero
//!    system allocations, and exactly one pool block per published sample;
//! 2. in real processes: every node of the real-time control chain and of the lockstep sim
//!    pipeline reports zero system allocations per cycle after its warm-up (the executor audits
//!    its own loop with the same counters);
//! 3. the same with the compensator's vision feedback on (it reads the estimator's
//!    `JointEstimate` stream every cycle and updates its correction from it).

use crate::runtime_support;

use bowden_actuator::{Actuator, ActuatorConfig};
use bowden_compensator::{Compensator, ControllerConfig, Mode, StepOutput};
use bowden_interfaces::{
    services, ComponentStatus, JointCommand, JointTarget, MotorCommand, PlantState, SafetyCommand,
};
use bowden_kinematics::Robot;
use bowden_plant::{Plant, PlantConfig};
use bowden_runtime::alloc::{self, RtAlloc};
use bowden_runtime::ports::PortContext;
use bowden_runtime::stats::LatencyHistogram;
use bowden_runtime::sys::{monotonic_ns, Reactor};
use runtime_support::*;

#[global_allocator]
static ALLOC: RtAlloc = RtAlloc;

#[test]
fn in_process_cycle_makes_no_system_allocation() {
    alloc::enable_pool();
    let (p, _guard_p) = guarded_prefix("alloc");
    let robot = Robot::paper_default();
    {
        let ctx = PortContext::new("cycle", &settings(&p)).unwrap();
        let mut target_out = ctx.output::<JointTarget>(services::JOINT_TARGET).unwrap();
        let target_wake = ctx.notifier(services::JOINT_TARGET).unwrap();
        let mut target_in = ctx.input::<JointTarget>(services::JOINT_TARGET, 4).unwrap();
        let target_wait = ctx.listener(services::JOINT_TARGET).unwrap();
        let mut cmd_out = ctx.output::<JointCommand>(services::JOINT_COMMAND).unwrap();
        let mut cmd_in = ctx.input::<JointCommand>(services::JOINT_COMMAND, 4).unwrap();
        let mut safety_in = ctx.input::<SafetyCommand>(services::SAFETY, 8).unwrap();
        let mut motor_out = ctx.output::<MotorCommand>(services::MOTOR_COMMAND).unwrap();
        let mut motor_in = ctx.input::<MotorCommand>(services::MOTOR_COMMAND, 4).unwrap();
        let mut state_out = ctx.output::<PlantState>(services::PLANT_STATE).unwrap();
        let mut state_in = ctx.input::<PlantState>(services::PLANT_STATE, 64).unwrap();
        let mut status_out = ctx.output::<ComponentStatus>(services::COMPONENT_STATUS).unwrap();
        let mut reactor = Reactor::new().unwrap();
        reactor.add(target_wait.fd()).unwrap();

        let mut cfg = ControllerConfig::shipped();
        cfg.mode = Mode::Paper;
        let mut comp = Compensator::from_config(&cfg, &robot).expect("shipped fixture models load");
        comp.set_budget_ns(0);
        let mut step_out = StepOutput::default();
        let mut act = Actuator::new(&robot, &ActuatorConfig::default(), "test").unwrap();
        // The robot-state monitor (a fault-hold check of every state) is part of the cycle.
        act.monitor_robot_state(1_000_000, "test").unwrap();
        let mut plant = Plant::new(&robot, &PlantConfig::paper_default(), 1);
        let mut hist = LatencyHistogram::new();
        let commands = bowden_trajectory::dataset_commands(&robot, 6, 1);

        let mut publishes = 0u64;
        let mut before = alloc::thread_counts();
        let warmup = 200;
        for k in 0..2000u64 {
            if k == warmup {
                before = alloc::thread_counts();
                publishes = 0;
            }
            let t0 = monotonic_ns();
            // trajectory
            let mut t = JointTarget {
                n_joints: 5,
                ..Default::default()
            };
            t.q_desired_deg[..5].copy_from_slice(&commands[(k / 50) as usize % commands.len()]);
            target_out.publish(k, t0, t).unwrap();
            target_wake.notify().unwrap();
            publishes += 1;
            // compensator, woken through the reactor
            let wake = reactor.wait(Some(t0 + 100_000_000)).unwrap();
            assert_ne!(wake.ready_mask, 0);
            target_wait.drain();
            let target = target_in.latest().expect("target");
            comp.step(&target.q_desired_deg[..5], &mut step_out).unwrap();
            let mut c = JointCommand::default();
            step_out.fill_joint_command(&mut c);
            cmd_out.publish(k, target.header.t_origin_ns, c).unwrap();
            publishes += 1;
            // actuator
            while let Some(s) = safety_in.recv() {
                act.safety(&s, t0);
            }
            while let Some(s) = state_in.recv() {
                assert!(act.observe_robot(&s).is_none(), "tick {k}: a healthy plant");
            }
            assert!(act.supervise(k * 1_000_000).is_none());
            let c = cmd_in.take_tick(k).expect("command");
            let r = act.command(&c.q_cmd_deg, c.n_joints, k * 1_000_000);
            motor_out
                .publish(k, c.header.t_origin_ns, r.output.to_motor_command())
                .unwrap();
            publishes += 1;
            let _ = act.idle(k * 1_000_000);
            // plant
            let m = motor_in.latest().expect("motor command");
            let w: [f64; 10] = core::array::from_fn(|i| m.cable_disp_mm[i]);
            plant.step(&w, 0.001).unwrap();
            let mut s = PlantState::default();
            plant.fill_state(&mut s);
            state_out.publish(k, k * 1_000_000, s).unwrap();
            publishes += 1;
            // bookkeeping
            hist.record(monotonic_ns() - t0);
            if k % 100 == 0 {
                let p = hist.percentiles();
                let mut st = ComponentStatus {
                    latency_p99_ns: p.p99_ns,
                    ..Default::default()
                };
                st.set_name("cycle");
                status_out.publish(k, t0, st).unwrap();
                publishes += 1;
            }
        }
        let d = alloc::thread_counts().since(&before);
        assert_eq!(d.system_allocs, 0, "system allocations in 1800 cycles: {d:?}");
        assert_eq!(
            d.pool_allocs, publishes,
            "one pool block (iceoryx2's Rc) per published sample: {d:?}"
        );
        assert_eq!(d.pool_frees, d.pool_allocs, "and it is returned at send");
        assert!(hist.count() == 2000);
    }
    bowden_runtime::cleanup::remove_prefix_files(&settings(&p)).unwrap();
    assert_clean(&p);
}

/// `(process, system allocations, measured cycles)` from the executors' exit summaries.
fn audits(stderr: &str) -> Vec<(String, u64, u64)> {
    let mut out = Vec::new();
    let mut current = None;
    for line in stderr.lines() {
        if let Some(rest) = line.strip_prefix('[') {
            if let Some((name, tail)) = rest.split_once(']') {
                if tail.starts_with(" exit summary") {
                    current = Some(name.to_string());
                }
            }
        }
        if let Some(rest) = line
            .trim()
            .strip_prefix("allocations after 100 warm-up cycles: system ")
        {
            let mut it = rest.split_whitespace();
            let sys: u64 = it.next().unwrap().parse().unwrap();
            let cycles: u64 = it.nth(1).unwrap().parse().unwrap();
            out.push((current.clone().expect("inside a summary"), sys, cycles));
        }
    }
    out
}

#[test]
fn node_processes_audit_zero_system_allocations() {
    // Real time: the control chain at 1 kHz.
    let (p, _guard_p) = guarded_prefix("aud");
    let cycle = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/cycle.toml");
    let out = run_ok(&["run", cycle.to_str().unwrap(), "--seconds", "1.5", "--prefix", &p]);
    let a = audits(&String::from_utf8_lossy(&out.stderr));
    for node in ["trajectory", "compensator", "actuator", "plant"] {
        let (_, sys, cycles) = a
            .iter()
            .find(|(n, ..)| n == node)
            .unwrap_or_else(|| panic!("no audit of {node}: {a:?}"));
        assert!(*cycles > 500, "{node}: {cycles} cycles measured");
        assert_eq!(*sys, 0, "{node} allocated in its real-time cycle");
    }
    assert_clean(&p);

    // Lockstep: every stage of the sim pipeline, camera and estimator included.
    let (q, _guard_q) = guarded_prefix("audl");
    let sim = sim_toml();
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("a.blog");
    let out = run_ok(&[
        "run",
        sim.to_str().unwrap(),
        "--mode",
        "lockstep",
        "--ticks",
        "400",
        "--prefix",
        &q,
        "--record",
        log.to_str().unwrap(),
    ]);
    let a = audits(&String::from_utf8_lossy(&out.stderr));
    assert_eq!(a.len(), 7, "{a:?}");
    for (node, sys, cycles) in &a {
        assert_eq!(*cycles, 300, "{node}");
        assert_eq!(*sys, 0, "{node} allocated in its lockstep cycle");
    }
    assert_clean(&q);
}

#[test]
fn feedback_node_audits_zero_system_allocations() {
    let (q, _guard_q) = guarded_prefix("audf");
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let controller = root.join("configs/controller-feedback-realtime.toml");
    let sim = std::fs::read_to_string(sim_toml()).unwrap();
    let with_feedback = sim.replacen(
        "mode = \"uncalibrated\"",
        &format!("config = \"{}\"\nmode = \"newton\"", controller.display()),
        1,
    );
    assert_ne!(with_feedback, sim, "configs/sim.toml changed: update this test");
    let dir = tempfile::tempdir().unwrap();
    let file = write_config(dir.path(), "sim-feedback.toml", &with_feedback);
    let out = run_ok(&[
        "run",
        file.to_str().unwrap(),
        "--mode",
        "lockstep",
        "--ticks",
        "1500",
        "--prefix",
        &q,
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    let a = audits(&stderr);
    let (_, sys, cycles) = a
        .iter()
        .find(|(n, ..)| n == "compensator")
        .unwrap_or_else(|| panic!("no audit of the compensator: {a:?}"));
    assert_eq!(*cycles, 1400);
    assert_eq!(*sys, 0, "the compensator allocated in its feedback cycle");
    assert!(a.iter().all(|(_, sys, _)| *sys == 0), "{a:?}");
    // The feedback ran: estimates came in and corrected the command.
    let line = stderr
        .lines()
        .find(|l| l.trim_start().starts_with("feedback: apply target"))
        .unwrap_or_else(|| panic!("no feedback summary:\n{stderr}"));
    let updates: u64 = line
        .split(", ")
        .find_map(|f| f.strip_suffix(" updates"))
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{line}"));
    assert!(updates > 10, "{line}");
    assert_clean(&q);
}
