//! Signed distance functions: the tree, its lowering to the flat tape every backend evaluates,
//! the evaluators, and region specialisation.
//!
//! Data flow: [`node::SdfNode`] (parsed from the scene file) → [`lower::lower`] → SSA
//! ([`ssa::SsaTape`]) → [`tape::Tape`] (evaluated by the CPU interpreter here, one point or a
//! SIMD packet of points at a time, and by the WGSL interpreter on the GPU). Interval
//! evaluation ([`interval`]) over a region lets [`simplify`] drop what cannot matter there.
pub mod conformance;
pub mod expr;
pub mod interval;
pub mod jit;
pub mod lanes;
pub mod lower;
pub mod math;
pub mod native;
pub mod node;
pub mod parts;
pub mod simd;
pub mod simplify;
pub mod ssa;
pub mod tape;

pub use lower::{LowerError, LoweredSdf, lower};
pub use node::SdfNode;
pub use tape::Tape;
