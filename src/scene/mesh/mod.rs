//! Triangle meshes from files: glTF 2.0, OBJ/MTL and PLY, loaded into one form.
//!
//! [`load`] picks the reader by the file's extension (case-insensitive): `gltf` and `glb`
//! (glTF 2.0 with external, base64-embedded or GLB-chunk buffers), `obj` (Wavefront OBJ with
//! its MTL libraries) and `ply` (ASCII and binary PLY). Every reader produces a [`MeshAsset`]:
//! meshes stored once, placed by [`MeshInstance`]s, with materials, textures, cameras and
//! lights already in the file's world space.
//!
//! Conventions shared by every format:
//!
//! - Triangles wind counter-clockwise seen from the front, as in all three formats; polygons
//!   (OBJ, PLY) are split by ear clipping in their best-fit plane, so concave polygons keep
//!   their shape.
//! - Normals are per vertex and unit length. A glTF primitive without normals gets flat ones,
//!   as glTF 2.0 requires: each triangle's corners become vertices of their own with the
//!   face's normal. An OBJ or PLY mesh without normals, and any vertex whose normal is zero or
//!   not finite, gets the normalised sum of the adjacent faces' area-weighted normals.
//! - Files are read only when they are regular files ([`crate::scene::read`]): a path that
//!   leads to a device or a pipe is an error (a missing material library, a warning).
//! - Texture coordinates follow glTF: (0, 0) is the top-left corner of the image. OBJ and PLY
//!   store v upwards, so their v is flipped (v ↦ 1 − v) while loading.
//! - Colours are linear RGB. Texture texels are decoded by their use: colour textures (base
//!   colour, emissive) from sRGB, data textures (metallic-roughness, normal, occlusion) as
//!   stored; see [`texture`](Texture).
//! - Material 0 is always the default grey ([`MaterialParams::default_grey`]); triangles
//!   without a material use it.
//!
//! glTF materials keep their metallic-roughness model (glTF 2.0's Appendix B BRDF, see
//! [`crate::shade::brdf`] and [`pbr_material`]): base colour, metallic and roughness factors,
//! `KHR_materials_transmission.transmissionFactor` as transparency and `KHR_materials_ior.ior`
//! as the index of refraction; smooth metals also mirror the scene (reflectivity
//! metallic·(1 − roughness)²). Their textures ([`MaterialTextures`]) follow glTF 2.0 §3.9:
//! base colour (RGBA, times `baseColorFactor` and `COLOR_0`), metallic-roughness (B metalness,
//! G roughness, times the factors), normal (tangent space with `scale`; tangents from
//! `TANGENT`, else generated with MikkTSpace), occlusion (R, with `strength`) and emissive
//! (times `emissiveFactor` and `KHR_materials_emissive_strength`), each on `TEXCOORD_0` or
//! `TEXCOORD_1` with its `KHR_texture_transform`; `alphaMode` and `alphaCutoff` become an
//! [`AlphaMode`]. OBJ/MTL materials are Lambert + Phong,
//! from MTL: `Kd` → `color` (default 0.8 grey), `Ks` → `specular` (default black), `Ns` →
//! `shininess` (at least 1), `d` → transparency 1 − d (or `Tr` → transparency Tr when there
//! is no `d`), `Ni` → `ior`, `map_Kd` → base colour texture, `diffuse` = 1, `reflectivity` = 0.

mod gltf;
mod obj;
mod ply;
mod polygon;
mod tangent;
mod texture;

use crate::geom::Aabb;
use crate::scene::material::MaterialParams;
use glam::{Affine3A, Vec2, Vec3, Vec4};
use std::path::{Path, PathBuf};

pub use texture::{Texture, UvTransform, Wrap, srgb_to_linear};

/// Everything a mesh file holds that the renderer uses.
#[derive(Debug, Clone)]
pub struct MeshAsset {
    /// The meshes, each stored once; [`MeshAsset::instances`] places them.
    pub meshes: Vec<TriangleMesh>,
    /// Materials; index 0 is always the default grey.
    pub materials: Vec<MeshMaterial>,
    /// Textures referenced by [`MeshMaterial::textures`].
    pub textures: Vec<Texture>,
    /// Placements of meshes in the file's world space.
    pub instances: Vec<MeshInstance>,
    /// glTF cameras, already in world space.
    pub cameras: Vec<NamedCamera>,
    /// `KHR_lights_punctual` lights, already in world space.
    pub lights: Vec<NamedLight>,
    /// What was skipped or replaced while loading (points and lines primitives, missing `.mtl`
    /// files or textures, ...), one sentence each.
    pub warnings: Vec<String>,
}

