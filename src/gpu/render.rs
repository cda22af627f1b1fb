//! The GPU render backend: a scene uploaded once ([`PreparedScene`]), then the image built up
//! one sample pass at a time in per-pixel sums that stay on the device ([`GpuPasses`]), read
//! back into the same [`SampleSums`] and [`Framebuffer`] the CPU fills, so PNG/EXR output,
//! AOVs and debug views are shared with the CPU path.

use super::GpuError;
use super::context::GpuContext;
use super::scene::{GpuScene, SceneData, scene_layout, supported};
use super::shade::{
    RenderPixel, RenderTile, ShadeCamera, ShadeLight, ShadeSettings, pass_bindings,
    shading_bindings, wgsl_prelude,
};
use super::shaders::{Bindings, bind_buffers, layout_entries, with_kernel};
use crate::render::progressive::{PixelSums, SampleSums};
use crate::render::{Framebuffer, RenderOptions, Tile};
use crate::scene::Scene;
use crate::scene::camera::Camera;
use crate::trace::SceneTracer;
use anyhow::{Result, bail};
use glam::Vec3;
use indicatif::{ProgressBar, ProgressStyle};
use wgpu::util::DeviceExt;

/// Shading on the GPU (`src/shade/mod.rs`, `src/shade/optics.rs`).
pub const SHADE_WGSL: &str = include_str!("../../shaders/shade.wgsl");
/// The render kernel (`src/render/cpu.rs`, `src/shade/integrator.rs`).
pub const RENDER_WGSL: &str = include_str!("../../shaders/render.wgsl");

/// Side of the square tiles [`GpuRenderer::render`] renders one after the other. A 64×64 tile
/// keeps each dispatch short (well under a second on lavapipe at the shipped scenes' sample
/// counts) so no driver watchdog fires, while the per-dispatch overhead stays small.
pub const GPU_TILE: u32 = 64;

/// The most pixels one dispatch of a pass renders (256×256): a larger image's pass is cut
/// into bands of rows, so no dispatch runs long enough for a driver watchdog.
pub const PASS_DISPATCH_PIXELS: u32 = 256 * 256;

/// Side of the kernel's square workgroups (`@workgroup_size(8, 8, 1)` in render.wgsl).
const WORKGROUP_SIDE: u32 = 8;

/// The complete WGSL of the render kernel: the scene library with its prelude, this
/// backend's generated structs and constants, the shading functions and the kernel.
pub fn render_shader_source() -> String {
    let kernel = format!("{}\n{SHADE_WGSL}\n{RENDER_WGSL}", wgsl_prelude());
    with_kernel(&kernel)
}

/// Renders the scene on the GPU in tiles of [`GPU_TILE`] pixels (compiling the kernel first;
/// keep a [`GpuRenderer`] to render several images with one compilation), with the pixels
/// the driver could not trace ([`GpuImage::on_cpu`]).
pub fn render(scene: &Scene, opts: &RenderOptions, ctx: &GpuContext) -> Result<GpuImage> {
    GpuRenderer::new(ctx).render_tiled(ctx, scene, opts, GPU_TILE)
}

/// The line that says how many pixels of a GPU image the CPU traced, if any.
pub fn on_cpu_note(image: &GpuImage, adapter: &str) -> Option<String> {
    (!image.on_cpu.is_empty()).then(|| {
        format!(
            "{} pixels were traced on the CPU: {adapter} cut their shader loops short \
             ({})",
            image.on_cpu.len(),
            super::LOOP_BUDGET
        )
    })
}

/// The compiled render kernel and its bind-group layouts; it does not depend on the scene.
pub struct GpuRenderer {
    pipeline: wgpu::ComputePipeline,
    /// Group 1: the shading settings and lights of a [`PreparedScene`].
    scene_layout: wgpu::BindGroupLayout,
    /// Group 2: the camera, the dispatch's pixels and the sums of a [`GpuPasses`].
    passes_layout: wgpu::BindGroupLayout,
}

/// A scene on the device, ready for [`GpuRenderer::render_pass`]: its buffers (group 0), its
/// shading settings and lights (group 1). Built once per scene, kept across passes and cameras.
pub struct PreparedScene {
    scene: GpuScene,
    bindings: wgpu::BindGroup,
}

/// An image of [`GpuRenderer::render_tiled`].
pub struct GpuImage {
    /// The image.
    pub image: Framebuffer,
    /// The pixels (x, y) the driver could not trace (llvmpipe's loop budget), traced by the
    /// CPU renderer instead.
    pub on_cpu: Vec<(u32, u32)>,
}

