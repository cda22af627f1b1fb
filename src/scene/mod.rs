//! Scene description: loading a RON scene file into validated, ready-to-trace form.
//!
//! [`Scene::load`] parses the file ([`file`]), checks every value while parsing ([`values`]),
//! resolves material names and lowers each object's SDF tree into tapes ([`crate::sdf`]).
//! Every error names the file, line and column.

pub mod camera;
pub mod file;
pub mod generate;
pub mod locate;
pub mod material;
pub mod mesh;
pub mod meshes;
pub mod model;
pub mod read;

use crate::geom::Aabb;
use crate::scene::material::MaterialParams;
use crate::sdf::lower::Step;
use crate::sdf::{self, LoweredSdf, SdfNode};
use camera::{Camera, Projection};
pub use file::Stepper;
use file::{CameraDesc, LightDesc, MaterialEntry, NormalMethod, SceneFile, ShadowDesc, ToneMap};
use glam::Vec3;
pub use meshes::{SceneMeshes, UnsetVariable, resolve_mesh_path};
use std::ffi::OsString;
use std::path::{Path, PathBuf};

/// The largest accepted image side, in pixels.
pub const MAX_IMAGE_SIDE: u32 = 16384;
/// The largest accepted number of pixels (width × height).
pub const MAX_PIXELS: u64 = 64 * 1024 * 1024;
/// The largest accepted samples per pixel.
pub const MAX_SAMPLES: u32 = 1024;
/// Largest exposure, in stops either way (2^±64 is far past any radiance an image holds).
pub const MAX_EXPOSURE: f32 = 64.0;

/// A scene error, always with the file it concerns and, where known, the place in it.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The file could not be read.
    #[error("{file}: cannot read: {error}")]
    Io {
        /// The file.
        file: PathBuf,
        /// Why (shown in the message itself, so not chained as a source).
        error: std::io::Error,
    },
    /// A problem with a whole file rather than a place in it (e.g. a mesh file with nothing
    /// to render, a camera it does not have).
    #[error("{file}: {message}")]
    File {
        /// The file.
        file: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A mesh file could not be loaded (the message names it and the place in it).
    #[error(transparent)]
    Mesh(mesh::MeshError),
    /// Syntax or value error, or an invalid setting, at a place in the file.
    #[error("{file}:{line}:{column}: {message}")]
    At {
        /// The file.
        file: PathBuf,
        /// Line, from 1.
        line: usize,
        /// Column, from 1.
        column: usize,
        /// What is wrong.
        message: String,
    },
}

/// Image settings after validation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageSettings {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Samples per pixel.
    pub samples: u32,
    /// Background radiance.
    pub background: Vec3,
    /// Exposure in stops.
    pub exposure: f32,
    /// Tone-mapping operator.
    pub tonemap: ToneMap,
}

/// Sphere-tracing settings after validation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TracerSettings {
    /// Hit threshold at t = 0.
    pub epsilon: f32,
    /// Growth of the hit threshold per unit distance.
    pub epsilon_per_unit: f32,
    /// Maximum ray distance.
    pub max_distance: f32,
    /// Maximum steps per ray.
    pub max_steps: u32,
    /// Normal estimator.
    pub normals: NormalMethod,
    /// Shadows on or off.
    pub shadows: bool,
    /// Build quality of the mesh BVHs.
    pub bvh: crate::scene::file::BuildQuality,
    /// Step rule of the sphere tracer.
    pub stepper: Stepper,
}

