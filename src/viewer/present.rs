//! Putting a picture on the window: a wgpu surface and the display pipeline
//! ([`crate::gpu::display`]) that draws the picture — the CPU's 8-bit pixels, or the GPU's sums
//! of samples where the render kernel left them — scaled to the window, with the heads-up band.
//!
//! The presenting device is the GPU backend's device too (one context, opened on the adapter
//! that can present to the window), so a GPU-rendered frame goes from the render kernel's
//! buffer to the window without leaving the device.

use crate::gpu::GpuContext;
use crate::gpu::display::{Display, HeadsUp, Shown, capture};
use image::RgbImage;
use std::sync::Arc;
use winit::window::Window;

/// A window's surface and what draws on it.
pub struct Presenter {
    surface: wgpu::Surface<'static>,
    ctx: GpuContext,
    config: wgpu::SurfaceConfiguration,
    display: Display,
    /// Draws captures (window shots) into plain 8-bit textures.
    capture_display: Option<Display>,
    adapter: wgpu::AdapterInfo,
}

impl Presenter {
    /// Opens a device that can present to `window`; with `render_on_gpu` the device is also
    /// the GPU backend's, and its context is returned for the render thread. Fails with one
    /// line when there is no Vulkan adapter for this window (or, rendering on the GPU, when
    /// the adapter cannot run the tracer).
    pub fn new(
        window: Arc<Window>,
        display: winit::event_loop::OwnedDisplayHandle,
        render_on_gpu: bool,
    ) -> Result<(Presenter, Option<GpuContext>), String> {
        let instance = wgpu::Instance::new(
            wgpu::InstanceDescriptor {
                backends: wgpu::Backends::VULKAN,
                ..wgpu::InstanceDescriptor::new_without_display_handle()
            }
            .with_display_handle(Box::new(display)),
        );
        let size = window.inner_size();
        let surface = instance.create_surface(window).map_err(|e| {
            format!(
                "cannot draw into the window: no Vulkan driver makes a surface for it ({e}); \
                     a software one comes with Debian's mesa-vulkan-drivers"
            )
        })?;
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: Some(&surface),
            apply_limit_buckets: false,
        }))
        .map_err(|e| {
            format!(
                "no Vulkan adapter can present to the window ({e}); a software one comes with \
                 Debian's mesa-vulkan-drivers"
            )
        })?;
        let ctx = if render_on_gpu {
            GpuContext::with_adapter(&adapter).map_err(|e| {
                format!("--backend gpu: the adapter that presents to the window cannot render: {e}")
            })?
        } else {
            GpuContext::for_drawing(&adapter)
                .map_err(|e| format!("cannot open the presenting device: {e}"))?
        };
        let mut config = surface
            .get_default_config(&adapter, size.width.max(1), size.height.max(1))
            .ok_or_else(|| "the adapter cannot present to this window".to_string())?;
        config.present_mode = wgpu::PresentMode::AutoVsync;
        surface.configure(&ctx.device, &config);
        let display = Display::new(&ctx, config.format);
        let gpu = render_on_gpu.then(|| ctx.clone());
        Ok((
            Presenter {
                surface,
                ctx,
                config,
                display,
                capture_display: None,
                adapter: adapter.get_info(),
            },
            gpu,
        ))
    }

    /// The presenting adapter, e.g. `llvmpipe (LLVM 15.0.6, 256 bits)`.
    pub fn adapter(&self) -> &wgpu::AdapterInfo {
        &self.adapter
    }

    /// Follows a new window size.
    pub fn resize(&mut self, width: u32, height: u32) {
        if width > 0 && height > 0 && (width, height) != (self.config.width, self.config.height) {
            self.config.width = width;
            self.config.height = height;
            self.surface.configure(&self.ctx.device, &self.config);
        }
    }

    /// Shows `shown` with the heads-up band over it.
    pub fn present(&mut self, shown: &Shown, heads_up: &HeadsUp) -> Result<(), String> {
        let frame = match self.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(f)
            | wgpu::CurrentSurfaceTexture::Suboptimal(f) => f,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                self.surface.configure(&self.ctx.device, &self.config);
                return Ok(());
            }
            // nothing to draw on now (minimised, a timeout): the next frame tries again
            _ => return Ok(()),
        };
        let target = frame.texture.create_view(&Default::default());
        let size = (frame.texture.width(), frame.texture.height());
        self.display
            .draw(&target, size, shown, heads_up)
            .map_err(|e| e.to_string())?;
        self.ctx.queue.present(frame);
        Ok(())
    }

    /// What [`Presenter::present`] draws for a window of `size`, read back: the same
    /// pipeline into a plain 8-bit target.
    pub fn capture(
        &mut self,
        size: (u32, u32),
        shown: &Shown,
        heads_up: &HeadsUp,
    ) -> Result<RgbImage, String> {
        let ctx = &self.ctx;
        let display = self
            .capture_display
            .get_or_insert_with(|| Display::new(ctx, wgpu::TextureFormat::Rgba8Unorm));
        capture(ctx, display, size, shown, heads_up).map_err(|e| e.to_string())
    }
}