/// Per-pixel sums of the passes rendered so far, kept on the device between passes: the
/// target of [`GpuRenderer::render_pass`] for a `width`×`height` image.
pub struct GpuPasses {
    width: u32,
    height: u32,
    /// The rectangle of the image the sums cover (all of it, but for one tile of
    /// [`GpuRenderer::render_tiled`]).
    region: Tile,
    /// Passes added since the sums were (re)started.
    passes: u32,
    camera: wgpu::Buffer,
    tile: wgpu::Buffer,
    sums: wgpu::Buffer,
    bindings: wgpu::BindGroup,
}

impl GpuRenderer {
    /// Compiles the render kernel for the context's device (once per context: later
    /// renderers share the pipeline, see [`GpuContext::compute_pipeline`]).
    ///
    /// # Panics
    /// If the device rejects the render kernel, which is validated in the tests: a bug.
    pub fn new(ctx: &GpuContext) -> Self {
        let device = &ctx.device;
        let compiled = ctx
            .compute_pipeline(
                "render.wgsl",
                &render_shader_source(),
                "render_tile_main",
                || {
                    let layout = |label, bindings: &Bindings| {
                        device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                            label: Some(label),
                            entries: &layout_entries(bindings),
                        })
                    };
                    vec![
                        scene_layout(ctx),
                        layout("render scene bindings", &shading_bindings()),
                        layout("render pass bindings", &pass_bindings()),
                    ]
                },
            )
            .unwrap_or_else(|e| panic!("{e}"));
        GpuRenderer {
            pipeline: compiled.pipeline,
            scene_layout: compiled.layouts[1].clone(),
            passes_layout: compiled.layouts[2].clone(),
        }
    }

    /// Uploads the scene: its buffers, shading settings and lights (not its camera, which
    /// every pass names).
    pub fn prepare(&self, ctx: &GpuContext, scene: &Scene) -> Result<PreparedScene> {
        self.upload(ctx, scene, &SceneData::from_scene(scene)?)
    }

    /// [`GpuRenderer::prepare`] with the acceleration structures of a CPU tracer built already
    /// (the viewer keeps one for picking): they are uploaded, not built again.
    pub fn prepare_with(&self, ctx: &GpuContext, tracer: &SceneTracer) -> Result<PreparedScene> {
        self.upload(ctx, tracer.scene(), &SceneData::from_tracer(tracer)?)
    }

    fn upload(&self, ctx: &GpuContext, scene: &Scene, data: &SceneData) -> Result<PreparedScene> {
        let gpu_scene = GpuScene::new(ctx, data)?;
        let settings = ShadeSettings::new(scene);
        // A storage binding cannot be empty: a scene without lights gets one unused record
        // (light_count says how many are real).
        let mut lights: Vec<ShadeLight> = scene.lights.iter().map(ShadeLight::new).collect();
        if lights.is_empty() {
            lights.push(ShadeLight::default());
        }
        let init = |label, contents: &[u8], usage| {
            ctx.device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some(label),
                    contents,
                    usage,
                })
        };
        let settings_buffer = init(
            "shading settings",
            bytemuck::bytes_of(&settings),
            wgpu::BufferUsages::UNIFORM,
        );
        let light_buffer = init(
            "lights",
            bytemuck::cast_slice(&lights),
            wgpu::BufferUsages::STORAGE,
        );
        // the bind group keeps its buffers alive
        let bindings = bind_buffers(
            &ctx.device,
            "render scene bindings",
            &self.scene_layout,
            &[&settings_buffer, &light_buffer],
        );
        Ok(PreparedScene {
            scene: gpu_scene,
            bindings,
        })
    }

    /// Renders sample `sample` of `opts.samples` of every pixel of `target` as `camera` sees
    /// the prepared scene, and adds it to the target's sums (the first pass after
    /// [`GpuPasses::new`] or [`GpuPasses::clear`] starts them). Passes 0..n added in order
    /// hold exactly what [`GpuRenderer::render`] averages. The pass is submitted in dispatches
    /// of at most [`PASS_DISPATCH_PIXELS`] pixels; read it with [`GpuPasses::read`].
    pub fn render_pass(
        &self,
        ctx: &GpuContext,
        prepared: &PreparedScene,
        camera: &Camera,
        opts: &RenderOptions,
        sample: u32,
        target: &mut GpuPasses,
    ) -> Result<()> {
        if (opts.width, opts.height) != (target.width, target.height) {
            bail!(
                "a pass of a {}×{} image into the sums of a {}×{} one",
                opts.width,
                opts.height,
                target.width,
                target.height
            );
        }
        let queue = &ctx.queue;
        queue.write_buffer(
            &target.camera,
            0,
            bytemuck::bytes_of(&ShadeCamera::new(camera)),
        );
        let region = target.region;
        let rows = (PASS_DISPATCH_PIXELS / region.w).max(1);
        for y0 in (region.y0..region.y0 + region.h).step_by(rows as usize) {
            let band = Tile {
                x0: region.x0,
                y0,
                w: region.w,
                h: rows.min(region.y0 + region.h - y0),
            };
            // One submission per dispatch: the uniform written before each submission is the
            // one its dispatch reads.
            let tile = RenderTile::new(opts, band, region, sample, target.passes > 0);
            queue.write_buffer(&target.tile, 0, bytemuck::bytes_of(&tile));
            let mut encoder = ctx
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("render pass"),
                });
            {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("render pass"),
                    timestamp_writes: None,
                });
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &prepared.scene.bind_group, &[]);
                pass.set_bind_group(1, &prepared.bindings, &[]);
                pass.set_bind_group(2, &target.bindings, &[]);
                pass.dispatch_workgroups(
                    band.w.div_ceil(WORKGROUP_SIDE),
                    band.h.div_ceil(WORKGROUP_SIDE),
                    1,
                );
            }
            queue.submit([encoder.finish()]);
        }
        target.passes += 1;
        Ok(())
    }

    /// Renders the scene in tiles of [`GPU_TILE`] pixels.
    pub fn render(
        &self,
        ctx: &GpuContext,
        scene: &Scene,
        opts: &RenderOptions,
    ) -> Result<Framebuffer> {
        Ok(self.render_tiled(ctx, scene, opts, GPU_TILE)?.image)
    }

    /// Renders the scene tile by tile, tiles of side `tile_side`, each with its passes
    /// 0..samples (at least one) of [`GpuRenderer::render_pass`] with the scene's camera.
    /// Every pixel depends only on its own coordinates, so the image does not depend on the
    /// tile size.
    ///
    /// Pixels whose kernel invocations the driver cut short (llvmpipe's loop budget, see
    /// `loops_were_cut` in shaders/tape.wgsl) are rendered again one by one: the budget is
    /// spent by a whole SIMD group together, and a pixel alone spends only its own. Those
    /// cut even alone are traced by the CPU renderer with the same acceleration structures
    /// (the image the GPU would have made, as the backends agree) and listed in the result.
    pub fn render_tiled(
        &self,
        ctx: &GpuContext,
        scene: &Scene,
        opts: &RenderOptions,
        tile_side: u32,
    ) -> Result<GpuImage> {
        if tile_side == 0 {
            bail!("GPU tile size must be at least 1 pixel");
        }
        supported(scene)?;
        let tracer = SceneTracer::new(scene);
        let prepared = self.prepare_with(ctx, &tracer)?;
        let all = crate::render::tiles(opts.width, opts.height, tile_side);
        let bar = progress_bar(opts.progress, all.len() as u64)?;
        let mut sums = SampleSums::new(opts.width, opts.height);
        let mut cut = Vec::new();
        for tile in all {
            let target = self.render_region(ctx, &prepared, scene, opts, tile)?;
            cut.extend(target.read_into(ctx, &mut sums)?);
            bar.inc(1);
        }
        let mut on_cpu = Vec::new();
        for (x0, y0) in cut {
            let alone = Tile { x0, y0, w: 1, h: 1 };
            let target = self.render_region(ctx, &prepared, scene, opts, alone)?;
            on_cpu.extend(target.read_into(ctx, &mut sums)?);
        }
        crate::render::cpu::render_pixels(&tracer, &scene.camera, opts, &on_cpu, &mut sums);
        bar.finish_and_clear();
        Ok(GpuImage {
            image: sums.mean(),
            on_cpu,
        })
    }

    /// All the samples of the pixels of `region`.
    fn render_region(
        &self,
        ctx: &GpuContext,
        prepared: &PreparedScene,
        scene: &Scene,
        opts: &RenderOptions,
        region: Tile,
    ) -> Result<GpuPasses> {
        let mut target = GpuPasses::covering(ctx, self, opts.width, opts.height, region)?;
        for sample in 0..opts.samples.max(1) {
            self.render_pass(ctx, prepared, &scene.camera, opts, sample, &mut target)?;
        }
        Ok(target)
    }
}