/// A light source.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Light {
    /// Point light at `position`.
    Point {
        /// Position.
        position: Vec3,
        /// Colour × intensity.
        radiance: Vec3,
        /// Distance beyond which the light is cut off (infinite: no cut-off); see
        /// [`range_window`].
        range: f32,
        /// Shadow kind.
        shadow: Shadow,
    },
    /// Cone of light from `position` around `direction` (KHR_lights_punctual's spot light).
    Spot {
        /// Position.
        position: Vec3,
        /// Unit direction of the cone's axis (the way the light travels).
        direction: Vec3,
        /// Colour × intensity (on the axis).
        radiance: Vec3,
        /// Cosine of the inner cone angle: full intensity inside it.
        cos_inner: f32,
        /// Cosine of the outer cone angle: no light outside it.
        cos_outer: f32,
        /// Distance beyond which the light is cut off (infinite: no cut-off).
        range: f32,
        /// Shadow kind.
        shadow: Shadow,
    },
    /// Light travelling along `direction` (unit).
    Directional {
        /// Travel direction.
        direction: Vec3,
        /// Colour × intensity.
        radiance: Vec3,
        /// Shadow kind.
        shadow: Shadow,
    },
    /// Ambient term.
    Ambient {
        /// Colour × intensity.
        radiance: Vec3,
    },
}

/// KHR_lights_punctual's recommended range window: clamp(1 − (d/range)⁴, 0, 1), which brings
/// a light to zero at `range` smoothly (1 for an infinite range).
#[inline]
pub fn range_window(distance: f32, range: f32) -> f32 {
    if range.is_finite() {
        (1.0 - (distance / range).powi(4)).clamp(0.0, 1.0)
    } else {
        1.0
    }
}

/// KHR_lights_punctual's spot-light falloff at cosine `cos_axis` between the cone's axis and
/// the direction from the light: s = clamp((cos_axis − cos_outer) / max(cos_inner − cos_outer,
/// 10⁻³), 0, 1), squared (the specification's smooth falloff).
#[inline]
pub fn spot_falloff(cos_axis: f32, cos_inner: f32, cos_outer: f32) -> f32 {
    let scale = 1.0 / (cos_inner - cos_outer).max(1e-3);
    let s = ((cos_axis - cos_outer) * scale).clamp(0.0, 1.0);
    s * s
}

/// How a light's visibility is estimated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shadow {
    /// Always visible.
    None,
    /// One shadow ray, visible or not.
    Hard,
    /// Penumbra estimate min(k·h/t) (Quilez 2010), sharpness k.
    Soft(f32),
    /// Penumbra with the closest approach between steps (Quilez 2010, improved), sharpness k.
    SoftImproved(f32),
}

impl From<ShadowDesc> for Shadow {
    fn from(d: ShadowDesc) -> Self {
        match d {
            ShadowDesc::None => Shadow::None,
            ShadowDesc::Hard => Shadow::Hard,
            ShadowDesc::Soft { k } => Shadow::Soft(k.0),
            ShadowDesc::SoftImproved { k } => Shadow::SoftImproved(k.0),
        }
    }
}

/// Ambient-occlusion settings (see [`file::AmbientOcclusionDesc`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AmbientOcclusion {
    /// Strength.
    pub strength: f32,
    /// Samples along the normal.
    pub steps: u32,
    /// Spacing of the samples.
    pub step: f32,
}

/// Shading settings after validation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShadingSettings {
    /// Ambient occlusion, if on.
    pub ambient_occlusion: Option<AmbientOcclusion>,
    /// Most reflection/refraction bounces per camera path.
    pub max_bounces: u32,
}

/// The largest accepted `shading.max_bounces`.
pub const MAX_BOUNCES: u32 = 16;

/// An SDF object ready to trace: an object of the file, or one part of an object whose shape
/// is a union of opaque members ([`sdf::parts`]).
#[derive(Debug, Clone)]
pub struct SdfObject {
    /// Name from the file, or `object N` (every part of an object has its name).
    pub name: String,
    /// The tree in world space (the object's transform wrapped around the shape).
    pub node: SdfNode,
    /// Tapes and bounds.
    pub lowered: LoweredSdf,
    /// Which part of its file object this is, when the object was split.
    pub part: Option<Part>,
}

/// The place of an [`SdfObject`] among the parts of the file object it was split from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Part {
    /// Index among the parts, from 0.
    pub index: usize,
    /// How many parts the file object was split into.
    pub count: usize,
}

