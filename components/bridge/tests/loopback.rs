//! Two bridges in this process, each on its own iceoryx2 prefix (two "machines"), joined by
//! Zenoh over TCP on loopback: samples and frames cross byte for byte, malformed messages are
//! refused and counted, a lost peer is a fault and not a hang.

use bowden_bridge::wire::{encode, WireType};
use bowden_bridge::BridgeStage;
use bowden_interfaces::{services, JointEstimate, RgbdFrameHeader};
use bowden_runtime::config::ConfigOrigin;
use bowden_runtime::ports::{IpcSettings, PortContext};
use bowden_runtime::stage::{Stage, StageEnv, StepCx};
use bowden_runtime::{Message, Overrides, PipelineConfig};
use std::time::{Duration, Instant};
use zenoh::Wait;

struct Guard(Vec<String>);

impl Drop for Guard {
    fn drop(&mut self) {
        for p in &self.0 {
            let s = settings(p);
            let _ = bowden_runtime::cleanup::remove_stale_nodes(&s);
            let _ = bowden_runtime::cleanup::remove_prefix_files(&s);
        }
    }
}

fn settings(prefix: &str) -> IpcSettings {
    IpcSettings {
        prefix: prefix.to_string(),
        namespace: String::new(),
    }
}

fn pipeline(prefix: &str, params: &str) -> PipelineConfig {
    let text = format!(
        "[runtime]\nmode = \"realtime\"\nprefix = \"{prefix}\"\nperiod_us = 1000\n\n\
         [[node]]\nname = \"bridge\"\n[node.params]\n{params}\n"
    );
    PipelineConfig::parse(
        &text,
        ConfigOrigin::File("test.toml".into()),
        ".".into(),
        &Overrides::default(),
        bowden_runtime::node::Registry(&[&bowden_bridge::KIND]),
    )
    .expect("bridge pipeline is valid")
}

fn stage(cfg: &PipelineConfig, ports: &PortContext) -> BridgeStage {
    BridgeStage::from_env(&StageEnv {
        spec: &cfg.stages[0],
        kind: &bowden_bridge::KIND,
        pipeline: cfg,
        ports,
    })
    .expect("bridge builds")
}

fn cx() -> StepCx {
    StepCx::realtime(0, 0, 0, 0)
}

/// Steps `stages` until `done` or `secs` pass.
fn step_until(stages: &mut [&mut BridgeStage], secs: u64, mut done: impl FnMut(&[&mut BridgeStage]) -> bool) -> bool {
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(secs) {
        for s in stages.iter_mut() {
            s.step(&cx()).unwrap();
        }
        if done(stages) {
            return true;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    false
}

fn estimate(seq: u64) -> JointEstimate {
    let mut e = JointEstimate::default();
    e.header.seq = seq;
    e.header.tick = 1000 + 33 * seq;
    e.header.t_origin_ns = 5_000_000_000 + seq * 33_333_333;
    e.frame_seq = seq;
    e.n_joints = 5;
    for j in 0..5 {
        e.q_phy_deg[j] = seq as f64 * 0.5 - j as f64;
    }
    e.joint_valid_mask = 0b11111;
    e
}

fn frame_payload(seq: u64) -> Vec<u8> {
    let mut x = seq.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    (0..RgbdFrameHeader::payload_len_for(640, 480))
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x as u8
        })
        .collect()
}

