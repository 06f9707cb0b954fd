//! The node contract: a pipeline's dataflow, wake-up sets and schedule come from the kinds'
//! declared ports, and a port's read policy is resolved by the runtime for either mode. The
//! kinds here are made up for the test: the runtime knows none of bowden's.

use bowden_interfaces::{services as s, JointTarget, SafetyCommand};
use bowden_runtime::config::{Activation, ConfigOrigin, Mode, Overrides, PipelineConfig};
use bowden_runtime::node::{InputDecl, NodeKind, Read, Registry, Schedule};
use bowden_runtime::ports::{IpcSettings, PortContext};
use bowden_runtime::stage::{StageEnv, StepCx};
use std::path::PathBuf;

type Local = iceoryx2::service::local::Service;

const EVENT: Schedule = Schedule {
    periodic: false,
    period_us: None,
    wake_timeout_us: None,
    deadline_us: None,
};

fn not_built(env: &StageEnv<'_>) -> Result<Box<dyn bowden_runtime::Stage>, bowden_runtime::stage::StageBuildError> {
    Err(env.error("not built in this test"))
}

const SOURCE: NodeKind = NodeKind {
    kind: "source",
    summary: "targets",
    inputs: &[],
    outputs: &[s::JOINT_TARGET],
    schedule: Schedule {
        periodic: true,
        period_us: Some(2_000),
        wake_timeout_us: None,
        deadline_us: Some(100),
    },
    ports_from_params: None,
    lockstep_refusal: None,
    build: not_built,
};

/// Reads the targets of the tick and, as feedback, the estimates of earlier ticks.
const CTRL: NodeKind = NodeKind {
    kind: "ctrl",
    summary: "controller",
    inputs: &[
        InputDecl::new(s::JOINT_TARGET, Read::Tick, 4),
        InputDecl::new(s::JOINT_ESTIMATE, Read::Feedback, 8),
    ],
    outputs: &[s::JOINT_COMMAND],
    schedule: EVENT,
    ports_from_params: None,
    lockstep_refusal: None,
    build: not_built,
};

/// The same controller, but waiting for the estimate of the tick: a cycle.
const CTRL_WAITS: NodeKind = NodeKind {
    kind: "ctrl-waits",
    inputs: &[
        InputDecl::new(s::JOINT_TARGET, Read::Tick, 4),
        InputDecl::new(s::JOINT_ESTIMATE, Read::Tick, 8),
    ],
    ..CTRL
};

const SENSE: NodeKind = NodeKind {
    kind: "sense",
    summary: "sensor",
    inputs: &[
        InputDecl::new(s::JOINT_COMMAND, Read::Tick, 4),
        InputDecl::new(s::SAFETY, Read::Side, 8),
        InputDecl::new(s::JOINT_TARGET, Read::Hint, 8),
    ],
    outputs: &[s::JOINT_ESTIMATE],
    schedule: Schedule {
        wake_timeout_us: Some(7_000),
        ..EVENT
    },
    ports_from_params: None,
    lockstep_refusal: None,
    build: not_built,
};

const REMOTE: NodeKind = NodeKind {
    kind: "remote",
    summary: "two clocks",
    inputs: &[],
    outputs: &[],
    schedule: EVENT,
    ports_from_params: None,
    lockstep_refusal: Some("a remote node has a clock of its own"),
    build: not_built,
};

const KINDS: Registry = Registry(&[
    &SOURCE,
    &CTRL,
    &CTRL_WAITS,
    &SENSE,
    &REMOTE,
    &bowden_runtime::record::KIND,
]);

fn parse(text: &str) -> Result<PipelineConfig, String> {
    PipelineConfig::parse(
        text,
        ConfigOrigin::File(PathBuf::from("contract.toml")),
        PathBuf::from("."),
        &Overrides::default(),
        KINDS,
    )
    .map_err(|e| e.to_string())
}

const HEAD: &str = "[runtime]\nmode = \"lockstep\"\nperiod_us = 1000\n";

