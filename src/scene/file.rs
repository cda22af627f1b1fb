//! The scene file format (RON): what a user writes, field by field, with defaults.
//!
//! Every field is documented in `docs/scene-format.md`; unknown fields are errors. Values are
//! validated while parsing (see [`super::values`]), so errors carry line and column.

use crate::geom::values::{Color, Direction, Finite, FiniteVec3, NonNegative, Positive, Unit};
use crate::sdf::SdfNode;
use serde::Deserialize;
use std::collections::HashSet;

/// A whole scene file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, rename = "Scene")]
pub struct SceneFile {
    /// Output image settings.
    #[serde(default)]
    pub image: ImageDesc,
    /// The camera.
    pub camera: CameraDesc,
    /// Light sources.
    #[serde(default)]
    pub lights: Vec<LightDesc>,
    /// Named materials, referenced by objects and `Material` nodes.
    #[serde(default)]
    pub materials: Materials,
    /// The objects.
    #[serde(default)]
    pub objects: Vec<ObjectDesc>,
    /// Sphere-tracing parameters.
    #[serde(default)]
    pub tracer: TracerDesc,
    /// Shading effects: ambient occlusion and secondary rays.
    #[serde(default)]
    pub shading: ShadingDesc,
}

/// Shading effects beyond direct light.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ShadingDesc {
    /// Ambient occlusion from the distance field (off when absent).
    pub ambient_occlusion: Option<AmbientOcclusionDesc>,
    /// Most reflection/refraction bounces along one camera path (0 = none).
    pub max_bounces: u32,
}

impl Default for ShadingDesc {
    fn default() -> Self {
        ShadingDesc {
            ambient_occlusion: None,
            max_bounces: 4,
        }
    }
}

/// Ambient occlusion by sampling the distance field along the normal (Evans, "Fast
/// approximations for global illumination on dynamic scenes", 2006; as in the CS171 report):
/// ao = clamp(1 − strength · Σᵢ 2⁻ⁱ (i·step − d(p + n·i·step)) / step, 0, 1), i = 1..steps.
/// Dividing by `step` makes the sum dimensionless (at most Σ i·2⁻ⁱ < 2), so the same strength
/// means the same darkening at any scene scale. It multiplies the ambient lights only.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AmbientOcclusionDesc {
    /// Strength (1 = as in the formula).
    pub strength: NonNegative,
    /// Number of samples along the normal.
    pub steps: u32,
    /// Distance between samples.
    pub step: Positive,
}

/// The `materials` map in file order, each value still as its RON text; a name defined twice
/// is an error (a map would silently keep the last one). The values are parsed by
/// [`MaterialEntry::parse`] once the whole file has been read, so that an error inside one can
/// be placed in the file (a nested parse only knows places inside its own text).
#[derive(Debug, Clone, Default)]
pub struct Materials(pub Vec<(String, Box<ron::value::RawValue>)>);

/// One entry of the `materials` map: Lambert + Phong unless it is written `Pbr(...)`.
#[derive(Debug, Clone)]
pub enum MaterialEntry {
    /// `(color: ..., ...)` or `Phong(color: ..., ...)`.
    Phong(MaterialDesc),
    /// `Pbr(base_color: ..., metallic: ..., roughness: ...)`.
    Pbr(PbrDesc),
}

impl MaterialEntry {
    /// The entry parsed from its RON text: `Pbr(...)` is the metallic-roughness model, anything
    /// else the Phong material (named `Phong` or unnamed).
    ///
    /// Why not a serde enum: RON writes an enum variant with its name, and the unnamed
    /// `(color: ...)` form every scene already uses must stay valid; serde's untagged enums
    /// would accept both but replace every field's error by "did not match any variant". So the
    /// value is captured as raw text, and its leading name picks the type to parse it as, which
    /// keeps RON's own message for a wrong field or value.
    pub fn parse(raw: &ron::value::RawValue) -> Result<MaterialEntry, ron::error::SpannedError> {
        let text = raw.trim().get_ron();
        let options = ron::Options::default()
            .with_default_extension(ron::extensions::Extensions::IMPLICIT_SOME);
        let named_pbr = text
            .strip_prefix("Pbr")
            .is_some_and(|rest| !rest.starts_with(|c: char| c.is_alphanumeric() || c == '_'));
        if named_pbr {
            options.from_str(text).map(MaterialEntry::Pbr)
        } else {
            options.from_str(text).map(MaterialEntry::Phong)
        }
    }
}

