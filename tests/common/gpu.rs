//! The GPU context the GPU tests share: one adapter per test process, as creating a device on
//! lavapipe takes a while. A missing adapter fails the tests, it does not skip them.

use hytrace::gpu::GpuContext;
use std::sync::OnceLock;

/// The process's GPU context; panics, naming the package to install, without an adapter.
pub fn ctx() -> &'static GpuContext {
    static CTX: OnceLock<GpuContext> = OnceLock::new();
    CTX.get_or_init(|| {
        GpuContext::new().unwrap_or_else(|e| {
            panic!(
                "the GPU tests need a GPU adapter and found none: {e}\n\
                 (install Mesa's lavapipe: apt-get install mesa-vulkan-drivers)"
            )
        })
    })
}
