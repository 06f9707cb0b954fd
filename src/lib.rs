//! The `bowden` package's library: the node registry the binary runs its pipelines with, so
//! library callers and tests validate a pipeline file against exactly the kinds the binary
//! knows.

pub mod registry;
