//! Signed distance functions: the tree, its bounds, and the flat tape both backends evaluate.
//!
//! Data flow: [`node::SdfNode`] (parsed from the scene file) → [`lower::lower`] →
//! [`tape::Tape`] (evaluated by the CPU interpreter here and by the WGSL interpreter on the GPU).
pub mod conformance;
pub mod expr;
pub mod interval;
pub mod lower;
pub mod node;
pub mod tape;

pub use lower::{LowerError, LoweredSdf, lower};
pub use node::SdfNode;
pub use tape::Tape;
