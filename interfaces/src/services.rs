//! Names of bowden's iceoryx2 services, in one place. Every process and every external
//! (hardware-in-the-loop) client uses these strings; a config may add a namespace prefix
//! (see [`qualified`]) so several robots or test runs share one machine.

/// q_desired from the trajectory source. Payload: `JointTarget`.
pub const JOINT_TARGET: &str = "bowden/joint_target";
/// q_cmd from the compensator. Payload: `JointCommand`.
pub const JOINT_COMMAND: &str = "bowden/joint_command";
/// Cable displacements from the actuator. Payload: `MotorCommand`.
pub const MOTOR_COMMAND: &str = "bowden/motor_command";
/// Simulated ground truth. Payload: `PlantState`.
pub const PLANT_STATE: &str = "bowden/plant_state";
/// RGBD frames. Payload: `[u8]` with user header `RgbdFrameHeader`.
pub const RGBD_FRAME: &str = "bowden/rgbd_frame";
/// Fitted marker centres. Payload: `MarkerSet`.
pub const MARKER_SET: &str = "bowden/marker_set";
/// Estimated joint configuration. Payload: `JointEstimate`.
pub const JOINT_ESTIMATE: &str = "bowden/joint_estimate";
/// Health of every node. Payload: `ComponentStatus`.
pub const COMPONENT_STATUS: &str = "bowden/component_status";
/// E-stop and release. Payload: `SafetyCommand`.
pub const SAFETY: &str = "bowden/safety";
/// Lockstep clock. Payload: `ClockTick`.
pub const CLOCK: &str = "bowden/clock";

/// New model weights from the `adapt` node. Payload: `ModelUpdate`.
pub const MODEL_UPDATE: &str = "bowden/model_update";

/// Every service name, for listing, recording and cleanup.
pub const ALL: [&str; 11] = [
    JOINT_TARGET,
    JOINT_COMMAND,
    MOTOR_COMMAND,
    PLANT_STATE,
    RGBD_FRAME,
    MARKER_SET,
    JOINT_ESTIMATE,
    COMPONENT_STATUS,
    SAFETY,
    CLOCK,
    MODEL_UPDATE,
];

/// `name` under an optional namespace: `qualified("", X) == X`, `qualified("arm2", X) == "arm2/" + X`.
pub fn qualified(namespace: &str, name: &str) -> String {
    if namespace.is_empty() {
        name.to_string()
    } else {
        format!("{namespace}/{name}")
    }
}
