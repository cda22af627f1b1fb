//! Host-side packing of what the GPU shading and render kernels read: camera, lights, shading
//! settings, the pixels being rendered and the per-pixel sums, as `#[repr(C)]` Pod structs whose
//! WGSL twins (and the constants the shaders test against) are generated here.

use crate::gpu::layout::{WgslStruct, WgslType};
use crate::gpu::shaders::{BindingKind, Bindings, bindings_wgsl, shadow_code};
use crate::render::RenderOptions;
use crate::render::Tile;
use crate::scene::camera::{Camera, Projection};
use crate::scene::{Light, MAX_BOUNCES, Scene, Shadow};
use glam::Vec3;

crate::gpu_struct! {
    /// The camera (`scene::camera::Camera`): `scale` is tan(fov/2) for a pinhole camera and
    /// the view height for an orthographic one.
    pub struct ShadeCamera (64) {
        /// Eye (perspective) or image-plane centre (orthographic).
        pub position: [f32; 3],
        /// [`PROJECTION_PERSPECTIVE`] or [`PROJECTION_ORTHOGRAPHIC`].
        pub projection: u32,
        /// Unit viewing direction.
        pub forward: [f32; 3],
        /// tan(fov_y / 2), or the orthographic view height.
        pub scale: f32,
        /// Unit right vector.
        pub right: [f32; 3],
        /// Unused.
        pub _pad0: u32,
        /// Unit up vector.
        pub up: [f32; 3],
        /// Unused.
        pub _pad1: u32,
    }
}

crate::gpu_struct! {
    /// Scene-wide shading settings: background, bounce limit, shadows switch, ambient
    /// occlusion (`ao_steps` = 0: off) and the light count (tracer ε is in `SceneGlobals`).
    pub struct ShadeSettings (48) {
        /// Background radiance.
        pub background: [f32; 3],
        /// Number of lights in the light buffer.
        pub light_count: u32,
        /// `shading.max_bounces`.
        pub max_bounces: u32,
        /// 1 when shadows are on.
        pub shadows: u32,
        /// Ambient-occlusion samples along the normal (0: no ambient occlusion).
        pub ao_steps: u32,
        /// Ambient-occlusion strength.
        pub ao_strength: f32,
        /// Spacing of the ambient-occlusion samples.
        pub ao_step: f32,
        /// Unused.
        pub _pad0: u32,
        /// Unused.
        pub _pad1: u32,
        /// Unused.
        pub _pad2: u32,
    }
}

crate::gpu_struct! {
    /// One light: `vector` is the position of a point or spot light and the travel direction
    /// of a directional one; `shadow` and `shadow_k` are the `scene_visibility` arguments; a
    /// spot light's cone is `axis`, `cos_inner` and `cos_outer`; `range` is the light's range
    /// (0: none, since WGSL has no infinity to compare with).
    pub struct ShadeLight (64) {
        /// Position (point, spot) or unit travel direction (directional).
        pub vector: [f32; 3],
        /// [`LIGHT_POINT`], [`LIGHT_SPOT`], [`LIGHT_DIRECTIONAL`] or [`LIGHT_AMBIENT`].
        pub kind: u32,
        /// Colour × intensity.
        pub radiance: [f32; 3],
        /// Shadow kind, numbered as `scene_visibility` expects.
        pub shadow: u32,
        /// Soft-shadow sharpness k.
        pub shadow_k: f32,
        /// Cosine of a spot light's inner cone angle.
        pub cos_inner: f32,
        /// Cosine of a spot light's outer cone angle.
        pub cos_outer: f32,
        /// Range of a point or spot light (0: unlimited).
        pub range: f32,
        /// Unit direction of a spot light's axis.
        pub axis: [f32; 3],
        /// Unused.
        pub _pad0: u32,
    }
}

