//! Node glue: `bowden node <name>` wires one component crate to its iceoryx2 ports.