impl GpuPasses {
    /// Sums of no passes yet for a `width`×`height` image; fails when they exceed the
    /// device's buffer limits.
    pub fn new(ctx: &GpuContext, renderer: &GpuRenderer, width: u32, height: u32) -> Result<Self> {
        let whole = Tile {
            x0: 0,
            y0: 0,
            w: width,
            h: height,
        };
        Self::covering(ctx, renderer, width, height, whole)
    }

    /// Sums covering the rectangle `region` of a `width`×`height` image.
    fn covering(
        ctx: &GpuContext,
        renderer: &GpuRenderer,
        width: u32,
        height: u32,
        region: Tile,
    ) -> Result<Self> {
        if region.w == 0 || region.h == 0 {
            bail!("cannot render a {}×{} image", region.w, region.h);
        }
        let bytes = region.w as u64 * region.h as u64 * std::mem::size_of::<RenderPixel>() as u64;
        let limits = ctx.limits();
        let limit = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        if bytes > limit {
            bail!(
                "the sums of a {}×{} image take {bytes} bytes, the device binds at most {limit}",
                region.w,
                region.h
            );
        }
        let device = &ctx.device;
        let camera = ctx.uniform_buffer("camera", bytemuck::bytes_of(&ShadeCamera::default()));
        let tile = ctx.uniform_buffer("tile", bytemuck::bytes_of(&RenderTile::default()));
        let sums = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("pixel sums"),
            size: bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let bindings = bind_buffers(
            device,
            "render pass bindings",
            &renderer.passes_layout,
            &[&camera, &tile, &sums],
        );
        Ok(GpuPasses {
            width,
            height,
            region,
            passes: 0,
            camera,
            tile,
            sums,
            bindings,
        })
    }

