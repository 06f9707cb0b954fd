//! Node glue: `bowden node <name> --config FILE` runs one process of a pipeline. Each module
//! here is a few lines over its component crate and the runtime's ports: it builds a
//! [`Stage`] from the stage's `[node.params]`, reads its inputs and publishes its outputs.

mod actuator;
mod adapt;
mod camera;
mod compensator;
mod estimator;
mod plant;
mod trajectory;

use bowden_kinematics::Robot;
use bowden_runtime::stage::{Stage, StageBuildError, StageEnv};

/// Every process of the `bowden` binary counts its allocations per thread; node processes also
/// serve small allocations (iceoryx2's per-sample `Rc`) from a pre-faulted pool.
#[global_allocator]
static ALLOC: bowden_runtime::alloc::RtAlloc = bowden_runtime::alloc::RtAlloc;

/// Why a `bridge` stage cannot run in a binary built without the `bridge` feature.
#[cfg(not(feature = "bridge"))]
pub const NO_BRIDGE: &str = "this bowden was built without the Zenoh bridge: rebuild with \
     `cargo build --release --features bridge` (or `cargo install --path . --features bridge`)";

/// Builds the stage of `env.spec.kind` (the runtime builds the recorder itself).
pub fn factory(env: &StageEnv<'_>) -> Result<Box<dyn Stage>, StageBuildError> {
    match env.spec.kind.as_str() {
        "trajectory" => trajectory::build(env),
        "compensator" => compensator::build(env),
        "actuator" => actuator::build(env),
        "plant" => plant::build(env),
        "camera" => camera::build(env),
        "estimator" => estimator::build(env),
        "adapt" => adapt::build(env),
        #[cfg(feature = "bridge")]
        "bridge" => Ok(Box::new(bowden_bridge::BridgeStage::from_env(env)?)),
        #[cfg(not(feature = "bridge"))]
        "bridge" => Err(env.error(NO_BRIDGE)),
        other => Err(env.error(format!("no built-in node of kind `{other}`"))),
    }
}

/// The robot of the pipeline: `[runtime] robot = "..."` or the shipped one.
fn robot(env: &StageEnv<'_>) -> Result<Robot, StageBuildError> {
    match &env.pipeline.runtime.robot {
        Some(p) => {
            let path = env.pipeline.resolve(p);
            Robot::load(&path).map_err(|e| env.error(e))
        }
        None => Ok(Robot::paper_default()),
    }
}

/// A path parameter resolved against the pipeline config's directory.
fn resolve(env: &StageEnv<'_>, p: &std::path::Path) -> std::path::PathBuf {
    env.pipeline.resolve(p)
}

/// The first `n` entries of a fixed-size sample array as a 5-joint vector, if finite.
fn joints5(v: &[f64], n: u32) -> Option<[f64; 5]> {
    if n as usize != 5 {
        return None;
    }
    let q: [f64; 5] = core::array::from_fn(|j| v[j]);
    q.iter().all(|x| x.is_finite()).then_some(q)
}
