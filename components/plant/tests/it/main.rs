//! The crate's integration tests, one binary: each module is one former test file.
//! (One binary per crate links once instead of once per file; see docs/architecture.md.)

mod common;

mod bad_input;
mod characterize_range;
mod determinism;
mod families;
mod figures;
mod no_alloc;
mod physics;
mod preisach;
mod slack;
