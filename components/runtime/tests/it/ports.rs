//! The port wrappers over iceoryx2 (ipc variant, a unique prefix per test, nothing left behind).

use bowden_interfaces::{services, JointTarget, RgbdFrameHeader};
use bowden_runtime::cleanup;
use bowden_runtime::ports::{IpcSettings, Message, PortContext};

fn settings(tag: &str) -> IpcSettings {
    IpcSettings {
        prefix: format!("bwt{}{tag}_", std::process::id()),
        namespace: "t".into(),
    }
}

fn assert_clean(s: &IpcSettings) {
    cleanup::remove_prefix_files(s).expect("cleanup");
    let left = cleanup::prefix_files(s);
    assert!(left.is_empty(), "left behind: {left:?}");
}

#[test]
fn samples_carry_headers_and_ticks() {
    let s = settings("a");
    {
        let a = PortContext::new("a", &s).unwrap();
        let b = PortContext::new("b", &s).unwrap();
        let mut out = a.output::<JointTarget>(services::JOINT_TARGET).unwrap();
        let mut inp = b.input::<JointTarget>(services::JOINT_TARGET, 8).unwrap();
        assert_eq!(out.service(), "t/bowden/joint_target");
        assert_eq!(inp.publisher_count(), 1);
        for k in 0..4u64 {
            let mut t = JointTarget {
                n_joints: 5,
                ..Default::default()
            };
            t.q_desired_deg[0] = k as f64;
            assert_eq!(out.publish(k, 1000 + k, t).unwrap(), 1);
        }
        // Lockstep: tick 2 skips ticks 0 and 1; tick 3 is kept for later.
        let t2 = inp.take_tick(2).expect("tick 2");
        assert_eq!((t2.header.seq, t2.header.tick, t2.header.t_origin_ns), (2, 2, 1002));
        assert_eq!(inp.stats().skipped, 2);
        assert!(inp.take_tick(2).is_none());
        assert_eq!(inp.take_tick(3).unwrap().q_desired_deg[0], 3.0);
        // Real time: newest wins.
        for k in 10..13u64 {
            out.publish(k, 0, JointTarget::default()).unwrap();
        }
        assert_eq!(inp.latest().unwrap().header.tick, 12);
        assert!(inp.latest().is_none());
        // Bytes round trip (what the recorder stores).
        let mut t = JointTarget::default();
        t.q_desired_deg[4] = -1.5;
        assert_eq!(JointTarget::from_bytes(t.as_bytes()), Some(t));
        assert_eq!(JointTarget::from_bytes(&t.as_bytes()[1..]), None);
        // One producer per data service.
        assert!(b.output::<JointTarget>(services::JOINT_TARGET).is_err());
    }
    assert_clean(&s);
}

#[test]
fn frames_are_zero_copy_slices() {
    let s = settings("f");
    {
        let a = PortContext::new("cam", &s).unwrap();
        let b = PortContext::new("est", &s).unwrap();
        let len = RgbdFrameHeader::payload_len_for(64, 48);
        let mut out = a.frame_output(services::RGBD_FRAME, len).unwrap();
        let mut inp = b.frame_input(services::RGBD_FRAME, 2).unwrap();
        let r = out
            .publish_with::<()>(7, 99, len, |h, buf| {
                h.width = 64;
                h.height = 48;
                buf.iter_mut().enumerate().for_each(|(i, b)| *b = (i % 251) as u8);
                Ok(())
            })
            .unwrap();
        assert_eq!(r, Ok(1));
        // A failing fill sends nothing.
        assert_eq!(
            out.publish_with(8, 0, len, |_, _| Err("render failed")).unwrap(),
            Err("render failed")
        );
        assert!(
            out.publish_with::<()>(9, 0, len + 1, |_, _| Ok(())).is_err(),
            "larger than the port"
        );
        let f = inp.take_tick(7).expect("frame");
        let h = f.user_header();
        assert_eq!(
            (h.width, h.height, h.header.tick, h.header.t_origin_ns, h.payload_len),
            (64, 48, 7, 99, len as u64)
        );
        assert!(f.payload().iter().enumerate().all(|(i, &b)| b == (i % 251) as u8));
        drop(f);
        assert!(inp.recv().is_none());
    }
    assert_clean(&s);
}

#[test]
fn events_wake_a_waiter() {
    let s = settings("e");
    {
        let a = PortContext::new("a", &s).unwrap();
        let w = a.listener(services::JOINT_COMMAND).unwrap();
        let n = a.notifier(services::JOINT_COMMAND).unwrap();
        assert_eq!(w.drain(), 0);
        assert_eq!(n.notify().unwrap(), 1);
        let mut r = bowden_runtime::sys::Reactor::new().unwrap();
        let tok = r.add(w.fd()).unwrap();
        let wake = r
            .wait(Some(bowden_runtime::sys::monotonic_ns() + 1_000_000_000))
            .unwrap();
        assert_ne!(wake.ready_mask & (1 << tok), 0);
        assert!(w.drain() >= 1);
        // Nothing pending: the absolute deadline ends the wait.
        let t0 = bowden_runtime::sys::monotonic_ns();
        let wake = r.wait(Some(t0 + 5_000_000)).unwrap();
        assert!(wake.timer && wake.ready_mask == 0);
        assert!(bowden_runtime::sys::monotonic_ns() >= t0 + 5_000_000);
    }
    assert_clean(&s);
}