#[test]
fn samples_and_frames_cross_intact_and_a_lost_peer_is_a_fault() {
    let tag = std::process::id();
    let (pa, pb) = (format!("bwt{tag}zA_"), format!("bwt{tag}zB_"));
    let _g = Guard(vec![pa.clone(), pb.clone()]);
    let port = bowden_bridge::free_loopback_port().unwrap();
    let services = "[\"bowden/joint_estimate\", \"bowden/rgbd_frame\"]";
    let cfg_a = pipeline(
        &pa,
        &format!("listen = [\"tcp/127.0.0.1:{port}\"]\nexport = {services}"),
    );
    let cfg_b = pipeline(
        &pb,
        &format!("connect = [\"tcp/127.0.0.1:{port}\"]\nimport = {services}"),
    );
    let ports_a = PortContext::new("bridge", &cfg_a.ipc()).unwrap();
    let ports_b = PortContext::new("bridge", &cfg_b.ipc()).unwrap();
    let mut a = stage(&cfg_a, &ports_a);
    let mut b = stage(&cfg_b, &ports_b);

    // The "vision PC" producers on A's prefix, the "control PC" consumers on B's.
    let src = PortContext::new("src", &settings(&pa)).unwrap();
    let mut est_out = src.output::<JointEstimate>(services::JOINT_ESTIMATE).unwrap();
    let mut frame_out = src.frame_output(services::RGBD_FRAME, 640 * 480 * 5).unwrap();
    let sink = PortContext::new("sink", &settings(&pb)).unwrap();
    let mut est_in = sink.input::<JointEstimate>(services::JOINT_ESTIMATE, 64).unwrap();
    let mut frame_in = sink.frame_input(services::RGBD_FRAME, 4).unwrap();
    est_out.update_connections().unwrap();

    assert!(
        step_until(&mut [&mut a, &mut b], 20, |s| s.iter().all(|s| s.peers().count() == 1)),
        "the two bridges found each other"
    );
    assert_eq!(b.counters().faults, 0);
    assert!(!b.counters().degraded);

    // Zenoh propagates B's subscriptions after the session is up: probe until one arrives.
    let mut probe = 0u64;
    let arrived = step_until(&mut [&mut a, &mut b], 20, |_| {
        est_out.publish_raw(estimate(10_000 + probe)).unwrap();
        probe += 1;
        std::thread::sleep(Duration::from_millis(5));
        est_in.recv().is_some()
    });
    assert!(arrived, "a probe sample crossed");
    // Let the remaining probes arrive, then drop them.
    step_until(&mut [&mut a, &mut b], 1, |_| false);
    while est_in.recv().is_some() {}

    // 20 samples with distinct headers: each arrives once, in order, byte for byte.
    for k in 0..20 {
        est_out.publish_raw(estimate(k)).unwrap();
    }
    let mut got = Vec::new();
    step_until(&mut [&mut a, &mut b], 20, |_| {
        while let Some(e) = est_in.recv() {
            got.push(e);
        }
        got.len() >= 20
    });
    assert_eq!(got.len(), 20, "every sample crossed");
    for (k, e) in got.iter().enumerate() {
        assert_eq!(
            e.as_bytes(),
            estimate(k as u64).as_bytes(),
            "sample {k} crossed byte for byte"
        );
    }

    // Three VGA frames: header and 1.5 MB payload intact.
    for k in 0..3u64 {
        let payload = frame_payload(k);
        let r = frame_out
            .publish_with(77 + k, 123_456 + k, payload.len(), |h, buf| {
                h.width = 640;
                h.height = 480;
                h.fx = 615.0;
                h.depth_offset = 640 * 480 * 3;
                buf.copy_from_slice(&payload);
                Ok::<(), ()>(())
            })
            .unwrap();
        assert!(r.is_ok());
        let mut frame = None;
        step_until(&mut [&mut a, &mut b], 20, |_| {
            frame = frame_in.recv();
            frame.is_some()
        });
        let f = frame.expect("the frame crossed");
        let h = f.user_header();
        assert_eq!(
            (h.header.tick, h.header.t_origin_ns, h.width, h.height),
            (77 + k, 123_456 + k, 640, 480)
        );
        assert_eq!(h.fx, 615.0);
        assert!(f.payload() == &payload[..], "frame {k} payload intact");
    }
    assert_eq!(b.counters().rejected, 0);

    // The peer goes away: B reports a fault and is degraded, without waiting on anything.
    a.finish().unwrap();
    drop(a);
    assert!(
        step_until(&mut [&mut b], 10, |s| s[0].peers().count() == 0),
        "the lost peer was noticed"
    );
    let c = b.counters();
    assert_eq!(c.faults, 1, "one fault for one lost peer: {c:?}");
    assert!(c.degraded);
    assert!(b
        .summary()
        .iter()
        .any(|l| l.contains("imported `bowden/joint_estimate`: ")));
    b.finish().unwrap();
}

