//! The crate's integration tests, one binary: each module is one test file.

mod serial;
