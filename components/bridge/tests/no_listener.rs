//! A bridge that only dials its peer opens no listening socket (its own test binary, so no
//! other test's listener shares the process).

use bowden_bridge::BridgeStage;
use bowden_runtime::config::ConfigOrigin;
use bowden_runtime::ports::PortContext;
use bowden_runtime::stage::{Stage, StageEnv};
use bowden_runtime::{Overrides, PipelineConfig};
use std::collections::BTreeSet;

/// Inodes of this process's sockets.
fn own_socket_inodes() -> BTreeSet<u64> {
    std::fs::read_dir("/proc/self/fd")
        .unwrap()
        .filter_map(|e| std::fs::read_link(e.ok()?.path()).ok())
        .filter_map(|l| {
            let s = l.to_string_lossy().to_string();
            s.strip_prefix("socket:[")?.strip_suffix(']')?.parse().ok()
        })
        .collect()
}

/// Local addresses of this process's TCP sockets in state LISTEN.
fn own_listeners() -> Vec<String> {
    let own = own_socket_inodes();
    let mut v = Vec::new();
    for f in ["/proc/self/net/tcp", "/proc/self/net/tcp6"] {
        let Ok(text) = std::fs::read_to_string(f) else { continue };
        for line in text.lines().skip(1) {
            let cols: Vec<&str> = line.split_whitespace().collect();
            if cols.len() > 9 && cols[3] == "0A" && cols[9].parse().is_ok_and(|i: u64| own.contains(&i)) {
                v.push(format!("{f}: {}", cols[1]));
            }
        }
    }
    v
}

/// The bridge stage of `cfg`, given 300 ms to open whatever it opens.
fn build(cfg: &PipelineConfig, ports: &PortContext) -> BridgeStage {
    let s = BridgeStage::from_env(&StageEnv {
        spec: &cfg.stages[0],
        kind: &bowden_bridge::KIND,
        pipeline: cfg,
        ports,
    })
    .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(300));
    s
}

#[test]
fn a_dialling_bridge_listens_nowhere_and_a_listening_one_only_where_told() {
    let p = format!("bwt{}zL_", std::process::id());
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let mk = |params: String| {
        let text = format!(
            "[runtime]\nmode = \"realtime\"\nprefix = \"{p}\"\nperiod_us = 1000\n\n[[node]]\nname = \"bridge\"\n\
             [node.params]\n{params}\n"
        );
        PipelineConfig::parse(
            &text,
            ConfigOrigin::File("t.toml".into()),
            ".".into(),
            &Overrides::default(),
            bowden_runtime::node::Registry(&[&bowden_bridge::KIND]),
        )
        .unwrap()
    };
    let before = own_listeners();
    assert!(before.is_empty(), "{before:?}");
    {
        let cfg = mk(format!(
            "connect = [\"tcp/127.0.0.1:{port}\"]\nexport = [\"bowden/plant_state\"]"
        ));
        let ports = PortContext::new("bridge", &cfg.ipc()).unwrap();
        let mut s = build(&cfg, &ports);
        assert_eq!(
            own_listeners(),
            Vec::<String>::new(),
            "a dialling bridge opened a listener"
        );
        s.finish().unwrap();
    }
    {
        let cfg = mk(format!(
            "listen = [\"tcp/127.0.0.1:{port}\"]\nimport = [\"bowden/plant_state\"]"
        ));
        let ports = PortContext::new("bridge", &cfg.ipc()).unwrap();
        let mut s = build(&cfg, &ports);
        let l = own_listeners();
        assert_eq!(l.len(), 1, "exactly the configured listener: {l:?}");
        assert!(l[0].ends_with(&format!(":{port:04X}")), "{l:?}");
        s.finish().unwrap();
    }
    let s = bowden_runtime::ports::IpcSettings {
        prefix: p.clone(),
        namespace: String::new(),
    };
    let _ = bowden_runtime::cleanup::remove_stale_nodes(&s);
    let _ = bowden_runtime::cleanup::remove_prefix_files(&s);
    assert!(bowden_runtime::cleanup::prefix_files(&s).is_empty());
}