/// A triangle mesh in its own object space.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriangleMesh {
    /// Name from the file (glTF mesh name, OBJ group or object name, PLY file stem).
    pub name: String,
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Unit normals, one per vertex; computed (area-weighted face normals) when the file has
    /// none.
    pub normals: Vec<Vec3>,
    /// Texture coordinates, one per vertex (glTF `TEXCOORD_0`, OBJ `vt`, PLY `u v`), with
    /// (0, 0) at the image's top-left corner; empty when the file has none.
    pub uvs: Vec<Vec2>,
    /// Second texture coordinates (glTF `TEXCOORD_1`), one per vertex; empty when no
    /// primitive has them.
    pub uvs1: Vec<Vec2>,
    /// Tangents for normal mapping, one per vertex: unit xyz along +u, w = ±1 such that the
    /// bitangent w·(normal × tangent) points up the image (glTF `TANGENT`, else generated with
    /// MikkTSpace); empty when no material of the mesh has a normal texture.
    pub tangents: Vec<Vec4>,
    /// Vertex colours (glTF `COLOR_0`, linear RGBA), one per vertex; empty when no primitive
    /// has them (white).
    pub colors: Vec<Vec4>,
    /// Triangles as vertex indices, counter-clockwise seen from the front.
    pub triangles: Vec<[u32; 3]>,
    /// Per triangle, an index into [`MeshAsset::materials`].
    pub triangle_material: Vec<u32>,
}

/// One placement of a mesh.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshInstance {
    /// Index into [`MeshAsset::meshes`].
    pub mesh: usize,
    /// Object → world.
    pub transform: Affine3A,
    /// Name of the placing node (glTF), or of the mesh (OBJ, PLY).
    pub name: String,
}

/// A surface material.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshMaterial {
    /// Name from the file (`(default)` for material 0).
    pub name: String,
    /// Shading parameters; see the module documentation for how they are derived. For glTF
    /// materials, `params.opacity` is `baseColorFactor`'s alpha.
    pub params: MaterialParams,
    /// Textures that modulate `params` across the surface.
    pub textures: MaterialTextures,
    /// How the base colour's alpha is used.
    pub alpha_mode: AlphaMode,
    /// `baseColorFactor`'s alpha (1 for other formats): with the texture's and the vertex
    /// colour's alpha, the coverage that [`AlphaMode::Mask`] compares with its cutoff (for
    /// [`AlphaMode::Blend`] it is also `params.opacity`).
    pub base_alpha: f32,
}

/// A material's textures (glTF 2.0 §3.9.2–3.9.5); each multiplies what its factor set.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MaterialTextures {
    /// sRGB base colour and linear alpha; multiplies `params.color` (and the alpha).
    pub base_color: Option<TextureRef>,
    /// Linear; blue multiplies `params.metallic`, green `params.roughness`.
    pub metallic_roughness: Option<TextureRef>,
    /// Linear tangent-space normals, with the normal scale (x and y of the decoded normal
    /// are multiplied by it).
    pub normal: Option<(TextureRef, f32)>,
    /// Linear; red is the occlusion, applied with the strength: 1 + strength·(R − 1).
    pub occlusion: Option<(TextureRef, f32)>,
    /// sRGB; multiplies `params.emissive`.
    pub emissive: Option<TextureRef>,
}

impl MaterialTextures {
    /// Every texture slot's reference, in the order base colour, metallic-roughness, normal,
    /// occlusion, emissive.
    pub fn slots(&self) -> [Option<&TextureRef>; 5] {
        [
            self.base_color.as_ref(),
            self.metallic_roughness.as_ref(),
            self.normal.as_ref().map(|n| &n.0),
            self.occlusion.as_ref().map(|o| &o.0),
            self.emissive.as_ref(),
        ]
    }

    /// Mutable [`Self::slots`].
    pub fn slots_mut(&mut self) -> [Option<&mut TextureRef>; 5] {
        [
            self.base_color.as_mut(),
            self.metallic_roughness.as_mut(),
            self.normal.as_mut().map(|n| &mut n.0),
            self.occlusion.as_mut().map(|o| &mut o.0),
            self.emissive.as_mut(),
        ]
    }
}