impl<'de> Deserialize<'de> for Materials {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl<'de> serde::de::Visitor<'de> for Visitor {
            type Value = Materials;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a map of material names to materials")
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut map: A,
            ) -> Result<Materials, A::Error> {
                let mut seen = HashSet::new();
                let mut out = Vec::new();
                while let Some(name) = map.next_key::<String>()? {
                    if !seen.insert(name.clone()) {
                        return Err(serde::de::Error::custom(format!(
                            "material \"{name}\" is defined twice"
                        )));
                    }
                    out.push((name, map.next_value::<Box<ron::value::RawValue>>()?));
                }
                Ok(Materials(out))
            }
        }
        d.deserialize_map(Visitor)
    }
}

/// Image size, sampling and background.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ImageDesc {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Samples per pixel.
    pub samples: u32,
    /// Radiance of rays that hit nothing (linear RGB).
    pub background: Color,
    /// Exposure in stops: radiance is multiplied by 2^exposure before tone mapping.
    pub exposure: Finite,
    /// Tone-mapping operator from linear radiance to display values.
    pub tonemap: ToneMap,
}

/// Tone-mapping operators (applied to exposed linear radiance before the sRGB curve).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
pub enum ToneMap {
    /// Clip each channel to [0, 1].
    #[default]
    Clamp,
    /// Reinhard's x/(1 + x) per channel (Reinhard et al. 2002).
    Reinhard,
    /// Narkowicz's fit of the ACES filmic curve (2015), per channel.
    Aces,
}

impl Default for ImageDesc {
    fn default() -> Self {
        ImageDesc {
            width: 800,
            height: 600,
            samples: 1,
            background: Color(glam::Vec3::new(0.05, 0.06, 0.08)),
            exposure: Finite(0.0),
            tonemap: ToneMap::Clamp,
        }
    }
}

/// Camera models.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub enum CameraDesc {
    /// Pinhole camera.
    Perspective {
        /// Eye position.
        position: FiniteVec3,
        /// Point the camera looks at.
        look_at: FiniteVec3,
        /// Up direction (default +y).
        #[serde(default)]
        up: Option<Direction>,
        /// Vertical field of view in degrees (default 45).
        #[serde(default)]
        fov: Option<Positive>,
    },
    /// Orthographic camera: parallel rays.
    Orthographic {
        /// Centre of the image plane.
        position: FiniteVec3,
        /// Point the camera looks at (sets the direction).
        look_at: FiniteVec3,
        /// Up direction (default +y).
        #[serde(default)]
        up: Option<Direction>,
        /// Height of the view in world units.
        height: Positive,
    },
}

/// Light sources.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub enum LightDesc {
    /// Point light; radiance falls off with the squared distance.
    Point {
        /// Position.
        position: FiniteVec3,
        /// Colour (default white).
        #[serde(default)]
        color: Color,
        /// Intensity (radiant intensity multiplier).
        intensity: NonNegative,
        /// Distance at which the light fades to nothing (KHR_lights_punctual's range window;
        /// default: no cut-off).
        #[serde(default)]
        range: Option<Positive>,
        /// Shadow kind (default `Hard`).
        #[serde(default)]
        shadow: ShadowDesc,
    },
    /// Spot light: a point light limited to a cone, with KHR_lights_punctual's smooth falloff
    /// between the inner and the outer cone angle.
    Spot {
        /// Position.
        position: FiniteVec3,
        /// Direction of the cone's axis (the way the light travels).
        direction: Direction,
        /// Colour (default white).
        #[serde(default)]
        color: Color,
        /// Intensity on the axis (as for a point light).
        intensity: NonNegative,
        /// Angle from the axis, in degrees, inside which the light is at full intensity
        /// (default 0).
        #[serde(default)]
        inner_angle: Option<NonNegative>,
        /// Angle from the axis, in degrees, beyond which there is no light (default 45; at
        /// most 90, and more than `inner_angle`).
        #[serde(default)]
        outer_angle: Option<Positive>,
        /// Distance at which the light fades to nothing (default: no cut-off).
        #[serde(default)]
        range: Option<Positive>,
        /// Shadow kind (default `Hard`).
        #[serde(default)]
        shadow: ShadowDesc,
    },
    /// Directional light (sun), travelling along `direction`.
    Directional {
        /// Direction in which the light travels.
        direction: Direction,
        /// Colour (default white).
        #[serde(default)]
        color: Color,
        /// Irradiance multiplier.
        intensity: NonNegative,
        /// Shadow kind (default `Hard`).
        #[serde(default)]
        shadow: ShadowDesc,
    },
    /// Constant ambient light.
    Ambient {
        /// Colour (default white).
        #[serde(default)]
        color: Color,
        /// Intensity.
        intensity: NonNegative,
    },
}

