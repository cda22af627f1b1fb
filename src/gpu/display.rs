//! Drawing a picture onto a window's texture: 8-bit pixels from the host, or the render
//! kernel's sums of samples tone-mapped where they are (no read-back), scaled to the target by
//! repeating pixels, with a heads-up band of text over the top.

use super::GpuError;
use super::context::{GpuContext, MIN_STORAGE_BYTES};
use super::layout::WgslStruct;
use super::shade::RenderPixel;
use crate::render::output::ToneMapping;
use crate::scene::file::ToneMap;
use image::{RgbImage, RgbaImage};

/// The display shader: the generated prelude, then `shaders/display.wgsl`.
const DISPLAY_WGSL: &str = include_str!("../../shaders/display.wgsl");

crate::gpu_struct! {
    /// What the display shader draws and how.
    pub struct DisplaySettings (48) {
        /// Target width in pixels.
        pub window_width: u32,
        /// Target height in pixels.
        pub window_height: u32,
        /// Width of the picture (scaled to the target by repeating pixels).
        pub picture_width: u32,
        /// Height of the picture.
        pub picture_height: u32,
        /// Rows of the heads-up band at the top (0: none).
        pub band_rows: u32,
        /// 1 when the target encodes to sRGB on writing (so the shader writes linear values).
        pub srgb_target: u32,
        /// Passes in the sums; 0 when the picture is the host's 8-bit pixels.
        pub passes: u32,
        /// `DISPLAY_TONE_*`.
        pub tone_operator: u32,
        /// 2^exposure, as `ToneMapping::apply` multiplies radiance by it.
        pub exposure_scale: f32,
        /// Unused.
        pub _pad0: u32,
        /// Unused.
        pub _pad1: u32,
        /// Unused.
        pub _pad2: u32,
    }
}

/// `DisplaySettings::tone_operator` of [`ToneMap::Clamp`].
pub const DISPLAY_TONE_CLAMP: u32 = 0;
/// `DisplaySettings::tone_operator` of [`ToneMap::Reinhard`].
pub const DISPLAY_TONE_REINHARD: u32 = 1;
/// `DisplaySettings::tone_operator` of [`ToneMap::Aces`].
pub const DISPLAY_TONE_ACES: u32 = 2;

/// The display shader's source: the shared declarations generated from Rust, then the file.
pub fn display_shader_source() -> String {
    let mut s = String::from("// Generated from src/gpu/display.rs.\n");
    s += &RenderPixel::wgsl();
    s += &DisplaySettings::wgsl();
    for (name, value) in [
        ("DISPLAY_TONE_CLAMP", DISPLAY_TONE_CLAMP),
        ("DISPLAY_TONE_REINHARD", DISPLAY_TONE_REINHARD),
        ("DISPLAY_TONE_ACES", DISPLAY_TONE_ACES),
    ] {
        s += &format!("const {name}: u32 = {value}u;\n");
    }
    s + DISPLAY_WGSL
}

/// The picture to show.
pub enum Shown<'a> {
    /// 8-bit sRGB pixels, RGBA, rows top to bottom.
    Pixels {
        /// `width`×`height`×4 bytes.
        rgba: &'a [u8],
        /// Width.
        width: u32,
        /// Height.
        height: u32,
    },
    /// The render kernel's sums of `passes` samples per pixel of a `width`×`height` image
    /// (one [`RenderPixel`] per pixel, row-major), tone-mapped as `tone` says.
    Sums {
        /// The sums.
        buffer: &'a wgpu::Buffer,
        /// Samples summed (at least 1).
        passes: u32,
        /// Width.
        width: u32,
        /// Height.
        height: u32,
        /// Exposure and operator.
        tone: ToneMapping,
    },
}

/// The heads-up band: text pixels (alpha 255) over the darkened top rows of the target,
/// `width` being the target's.
pub struct HeadsUp<'a> {
    /// The band's text; its height is the band's.
    pub text: &'a RgbaImage,
}

/// The pipeline that draws [`Shown`] pictures into targets of one format.
pub struct Display {
    device: wgpu::Device,
    queue: wgpu::Queue,
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    target_format: wgpu::TextureFormat,
    settings: wgpu::Buffer,
    /// Stand in for the bindings a picture does not use: sums, and a 1×1 texture for the
    /// host's pixels or the band's text.
    empty_sums: wgpu::Buffer,
    blank: wgpu::Texture,
    /// The last pixels texture, reused while its size stays.
    pixels: Option<(wgpu::Texture, u32, u32)>,
}

