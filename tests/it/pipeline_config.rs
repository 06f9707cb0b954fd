//! Pipeline configs with the binary's node kinds (`bowden::registry`): the shipped ones load;
//! bad ones fail with the file and field named.

use bowden::registry::REGISTRY;
use bowden_runtime::config::{Activation, ConfigOrigin, Mode, Overrides, PipelineConfig};
use std::path::PathBuf;

fn parse(text: &str) -> Result<PipelineConfig, String> {
    PipelineConfig::parse(
        text,
        ConfigOrigin::File(PathBuf::from("test.toml")),
        PathBuf::from("."),
        &Overrides::default(),
        REGISTRY,
    )
    .map_err(|e| e.to_string())
}

const HEAD: &str = "[runtime]\nmode = \"lockstep\"\nperiod_us = 1000\n";
const RT_HEAD: &str = "[runtime]\nmode = \"realtime\"\nperiod_us = 1000\n";

#[test]
fn shipped_configs_load() {
    let sim = PipelineConfig::embedded_sim(&Overrides::default(), REGISTRY).expect("embedded sim.toml");
    assert_eq!(sim.mode(), Mode::Realtime);
    let names: Vec<&str> = sim.stages.iter().map(|s| s.name.as_str()).collect();
    assert!(
        names.starts_with(&["trajectory", "compensator", "actuator"]),
        "{names:?}"
    );
    // The recorder is off unless asked for.
    assert!(!names.contains(&"recorder"));
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("configs");
    for f in ["sim.toml", "cycle.toml"] {
        PipelineConfig::load(&root.join(f), &Overrides::default(), REGISTRY).unwrap_or_else(|e| panic!("{f}: {e}"));
    }
}

#[test]
fn overrides_apply() {
    let ov = Overrides {
        mode: Some(Mode::Lockstep),
        prefix: Some("zz_".into()),
        record_path: Some("x.blog".into()),
        ..Default::default()
    };
    let c = PipelineConfig::embedded_sim(&ov, REGISTRY).unwrap();
    assert!(c.lockstep());
    assert_eq!(c.ipc().prefix, "zz_");
    let rec = c.stage("recorder").expect("--record enables the recorder");
    assert_eq!(rec.params.get("path").and_then(|v| v.as_str()), Some("x.blog"));
    // The recorder waits for every producer of what it records.
    let i = c.stages.iter().position(|s| s.name == "recorder").unwrap();
    let ups: Vec<&str> = c.upstream_of(i).iter().map(|&u| c.stages[u].name.as_str()).collect();
    assert!(ups.contains(&"actuator") && ups.contains(&"trajectory"), "{ups:?}");
}

#[test]
fn activation_follows_kind() {
    let c = parse(&format!(
        "{HEAD}[[node]]\nname = \"trajectory\"\n[node.params]\nsource = \"dataset\"\nsamples = 3\n\
         [[node]]\nname = \"actuator\"\nwake_timeout_us = 300\n"
    ))
    .unwrap();
    assert!(matches!(
        c.processes[0].activation,
        Activation::Periodic {
            period_ns: 1_000_000,
            ..
        }
    ));
    assert_eq!(
        c.processes[1].activation,
        Activation::Event {
            timeout_ns: Some(300_000)
        }
    );
}

#[test]
fn grouped_stages_share_a_process_in_order() {
    let c = parse(&format!(
        "{HEAD}[[node]]\nname = \"trajectory\"\nprocess = \"control\"\n\
         [[node]]\nname = \"compensator\"\nprocess = \"control\"\n"
    ))
    .unwrap();
    assert_eq!(c.processes.len(), 1);
    assert_eq!(c.processes[0].stages, vec![0, 1]);
    let e = parse(&format!(
        "{HEAD}[[node]]\nname = \"compensator\"\nprocess = \"control\"\n\
         [[node]]\nname = \"trajectory\"\nprocess = \"control\"\n"
    ))
    .unwrap_err();
    assert!(
        e.contains("test.toml") && e.contains("compensator") && e.contains("first"),
        "{e}"
    );
}

#[test]
fn bad_configs_name_file_and_field() {
    let cases: Vec<(String, &str)> = vec![
        (format!("{HEAD}bogus = 1\n[[node]]\nname = \"plant\"\n"), "bogus"),
        ("[runtime]\nmode = \"fast\"\nperiod_us = 1000\n".to_string(), "mode"),
        ("[runtime]\nmode = \"lockstep\"\nperiod_us = 0\n[[node]]\nname = \"plant\"\n".to_string(), "runtime.period_us"),
        (format!("{HEAD}prefix = \"a b\"\n[[node]]\nname = \"plant\"\n"), "runtime.prefix"),
        (format!("{HEAD}[[node]]\nname = \"Plant!\"\n"), "name"),
        (format!("{HEAD}[[node]]\nname = \"robot\"\n"), "kind"),
        (format!("{HEAD}[[node]]\nname = \"plant\"\n[[node]]\nname = \"plant\"\n"), "duplicate"),
        (
            format!("{HEAD}[[node]]\nname = \"a\"\nkind = \"plant\"\n[[node]]\nname = \"b\"\nkind = \"plant\"\n"),
            "already produced",
        ),
        (
            format!("{HEAD}[[node]]\nname = \"x\"\nexec = [\"/bin/true\"]\ninputs = [\"bowden/nope\"]\noutputs = []\n"),
            "unknown service",
        ),
        (
            format!(
                "{HEAD}[[node]]\nname = \"a\"\nexec = [\"/bin/true\"]\ninputs = [\"bowden/plant_state\"]\noutputs = [\"bowden/motor_command\"]\n\
                 [[node]]\nname = \"plant\"\n"
            ),
            "cycle",
        ),
        (format!("{HEAD}[[node]]\nname = \"recorder\"\n[node.params]\npath = \"x\"\n"), "services"),
        (format!("{HEAD}[[node]]\nname = \"actuator\"\n[node.rt]\nsched_fifo = true\npriority = 0\n"), "rt.priority"),
        (format!("{HEAD}[[node]]\nname = \"plant\"\nenabled = false\n"), "no enabled"),
    ];
    for (text, needle) in cases {
        let e = parse(&text).expect_err(&text);
        assert!(e.contains("test.toml"), "no file in `{e}`");
        assert!(e.contains(needle), "`{needle}` not in `{e}`");
    }
}

#[test]
fn external_node_needs_its_services_unless_known_kind() {
    let c = parse(&format!(
        "{RT_HEAD}[[node]]\nname = \"motor-driver\"\nkind = \"plant\"\nexec = [\"/opt/driver\", \"--can0\"]\n"
    ))
    .unwrap();
    assert_eq!(
        c.processes[0].exec.as_deref(),
        Some(&["/opt/driver".to_string(), "--can0".to_string()][..])
    );
    assert!(!c.processes[0].reports_status);
    let e = parse(&format!("{RT_HEAD}[[node]]\nname = \"cam\"\nexec = [\"/opt/cam\"]\n")).unwrap_err();
    assert!(e.contains("inputs"), "{e}");
    // In lockstep an external node must speak the per-tick protocol.
    let lock = "[runtime]\nmode = \"lockstep\"\nperiod_us = 1000\n[[node]]\nname = \"plant\"\nexec = [\"/opt/d\"]\n";
    let e = parse(lock).unwrap_err();
    assert!(e.contains("reports_status"), "{e}");
    parse(&format!("{lock}reports_status = true\n")).unwrap();
}