    /// Width of the image.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height of the image.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Passes added since the sums were started.
    pub fn passes(&self) -> u32 {
        self.passes
    }

    /// A copy of the sums of the passes so far, made on the device (nothing is read back):
    /// what a window shows while later passes add to the sums. Only for sums covering the
    /// whole image.
    pub fn snapshot(&self, ctx: &GpuContext) -> Result<wgpu::Buffer> {
        if (self.region.w, self.region.h) != (self.width, self.height) {
            bail!("the sums cover one tile, not the image");
        }
        let copy = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("pixel sums shown"),
            size: self.sums.size(),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        encoder.copy_buffer_to_buffer(&self.sums, 0, &copy, 0, self.sums.size());
        ctx.queue.submit([encoder.finish()]);
        Ok(copy)
    }

    /// Forgets the passes: the next one starts the sums again (when the camera moved).
    pub fn clear(&mut self) {
        self.passes = 0;
    }

    /// The sums of the passes so far, read back from the device (waiting for them). Fails
    /// with [`GpuError::LoopsCut`] when the driver cut some pixels' work short.
    pub fn read(&self, ctx: &GpuContext) -> Result<SampleSums> {
        let mut sums = SampleSums::new(self.width, self.height);
        let cut = self.read_into(ctx, &mut sums)?.len();
        if cut > 0 {
            return Err(GpuError::LoopsCut {
                count: cut,
                what: "pixels",
            }
            .into());
        }
        Ok(sums)
    }

    /// Reads the sums back into their rectangle of `sums`, an image-sized accumulator;
    /// returns the pixels (x, y) whose sums the driver cut short (their sums are read too).
    fn read_into(&self, ctx: &GpuContext, sums: &mut SampleSums) -> Result<Vec<(u32, u32)>> {
        if self.passes == 0 {
            // nothing written yet: the buffer holds no sums
            return Ok(Vec::new());
        }
        let bytes = ctx.read_buffer(&self.sums, self.sums.size())?;
        let pixels: &[RenderPixel] = bytemuck::cast_slice(&bytes);
        let region = self.region;
        let mut cut = Vec::new();
        for (j, row) in pixels.chunks_exact(region.w as usize).enumerate() {
            let y = region.y0 + j as u32;
            let start = (y * sums.width + region.x0) as usize;
            for (i, (into, p)) in sums.pixels[start..start + row.len()]
                .iter_mut()
                .zip(row)
                .enumerate()
            {
                *into = pixel_sums(p, self.passes);
                if p.cut != 0 {
                    cut.push((region.x0 + i as u32, y));
                }
            }
        }
        Ok(cut)
    }
}

/// A pixel's sums as the kernel leaves them, over `count` samples; a negative depth means
/// every sample missed.
fn pixel_sums(p: &RenderPixel, count: u32) -> PixelSums {
    PixelSums {
        radiance: Vec3::from_array(p.radiance),
        depth: if p.depth < 0.0 {
            f32::INFINITY
        } else {
            p.depth
        },
        normal: Vec3::from_array(p.normal),
        albedo: Vec3::from_array(p.albedo),
        steps: p.steps,
        gradient: p.gradient,
        count,
    }
}

/// The progress bar the CPU backend draws, or a hidden one.
fn progress_bar(show: bool, tiles: u64) -> Result<ProgressBar> {
    Ok(if show {
        let b = ProgressBar::new(tiles);
        b.set_style(
            ProgressStyle::with_template(
                "{spinner} rendering on the GPU [{bar:40}] {percent:>3}% {pos}/{len} tiles, ETA {eta}",
            )?
            .progress_chars("=> "),
        );
        b
    } else {
        ProgressBar::hidden()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn render_shader_parses_and_validates_with_naga() {
        let module = crate::gpu::shaders::validate("render", &render_shader_source());
        assert!(
            module
                .entry_points
                .iter()
                .any(|e| e.name == "render_tile_main" && e.stage == naga::ShaderStage::Compute)
        );
    }
}
