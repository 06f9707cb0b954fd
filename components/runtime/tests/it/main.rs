//! The crate's integration tests, one binary: each module is one former test file.
//! (One binary per crate links once instead of once per file; see docs/architecture.md.)

mod contract;
mod ports;
mod record;