impl Display {
    /// The pipeline for targets of `target_format` on `ctx`'s device.
    pub fn new(ctx: &GpuContext, target_format: wgpu::TextureFormat) -> Display {
        let device = &ctx.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("display.wgsl"),
            source: wgpu::ShaderSource::Wgsl(display_shader_source().into()),
        });
        let texture = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::FRAGMENT,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: false },
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
            count: None,
        };
        let buffer = |binding, ty| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::FRAGMENT,
            ty: wgpu::BindingType::Buffer {
                ty,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("display bindings"),
            entries: &[
                buffer(0, wgpu::BufferBindingType::Uniform),
                texture(1),
                buffer(2, wgpu::BufferBindingType::Storage { read_only: true }),
                texture(3),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("display pipeline layout"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("display pipeline"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("cover_vertex"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("display_fragment"),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format: target_format,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: None,
            multisample: wgpu::MultisampleState::default(),
            multiview_mask: None,
            cache: None,
        });
        let blank = rgba8_texture(
            device,
            "blank",
            (1, 1),
            wgpu::TextureUsages::TEXTURE_BINDING,
        );
        Display {
            blank,
            device: ctx.device.clone(),
            queue: ctx.queue.clone(),
            pipeline,
            layout,
            target_format,
            settings: ctx.uniform_buffer(
                "display settings",
                bytemuck::bytes_of(&DisplaySettings::default()),
            ),
            empty_sums: ctx.storage_buffer("no sums", &[0u8; MIN_STORAGE_BYTES], false),
            pixels: None,
        }
    }

    /// Draws `shown` with `heads_up` over it into `target` (of the pipeline's format and
    /// `size`), then submits.
    pub fn draw(
        &mut self,
        target: &wgpu::TextureView,
        size: (u32, u32),
        shown: &Shown,
        heads_up: &HeadsUp,
    ) -> Result<(), GpuError> {
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        self.encode(&mut encoder, target, size, shown, heads_up)?;
        self.queue.submit([encoder.finish()]);
        Ok(())
    }

    fn encode(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        target: &wgpu::TextureView,
        (window_width, window_height): (u32, u32),
        shown: &Shown,
        heads_up: &HeadsUp,
    ) -> Result<(), GpuError> {
        let (width, height) = match *shown {
            Shown::Pixels { width, height, .. } | Shown::Sums { width, height, .. } => {
                (width, height)
            }
        };
        if width == 0 || height == 0 || window_width == 0 || window_height == 0 {
            return Err(GpuError::Unsupported(format!(
                "a picture of {width}×{height} pixels on a target of \
                 {window_width}×{window_height}"
            )));
        }
        let (passes, tone) = match shown {
            Shown::Pixels { rgba, .. } => {
                if rgba.len() != width as usize * height as usize * 4 {
                    return Err(GpuError::Unsupported(format!(
                        "a picture of {width}×{height} pixels with {} bytes",
                        rgba.len()
                    )));
                }
                // pixels are tone-mapped already: the shader reads no tone map for them
                let unused = ToneMapping {
                    exposure: 0.0,
                    operator: ToneMap::Clamp,
                };
                (0, unused)
            }
            Shown::Sums {
                buffer,
                passes,
                tone,
                ..
            } => {
                let needed = width as u64 * height as u64 * size_of::<RenderPixel>() as u64;
                if buffer.size() < needed || *passes == 0 {
                    return Err(GpuError::Unsupported(format!(
                        "sums of {passes} passes in {} bytes for a {width}×{height} picture",
                        buffer.size()
                    )));
                }
                (*passes, *tone)
            }
        };
        let text = heads_up.text;
        let band_rows = if text.width() == window_width {
            text.height().min(window_height)
        } else {
            0
        };
        let settings = DisplaySettings {
            window_width,
            window_height,
            picture_width: width,
            picture_height: height,
            band_rows,
            srgb_target: self.target_format.is_srgb() as u32,
            passes,
            tone_operator: match tone.operator {
                ToneMap::Clamp => DISPLAY_TONE_CLAMP,
                ToneMap::Reinhard => DISPLAY_TONE_REINHARD,
                ToneMap::Aces => DISPLAY_TONE_ACES,
            },
            exposure_scale: tone.exposure.exp2(),
            ..Default::default()
        };
        self.queue
            .write_buffer(&self.settings, 0, bytemuck::bytes_of(&settings));
        let picture = match shown {
            Shown::Pixels { rgba, .. } => self.pixels_texture(rgba, width, height),
            Shown::Sums { .. } => self.blank.clone(),
        };
        let text_texture = if band_rows > 0 {
            let rows = &text.as_raw()[..(window_width * band_rows * 4) as usize];
            self.texture("heads-up text", rows, window_width, band_rows)
        } else {
            self.blank.clone()
        };
        let sums = match shown {
            Shown::Sums { buffer, .. } => *buffer,
            Shown::Pixels { .. } => &self.empty_sums,
        };
        let picture_view = picture.create_view(&Default::default());
        let text_view = text_texture.create_view(&Default::default());
        let bind = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("display binding"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: self.settings.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&picture_view),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: sums.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: wgpu::BindingResource::TextureView(&text_view),
                },
            ],
        });
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("display"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: target,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: None,
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &bind, &[]);
        pass.draw(0..3, 0..1);
        Ok(())
    }

    /// The host's pixels in the reused texture (made again when the size changes).
    fn pixels_texture(&mut self, rgba: &[u8], width: u32, height: u32) -> wgpu::Texture {
        match &self.pixels {
            Some((t, w, h)) if (*w, *h) == (width, height) => {
                let t = t.clone();
                self.upload(&t, rgba, width, height);
                t
            }
            _ => {
                let t = self.texture("picture", rgba, width, height);
                self.pixels = Some((t.clone(), width, height));
                t
            }
        }
    }

    /// A new 8-bit RGBA texture holding `rgba` (read as codes, not decoded from sRGB).
    fn texture(&self, label: &str, rgba: &[u8], width: u32, height: u32) -> wgpu::Texture {
        let t = rgba8_texture(
            &self.device,
            label,
            (width, height),
            wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        );
        self.upload(&t, rgba, width, height);
        t
    }

    fn upload(&self, texture: &wgpu::Texture, rgba: &[u8], width: u32, height: u32) {
        self.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            rgba,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(4 * width),
                rows_per_image: Some(height),
            },
            wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
        );
    }
}