/// How a light's shadows are computed.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub enum ShadowDesc {
    /// No shadow ray.
    None,
    /// Binary visibility from one shadow ray.
    #[default]
    Hard,
    /// Quilez's penumbra estimate min(k·h/t) along the shadow ray ("soft shadows in raymarched
    /// SDFs", 2010): larger k, harder shadow.
    Soft {
        /// Sharpness k.
        k: Positive,
    },
    /// The improved estimate that places the closest approach between two steps
    /// (y = h²/(2h'), d = √(h² − y²), min(k·d/(t − y))), which removes banding.
    SoftImproved {
        /// Sharpness k.
        k: Positive,
    },
}

/// A material: Lambert diffuse + Phong specular, plus reflection and refraction parameters.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default, rename = "Phong")]
pub struct MaterialDesc {
    /// Base (albedo) colour, linear RGB.
    pub color: Color,
    /// Diffuse weight.
    pub diffuse: NonNegative,
    /// Phong specular colour.
    pub specular: Color,
    /// Phong exponent.
    pub shininess: Positive,
    /// Mirror reflectance at normal incidence (0 = none).
    pub reflectivity: Unit,
    /// Fraction of light transmitted (0 = opaque).
    pub transparency: Unit,
    /// Index of refraction.
    pub ior: Positive,
    /// Emitted radiance, linear RGB (default black).
    pub emissive: Color,
}

impl Default for MaterialDesc {
    fn default() -> Self {
        MaterialDesc {
            color: Color(glam::Vec3::splat(0.8)),
            diffuse: NonNegative(1.0),
            specular: Color(glam::Vec3::ZERO),
            shininess: Positive(32.0),
            reflectivity: Unit(0.0),
            transparency: Unit(0.0),
            ior: Positive(1.5),
            emissive: Color(glam::Vec3::ZERO),
        }
    }
}

/// A material in glTF 2.0's metallic-roughness model (its Appendix B: GGX distribution, Smith
/// visibility, Schlick Fresnel, the metal/dielectric mix), written `Pbr(...)`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default, rename = "Pbr")]
pub struct PbrDesc {
    /// Base colour, linear RGB: the diffuse albedo of a dielectric, the reflectance of a metal.
    pub base_color: Color,
    /// 0 dielectric, 1 metal.
    pub metallic: Unit,
    /// Perceptual roughness (GGX α = roughness²).
    pub roughness: Unit,
    /// Mirror reflectance the path follows (default metallic·(1 − roughness)²).
    pub reflectivity: Option<Unit>,
    /// Fraction of light transmitted (0 = opaque).
    pub transparency: Unit,
    /// Index of refraction of the transmitted part.
    pub ior: Positive,
    /// Emitted radiance, linear RGB (default black).
    pub emissive: Color,
}

impl Default for PbrDesc {
    fn default() -> Self {
        PbrDesc {
            base_color: Color(glam::Vec3::splat(0.8)),
            metallic: Unit(0.0),
            roughness: Unit(0.5),
            reflectivity: None,
            transparency: Unit(0.0),
            ior: Positive(1.5),
            emissive: Color(glam::Vec3::ZERO),
        }
    }
}

/// One object: an SDF tree placed in the world.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectDesc {
    /// Optional name, shown in errors and `info`.
    #[serde(default)]
    pub name: Option<String>,
    /// The SDF tree (give either `shape` or `mesh`).
    #[serde(default)]
    pub shape: Option<SdfNode>,
    /// A mesh file (.gltf, .glb, .obj, .ply), relative to the scene file; a leading
    /// `$NAME/` has `$NAME` replaced by the environment variable NAME (an error when it is
    /// unset; see [`resolve_mesh_path`](super::resolve_mesh_path)).
    #[serde(default)]
    pub mesh: Option<String>,
    /// Translation.
    #[serde(default)]
    pub translate: Option<FiniteVec3>,
    /// Euler rotation in degrees (about x, then y, then z).
    #[serde(default)]
    pub rotate: Option<FiniteVec3>,
    /// Uniform scale.
    #[serde(default)]
    pub scale: Option<Positive>,
    /// Material name (default: the built-in grey for SDFs, the file's own materials for
    /// meshes; given for a mesh, it overrides them all).
    #[serde(default)]
    pub material: Option<String>,
}