impl SdfObject {
    /// World-space bounds (possibly infinite).
    pub fn bounds(&self) -> Aabb {
        self.lowered.bounds
    }

    /// The name, with the part for a part: `spiral (part 3 of 400)`.
    pub fn label(&self) -> String {
        match self.part {
            None => self.name.clone(),
            Some(p) => format!("{} (part {} of {})", self.name, p.index + 1, p.count),
        }
    }

    /// Whether this is the first traced object of its file object (every object but the
    /// second and later parts): counting these counts the file's SDF objects.
    pub fn starts_file_object(&self) -> bool {
        self.part.is_none_or(|p| p.index == 0)
    }

    /// The objects that trace `node` (the object's transform folded in), lowered with
    /// `material_index` and `default_material`: `node` as one object, or, when its root is a
    /// union ([`sdf::parts::union_members`]) whose materials are all opaque (`opaque` of a
    /// material index: no transparency, full coverage — a transparent union's inside is
    /// one, its members' insides overlap), one object per part ([`sdf::parts::parts`]). The
    /// union is lowered whole first, so that an error names its place in the whole tree.
    pub fn split(
        name: &str,
        node: SdfNode,
        material_index: &dyn Fn(&str) -> Option<u32>,
        default_material: u32,
        opaque: &dyn Fn(u32) -> bool,
    ) -> Result<Vec<SdfObject>, sdf::LowerError> {
        let lowered = sdf::lower(&node, material_index, default_material)?;
        let members = sdf::parts::union_members(&node);
        let all_opaque = opaque(default_material)
            && sdf::parts::material_names(&node)
                .into_iter()
                .all(|m| material_index(m).is_some_and(opaque));
        if members.len() < 2 || !all_opaque {
            return Ok(vec![SdfObject {
                name: name.to_string(),
                node,
                lowered,
                part: None,
            }]);
        }
        drop(lowered);
        let parts = sdf::parts::parts(members);
        let count = parts.len();
        parts
            .into_iter()
            .enumerate()
            .map(|(index, node)| {
                let lowered = sdf::lower(&node, material_index, default_material)?;
                Ok(SdfObject {
                    name: name.to_string(),
                    node,
                    lowered,
                    part: Some(Part { index, count }),
                })
            })
            .collect()
    }
}

/// A loaded scene.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Where it came from (for messages).
    pub source_name: String,
    /// Image settings.
    pub image: ImageSettings,
    /// The camera.
    pub camera: Camera,
    /// Lights.
    pub lights: Vec<Light>,
    /// Materials; index 0 is the default grey.
    pub materials: Vec<MaterialParams>,
    /// Material names, parallel to `materials`.
    pub material_names: Vec<String>,
    /// SDF objects.
    pub objects: Vec<SdfObject>,
    /// Tracer settings.
    pub tracer: TracerSettings,
    /// Shading settings.
    pub shading: ShadingSettings,
    /// Triangle meshes and their placements.
    pub meshes: SceneMeshes,
}

/// What a scene load takes from outside the scene file.
#[derive(Debug, Clone, Default)]
pub struct LoadOptions {
    /// Values of environment variables for mesh paths that start with `$NAME/` (see
    /// [`resolve_mesh_path`]), used when the environment does not set NAME: a program's
    /// defaults for the variables it documents. Later entries of the same name are ignored.
    pub variable_defaults: Vec<(String, OsString)>,
}

impl LoadOptions {
    /// Options with a default value for the variable `name`.
    pub fn with_default(mut self, name: &str, value: impl Into<OsString>) -> Self {
        self.variable_defaults
            .push((name.to_string(), value.into()));
        self
    }

    /// The value of the variable `name`: the environment's, else the default given here.
    pub fn variable(&self, name: &str) -> Option<OsString> {
        std::env::var_os(name).or_else(|| {
            self.variable_defaults
                .iter()
                .find(|(n, _)| n == name)
                .map(|(_, v)| v.clone())
        })
    }
}

