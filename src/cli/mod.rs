//! The subcommands of the `hytrace` binary, one module each.
pub mod bench;
pub mod info;
pub mod render;
pub mod slice;