#[test]
fn dataflow_comes_from_the_declared_read_policies() {
    let c = parse(&format!(
        "{HEAD}[[node]]\nname = \"source\"\n[[node]]\nname = \"ctrl\"\n[[node]]\nname = \"sense\"\n"
    ))
    .expect("a feedback path from downstream is not a cycle");
    let ctrl = c.stage("ctrl").unwrap();
    assert_eq!(ctrl.inputs, vec![s::JOINT_TARGET]);
    assert_eq!(ctrl.passive_inputs, vec![s::JOINT_ESTIMATE]);
    let sense = c.stage("sense").unwrap();
    assert_eq!(sense.inputs, vec![s::JOINT_COMMAND]);
    assert_eq!(sense.side_inputs, vec![s::SAFETY]);
    assert_eq!(sense.passive_inputs, vec![s::JOINT_TARGET]);
    assert_eq!(sense.outputs, vec![s::JOINT_ESTIMATE]);
    // A lockstep tick waits only for Tick inputs' producers.
    let name = |v: Vec<usize>| -> Vec<String> { v.into_iter().map(|i| c.stages[i].name.clone()).collect() };
    assert_eq!(name(c.upstream_of(1)), vec!["source"]);
    assert_eq!(name(c.upstream_of(2)), vec!["ctrl"]);
    // The schedule defaults are the kinds'.
    assert_eq!(
        c.processes[0].activation,
        Activation::Periodic {
            period_ns: 2_000_000,
            phase_ns: 0
        }
    );
    assert_eq!(c.stages[0].deadline_ns, Some(100_000));
    assert_eq!(
        c.processes[2].activation,
        Activation::Event {
            timeout_ns: Some(7_000_000)
        }
    );
}

#[test]
fn waiting_for_a_downstream_sample_is_a_cycle() {
    let e = parse(&format!(
        "{HEAD}[[node]]\nname = \"source\"\n[[node]]\nname = \"ctrl-waits\"\n[[node]]\nname = \"sense\"\n"
    ))
    .unwrap_err();
    assert!(e.contains("contract.toml") && e.contains("cycle"), "{e}");
}

#[test]
fn unknown_kinds_and_lockstep_refusals_are_named() {
    let e = parse(&format!("{HEAD}[[node]]\nname = \"plant\"\n")).unwrap_err();
    assert!(
        e.contains("node[0] (plant).kind") && e.contains("unknown kind `plant`") && e.contains("source, ctrl"),
        "{e}"
    );
    let e = parse(&format!("{HEAD}[[node]]\nname = \"remote\"\n")).unwrap_err();
    assert!(e.contains("(remote).kind") && e.contains("a clock of its own"), "{e}");
    let rt = HEAD.replace("lockstep", "realtime");
    let c = parse(&format!("{rt}[[node]]\nname = \"remote\"\n")).unwrap();
    assert_eq!(c.mode(), Mode::Realtime);
    // The recorder, the runtime's own kind: its inputs are the services its parameters name.
    let c = parse(&format!(
        "{HEAD}[[node]]\nname = \"source\"\n[[node]]\nname = \"recorder\"\n[node.params]\npath = \"x\"\nservices = [\"bowden/joint_target\"]\n"
    ))
    .unwrap();
    assert_eq!(c.stage("recorder").unwrap().inputs, vec![s::JOINT_TARGET]);
}

fn target(tick: u64) -> JointTarget {
    let mut t = JointTarget::from_deg(&[tick as f64; 5]);
    t.header.tick = tick;
    t
}

