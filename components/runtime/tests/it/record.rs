//! Log files: round trip, index, and every kind of damage reported with file and offset.

use bowden_interfaces::{services, JointCommand, PlantState, RgbdFrameHeader, SampleHeader};
use bowden_runtime::ports::Message;
use bowden_runtime::record::{index_path, LogError, LogReader, LogWriter, KIND_FRAME, KIND_SAMPLE};
use bowden_runtime::replay::summarize;

fn write_log(path: &std::path::Path) -> Vec<JointCommand> {
    let svc = vec![
        services::JOINT_COMMAND.to_string(),
        services::PLANT_STATE.to_string(),
        services::RGBD_FRAME.to_string(),
    ];
    let mut w = LogWriter::create(path, &svc).unwrap();
    let mut cmds = Vec::new();
    for k in 0..10u64 {
        let mut c = JointCommand {
            header: SampleHeader {
                seq: k,
                tick: k,
                t_origin_ns: k * 1_000_000,
            },
            n_joints: 5,
            ..Default::default()
        };
        c.q_cmd_deg[0] = k as f64 * 0.5;
        w.append(0, KIND_SAMPLE, &[c.as_bytes()], &c.header).unwrap();
        cmds.push(c);
        let mut p = PlantState {
            header: c.header,
            n_joints: 5,
            ..Default::default()
        };
        p.q_cmd_deg[0] = c.q_cmd_deg[0];
        p.q_phy_deg[0] = c.q_cmd_deg[0] - 2.0;
        w.append(1, KIND_SAMPLE, &[p.as_bytes()], &p.header).unwrap();
        if k % 5 == 0 {
            let h = RgbdFrameHeader {
                header: c.header,
                width: 4,
                height: 2,
                payload_len: 40,
                ..Default::default()
            };
            let px = [k as u8; 40];
            w.append(2, KIND_FRAME, &[h.as_bytes(), &px], &h.header).unwrap();
        }
    }
    w.finish().unwrap();
    cmds
}

#[test]
fn round_trip_with_index() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.blog");
    let cmds = write_log(&path);
    let mut r = LogReader::open(&path).unwrap();
    assert!(!r.rebuilt_index);
    assert_eq!(r.entries.len(), 22);
    assert_eq!(r.services.len(), 3);
    let mut buf = Vec::new();
    let got: Vec<JointCommand> = (0..r.entries.len())
        .filter_map(|i| r.sample::<JointCommand>(i, &mut buf).unwrap())
        .collect();
    assert_eq!(got, cmds);
    let frame = r.entries.iter().position(|e| e.kind == KIND_FRAME).unwrap();
    r.payload(frame, &mut buf).unwrap();
    assert_eq!(buf.len(), 88 + 40);
    let s = summarize(&path).unwrap();
    assert_eq!(s.records, 22);
    assert!((s.plant_mean_abs_error_deg[0] - 2.0).abs() < 1e-12);
    assert_eq!(s.services[0].seq_gaps, 0);
    assert!(s.to_markdown().contains("bowden/joint_command | 10 | 0..9"));
}

#[test]
fn missing_or_partial_index_is_rebuilt() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.blog");
    write_log(&path);
    let idx = index_path(&path);
    let bytes = std::fs::read(&idx).unwrap();
    std::fs::write(&idx, &bytes[..bytes.len() - 40]).unwrap();
    let r = LogReader::open(&path).unwrap();
    assert!(r.rebuilt_index);
    assert_eq!(r.entries.len(), 22);
    std::fs::remove_file(&idx).unwrap();
    assert_eq!(LogReader::open(&path).unwrap().entries.len(), 22);
    // A record cut in half by a crash ends the log there.
    let data = std::fs::read(&path).unwrap();
    std::fs::write(&path, &data[..data.len() - 30]).unwrap();
    let r = LogReader::open(&path).unwrap();
    assert_eq!(r.entries.len(), 21);
}

#[test]
fn damage_is_reported_with_offset() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.blog");
    write_log(&path);
    let data = std::fs::read(&path).unwrap();
    // Flip a payload byte of the first record: the checksum catches it.
    let first_payload = 16 + 3 * 136 + 16 + 30;
    let mut bad = data.clone();
    bad[first_payload] ^= 0xff;
    std::fs::write(&path, &bad).unwrap();
    let mut r = LogReader::open(&path).unwrap();
    let mut buf = Vec::new();
    match r.payload(0, &mut buf) {
        Err(LogError::Corrupt { offset, what, .. }) => {
            assert_eq!(offset, 16 + 3 * 136);
            assert!(what.contains("checksum"), "{what}");
        }
        other => panic!("{other:?}"),
    }
    let e = summarize(&path).unwrap_err().to_string();
    assert!(e.contains("run.blog") && e.contains("corrupt at byte"), "{e}");
    // Not a log at all.
    std::fs::write(&path, b"hello world, definitely not a log").unwrap();
    let e = LogReader::open(&path).err().unwrap().to_string();
    assert!(e.contains("not a bowden log"), "{e}");
    // A service table that does not match this build's layout.
    let mut bad = data.clone();
    bad[16 + 132] = 1; // sample size of the first service
    std::fs::write(&path, &bad).unwrap();
    let e = LogReader::open(&path).err().unwrap().to_string();
    assert!(e.contains("does not match"), "{e}");
    // Missing file.
    let e = LogReader::open(&dir.path().join("nope.blog"))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("nope.blog") && e.contains("open"), "{e}");
}
