//! Recorder and replay: a recorded sequence replays bit-exact; bad or missing files give
//! typed errors naming the file.

use bowden_camera::record::{INDEX_FILE, INDEX_FORMAT};
use bowden_camera::{CameraConfig, CameraError, Recorder, ReplaySource, StreamInfo, SyntheticCamera};
use bowden_interfaces::SampleHeader;
use bowden_kinematics::{markers::MarkerGeometry, Robot};
use std::path::Path;

fn camera() -> SyntheticCamera {
    SyntheticCamera::new(
        Robot::paper_default(),
        MarkerGeometry::paper_default(),
        CameraConfig::paper_default(),
        4,
    )
}

type Frames = Vec<(SampleHeader, Vec<u8>, Vec<u16>)>;

/// Records `n` frames of a short motion into `dir`; returns what was recorded.
fn record(dir: &Path, n: usize) -> Frames {
    let mut cam = camera();
    let stream = StreamInfo::from_header(&cam.header(0, 0, 0));
    let mut rec = Recorder::create(dir, stream).expect("create");
    let px = (cam.width() * cam.height()) as usize;
    let mut frames = Vec::new();
    for k in 0..n {
        let q = [5.0 * k as f64, -3.0 * k as f64, 4.0 * k as f64, -10.0, 10.0 + k as f64];
        let (mut rgb, mut depth) = (vec![0u8; px * 3], vec![0u16; px]);
        cam.render(&q, k as u64, &mut rgb, &mut depth).expect("render");
        let h = SampleHeader {
            seq: k as u64,
            tick: 10 + k as u64,
            t_origin_ns: 1_000_000_000 + 33_333_333 * k as u64,
        };
        rec.record(&h, &rgb, &depth).expect("record");
        frames.push((h, rgb, depth));
    }
    let index = rec.finish().expect("finish");
    assert_eq!(index, dir.join(INDEX_FILE));
    frames
}

#[test]
fn replay_of_a_recording_gives_identical_frames() {
    let dir = tempfile::tempdir().expect("tempdir");
    let frames = record(dir.path(), 4);
    let mut replay = ReplaySource::open(dir.path()).expect("open");
    assert_eq!(replay.len(), 4);
    let s = *replay.stream();
    assert_eq!(
        (s.width, s.height, s.fx, s.cx, s.depth_unit_mm),
        (640, 480, 615.0, 320.0, 1.0)
    );
    let px = s.pixels();
    let (mut rgb, mut depth) = (vec![0u8; px * 3], vec![0u16; px]);
    let mut payload = vec![0u8; px * 5];
    for (i, (h, want_rgb, want_depth)) in frames.iter().enumerate() {
        let got = replay.read(i, &mut rgb, &mut depth).expect("read");
        assert_eq!(got.header, *h);
        assert!(rgb == *want_rgb, "frame {i} colour differs");
        assert!(depth == *want_depth, "frame {i} depth differs");
        let got = replay.read_into_payload(i, &mut payload).expect("payload");
        assert_eq!(got.header, *h);
        assert_eq!(got.payload_len as usize, payload.len());
        assert_eq!(&payload[..px * 3], &want_rgb[..]);
        assert!(payload[px * 3..]
            .chunks_exact(2)
            .zip(want_depth)
            .all(|(b, d)| u16::from_le_bytes([b[0], b[1]]) == *d));
    }
    match replay.read(4, &mut rgb, &mut depth) {
        Err(CameraError::FrameOutOfRange { index: 4, len: 4, .. }) => {}
        other => panic!("{other:?}"),
    }
}

#[test]
fn payload_frames_record_and_a_second_recording_may_not_overwrite() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut cam = camera();
    let header = cam.header(3, 4, 5);
    let mut payload = vec![0u8; cam.payload_len()];
    cam.render_into_payload(&[0.0; 5], 0, &mut payload).expect("render");
    let mut rec = Recorder::create(dir.path(), StreamInfo::from_header(&header)).expect("create");
    rec.record_payload(&header, &payload).expect("record");
    // A frame of another stream is refused.
    let mut other = header;
    other.width = 320;
    assert!(matches!(
        rec.record_payload(&other, &payload),
        Err(CameraError::Index { .. })
    ));
    assert!(matches!(
        rec.record_payload(&header, &payload[1..]),
        Err(CameraError::BufferSize { buffer: "payload", .. })
    ));
    drop(rec); // unfinished: the index is still written
    let mut replay = ReplaySource::open(dir.path()).expect("open");
    let mut back = vec![0u8; payload.len()];
    let h = replay.read_into_payload(0, &mut back).expect("read");
    assert_eq!(h, header);
    assert!(back == payload);
    match Recorder::create(dir.path(), StreamInfo::from_header(&header)) {
        Err(CameraError::Index { path, .. }) => assert!(path.ends_with(INDEX_FILE)),
        other => panic!("{other:?}"),
    }
}

