//! The GPU render backend: the scene uploaded once, then one compute dispatch per image tile
//! (`shaders/render.wgsl`), each tile read back into the same [`Framebuffer`] the CPU fills,
//! so PNG/EXR output, AOVs and debug views are shared with the CPU path.

use super::context::GpuContext;
use super::scene::{GpuScene, SceneData, scene_layout};
use super::shade::{RenderPixel, RenderTile, ShadeCamera, ShadeLight, ShadeSettings, wgsl_prelude};
use super::shaders::with_kernel;
use crate::render::{Framebuffer, RenderOptions, Tile};
use crate::scene::Scene;
use anyhow::{Context, Result, bail};
use glam::Vec3;
use indicatif::{ProgressBar, ProgressStyle};
use wgpu::util::DeviceExt;

/// Shading on the GPU (`src/shade/mod.rs`, `src/shade/optics.rs`).
pub const SHADE_WGSL: &str = include_str!("../../shaders/shade.wgsl");
/// The render kernel (`src/render/cpu.rs`, `src/shade/integrator.rs`).
pub const RENDER_WGSL: &str = include_str!("../../shaders/render.wgsl");

/// Side of the square tiles one dispatch renders. A 64×64 tile keeps each dispatch short
/// (well under a second on lavapipe at the shipped scenes' sample counts) so no driver
/// watchdog fires, while the per-dispatch overhead stays small.
pub const GPU_TILE: u32 = 64;

/// Side of the kernel's square workgroups (`@workgroup_size(8, 8, 1)` in render.wgsl).
const WORKGROUP_SIDE: u32 = 8;

/// The complete WGSL of the render kernel: the scene library with its prelude, this
/// backend's generated structs and constants, the shading functions and the kernel.
pub fn render_shader_source() -> String {
    let kernel = format!("{}\n{SHADE_WGSL}\n{RENDER_WGSL}", wgsl_prelude());
    with_kernel(&kernel)
}

/// Renders the scene on the GPU in tiles of [`GPU_TILE`] pixels (compiling the kernel first;
/// keep a [`GpuRenderer`] to render several images with one compilation).
pub fn render(scene: &Scene, opts: &RenderOptions, ctx: &GpuContext) -> Result<Framebuffer> {
    GpuRenderer::new(ctx).render(ctx, scene, opts)
}

/// The image cut into square tiles of side `side`, row by row.
fn tiles_of(width: u32, height: u32, side: u32) -> Vec<Tile> {
    let mut v = Vec::new();
    for y0 in (0..height).step_by(side as usize) {
        for x0 in (0..width).step_by(side as usize) {
            v.push(Tile {
                x0,
                y0,
                w: side.min(width - x0),
                h: side.min(height - y0),
            });
        }
    }
    v
}

/// The compiled render kernel and its bind-group layouts; it does not depend on the scene.
pub struct GpuRenderer {
    pipeline: wgpu::ComputePipeline,
    render_layout: wgpu::BindGroupLayout,
}

impl GpuRenderer {
    /// Compiles the render kernel for the context's device.
    pub fn new(ctx: &GpuContext) -> Self {
        let device = &ctx.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("render.wgsl"),
            source: wgpu::ShaderSource::Wgsl(render_shader_source().into()),
        });
        let uniform = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let storage = |binding, read_only| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        // binding numbers as declared at the top of render.wgsl
        let render_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("render bindings"),
            entries: &[
                uniform(0),
                uniform(1),
                storage(2, true),
                uniform(3),
                storage(4, false),
            ],
        });
        let scene_layout = scene_layout(ctx);
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("render pipeline layout"),
            bind_group_layouts: &[Some(&scene_layout), Some(&render_layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("render pipeline"),
            layout: Some(&pipeline_layout),
            module: &module,
            entry_point: Some("render_tile_main"),
            compilation_options: Default::default(),
            cache: None,
        });
        GpuRenderer {
            pipeline,
            render_layout,
        }
    }

    /// Renders the scene in tiles of [`GPU_TILE`] pixels.
    pub fn render(
        &self,
        ctx: &GpuContext,
        scene: &Scene,
        opts: &RenderOptions,
    ) -> Result<Framebuffer> {
        self.render_tiled(ctx, scene, opts, GPU_TILE)
    }

    /// Renders the scene with one dispatch per tile of side `tile_side`. Every pixel depends
    /// only on its own coordinates, so the image does not depend on the tile size.
    pub fn render_tiled(
        &self,
        ctx: &GpuContext,
        scene: &Scene,
        opts: &RenderOptions,
        tile_side: u32,
    ) -> Result<Framebuffer> {
        if tile_side == 0 {
            bail!("GPU tile size must be at least 1 pixel");
        }
        let device = &ctx.device;
        let queue = &ctx.queue;
        let gpu_scene = GpuScene::new(ctx, &SceneData::from_scene(scene)?)?;
        let (pipeline, render_layout) = (&self.pipeline, &self.render_layout);

        let init = |label, contents: &[u8], usage| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage,
            })
        };
        let camera = ShadeCamera::new(&scene.camera);
        let settings = ShadeSettings::new(scene);
        // A storage binding cannot be empty: a scene without lights gets one unused record
        // (light_count says how many are real).
        let mut lights: Vec<ShadeLight> = scene.lights.iter().map(ShadeLight::new).collect();
        if lights.is_empty() {
            lights.push(ShadeLight::default());
        }
        let camera_buffer = init(
            "camera",
            bytemuck::bytes_of(&camera),
            wgpu::BufferUsages::UNIFORM,
        );
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
        let tile_buffer = init(
            "tile",
            bytemuck::bytes_of(&RenderTile::default()),
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        );
        let pixel_bytes = std::mem::size_of::<RenderPixel>() as u64;
        let max_tile_pixels = tile_side.min(opts.width) as u64 * tile_side.min(opts.height) as u64;
        let output_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("tile pixels"),
            size: max_tile_pixels * pixel_bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let readback_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("tile readback"),
            size: max_tile_pixels * pixel_bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let render_bindings = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("render bindings"),
            layout: render_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: camera_buffer.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: settings_buffer.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: light_buffer.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: tile_buffer.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: output_buffer.as_entire_binding(),
                },
            ],
        });

        let all = tiles_of(opts.width, opts.height, tile_side);
        let bar = progress_bar(opts.progress, all.len() as u64)?;
        let mut fb = Framebuffer::new(opts.width, opts.height);
        let samples = opts.samples.max(1);
        for tile in all {
            let bytes = (tile.w * tile.h) as u64 * pixel_bytes;
            // One submission per sample: the tile uniform written before each submission is
            // the one its dispatch reads.
            for sample in 0..samples {
                queue.write_buffer(
                    &tile_buffer,
                    0,
                    bytemuck::bytes_of(&RenderTile::new(opts, tile, sample)),
                );
                let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("render tile sample"),
                });
                {
                    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                        label: Some("render tile sample"),
                        timestamp_writes: None,
                    });
                    pass.set_pipeline(pipeline);
                    pass.set_bind_group(0, &gpu_scene.bind_group, &[]);
                    pass.set_bind_group(1, &render_bindings, &[]);
                    pass.dispatch_workgroups(
                        tile.w.div_ceil(WORKGROUP_SIDE),
                        tile.h.div_ceil(WORKGROUP_SIDE),
                        1,
                    );
                }
                if sample + 1 < samples {
                    queue.submit([encoder.finish()]);
                    continue;
                }
                encoder.copy_buffer_to_buffer(&output_buffer, 0, &readback_buffer, 0, bytes);
                queue.submit([encoder.finish()]);
            }
            let pixels = read_back(ctx, &readback_buffer, bytes)?;
            store_tile(&mut fb, tile, &pixels, samples);
            bar.inc(1);
        }
        bar.finish_and_clear();
        Ok(fb)
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

