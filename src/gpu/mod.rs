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
}
