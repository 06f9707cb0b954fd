//! Subcommands, one module per concern (and per owner).

pub mod bench;
pub mod camera;
pub mod collect;
pub mod compensate;
pub mod estimator;
pub mod evaluate;
pub mod kin;
pub mod learning;
pub mod plant;
pub mod runtime;
pub mod trajectory;
pub mod transfer;
pub mod tune;

// Node glue for `bowden node ...` lives in `crate::nodes`.