impl Scene {
    /// Reads and loads a scene file.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        Scene::load_with(path, &LoadOptions::default())
    }

    /// Reads and loads a scene file with `options`.
    pub fn load_with(path: &Path, options: &LoadOptions) -> Result<Scene, SceneError> {
        let source = read::read_to_string(path).map_err(|error| SceneError::Io {
            file: path.to_path_buf(),
            error,
        })?;
        Scene::from_source_with(&source, path, options)
    }

    /// The mesh files a scene file's text names, resolved as a load resolves them (those whose
    /// `$NAME` is unset left out); none when the text does not parse. For a viewer that
    /// watches the files of a scene that failed to load (a mesh not written yet).
    pub fn mesh_files_named(source: &str, path: &Path, options: &LoadOptions) -> Vec<PathBuf> {
        let Ok(file) = parse_scene_file(scene_text(source)) else {
            return Vec::new();
        };
        (file.objects.iter())
            .filter_map(|o| o.mesh.as_deref())
            .filter_map(|mesh| resolve_mesh_path(path, mesh, |v| options.variable(v)).ok())
            .collect()
    }

    /// Loads a scene from text; `path` is used in errors and mesh paths are relative to its
    /// folder.
    pub fn from_source(source: &str, path: &Path) -> Result<Scene, SceneError> {
        Scene::from_source_with(source, path, &LoadOptions::default())
    }

    /// Loads a scene from text with `options`; `path` as for [`Scene::from_source`].
    pub fn from_source_with(
        source: &str,
        path: &Path,
        options: &LoadOptions,
    ) -> Result<Scene, SceneError> {
        let source = scene_text(source);
        let at = |offset: usize, message: String| {
            let p = locate::place_of(source, offset);
            SceneError::At {
                file: path.to_path_buf(),
                line: p.line,
                column: p.column,
                message,
            }
        };
        let file = parse_scene_file(source).map_err(|e| SceneError::At {
            file: path.to_path_buf(),
            line: e.span.start.line,
            column: e.span.start.col,
            message: if let Some(message) = non_decimal_number_at(source, e.span.start) {
                message
            } else if e.code == ron::Error::ExpectedComma && decimal_point_at(source, e.span.start)
            {
                "a whole number goes here, without a decimal point".to_string()
            } else {
                parse_message(&e.code)
            },
        })?;
        // The field itself, else its enclosing section, else the file's start.
        let top = |path: &[&str]| {
            (1..=path.len())
                .rev()
                .find_map(|n| locate::field(source, &path[..n]))
                .unwrap_or(0)
        };

        let img = &file.image;
        if img.width == 0 || img.height == 0 {
            let which = if img.width == 0 { "width" } else { "height" };
            return Err(at(
                top(&["image", which]),
                format!(
                    "image size {}×{} is empty: width and height must be at least 1",
                    img.width, img.height
                ),
            ));
        }
        if img.width > MAX_IMAGE_SIDE
            || img.height > MAX_IMAGE_SIDE
            || img.width as u64 * img.height as u64 > MAX_PIXELS
        {
            let which = if img.width > img.height {
                "width"
            } else {
                "height"
            };
            return Err(at(
                top(&["image", which]),
                format!(
                    "image size {}×{} is too large (at most {MAX_IMAGE_SIDE} per side and {MAX_PIXELS} pixels)",
                    img.width, img.height
                ),
            ));
        }
        if img.samples == 0 || img.samples > MAX_SAMPLES {
            return Err(at(
                top(&["image", "samples"]),
                format!(
                    "samples = {} is out of range 1..={MAX_SAMPLES}",
                    img.samples
                ),
            ));
        }
        if img.exposure.0.abs() > MAX_EXPOSURE {
            return Err(at(
                top(&["image", "exposure"]),
                format!(
                    "exposure = {} is out of range -{MAX_EXPOSURE}..={MAX_EXPOSURE} stops",
                    img.exposure.0
                ),
            ));
        }
        let t = &file.tracer;
        if t.max_steps == 0 || t.max_steps > 1_000_000 {
            return Err(at(
                top(&["tracer", "max_steps"]),
                format!("max_steps = {} is out of range 1..=1000000", t.max_steps),
            ));
        }
        if let Stepper::Relaxed(omega) = t.stepper {
            // ω ≥ 2 can step past a surface that the fallback test then cannot see (Keinert
            // et al. 2014, §3.1: the test needs ω·f(p) < 2·f(p)).
            if !(1.0..2.0).contains(&omega) {
                return Err(at(
                    top(&["tracer", "stepper"]),
                    format!("Relaxed({omega}): the relaxation factor must be in 1 ≤ ω < 2"),
                ));
            }
        }

        let sh = &file.shading;
        if sh.max_bounces > MAX_BOUNCES {
            return Err(at(
                top(&["shading", "max_bounces"]),
                format!(
                    "max_bounces = {} is out of range 0..={MAX_BOUNCES}",
                    sh.max_bounces
                ),
            ));
        }
        if let Some(ao) = &sh.ambient_occlusion
            && (ao.steps == 0 || ao.steps > 64)
        {
            return Err(at(
                top(&["shading", "ambient_occlusion", "steps"]),
                format!(
                    "ambient_occlusion.steps = {} is out of range 1..=64",
                    ao.steps
                ),
            ));
        }
        let shading = ShadingSettings {
            ambient_occlusion: sh.ambient_occlusion.map(|a| AmbientOcclusion {
                strength: a.strength.0,
                steps: a.steps,
                step: a.step.0,
            }),
            max_bounces: sh.max_bounces,
        };

        let camera = match &file.camera {
            CameraDesc::Perspective {
                position,
                look_at,
                up,
                fov,
            } => {
                let fov = fov.map(|f| f.0).unwrap_or(45.0);
                if fov >= 179.0 {
                    return Err(at(
                        top(&["camera", "fov"]),
                        format!("fov = {fov}° must be below 179°"),
                    ));
                }
                Camera::look_at(
                    position.0,
                    look_at.0,
                    up.map(|u| u.0).unwrap_or(Vec3::Y),
                    Projection::perspective_degrees(fov),
                )
            }
            CameraDesc::Orthographic {
                position,
                look_at,
                up,
                height,
            } => Camera::look_at(
                position.0,
                look_at.0,
                up.map(|u| u.0).unwrap_or(Vec3::Y),
                Projection::Orthographic { height: height.0 },
            ),
        }
        .map_err(|m| at(top(&["camera"]), m))?;

        let light_spans = locate::list_elements(source, "lights");
        for (i, l) in file.lights.iter().enumerate() {
            if let LightDesc::Spot {
                inner_angle,
                outer_angle,
                ..
            } = l
            {
                let inner = inner_angle.map_or(0.0, |a| a.0);
                let outer = outer_angle.map_or(45.0, |a| a.0);
                if outer > 90.0 || inner >= outer {
                    return Err(at(
                        light_spans.get(i).map_or(top(&["lights"]), |s| s.0),
                        format!(
                            "spot light: inner_angle {inner}° and outer_angle {outer}° must \
                             satisfy 0 ≤ inner_angle < outer_angle ≤ 90"
                        ),
                    ));
                }
            }
        }
        let lights = file
            .lights
            .iter()
            .map(|l| match l {
                LightDesc::Point {
                    position,
                    color,
                    intensity,
                    range,
                    shadow,
                } => Light::Point {
                    position: position.0,
                    radiance: color.0 * intensity.0,
                    range: range.map_or(f32::INFINITY, |r| r.0),
                    shadow: (*shadow).into(),
                },
                LightDesc::Spot {
                    position,
                    direction,
                    color,
                    intensity,
                    inner_angle,
                    outer_angle,
                    range,
                    shadow,
                } => Light::Spot {
                    position: position.0,
                    direction: direction.0,
                    radiance: color.0 * intensity.0,
                    cos_inner: inner_angle.map_or(0.0, |a| a.0).to_radians().cos(),
                    cos_outer: outer_angle.map_or(45.0, |a| a.0).to_radians().cos(),
                    range: range.map_or(f32::INFINITY, |r| r.0),
                    shadow: (*shadow).into(),
                },
                LightDesc::Directional {
                    direction,
                    color,
                    intensity,
                    shadow,
                } => Light::Directional {
                    direction: direction.0,
                    radiance: color.0 * intensity.0,
                    shadow: (*shadow).into(),
                },
                LightDesc::Ambient { color, intensity } => Light::Ambient {
                    radiance: color.0 * intensity.0,
                },
            })
            .collect();

        let mut materials = vec![MaterialParams::default_grey()];
        let mut material_names = vec!["(default)".to_string()];
        for (name, raw) in &file.materials.0 {
            let entry = MaterialEntry::parse(raw).map_err(|e| {
                // The nested parse places its error inside the value's own (trimmed) text;
                // shift that place by where the value starts in the file.
                let start = locate::field(source, &["materials", name])
                    .unwrap_or_else(|| top(&["materials"]));
                at(
                    start + locate::offset_of(raw.trim().get_ron(), e.span.start),
                    format!("material \"{name}\": {}", parse_message(&e.code)),
                )
            })?;
            materials.push(match &entry {
                MaterialEntry::Phong(d) => MaterialParams::from(d),
                MaterialEntry::Pbr(d) => MaterialParams::from(d),
            });
            material_names.push(name.clone());
        }
        let index_of = |name: &str| {
            material_names
                .iter()
                .skip(1)
                .position(|n| n == name)
                .map(|i| i as u32 + 1)
        };

        let spans = locate::list_elements(source, "objects");
        let mut objects = Vec::with_capacity(file.objects.len());
        let mut meshes = SceneMeshes::new(materials.len() as u32);
        for (i, o) in file.objects.iter().enumerate() {
            let span = spans.get(i).copied().unwrap_or((0, source.len()));
            let name = o.name.clone().unwrap_or_else(|| format!("object {i}"));
            let material = match &o.material {
                None => 0,
                Some(m) => index_of(m).ok_or_else(|| {
                    let pos = locate::follow(source, span.0, &[locate::Nav::Field("material")]);
                    at(
                        pos,
                        format!(
                            "{name}: unknown material \"{m}\" (defined: {})",
                            defined(&material_names)
                        ),
                    )
                })?,
            };
            let wrapped = o.translate.is_some() || o.rotate.is_some() || o.scale.is_some();
            let shape = match (&o.shape, &o.mesh) {
                (Some(shape), None) => shape,
                (None, Some(file)) => {
                    // Found only for an error: `follow` reads the file's text again, and a scene
                    // of many meshes paid for it once per object (quadratic in the file).
                    let place = || locate::follow(source, span.0, &[locate::Nav::Field("mesh")]);
                    let (transform, _) = sdf::lower::transform_of(&SdfNode::Transform {
                        translate: o.translate,
                        rotate: o.rotate,
                        scale: o.scale,
                        shape: Box::new(SdfNode::Union(Vec::new())),
                    });
                    let override_material = o.material.as_ref().map(|_| material);
                    let mesh_path = resolve_mesh_path(path, file, |v| options.variable(v))
                        .map_err(|e| at(place(), format!("{name}: {e}")))?;
                    meshes
                        .add_file(&mesh_path, transform, override_material, &name)
                        .map_err(|e| at(place(), format!("{name}: {e}")))?;
                    continue;
                }
                (Some(_), Some(_)) => {
                    let place = locate::follow(source, span.0, &[locate::Nav::Field("mesh")]);
                    return Err(at(
                        place,
                        format!("{name}: give either `shape` or `mesh`, not both"),
                    ));
                }
                (None, None) => {
                    return Err(at(
                        span.0,
                        format!(
                            "{name}: an object needs a `shape` (an SDF tree) or a `mesh` (a file)"
                        ),
                    ));
                }
            };
            let node = if wrapped {
                SdfNode::Transform {
                    translate: o.translate,
                    rotate: o.rotate,
                    scale: o.scale,
                    shape: Box::new(shape.clone()),
                }
            } else {
                shape.clone()
            };
            let opaque = |m: u32| {
                let m = &materials[m as usize];
                m.transparency <= 0.0 && m.opacity >= 1.0
            };
            let parts =
                SdfObject::split(&name, node, &index_of, material, &opaque).map_err(|e| {
                    // Point at the failing node (or field) by following its path in the text; the
                    // object's own translate/rotate/scale wrapper does not appear there.
                    let mut steps = e.path.as_slice();
                    if wrapped {
                        steps = steps.get(2..).unwrap_or(&[]);
                    }
                    let mut nav = vec![locate::Nav::Field("shape")];
                    nav.extend(steps.iter().map(|s| match s {
                        Step::Node(k) => locate::Nav::Node(k),
                        Step::Field(f) => locate::Nav::Field(f),
                        Step::Index(i) => locate::Nav::Index(*i),
                    }));
                    let pos = locate::follow(source, span.0, &nav);
                    let extra = if e.message.starts_with("unknown material") {
                        format!(" (defined: {})", defined(&material_names))
                    } else {
                        String::new()
                    };
                    let shown = sdf::LowerError {
                        path: steps.to_vec(),
                        message: e.message.clone(),
                    };
                    at(pos, format!("{name}: {shown}{extra}"))
                })?;
            objects.extend(parts);
        }

        materials.extend(meshes.materials.iter().map(|m| m.params));
        material_names.extend(meshes.materials.iter().map(|m| m.name.clone()));
        Ok(Scene {
            source_name: path.display().to_string(),
            image: ImageSettings {
                width: img.width,
                height: img.height,
                samples: img.samples,
                background: img.background.0,
                exposure: img.exposure.0,
                tonemap: img.tonemap,
            },
            camera,
            lights,
            materials,
            material_names,
            objects,
            tracer: TracerSettings {
                epsilon: t.epsilon.0,
                epsilon_per_unit: t.epsilon_per_unit.0,
                max_distance: t.max_distance.0,
                max_steps: t.max_steps,
                normals: t.normals,
                shadows: t.shadows,
                bvh: t.bvh,
                stepper: t.stepper,
            },
            shading,
            meshes,
        })
    }

    /// The SDF objects of the file: an object split into parts counts once.
    pub fn sdf_object_count(&self) -> usize {
        self.objects
            .iter()
            .filter(|o| o.starts_file_object())
            .count()
    }

    /// Bounds of everything finite in the scene (infinite objects are left out).
    pub fn finite_bounds(&self) -> Aabb {
        self.objects
            .iter()
            .map(|o| o.bounds())
            .filter(|b| b.is_finite())
            .fold(Aabb::EMPTY, |acc, b| acc.union(&b))
    }

    /// Every material packed for the tape.
    pub fn material_table(&self) -> Vec<sdf::tape::MaterialVec> {
        self.materials.iter().map(|m| m.to_vec()).collect()
    }
}