crate::gpu_struct! {
    /// The image, the pixels one dispatch renders and where their sums are: the output buffer
    /// holds a rectangle of the image (all of it, or one tile) row by row.
    pub struct RenderTile (48) {
        /// Image width.
        pub width: u32,
        /// Image height.
        pub height: u32,
        /// Samples per pixel.
        pub samples: u32,
        /// Left column of the pixels rendered.
        pub x0: u32,
        /// Top row of the pixels rendered.
        pub y0: u32,
        /// Width of the pixels rendered.
        pub w: u32,
        /// Height of the pixels rendered.
        pub h: u32,
        /// The sample this dispatch adds (0 ..= samples − 1).
        pub sample: u32,
        /// Left column of the rectangle the output buffer holds.
        pub sums_x0: u32,
        /// Top row of the rectangle the output buffer holds.
        pub sums_y0: u32,
        /// Width of the rectangle the output buffer holds (its row length).
        pub sums_width: u32,
        /// 1: add to the sums in the buffer; 0: this is their first sample.
        pub accumulate: u32,
    }
}

crate::gpu_struct! {
    /// One rendered pixel: the sums over its samples so far (`render::progressive::PixelSums`,
    /// which the host divides by the count) and the nearest depth, < 0 while every sample missed.
    pub struct RenderPixel (64) {
        /// Sum of linear radiance.
        pub radiance: [f32; 3],
        /// Nearest first-hit distance, or −1.
        pub depth: f32,
        /// Sum of first-hit normals.
        pub normal: [f32; 3],
        /// Sum of the camera rays' sphere-tracing steps.
        pub steps: f32,
        /// Sum of first-hit albedos.
        pub albedo: [f32; 3],
        /// Sum of |∇f| at the first hits.
        pub gradient: f32,
        /// Samples whose kernel invocation the driver cut short (`loops_were_cut` in
        /// shaders/tape.wgsl): their sums are wrong.
        pub cut: u32,
        /// Unused.
        pub pad0: u32,
        /// Unused.
        pub pad1: u32,
        /// Unused.
        pub pad2: u32,
    }
}

/// `ShadeCamera::projection` of a pinhole camera.
pub const PROJECTION_PERSPECTIVE: u32 = 0;
/// `ShadeCamera::projection` of an orthographic camera.
pub const PROJECTION_ORTHOGRAPHIC: u32 = 1;
/// `ShadeLight::kind` of a point light.
pub const LIGHT_POINT: u32 = 0;
/// `ShadeLight::kind` of a directional light.
pub const LIGHT_DIRECTIONAL: u32 = 1;
/// `ShadeLight::kind` of an ambient light.
pub const LIGHT_AMBIENT: u32 = 2;
/// `ShadeLight::kind` of a spot light.
pub const LIGHT_SPOT: u32 = 3;
/// Capacity of the render kernel's path stack: max_bounces + 1 entries at most are pending
/// (see `shade::integrator`), and one more keeps the bound obvious.
pub const RENDER_STACK: u32 = MAX_BOUNCES + 2;

/// The render kernel's group 1, what the scene fixes: its shading settings and lights.
pub fn shading_bindings() -> Bindings {
    vec![
        (
            "shade_settings",
            BindingKind::Uniform,
            ShadeSettings::wgsl_name(),
        ),
        (
            "shade_lights",
            BindingKind::Storage,
            format!("array<{}>", ShadeLight::wgsl_name()),
        ),
    ]
}

/// The render kernel's group 2, one pass: the camera, the rectangle rendered and the sums it
/// adds to.
pub fn pass_bindings() -> Bindings {
    vec![
        (
            "shade_camera",
            BindingKind::Uniform,
            ShadeCamera::wgsl_name(),
        ),
        ("render_tile", BindingKind::Uniform, RenderTile::wgsl_name()),
        (
            "render_pixels",
            BindingKind::StorageReadWrite,
            format!("array<{}>", RenderPixel::wgsl_name()),
        ),
    ]
}