/// The read policies, resolved by the runtime for each mode, on iceoryx2's process-local
/// service (nothing in /dev/shm).
#[test]
fn read_policies_resolve_per_mode() {
    let ipc = IpcSettings {
        prefix: "contract_".into(),
        namespace: String::new(),
    };
    let ctx = PortContext::<Local>::create("contract", &ipc).unwrap();
    let mut out = ctx.output::<JointTarget>(s::JOINT_TARGET).unwrap();
    let mut tick_in = ctx
        .input::<JointTarget>(s::JOINT_TARGET, 8)
        .unwrap()
        .with_read(Read::Tick);
    let mut fb_in = ctx
        .input::<JointTarget>(s::JOINT_TARGET, 8)
        .unwrap()
        .with_read(Read::Feedback);
    for k in [3, 4, 5] {
        out.publish_raw(target(k)).unwrap();
    }
    // Lockstep, tick 4: Tick reads the sample of tick 4 (3 skipped, 5 kept for its tick);
    // Feedback reads only the ticks before (3), in order.
    let cx4 = StepCx::lockstep(4, 4_000_000, 1_000_000);
    assert_eq!(tick_in.next(&cx4).map(|t| t.header.tick), Some(4));
    assert_eq!(tick_in.next(&cx4), None);
    assert_eq!(fb_in.next(&cx4).map(|t| t.header.tick), Some(3));
    assert_eq!(fb_in.next(&cx4), None, "tick 4 is not an earlier tick");
    let cx6 = StepCx::lockstep(6, 6_000_000, 1_000_000);
    assert_eq!(tick_in.next(&cx6), None, "5 passed without being read at its tick");
    assert_eq!(tick_in.stats().skipped, 2);
    assert_eq!(fb_in.next(&cx6).map(|t| t.header.tick), Some(4));
    assert_eq!(fb_in.next(&cx6).map(|t| t.header.tick), Some(5));
    // Real time: Tick reads the newest, Feedback every sample in arrival order.
    for k in [7, 8] {
        out.publish_raw(target(k)).unwrap();
    }
    let rt = StepCx::realtime(0, 1, 1_000_000, 1);
    assert_eq!(tick_in.next(&rt).map(|t| t.header.tick), Some(8));
    assert_eq!(fb_in.next(&rt).map(|t| t.header.tick), Some(7));
    assert_eq!(fb_in.next(&rt).map(|t| t.header.tick), Some(8));
    // Side: everything, in both modes.
    let mut safety_out = ctx.output::<SafetyCommand>(s::SAFETY).unwrap();
    let mut side = ctx.input::<SafetyCommand>(s::SAFETY, 8).unwrap().with_read(Read::Side);
    safety_out.publish(9, 0, SafetyCommand::default()).unwrap();
    safety_out.publish(2, 0, SafetyCommand::default()).unwrap();
    assert_eq!(side.next(&cx4).map(|c| c.header.tick), Some(9));
    assert_eq!(side.next(&cx4).map(|c| c.header.tick), Some(2));
}

#[test]
fn stamps_and_time_steps_resolve_per_mode() {
    let lock = StepCx::lockstep(10, 10_000_000, 1_000_000);
    assert!(lock.reproducible());
    assert_eq!(lock.out_tick(7), 10, "lockstep: every output of tick k belongs to k");
    assert_eq!(lock.clock_ns(), 10_000_000);
    assert_eq!(lock.time_step_ns(123_456_789, Some(1)), 1_000_000);
    let rt = StepCx::realtime(3, 50_000_000, 1_000_000, 50_000_000);
    assert!(!rt.reproducible());
    assert_eq!(rt.out_tick(7), 7, "real time: the input's tick is forwarded");
    assert_eq!(
        rt.time_step_ns(52_500_000, Some(50_000_000)),
        2_500_000,
        "the time that passed"
    );
    assert_eq!(
        rt.time_step_ns(52_500_000, None),
        1_000_000,
        "the period on the first step"
    );
    assert_eq!(rt.time_step_ns(5, Some(5)), 1, "never zero");
}

// The "write your own node" walk-through of docs/architecture.md, as a newcomer would type it:
// a kind, its declared ports, its step; built by the runtime from a pipeline file and stepped
// in both modes.
mod tip_logger {
    use bowden_interfaces::{services, JointEstimate};
    use bowden_runtime::node::{InputDecl, NodeKind, Read, Schedule};
    use bowden_runtime::ports::Input;
    use bowden_runtime::stage::{Stage, StageError, StepCx, StepReport};