/// One texture as a material uses it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TextureRef {
    /// Index into the textures ([`MeshAsset::textures`], `SceneMeshes::textures`).
    pub texture: usize,
    /// Which texture coordinates: 0 ([`TriangleMesh::uvs`]) or 1 ([`TriangleMesh::uvs1`]).
    pub tex_coord: u32,
    /// `KHR_texture_transform`, applied to the coordinates before sampling.
    pub transform: UvTransform,
}

/// glTF's `alphaMode` (§3.9.6).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum AlphaMode {
    /// Alpha is ignored: the surface is fully opaque.
    #[default]
    Opaque,
    /// Where alpha (base colour factor × texture × vertex colour) is below the cutoff the
    /// surface is not there at all, for every ray; elsewhere it is opaque.
    Mask {
        /// The cutoff, `alphaCutoff` (0.5 when absent).
        cutoff: f32,
    },
    /// Alpha is the surface's coverage: the fraction of the light it shades, the rest passing
    /// through (`MaterialParams::opacity`).
    Blend,
}

/// A camera from the file, in world space.
#[derive(Debug, Clone, PartialEq)]
pub struct NamedCamera {
    /// Camera or node name.
    pub name: String,
    /// Eye position.
    pub position: Vec3,
    /// Unit viewing direction (the node's −Z axis).
    pub forward: Vec3,
    /// Unit up vector orthogonal to `forward` (the node's +Y axis).
    pub up: Vec3,
    /// Projection.
    pub projection: CameraProjection,
}

/// A camera's projection as glTF gives it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CameraProjection {
    /// Pinhole camera.
    Perspective {
        /// Vertical field of view in radians.
        yfov_radians: f32,
        /// Width / height, when the file fixes it.
        aspect: Option<f32>,
    },
    /// Parallel projection.
    Orthographic {
        /// Half the view's height.
        ymag: f32,
        /// Half the view's width.
        xmag: f32,
    },
}

/// A punctual light from the file, in world space.
#[derive(Debug, Clone, PartialEq)]
pub struct NamedLight {
    /// Light or node name.
    pub name: String,
    /// Kind and placement.
    pub kind: LightKind,
    /// Linear RGB colour.
    pub color: Vec3,
    /// Intensity as the file gives it (candela for point and spot lights, lux for
    /// directional lights in glTF).
    pub intensity: f32,
    /// Distance at which the light reaches zero (KHR_lights_punctual's `range`), if any.
    pub range: Option<f32>,
}

/// Kind and placement of a [`NamedLight`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LightKind {
    /// Light from a point.
    Point {
        /// World position.
        position: Vec3,
    },
    /// Parallel light.
    Directional {
        /// Unit direction in which the light travels (the node's −Z axis).
        direction: Vec3,
    },
    /// Cone of light from a point.
    Spot {
        /// World position.
        position: Vec3,
        /// Unit direction of the cone's axis (the node's −Z axis).
        direction: Vec3,
        /// Angle from the axis, in radians, inside which the light has full intensity.
        inner_cone_angle: f32,
        /// Angle from the axis, in radians, beyond which there is no light (at most π/2).
        outer_cone_angle: f32,
    },
}