/// How normals are estimated from the field.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
pub enum NormalMethod {
    /// Central differences: 6 evaluations.
    #[default]
    Central,
    /// Tetrahedral 4-tap estimate (Quilez, "normals for an SDF").
    Tetrahedral,
}

/// How much time the mesh BVH builder spends on its trees (mapped onto the builders by
/// `accel::bvh`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Deserialize)]
pub enum BuildQuality {
    /// Binned SAH splits in parallel (the approach of Embree's builder), collapsed to eight
    /// children per node by the SAH, without spatial pre-splits.
    Fast,
    /// As `Fast`, with spatial pre-splits of large triangles (a triangle may sit in several
    /// leaves; the split boxes are padded to stay conservative). Traces as fast as `Highest`
    /// on the bench's models within a few per cent, at a fifth to a seventh of its build time.
    #[default]
    Medium,
    /// obvhs's `slow_build()`: PLOC radius 24, 128-bit Morton codes, reinsertion, and the
    /// spatial pre-splits.
    High,
    /// obvhs's `very_slow_build()`: as `High`, with reinsertion over every node.
    Highest,
}

/// How the sphere tracer steps along a ray (see `crate::trace::sphere`).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Default)]
pub enum Stepper {
    /// Plain sphere tracing: step by the field value (Hart 1996).
    #[default]
    Hart,
    /// Over-relaxed sphere tracing with its fallback (Keinert et al. 2014, "Enhanced Sphere
    /// Tracing", §3.1): step by ω·f, 1 ≤ ω < 2, back off to the plain step when the two
    /// unbounding spheres do not overlap.
    Relaxed(f32),
    /// Over-relaxation whose factor follows the field's slope along the ray, ω = 2/(1 + g)
    /// for a field falling by g per unit of t (the largest step the overlap test can accept
    /// on a plane; after Bálint & Valasek, "Accelerating Sphere Tracing", Eurographics 2018
    /// short papers), with Keinert's fallback.
    Adaptive,
    /// Segment tracing (Galin et al., "Segment Tracing Using Local Lipschitz Bounds",
    /// Eurographics 2020): interval enclosures of the field and of its slope along the ray over
    /// candidate segments skip empty stretches whole and step by f/λ with a local bound λ; the
    /// final approach and the hit test are Hart's.
    Segment,
}

/// The stepper as a scene file spells it: `Hart`, `Relaxed(1.6)`, `Adaptive`, `Segment`.
impl std::fmt::Display for Stepper {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        match self {
            Stepper::Hart => f.write_str("Hart"),
            Stepper::Relaxed(w) => write!(f, "Relaxed({w})"),
            Stepper::Adaptive => f.write_str("Adaptive"),
            Stepper::Segment => f.write_str("Segment"),
        }
    }
}

/// Sphere-tracing parameters (Hart 1996).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TracerDesc {
    /// Hit threshold at t = 0.
    pub epsilon: Positive,
    /// Growth of the hit threshold per unit of distance (a pixel-footprint cone): ε(t) =
    /// epsilon + epsilon_per_unit·t.
    pub epsilon_per_unit: NonNegative,
    /// Rays stop after this distance.
    pub max_distance: Positive,
    /// Rays stop after this many steps (counted as a miss).
    pub max_steps: u32,
    /// Normal estimator.
    pub normals: NormalMethod,
    /// Shadows from point and directional lights (each light's `shadow` says which kind).
    pub shadows: bool,
    /// Build quality of the mesh BVHs (obvhs PLOC presets).
    pub bvh: BuildQuality,
    /// Step rule of the sphere tracer (opt-in faster steppers; Hart by default).
    pub stepper: Stepper,
}

impl Default for TracerDesc {
    fn default() -> Self {
        TracerDesc {
            epsilon: Positive(1e-4),
            epsilon_per_unit: NonNegative(1e-4),
            max_distance: Positive(100.0),
            max_steps: 1024,
            normals: NormalMethod::Central,
            shadows: true,
            bvh: BuildQuality::Medium,
            stepper: Stepper::Hart,
        }
    }
}