    pub const KIND: NodeKind = NodeKind {
        kind: "tip-logger",
        summary: "prints the estimated joint angles once per second",
        inputs: &[InputDecl::new(services::JOINT_ESTIMATE, Read::Feedback, 64)],
        outputs: &[],
        schedule: Schedule {
            periodic: true,
            period_us: Some(1_000_000),
            wake_timeout_us: None,
            deadline_us: None,
        },
        ports_from_params: None,
        lockstep_refusal: None,
        build: |env| {
            Ok(Box::new(TipLogger {
                estimates: env.input(services::JOINT_ESTIMATE)?,
                seen: 0,
            }))
        },
    };

    pub struct TipLogger {
        estimates: Input<JointEstimate>,
        seen: u64,
    }

    impl Stage for TipLogger {
        fn step(&mut self, cx: &StepCx) -> Result<StepReport, StageError> {
            let mut last = None;
            while let Some(e) = self.estimates.next(cx) {
                last = Some(e);
                self.seen += 1;
            }
            if let Some(e) = last {
                println!("tick {}: q = {:?}", cx.tick(), &e.q_phy_deg[..e.n_joints as usize]);
            }
            Ok(StepReport::IDLE)
        }

        fn summary(&self) -> Vec<String> {
            vec![format!("tip-logger: {} estimates", self.seen)]
        }
    }
}

#[test]
fn a_new_kind_is_a_declaration_and_a_step() {
    use bowden_runtime::stage::StageEnv;
    const MINE: Registry = Registry(&[&SENSE, &tip_logger::KIND]);
    let prefix = format!("ctl{}_", std::process::id());
    let text = format!(
        "[runtime]\nmode = \"lockstep\"\nprefix = \"{prefix}\"\nperiod_us = 1000\n\
         [[node]]\nname = \"sense\"\n[[node]]\nname = \"tip-logger\"\n"
    );
    let cfg = PipelineConfig::parse(
        &text,
        ConfigOrigin::File(PathBuf::from("mine.toml")),
        PathBuf::from("."),
        &Overrides::default(),
        MINE,
    )
    .unwrap();
    let logger = cfg.stage("tip-logger").unwrap();
    assert_eq!(
        logger.passive_inputs,
        vec![s::JOINT_ESTIMATE],
        "feedback: not waited for"
    );
    assert!(matches!(
        cfg.processes[1].activation,
        Activation::Periodic {
            period_ns: 1_000_000_000,
            ..
        }
    ));
    {
        let ports = PortContext::new("tip-logger", &cfg.ipc()).unwrap();
        let mut stage = (tip_logger::KIND.build)(&StageEnv {
            spec: logger,
            kind: &tip_logger::KIND,
            pipeline: &cfg,
            ports: &ports,
        })
        .unwrap();
        let mut est = ports
            .output::<bowden_interfaces::JointEstimate>(s::JOINT_ESTIMATE)
            .unwrap();
        for k in 0..3 {
            est.publish(k, 0, bowden_interfaces::JointEstimate::default()).unwrap();
        }
        // Lockstep tick 2 reads the estimates of ticks 0 and 1; real time reads what is left.
        stage.step(&StepCx::lockstep(2, 2_000_000, 1_000_000)).unwrap();
        assert_eq!(stage.summary(), vec!["tip-logger: 2 estimates"]);
        stage.step(&StepCx::realtime(0, 1, 1_000_000, 1)).unwrap();
        assert_eq!(stage.summary(), vec!["tip-logger: 3 estimates"]);
        // An undeclared port is refused when the node is built.
        let undeclared = StageEnv {
            spec: logger,
            kind: &tip_logger::KIND,
            pipeline: &cfg,
            ports: &ports,
        }
        .input::<bowden_interfaces::PlantState>(s::PLANT_STATE)
        .err()
        .expect("undeclared");
        assert!(undeclared.to_string().contains("does not declare"), "{undeclared}");
    }
    bowden_runtime::cleanup::remove_prefix_files(&cfg.ipc()).unwrap();
    assert!(bowden_runtime::cleanup::prefix_files(&cfg.ipc()).is_empty());
}