/// Why a mesh file could not be loaded. Every message names the file and, where known, the
/// place in it: a glTF JSON path (`meshes[2].primitives[0].attributes.POSITION`,
/// `accessors[5]`) or an OBJ/PLY line number.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// The file could not be read (missing, a directory, no permission...).
    #[error("{}: cannot read: {error}", .file.display())]
    Io {
        /// The file.
        file: PathBuf,
        /// Why (shown in the message itself, so not chained as a source).
        error: std::io::Error,
    },
    /// The extension is none of `gltf`, `glb`, `obj`, `ply`.
    #[error(
        "{}: unsupported mesh file type (the extension must be .gltf, .glb, .obj or .ply)",
        .file.display()
    )]
    Unsupported {
        /// The file.
        file: PathBuf,
    },
    /// The file has no bytes.
    #[error("{}: the file is empty", .file.display())]
    Empty {
        /// The file.
        file: PathBuf,
    },
    /// Invalid glTF: bad JSON or binary container, failed validation, data out of range,
    /// unreadable buffers.
    #[error("{}: {}{message}", .file.display(), place_prefix(.place))]
    Gltf {
        /// The file.
        file: PathBuf,
        /// JSON path of the offending item, such as `accessors[5]`; empty when the whole file
        /// is concerned.
        place: String,
        /// What is wrong.
        message: String,
    },
    /// Geometry beyond [`crate::geom::LARGEST_TREE_COORDINATE`] (in the file, or where the
    /// scene places it).
    #[error(
        "{}: {what} reaches {reach:e}, beyond ±{:e}, the largest coordinate the renderer builds its trees over",
        .file.display(),
        crate::geom::LARGEST_TREE_COORDINATE
    )]
    TooLarge {
        /// The file.
        file: PathBuf,
        /// What reaches so far: a mesh, or its placement.
        what: String,
        /// The largest magnitude of a coordinate.
        reach: f32,
    },
    /// Invalid OBJ data.
    #[error("{}{}: {message}", .file.display(), line_suffix(.line))]
    Obj {
        /// The file.
        file: PathBuf,
        /// Line, from 1, when known.
        line: Option<usize>,
        /// What is wrong.
        message: String,
    },
    /// Invalid PLY data.
    #[error("{}{}: {message}", .file.display(), line_suffix(.line))]
    Ply {
        /// The file.
        file: PathBuf,
        /// Line, from 1, when known (ASCII files, and the header of binary ones).
        line: Option<usize>,
        /// What is wrong.
        message: String,
    },
}

fn place_prefix(place: &str) -> String {
    if place.is_empty() {
        String::new()
    } else {
        format!("{place}: ")
    }
}

fn line_suffix(line: &Option<usize>) -> String {
    match line {
        Some(l) => format!(":{l}"),
        None => String::new(),
    }
}

/// Loads a mesh file, choosing the reader by its extension (case-insensitive): `gltf`, `glb`,
/// `obj` or `ply`. Bad input of any kind is a [`MeshError`] naming the file, never a panic.
pub fn load(path: &Path) -> Result<MeshAsset, MeshError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    let kind = match ext.as_str() {
        "gltf" | "glb" => Kind::Gltf,
        "obj" => Kind::Obj,
        "ply" => Kind::Ply,
        _ => {
            return Err(MeshError::Unsupported {
                file: path.to_path_buf(),
            });
        }
    };
    let bytes = crate::scene::read::read(path).map_err(|error| MeshError::Io {
        file: path.to_path_buf(),
        error,
    })?;
    if bytes.is_empty() {
        return Err(MeshError::Empty {
            file: path.to_path_buf(),
        });
    }
    let mut asset = match kind {
        Kind::Gltf => gltf::load(path, &bytes)?,
        Kind::Obj => obj::load(path, &bytes)?,
        Kind::Ply => ply::load(path, &bytes)?,
    };
    for mesh in &mut asset.meshes {
        debug_assert_eq!(mesh.triangles.len(), mesh.triangle_material.len());
        debug_assert_eq!(mesh.positions.len(), mesh.normals.len());
        debug_assert!(mesh.uvs.is_empty() || mesh.uvs.len() == mesh.positions.len());
        debug_assert!(mesh.uvs1.is_empty() || mesh.uvs1.len() == mesh.positions.len());
        debug_assert!(mesh.tangents.is_empty() || mesh.tangents.len() == mesh.positions.len());
        debug_assert!(mesh.colors.is_empty() || mesh.colors.len() == mesh.positions.len());
        mesh.triangle_material.resize(mesh.triangles.len(), 0);
    }
    Ok(asset)
}

enum Kind {
    Gltf,
    Obj,
    Ply,
}

impl MeshAsset {
    /// An asset holding only the default material.
    fn empty() -> MeshAsset {
        MeshAsset {
            meshes: Vec::new(),
            materials: vec![MeshMaterial::default_grey()],
            textures: Vec::new(),
            instances: Vec::new(),
            cameras: Vec::new(),
            lights: Vec::new(),
            warnings: Vec::new(),
        }
    }

    /// Triangles over all instances (a mesh placed twice counts twice).
    pub fn triangle_count(&self) -> usize {
        self.instances
            .iter()
            .filter_map(|i| self.meshes.get(i.mesh))
            .map(|m| m.triangles.len())
            .sum()
    }

