//! The one table that maps a pipeline file's `kind = "..."` to its node: every kind this
//! binary runs, each declared beside its component crate (`<crate>::node::KIND`: ports, read
//! policies, schedule, constructor). The runtime derives the pipeline's validation, the
//! lockstep dataflow and the wake-up sets from these declarations; it names no kind itself
//! but its own recorder. Adding a node kind is one crate with a `node` module and one line
//! here (docs/architecture.md, "Write your own node").

use bowden_runtime::node::{NodeKind, Registry};

/// Every node kind of the `bowden` binary.
pub const REGISTRY: Registry = Registry(&[
    &bowden_trajectory::node::KIND,
    &bowden_compensator::node::KIND,
    &bowden_actuator::node::KIND,
    &bowden_plant::node::KIND,
    &bowden_camera::node::KIND,
    &bowden_estimator::node::KIND,
    &bowden_adapt::node::KIND,
    &BRIDGE,
    &bowden_runtime::record::KIND,
]);

#[cfg(feature = "bridge")]
const BRIDGE: NodeKind = bowden_bridge::KIND;

#[cfg(not(feature = "bridge"))]
const BRIDGE: NodeKind = NOT_BUILT_BRIDGE;

/// Without the `bridge` feature the kind is still known, so a pipeline with a bridge fails on
/// load with the way to get one, not with "unknown kind". Compiled in both configurations, so
/// the tests (which build with the feature) type-check the default build's stand-in too.
#[cfg_attr(feature = "bridge", allow(dead_code))]
const NOT_BUILT_BRIDGE: NodeKind = NodeKind {
    kind: "bridge",
    summary: "forwards chosen services to and from another machine over Zenoh (not built in)",
    inputs: &[],
    outputs: &[],
    schedule: bowden_runtime::node::Schedule::EVENT,
    ports_from_params: Some(|_| Err(bowden_runtime::node::ParamPortsError::Missing { what: NO_BRIDGE })),
    lockstep_refusal: None,
    build: |env| Err(env.error(NO_BRIDGE)),
};

/// Why a `bridge` stage cannot run in a binary built without the `bridge` feature.
pub const NO_BRIDGE: &str = "this bowden was built without the Zenoh bridge: rebuild with \
     `cargo build --release --features bridge` (or `cargo install --path . --features bridge`)";
