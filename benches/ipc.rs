//! One IPC hop over iceoryx2 shared memory: bowden's ports against the raw iceoryx2 API, same
//! run, same QoS, pong side in a second thread busy-polling (`bowden bench ipc` measures the
//! same with the pong side in a second process and prints percentiles). Plus the loop-back cost
//! of one publish + receive, and the actuator's per-command work.
//!
//! `cargo bench --bench ipc`

use bowden_actuator::{Actuator, ActuatorConfig};
use bowden_interfaces::{services, JointCommand};
use bowden_kinematics::Robot;
use bowden_runtime::alloc::RtAlloc;
use bowden_runtime::bench::{IpcVariant, Peer, PingPong};
use bowden_runtime::ports::{IpcSettings, PortContext};
use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;

#[global_allocator]
static ALLOC: RtAlloc = RtAlloc;

fn settings(tag: &str) -> IpcSettings {
    IpcSettings {
        prefix: format!("bwcrit{}{tag}_", std::process::id()),
        namespace: String::new(),
    }
}

fn cleanup(s: &IpcSettings) {
    let _ = bowden_runtime::cleanup::remove_stale_nodes(s);
    let _ = bowden_runtime::cleanup::remove_prefix_files(s);
}

fn round_trips(c: &mut Criterion) {
    bowden_runtime::alloc::enable_pool();
    let mut g = c.benchmark_group("ipc_round_trip");
    for (i, v) in [
        IpcVariant::RawSample,
        IpcVariant::PortsSample,
        IpcVariant::RawFrameSmall,
        IpcVariant::PortsFrameSmall,
        IpcVariant::RawFrameVga,
        IpcVariant::PortsFrameVga,
    ]
    .into_iter()
    .enumerate()
    {
        let s = settings(&format!("rt{i}"));
        let mut pp = PingPong::start(v, &s.prefix, &Peer::Thread, 0, 0, None).expect("ping-pong starts");
        g.bench_function(v.as_str(), |b| {
            b.iter(|| black_box(pp.round_trip().expect("round trip")))
        });
        pp.finish().expect("peer stops");
        cleanup(&s);
    }
    g.finish();
}

fn loopback(c: &mut Criterion) {
    bowden_runtime::alloc::enable_pool();
    let s = settings("lb");
    {
        let ctx = PortContext::new("lb", &s).unwrap();
        let mut out = ctx.output::<JointCommand>(services::JOINT_COMMAND).unwrap();
        let mut inp = ctx.input::<JointCommand>(services::JOINT_COMMAND, 4).unwrap();
        let wake = ctx.notifier(services::JOINT_COMMAND).unwrap();
        let wait = ctx.listener(services::JOINT_COMMAND).unwrap();
        let mut g = c.benchmark_group("ipc_loopback");
        let mut k = 0u64;
        g.bench_function("publish+receive 240 B", |b| {
            b.iter(|| {
                k += 1;
                out.publish(k, k, JointCommand::default()).unwrap();
                black_box(inp.recv().unwrap())
            })
        });
        // iceoryx2's per-loan Rc from the system allocator instead of the pool.
        bowden_runtime::alloc::disable_pool();
        g.bench_function("publish+receive 240 B, Rc from malloc", |b| {
            b.iter(|| {
                k += 1;
                out.publish(k, k, JointCommand::default()).unwrap();
                black_box(inp.recv().unwrap())
            })
        });
        bowden_runtime::alloc::enable_pool();
        g.bench_function("publish+notify+drain+receive 240 B", |b| {
            b.iter(|| {
                k += 1;
                out.publish(k, k, JointCommand::default()).unwrap();
                wake.notify().unwrap();
                wait.drain();
                black_box(inp.recv().unwrap())
            })
        });
        g.finish();
    }
    cleanup(&s);
}

fn actuator(c: &mut Criterion) {
    let robot = Robot::paper_default();
    let mut a = Actuator::new(&robot, &ActuatorConfig::default(), "bench").unwrap();
    let mut t = 0u64;
    let q = [12.0, -8.0, 15.0, -5.0, 9.0];
    c.bench_function("actuator_command_to_cables", |b| {
        b.iter(|| {
            t += 1_000_000;
            black_box(a.command(black_box(&q), 5, t).output.to_motor_command())
        })
    });
}

criterion_group!(benches, round_trips, loopback, actuator);
criterion_main!(benches);