    /// Triangles over the stored meshes (each mesh once).
    pub fn unique_triangle_count(&self) -> usize {
        self.meshes.iter().map(|m| m.triangles.len()).sum()
    }

    /// World bounds over all instances: every vertex of each placed mesh, transformed.
    /// Empty ([`Aabb::EMPTY`]) when nothing is placed.
    pub fn bounds(&self) -> Aabb {
        let mut b = Aabb::EMPTY;
        for inst in &self.instances {
            let Some(mesh) = self.meshes.get(inst.mesh) else {
                continue;
            };
            let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
            for p in &mesh.positions {
                let q = inst.transform.transform_point3(*p);
                lo = lo.min(q);
                hi = hi.max(q);
            }
            b = b.union(&Aabb::new(lo, hi));
        }
        b
    }
}

impl MeshMaterial {
    /// Material 0 of every asset.
    fn default_grey() -> MeshMaterial {
        MeshMaterial {
            name: "(default)".to_string(),
            params: MaterialParams::default_grey(),
            textures: MaterialTextures::default(),
            alpha_mode: AlphaMode::Opaque,
            base_alpha: 1.0,
        }
    }
}

/// The renderer's material for a glTF metallic-roughness material: the same model (see
/// [`MaterialParams::metallic_roughness`]), with `KHR_materials_transmission` as transparency
/// and `KHR_materials_ior` as the index of refraction. Factors are clamped to their ranges.
pub fn pbr_material(
    base_color: Vec3,
    metallic: f32,
    roughness: f32,
    transmission: f32,
    ior: f32,
) -> MaterialParams {
    MaterialParams {
        transparency: if transmission.is_finite() {
            transmission.clamp(0.0, 1.0)
        } else {
            0.0
        },
        ior: if ior.is_finite() && ior > 0.0 {
            ior
        } else {
            1.5
        },
        ..MaterialParams::metallic_roughness(base_color, metallic, roughness, None)
    }
}

/// `v` scaled to unit length, accurately even for tiny or huge vectors (scaled by the largest
/// component first); `None` for zero or non-finite vectors.
fn unit(v: Vec3) -> Option<Vec3> {
    let m = v.abs().max_element();
    if !(m > 0.0 && m.is_finite()) {
        return None;
    }
    (v / m).try_normalize()
}

/// Area-weighted vertex normals: each vertex gets the normalised sum of the (unnormalised)
/// cross products of its triangles; vertices without any non-degenerate triangle get +Z.
fn vertex_normals(positions: &[Vec3], triangles: &[[u32; 3]]) -> Vec<Vec3> {
    let mut acc = vec![Vec3::ZERO; positions.len()];
    accumulate_face_normals(positions, triangles, |i, n| {
        if let Some(a) = acc.get_mut(i) {
            *a += n;
        }
    });
    acc.into_iter()
        .map(|n| unit(n).unwrap_or(Vec3::Z))
        .collect()
}

/// Calls `add(vertex, n)` for each corner of each triangle with the triangle's cross product
/// (twice its area times its unit normal).
fn accumulate_face_normals(
    positions: &[Vec3],
    triangles: &[[u32; 3]],
    mut add: impl FnMut(usize, Vec3),
) {
    for t in triangles {
        let [a, b, c] = t.map(|i| i as usize);
        let (Some(pa), Some(pb), Some(pc)) = (positions.get(a), positions.get(b), positions.get(c))
        else {
            continue;
        };
        let n = (*pb - *pa).cross(*pc - *pa);
        if !n.is_finite() {
            continue;
        }
        add(a, n);
        add(b, n);
        add(c, n);
    }
}

/// Makes file normals unit length; those that are zero or not finite are replaced by the
/// area-weighted normals of `triangles`. Returns how many were replaced.
fn repair_normals(normals: &mut [Vec3], positions: &[Vec3], triangles: &[[u32; 3]]) -> usize {
    let mut bad = 0;
    for n in normals.iter_mut() {
        match unit(*n) {
            Some(u) => *n = u,
            None => {
                *n = Vec3::NAN;
                bad += 1;
            }
        }
    }
    if bad > 0 {
        let computed = vertex_normals(positions, triangles);
        for (n, c) in normals.iter_mut().zip(computed) {
            if n.is_nan() {
                *n = c;
            }
        }
    }
    bad
}