fn expect_err_naming(dir: &Path, file: &str, what: &str) {
    let e = ReplaySource::open(dir)
        .and_then(|mut r| {
            let px = r.stream().pixels();
            let (mut rgb, mut depth) = (vec![0u8; px * 3], vec![0u16; px]);
            (0..r.len()).try_for_each(|i| r.read(i, &mut rgb, &mut depth).map(|_| ()))
        })
        .expect_err(what);
    let msg = e.to_string();
    assert!(msg.contains(file), "{what}: error {msg:?} does not name {file}");
}

fn edit_index(dir: &Path, f: impl FnOnce(&mut serde_json::Value)) {
    let p = dir.join(INDEX_FILE);
    let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&p).expect("read")).expect("json");
    f(&mut v);
    std::fs::write(&p, serde_json::to_string(&v).expect("ser")).expect("write");
}

#[test]
fn bad_recordings_give_typed_errors_naming_the_file() {
    // Missing index.
    let empty = tempfile::tempdir().expect("tempdir");
    assert!(matches!(
        ReplaySource::open(empty.path()),
        Err(CameraError::Read { .. })
    ));
    expect_err_naming(empty.path(), INDEX_FILE, "missing index");

    let base = tempfile::tempdir().expect("tempdir");
    record(base.path(), 2);
    let fresh = |name: &str| {
        let d = base.path().join(name);
        for sub in ["color", "depth"] {
            std::fs::create_dir_all(d.join(sub)).expect("mkdir");
            for f in std::fs::read_dir(base.path().join(sub)).expect("ls") {
                let f = f.expect("entry").path();
                std::fs::copy(&f, d.join(sub).join(f.file_name().expect("name"))).expect("copy");
            }
        }
        std::fs::copy(base.path().join(INDEX_FILE), d.join(INDEX_FILE)).expect("copy");
        d
    };

    let d = fresh("corrupt_png");
    std::fs::write(d.join("color/000001.png"), b"\x89PNG\r\n\x1a\nnot really").expect("write");
    expect_err_naming(&d, "color/000001.png", "corrupt colour PNG");

    let d = fresh("truncated_depth");
    let bytes = std::fs::read(d.join("depth/000000.png")).expect("read");
    std::fs::write(d.join("depth/000000.png"), &bytes[..bytes.len() / 2]).expect("write");
    expect_err_naming(&d, "depth/000000.png", "truncated depth PNG");

    let d = fresh("swapped");
    std::fs::copy(d.join("color/000000.png"), d.join("depth/000001.png")).expect("copy");
    expect_err_naming(&d, "depth/000001.png", "8-bit colour where 16-bit depth belongs");

    let d = fresh("missing_file");
    std::fs::remove_file(d.join("depth/000001.png")).expect("rm");
    expect_err_naming(&d, "depth/000001.png", "missing depth file");

    let d = fresh("wrong_size");
    edit_index(&d, |v| v["width"] = 320.into());
    expect_err_naming(&d, "color/000000.png", "index size disagrees with the PNG");

    let d = fresh("escape");
    edit_index(&d, |v| v["frames"][0]["color"] = "../../etc/passwd".into());
    expect_err_naming(&d, INDEX_FILE, "path outside the recording");

    let d = fresh("bad_format");
    edit_index(&d, |v| v["format"] = "tum".into());
    expect_err_naming(&d, INDEX_FILE, "wrong format tag");
    assert_eq!(INDEX_FORMAT, "bowden-rgbd/1");

    let d = fresh("bad_intrinsics");
    edit_index(&d, |v| v["fx"] = (-1.0).into());
    expect_err_naming(&d, INDEX_FILE, "negative focal length");

    let d = fresh("unknown_field");
    edit_index(&d, |v| v["exposure"] = 3.into());
    expect_err_naming(&d, INDEX_FILE, "unknown field");

    let d = fresh("malformed");
    std::fs::write(d.join(INDEX_FILE), "{ \"format\": ").expect("write");
    expect_err_naming(&d, INDEX_FILE, "malformed JSON");

    // Wrong buffers are refused before any file is touched.
    let mut r = ReplaySource::open(base.path()).expect("open");
    let mut small = vec![0u8; 10];
    let mut depth = vec![0u16; 640 * 480];
    assert!(matches!(
        r.read(0, &mut small, &mut depth),
        Err(CameraError::BufferSize { buffer: "rgb", .. })
    ));
}