/// Waits for the submitted work and copies the first `bytes` of `buffer` out.
fn read_back(ctx: &GpuContext, buffer: &wgpu::Buffer, bytes: u64) -> Result<Vec<RenderPixel>> {
    let slice = buffer.slice(0..bytes);
    let (sender, receiver) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        // the receiver lives until recv() below returns
        let _ = sender.send(r);
    });
    ctx.device
        .poll(wgpu::PollType::wait_indefinitely())
        .context("waiting for the GPU to render a tile")?;
    receiver
        .recv()
        .context("the GPU dropped the tile read-back")?
        .context("mapping the tile read-back buffer")?;
    let pixels = {
        let view = slice
            .get_mapped_range()
            .context("reading the tile read-back buffer")?;
        bytemuck::cast_slice::<u8, RenderPixel>(&view).to_vec()
    };
    buffer.unmap();
    Ok(pixels)
}

/// Copies a tile's per-pixel sums over `samples` samples into the framebuffer as means (the
/// division `Framebuffer::set` does); a negative depth means every sample missed.
fn store_tile(fb: &mut Framebuffer, tile: Tile, pixels: &[RenderPixel], samples: u32) {
    let n = samples as f32;
    for j in 0..tile.h {
        for i in 0..tile.w {
            let p = &pixels[(j * tile.w + i) as usize];
            let k = ((tile.y0 + j) * fb.width + tile.x0 + i) as usize;
            fb.pixels[k] = Vec3::from_array(p.radiance) / n;
            fb.depth[k] = if p.depth < 0.0 {
                f32::INFINITY
            } else {
                p.depth
            };
            fb.normal[k] = Vec3::from_array(p.normal) / n;
            fb.albedo[k] = Vec3::from_array(p.albedo) / n;
            fb.steps[k] = p.steps / n;
            fb.gradient[k] = p.gradient / n;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn render_shader_parses_and_validates_with_naga() {
        let source = render_shader_source();
        let module = naga::front::wgsl::parse_str(&source)
            .unwrap_or_else(|e| panic!("{}", e.emit_to_string(&source)));
        naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::default(),
        )
        .validate(&module)
        .unwrap_or_else(|e| panic!("{}", e.emit_to_string(&source)));
        assert!(
            module
                .entry_points
                .iter()
                .any(|e| e.name == "render_tile_main" && e.stage == naga::ShaderStage::Compute)
        );
    }

    #[test]
    fn tiles_cover_the_image_once() {
        for (w, h, side) in [(128, 96, 64), (130, 7, 8), (1, 1, 64), (65, 64, 64)] {
            let mut covered = vec![0u32; (w * h) as usize];
            for t in tiles_of(w, h, side) {
                assert!(t.w >= 1 && t.h >= 1 && t.w <= side && t.h <= side);
                for y in t.y0..t.y0 + t.h {
                    for x in t.x0..t.x0 + t.w {
                        covered[(y * w + x) as usize] += 1;
                    }
                }
            }
            assert!(
                covered.iter().all(|&c| c == 1),
                "{w}×{h} in tiles of {side}"
            );
        }
    }
}