/// The WGSL declarations of this module's structs and constants, generated from the Rust ones.
pub fn wgsl_prelude() -> String {
    let mut s =
        String::from("// Generated from src/gpu/shade.rs by hytrace::gpu::shade::wgsl_prelude.\n");
    for decl in [
        ShadeCamera::wgsl(),
        ShadeSettings::wgsl(),
        ShadeLight::wgsl(),
        RenderTile::wgsl(),
        RenderPixel::wgsl(),
    ] {
        s += &decl;
    }
    // group 1: what the scene fixes; group 2: the view and the sums it accumulates into
    s += &bindings_wgsl(1, &shading_bindings());
    s += &bindings_wgsl(2, &pass_bindings());
    for (name, value) in [
        ("PROJECTION_PERSPECTIVE", PROJECTION_PERSPECTIVE),
        ("PROJECTION_ORTHOGRAPHIC", PROJECTION_ORTHOGRAPHIC),
        ("LIGHT_POINT", LIGHT_POINT),
        ("LIGHT_DIRECTIONAL", LIGHT_DIRECTIONAL),
        ("LIGHT_AMBIENT", LIGHT_AMBIENT),
        ("LIGHT_SPOT", LIGHT_SPOT),
        ("MAX_BOUNCES", MAX_BOUNCES),
        ("RENDER_STACK", RENDER_STACK),
    ] {
        s += &format!("const {name}: u32 = {value}u;\n");
    }
    s
}

impl ShadeCamera {
    /// Packs a camera.
    pub fn new(camera: &Camera) -> Self {
        let (projection, scale) = match camera.projection {
            Projection::Perspective { tan_half_fov } => (PROJECTION_PERSPECTIVE, tan_half_fov),
            Projection::Orthographic { height } => (PROJECTION_ORTHOGRAPHIC, height),
        };
        ShadeCamera {
            position: camera.position.to_array(),
            projection,
            forward: camera.forward.to_array(),
            scale,
            right: camera.right.to_array(),
            up: camera.up.to_array(),
            ..Default::default()
        }
    }
}

impl ShadeSettings {
    /// Packs the scene's shading and tracer settings.
    pub fn new(scene: &Scene) -> Self {
        let ao = scene.shading.ambient_occlusion;
        ShadeSettings {
            background: scene.image.background.to_array(),
            light_count: scene.lights.len() as u32,
            max_bounces: scene.shading.max_bounces,
            shadows: scene.tracer.shadows as u32,
            ao_steps: ao.map_or(0, |a| a.steps),
            ao_strength: ao.map_or(0.0, |a| a.strength),
            ao_step: ao.map_or(0.0, |a| a.step),
            ..Default::default()
        }
    }
}

impl ShadeLight {
    /// Packs a light.
    pub fn new(light: &Light) -> Self {
        let finite_or_zero = |r: f32| if r.is_finite() { r } else { 0.0 };
        match *light {
            Light::Point {
                position,
                radiance,
                range,
                shadow,
            } => ShadeLight {
                range: finite_or_zero(range),
                ..ShadeLight::packed(LIGHT_POINT, position, radiance, shadow)
            },
            Light::Spot {
                position,
                direction,
                radiance,
                cos_inner,
                cos_outer,
                range,
                shadow,
            } => ShadeLight {
                cos_inner,
                cos_outer,
                range: finite_or_zero(range),
                axis: direction.to_array(),
                ..ShadeLight::packed(LIGHT_SPOT, position, radiance, shadow)
            },
            Light::Directional {
                direction,
                radiance,
                shadow,
            } => ShadeLight::packed(LIGHT_DIRECTIONAL, direction, radiance, shadow),
            Light::Ambient { radiance } => {
                ShadeLight::packed(LIGHT_AMBIENT, Vec3::ZERO, radiance, Shadow::None)
            }
        }
    }

    fn packed(kind: u32, vector: Vec3, radiance: Vec3, shadow: Shadow) -> Self {
        let (shadow, shadow_k) = shadow_code(shadow);
        ShadeLight {
            vector: vector.to_array(),
            kind,
            radiance: radiance.to_array(),
            shadow,
            shadow_k,
            ..Default::default()
        }
    }
}

impl RenderTile {
    /// Sample `sample` of the pixels `pixels` of an image rendered with `opts`, into an output
    /// buffer holding the rectangle `sums` (which contains `pixels`), added to the sums already
    /// there when `accumulate`.
    pub fn new(
        opts: &RenderOptions,
        pixels: Tile,
        sums: Tile,
        sample: u32,
        accumulate: bool,
    ) -> Self {
        RenderTile {
            width: opts.width,
            height: opts.height,
            samples: opts.samples,
            x0: pixels.x0,
            y0: pixels.y0,
            w: pixels.w,
            h: pixels.h,
            sample,
            sums_x0: sums.x0,
            sums_y0: sums.y0,
            sums_width: sums.w,
            accumulate: accumulate as u32,
        }
    }
}
