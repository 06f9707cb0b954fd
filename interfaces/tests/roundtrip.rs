//! Every sample type survives a real iceoryx2 publish-subscribe hop bit for bit
//! (process-local service variant: nothing is created in /dev/shm).

use bowden_interfaces::*;
use core::fmt::Debug;
use iceoryx2::prelude::*;

fn bytes_of<T: Copy>(v: &T) -> Vec<u8> {
    // SAFETY: every sample type is `#[repr(C)]` plain data whose fields tile it without
    // padding (sizes are asserted at compile time), so all its bytes are initialised.
    unsafe { core::slice::from_raw_parts((v as *const T).cast::<u8>(), core::mem::size_of::<T>()) }.to_vec()
}

/// A sample with every byte pattern we can think of: distinct non-zero values everywhere.
fn filled<T: Copy + Default>(seed: u8) -> T {
    let mut v = T::default();
    // SAFETY: as above; any byte pattern is a valid value of these types except for bool/enums,
    // which they do not contain (enums travel as u32).
    let bytes = unsafe { core::slice::from_raw_parts_mut((&mut v as *mut T).cast::<u8>(), core::mem::size_of::<T>()) };
    for (i, b) in bytes.iter_mut().enumerate() {
        *b = (i as u8).wrapping_mul(31).wrapping_add(seed);
    }
    v
}

fn roundtrip<T: Copy + Default + Debug + ZeroCopySend + 'static>(name: &str) {
    let node = NodeBuilder::new().create::<local::Service>().unwrap();
    let svc = node
        .service_builder(&name.try_into().unwrap())
        .publish_subscribe::<T>()
        .open_or_create()
        .unwrap();
    let publisher = svc.publisher_builder().create().unwrap();
    let subscriber = svc.subscriber_builder().create().unwrap();
    for seed in [1u8, 77, 200] {
        let sent: T = filled(seed);
        publisher.send_copy(sent).unwrap();
        let got = subscriber.receive().unwrap().expect("a sample arrives");
        assert_eq!(bytes_of(&sent), bytes_of(&*got), "{name}: bytes differ");
    }
}

#[test]
fn every_sample_type_roundtrips_bit_identical() {
    roundtrip::<JointTarget>("t/joint_target");
    roundtrip::<JointCommand>("t/joint_command");
    roundtrip::<MotorCommand>("t/motor_command");
    roundtrip::<PlantState>("t/plant_state");
    roundtrip::<MarkerSet>("t/marker_set");
    roundtrip::<JointEstimate>("t/joint_estimate");
    roundtrip::<ComponentStatus>("t/status");
    roundtrip::<SafetyCommand>("t/safety");
    roundtrip::<ClockTick>("t/clock");
}

#[test]
fn rgbd_frame_slice_with_header_roundtrips() {
    let (w, h) = (640u32, 480u32);
    let len = RgbdFrameHeader::payload_len_for(w, h);
    let node = NodeBuilder::new().create::<local::Service>().unwrap();
    let svc = node
        .service_builder(&"t/rgbd".try_into().unwrap())
        .publish_subscribe::<[u8]>()
        .user_header::<RgbdFrameHeader>()
        .open_or_create()
        .unwrap();
    let publisher = svc
        .publisher_builder()
        .initial_max_slice_len(len)
        .allocation_strategy(AllocationStrategy::Static)
        .create()
        .unwrap();
    let subscriber = svc.subscriber_builder().create().unwrap();
    let mut header: RgbdFrameHeader = filled(9);
    header.width = w;
    header.height = h;
    header.depth_offset = (w * h * 3) as u64;
    header.payload_len = len as u64;
    let mut sample = publisher.loan_slice_uninit(len).unwrap();
    *sample.user_header_mut() = header;
    let sample = sample.write_from_fn(|i| (i.wrapping_mul(2654435761) >> 7) as u8);
    sample.send().unwrap();
    let got = subscriber.receive().unwrap().expect("a frame arrives");
    assert_eq!(bytes_of(&header), bytes_of(got.user_header()));
    assert_eq!(got.payload().len(), len);
    assert!(got
        .payload()
        .iter()
        .enumerate()
        .all(|(i, &b)| b == (i.wrapping_mul(2654435761) >> 7) as u8));
}

#[test]
fn layout_contract() {
    use core::mem::{offset_of, size_of};
    // Offsets a C or Python client mirrors (see interfaces/LAYOUT.md).
    assert_eq!(offset_of!(JointTarget, q_desired_deg), 32);
    assert_eq!(offset_of!(JointCommand, q_cmd_deg), 32);
    assert_eq!(offset_of!(MotorCommand, cable_disp_mm), 32);
    assert_eq!(offset_of!(RgbdFrameHeader, fx), 32);
    assert_eq!(offset_of!(MarkerSet, centre_cam_mm), 32);
    assert_eq!(offset_of!(JointEstimate, q_phy_deg), 40);
    assert_eq!(size_of::<RgbdFrameHeader>(), 88);
    assert_eq!(RgbdFrameHeader::payload_len_for(640, 480), 640 * 480 * 5);
    let mut s = ComponentStatus::default();
    s.set_name("estimator");
    assert_eq!(s.name(), "estimator");
    assert_eq!(CompensationMode::from_u32(2), Some(CompensationMode::Newton));
    assert_eq!(CompensationMode::from_u32(9), None);
    assert_eq!(services::qualified("arm2", services::CLOCK), "arm2/bowden/clock");
}