/// A scene file's text without its byte-order mark, if it has one (some Windows editors write
/// one): what every parse reads and every place in an error counts in, as the editor shows it.
fn scene_text(source: &str) -> &str {
    source.strip_prefix('\u{feff}').unwrap_or(source)
}

/// Parses a scene file's text (see [`scene_text`]). `implicit_some` lets optional fields be
/// written plainly (`fov: 40`, not `Some(40)`).
fn parse_scene_file(text: &str) -> Result<SceneFile, ron::error::SpannedError> {
    ron::Options::default()
        .with_default_extension(ron::extensions::Extensions::IMPLICIT_SOME)
        .from_str(text)
}

/// Whether the parser stopped at a decimal point that follows digits: `width: 800.5`, where a
/// whole number goes, is read as 800 followed by something that is not a comma.
fn decimal_point_at(source: &str, at: ron::error::Position) -> bool {
    let Some(line) = source.lines().nth(at.line.saturating_sub(1)) else {
        return false;
    };
    let chars: Vec<char> = line.chars().collect();
    let i = at.col.saturating_sub(1);
    i > 0 && chars.get(i) == Some(&'.') && chars[i - 1].is_ascii_digit()
}

/// When the parser stopped in or at a hexadecimal, binary or octal literal (`0x10`: it reads
/// the 0 as a number, then fails on what follows or takes the value 0), the message that says
/// so.
fn non_decimal_number_at(source: &str, at: ron::error::Position) -> Option<String> {
    let line: Vec<char> = source
        .lines()
        .nth(at.line.checked_sub(1)?)?
        .chars()
        .collect();
    // back to the start of the word the position is in (with its sign)
    let mut start = at.col.checked_sub(1)?.min(line.len());
    while start > 0 && (line[start - 1].is_ascii_alphanumeric() || line[start - 1] == '_') {
        start -= 1;
    }
    if start > 0 && matches!(line[start - 1], '-' | '+') {
        start -= 1;
    }
    let rest: String = line[start..].iter().collect();
    let digits = rest.trim_start_matches(['-', '+']);
    let radix = match digits.get(..2)? {
        "0x" | "0X" => 16,
        "0b" | "0B" => 2,
        "0o" | "0O" => 8,
        _ => return None,
    };
    let literal: String = rest
        .chars()
        .take_while(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '+' | '_'))
        .collect();
    let body: String = (digits[2..].chars())
        .take_while(|c| c.is_digit(radix) || *c == '_')
        .filter(|c| *c != '_')
        .collect();
    let sign = if rest.starts_with('-') { "-" } else { "" };
    Some(match u64::from_str_radix(&body, radix) {
        Ok(v) => {
            format!("`{literal}`: numbers are written in decimal here (this one is {sign}{v})")
        }
        Err(_) => format!("`{literal}`: numbers are written in decimal here"),
    })
}