#[test]
fn malformed_messages_from_the_network_are_refused_and_counted() {
    let tag = std::process::id();
    let p = format!("bwt{tag}zM_");
    let _g = Guard(vec![p.clone()]);
    let port = bowden_bridge::free_loopback_port().unwrap();
    let cfg = pipeline(
        &p,
        &format!("listen = [\"tcp/127.0.0.1:{port}\"]\nimport = [\"bowden/joint_estimate\", \"bowden/rgbd_frame\"]"),
    );
    let ports = PortContext::new("bridge", &cfg.ipc()).unwrap();
    let mut b = stage(&cfg, &ports);
    let sink = PortContext::new("sink", &settings(&p)).unwrap();
    let mut est_in = sink.input::<JointEstimate>(services::JOINT_ESTIMATE, 64).unwrap();
    let mut frame_in = sink.frame_input(services::RGBD_FRAME, 4).unwrap();

    // A foreign Zenoh peer (not a bowden bridge) writing onto the bridge's keys, with the same
    // transport settings as a bridge carrying frames.
    let params: bowden_bridge::BridgeParams = toml::from_str(&format!(
        "connect = [\"tcp/127.0.0.1:{port}\"]\nimport = [\"bowden/rgbd_frame\"]"
    ))
    .unwrap();
    let raw = zenoh::open(params.zenoh_config().unwrap()).wait().unwrap();
    let est_key = params.key_of(services::JOINT_ESTIMATE);
    let frame_key = params.key_of(services::RGBD_FRAME);
    let est_ty = WireType::of(services::JOINT_ESTIMATE).unwrap();
    let frame_ty = WireType::of(services::RGBD_FRAME).unwrap();
    let mut bad_frame = RgbdFrameHeader {
        width: 640,
        height: 480,
        ..Default::default()
    };
    bad_frame.payload_len = 10;
    let garbage: Vec<(String, Vec<u8>)> = vec![
        (est_key.clone(), b"hello".to_vec()),
        (
            est_key.clone(),
            encode(WireType::of(services::JOINT_COMMAND).unwrap(), &[&[0u8; 8]]),
        ),
        (est_key.clone(), encode(est_ty, &[&[1u8; 24]])),
        (frame_key.clone(), encode(frame_ty, &[bad_frame.as_bytes(), &[0u8; 10]])),
    ];
    let good = estimate(3);
    // Until the bridge's subscription reached the raw peer, puts go nowhere: repeat the
    // round (garbage then one good sample) until the good one arrives.
    let mut rounds = 0u64;
    let mut received = None;
    let ok = step_until(&mut [&mut b], 20, |_| {
        for (k, g) in &garbage {
            raw.put(k, g.clone()).wait().unwrap();
        }
        raw.put(&est_key, encode(est_ty, &[good.as_bytes()])).wait().unwrap();
        rounds += 1;
        std::thread::sleep(Duration::from_millis(5));
        received = est_in.recv();
        received.is_some()
    });
    assert!(ok, "the good sample after the garbage crossed");
    assert_eq!(received.unwrap().as_bytes(), good.as_bytes());
    // The link is up now: one more round is delivered whole and in order, so exactly its four
    // malformed messages are refused before its good sample is published.
    step_until(&mut [&mut b], 1, |_| false);
    while est_in.recv().is_some() {}
    let before = b.counters().rejected;
    for (k, g) in &garbage {
        raw.put(k, g.clone()).wait().unwrap();
    }
    raw.put(&est_key, encode(est_ty, &[good.as_bytes()])).wait().unwrap();
    assert!(
        step_until(&mut [&mut b], 20, |_| est_in.recv().is_some()),
        "the last round's good sample crossed"
    );
    let c = b.counters();
    assert_eq!(
        c.rejected - before,
        4,
        "four refusals in the last round: {c:?} after {rounds} rounds"
    );
    assert!(frame_in.recv().is_none(), "the malformed frame was not published");
    let s = b.summary().join("\n");
    assert!(
        s.contains("first problem: message on `bowden/joint_estimate` from the peer refused: 5 bytes: shorter than"),
        "{s}"
    );
    drop(raw);
    b.finish().unwrap();
}