/// A 2D texture of 8-bit RGBA codes.
fn rgba8_texture(
    device: &wgpu::Device,
    label: &str,
    (width, height): (u32, u32),
    usage: wgpu::TextureUsages,
) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba8Unorm,
        usage,
        view_formats: &[],
    })
}

/// Draws `shown` with `heads_up` as [`Display::draw`] does into a `width`×`height` target
/// made for it, and reads the result back: what a window of that size shows.
pub fn capture(
    ctx: &GpuContext,
    display: &mut Display,
    size: (u32, u32),
    shown: &Shown,
    heads_up: &HeadsUp,
) -> Result<RgbImage, GpuError> {
    let (width, height) = size;
    if display.target_format != wgpu::TextureFormat::Rgba8Unorm {
        return Err(GpuError::Unsupported(
            "captures are drawn by a display for Rgba8Unorm targets".into(),
        ));
    }
    let target = rgba8_texture(
        &ctx.device,
        "capture",
        size,
        wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
    );
    // rows of a texture-to-buffer copy are padded to 256 bytes
    let row = (4 * width).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
        * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
    let buffer = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("capture rows"),
        size: row as u64 * height as u64,
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    let mut encoder = ctx
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
    let view = target.create_view(&Default::default());
    display.encode(&mut encoder, &view, size, shown, heads_up)?;
    encoder.copy_texture_to_buffer(
        wgpu::TexelCopyTextureInfo {
            texture: &target,
            mip_level: 0,
            origin: wgpu::Origin3d::ZERO,
            aspect: wgpu::TextureAspect::All,
        },
        wgpu::TexelCopyBufferInfo {
            buffer: &buffer,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(row),
                rows_per_image: Some(height),
            },
        },
        wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        },
    );
    ctx.queue.submit([encoder.finish()]);
    let bytes = ctx.read_buffer(&buffer, buffer.size())?;
    let mut img = RgbImage::new(width, height);
    for (y, line) in bytes.chunks_exact(row as usize).enumerate() {
        for x in 0..width as usize {
            let p = &line[4 * x..4 * x + 3];
            img.put_pixel(x as u32, y as u32, image::Rgb([p[0], p[1], p[2]]));
        }
    }
    Ok(img)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn display_shader_parses_and_validates_with_naga() {
        let module = crate::gpu::shaders::validate("display", &display_shader_source());
        for (name, stage) in [
            ("cover_vertex", naga::ShaderStage::Vertex),
            ("display_fragment", naga::ShaderStage::Fragment),
        ] {
            assert!(
                module
                    .entry_points
                    .iter()
                    .any(|e| e.name == name && e.stage == stage),
                "{name}"
            );
        }
    }
}
