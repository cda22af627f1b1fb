//! The GPU tracer: wgpu compute kernels over WGSL shaders that evaluate the CPU's tapes and
//! mirror its tracing queries (see `shaders/README.md`).
//!
//! [`context`] opens a headless device, [`scene`] uploads a scene (tapes, the objects' field
//! octrees, BVHs, meshes, materials, textures) as the buffer [`records`] whose WGSL twins
//! [`layout`] generates, [`shaders`] assembles the WGSL (a generated prelude of shared
//! constants and structs, then `shaders/*.wgsl`), [`query`] answers ray batches with it,
//! [`shade`] packs what the shading kernels read, [`render`] builds images pass by pass and
//! [`display`] draws pictures (or the sums of passes, where they are) onto a window's texture.

pub mod context;
pub mod display;
pub mod layout;
pub mod query;
pub mod records;
pub mod render;
pub mod scene;
pub mod shade;
pub mod shaders;

pub use context::GpuContext;
pub use query::{GpuQuery, GpuSdfEvaluator};
pub use scene::{GpuScene, SceneData};

/// What llvmpipe (lavapipe) does to long kernels, as errors and notes say it (see
/// `loops_were_cut` in shaders/tape.wgsl).
pub const LOOP_BUDGET: &str =
    "llvmpipe ends every loop of a shader invocation after 65,535 iterations in all";

/// What can go wrong on the GPU side.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No adapter: no Vulkan driver, or no device it can drive.
    #[error(
        "no GPU adapter found ({0}); on a machine without a GPU install Mesa's lavapipe \
         (Debian package `mesa-vulkan-drivers`)"
    )]
    NoAdapter(String),
    /// The adapter refused to create a device.
    #[error("the GPU adapter could not open a device: {0}")]
    Device(String),
    /// The scene or the adapter is outside what the GPU tracer handles.
    #[error("unsupported on this GPU: {0}")]
    Unsupported(String),
    /// A shader did not compile (a bug: they are validated with naga in the tests).
    #[error("shader `{name}` failed: {message}")]
    Shader {
        /// Shader module.
        name: String,
        /// Driver or wgpu message.
        message: String,
    },
    /// Reading a result buffer back failed.
    #[error("reading GPU results back failed: {0}")]
    ReadBack(String),
    /// The driver ended kernel invocations' loops early, so some answers are wrong: llvmpipe
    /// (lavapipe) stops every loop of an invocation once 65,535 iterations are spent (see
    /// `loops_were_cut` in shaders/tape.wgsl). Long tapes (large smooth unions, big CSG
    /// trees) reach that; hardware drivers have no such limit.
    #[error(
        "the GPU driver cut the shader loops of {count} {what} short ({LOOP_BUDGET}), so they \
         would be wrong; render this scene with --backend cpu"
    )]
    LoopsCut {
        /// How many pixels or rays.
        count: usize,
        /// "pixels" or "rays".
        what: &'static str,
    },
}