/// The parser's message, with advice meant for Rust developers turned into advice for users.
fn parse_message(code: &ron::Error) -> String {
    match code {
        ron::Error::ExceededRecursionLimit => {
            "the file nests more than 128 levels deep (an SDF node inside another takes about \
             three: some 40 nested nodes); flatten the tree (e.g. one Union with many shapes \
             instead of nested Unions)"
                .to_string()
        }
        other => other.to_string(),
    }
}

fn defined(names: &[String]) -> String {
    if names.len() <= 1 {
        "none".to_string()
    } else {
        names[1..].join(", ")
    }
}

/// The `.ron` scene files of a folder: the showcase first, then the others by name.
pub fn scene_files(dir: &Path) -> std::io::Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "ron"))
        .collect();
    files.sort_by_key(|p| (p.file_stem().is_none_or(|s| s != "showcase"), p.clone()));
    Ok(files)
}

/// Every scene file shipped in `assets/scenes`, loaded, with its file stem (for tests that run
/// over all of them; `hybrid.ron` names the shared models through an environment variable,
/// which `scripts/test.sh` exports and `.cargo/config.toml` defaults for every cargo run).
/// Panics on a file that does not load (an unset variable's error names it).
#[cfg(test)]
pub(crate) fn shipped_scenes() -> Vec<(String, Scene)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/scenes");
    let files = scene_files(&dir).expect("assets/scenes");
    assert!(!files.is_empty(), "no scenes in {}", dir.display());
    files
        .iter()
        .map(|p| {
            let scene = Scene::load(p).unwrap_or_else(|e| panic!("{e}"));
            (p.file_stem().unwrap().to_string_lossy().into_owned(), scene)
        })
        .collect()
}
