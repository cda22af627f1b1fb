//! The triangle meshes of a scene: files loaded once, placed any number of times.

use super::material::MaterialParams;
use super::mesh::{self, AlphaMode, MeshError, MeshMaterial, Texture, TextureRef, TriangleMesh};
use crate::geom::Aabb;
use glam::{Affine3A, Mat3A, Vec2, Vec3, Vec4};
use std::collections::HashMap;
use std::ffi::OsString;
use std::path::{Path, PathBuf};

/// One placement of a mesh in the scene.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneInstance {
    /// Index into [`SceneMeshes::meshes`].
    pub mesh: usize,
    /// Object → world.
    pub transform: Affine3A,
    /// The inverse transpose of the transform's linear part, which maps normals.
    pub normal_matrix: Mat3A,
    /// Scene material index added to the mesh's per-triangle material indices.
    pub material_base: u32,
    /// A scene material replacing the file's materials, if the object names one.
    pub material_override: Option<u32>,
    /// The scene object's name (and the node's, for files with several).
    pub name: String,
}

/// Every mesh of a scene: geometry stored once per file, instances, and the materials and
/// textures the files bring (appended to the scene's material table after the scene's own).
#[derive(Debug, Clone, Default)]
pub struct SceneMeshes {
    /// Meshes, each stored once.
    pub meshes: Vec<TriangleMesh>,
    /// Placements.
    pub instances: Vec<SceneInstance>,
    /// Materials from the files, in scene order starting at `material_offset`.
    pub materials: Vec<MeshMaterial>,
    /// Textures from the files; `MeshMaterial::textures` indexes here.
    pub textures: Vec<Texture>,
    /// Loaded files: path → (first mesh, first material, the file's own instances).
    loaded: HashMap<PathBuf, LoadedFile>,
    /// The scene-material index of `materials[0]`.
    pub material_offset: u32,
    /// Warnings from the loaders (missing textures, skipped primitives...).
    pub warnings: Vec<String>,
    /// Cameras and lights found in the files.
    pub cameras: Vec<mesh::NamedCamera>,
    /// Lights found in the files (KHR_lights_punctual), in world space.
    pub lights: Vec<mesh::NamedLight>,
}

#[derive(Debug, Clone)]
struct LoadedFile {
    material_base: u32,
    instances: Vec<(usize, Affine3A, String)>,
}

impl SceneMeshes {
    /// An empty set whose materials will follow the scene's first `material_offset` ones.
    pub fn new(material_offset: u32) -> Self {
        SceneMeshes {
            material_offset,
            ..Default::default()
        }
    }

    /// Places the contents of a mesh file with `transform` (object → world). The file is
    /// read once however often it is placed.
    pub fn add_file(
        &mut self,
        path: &Path,
        transform: Affine3A,
        material_override: Option<u32>,
        name: &str,
    ) -> Result<(), MeshError> {
        let key = path.canonicalize().unwrap_or_else(|_| path.to_path_buf());
        if !self.loaded.contains_key(&key) {
            let asset = mesh::load(path)?;
            let mesh_base = self.meshes.len();
            let texture_base = self.textures.len();
            let material_base = self.material_offset + self.materials.len() as u32;
            self.warnings.extend(
                asset
                    .warnings
                    .iter()
                    .map(|w| format!("{}: {w}", path.display())),
            );
            self.meshes.extend(asset.meshes);
            self.textures.extend(asset.textures);
            self.materials
                .extend(asset.materials.into_iter().map(|mut m| {
                    for slot in m.textures.slots_mut().into_iter().flatten() {
                        slot.texture += texture_base;
                    }
                    m
                }));
            self.cameras.extend(asset.cameras);
            self.lights.extend(asset.lights);
            let instances = asset
                .instances
                .into_iter()
                .map(|i| (i.mesh + mesh_base, i.transform, i.name))
                .collect();
            self.loaded.insert(
                key.clone(),
                LoadedFile {
                    material_base,
                    instances,
                },
            );
        }
        let file = &self.loaded[&key];
        let too_large = |what: String, reach: f32| MeshError::TooLarge {
            file: path.to_path_buf(),
            what,
            reach,
        };
        // each mesh's own bounds, once however often the file places it
        let mut own_bounds: HashMap<usize, Aabb> = HashMap::new();
        for (mesh, local, node) in &file.instances {
            let world = transform * *local;
            // the trees over the meshes' triangles and over the placed meshes take only so
            // large coordinates (NaN and infinite vertices are dropped as broken triangles)
            let m = &self.meshes[*mesh];
            let own = *own_bounds.entry(*mesh).or_insert_with(|| {
                (m.positions.iter())
                    .filter(|p| p.is_finite())
                    .fold(Aabb::EMPTY, |b, &p| Aabb::new(b.min.min(p), b.max.max(p)))
            });
            let limit = crate::geom::LARGEST_TREE_COORDINATE;
            if !own.is_empty() && own.reach() > limit {
                return Err(too_large(format!("mesh {:?}", m.name), own.reach()));
            }
            let placed = own.transformed(&world);
            // (a placement that overflows to ∞ or NaN is beyond it too)
            if !own.is_empty() && (placed.reach() > limit || placed.reach().is_nan()) {
                return Err(too_large(
                    format!("mesh {:?} as the scene places it", m.name),
                    placed.reach(),
                ));
            }
            self.instances.push(SceneInstance {
                mesh: *mesh,
                transform: world,
                normal_matrix: world.matrix3.inverse().transpose(),
                material_base: file.material_base,
                material_override,
                name: if node.is_empty() {
                    name.to_string()
                } else {
                    format!("{name}/{node}")
                },
            });
        }
        Ok(())
    }

    /// Triangles over all instances.
    pub fn triangle_count(&self) -> usize {
        self.instances
            .iter()
            .map(|i| self.meshes[i.mesh].triangles.len())
            .sum()
    }

    /// Triangles stored (each mesh once).
    pub fn unique_triangle_count(&self) -> usize {
        self.meshes.iter().map(|m| m.triangles.len()).sum()
    }

    /// The mesh files the scene loaded, each once (what the viewer watches for edits).
    pub fn files(&self) -> Vec<&Path> {
        let mut v: Vec<&Path> = self.loaded.keys().map(PathBuf::as_path).collect();
        v.sort();
        v
    }

    /// World bounds of all instances.
    pub fn bounds(&self) -> Aabb {
        self.instances.iter().fold(Aabb::EMPTY, |acc, i| {
            let m = &self.meshes[i.mesh];
            let local = m
                .positions
                .iter()
                .fold(Aabb::EMPTY, |b, &p| Aabb::new(b.min.min(p), b.max.max(p)));
            acc.union(&local.transformed(&i.transform))
        })
    }

    /// The file material of `triangle` of instance `instance`, or `None` when the scene
    /// overrides the instance's materials (and the file's textures and alpha do not apply).
    pub fn file_material(&self, instance: usize, triangle: usize) -> Option<&MeshMaterial> {
        let inst = self.instances.get(instance)?;
        if inst.material_override.is_some() {
            return None;
        }
        let m = self.meshes.get(inst.mesh)?;
        let local = m.triangle_material.get(triangle).copied().unwrap_or(0);
        self.materials
            .get((inst.material_base - self.material_offset + local) as usize)
    }

    /// Whether any triangle of instance `instance` has an alpha-masked material
    /// ([`AlphaMode::Mask`]): whether hits on it need [`Self::masked_out`].
    pub fn alpha_tested(&self, instance: usize) -> bool {
        let Some(inst) = self.instances.get(instance) else {
            return false;
        };
        if inst.material_override.is_some() {
            return false;
        }
        let first = (inst.material_base - self.material_offset) as usize;
        let m = &self.meshes[inst.mesh];
        let masked = |k: &u32| {
            self.materials
                .get(first + *k as usize)
                .is_some_and(|mm| matches!(mm.alpha_mode, AlphaMode::Mask { .. }))
        };
        // most meshes use one or two materials: test each distinct index once
        let mut seen: Vec<u32> = m.triangle_material.clone();
        seen.sort_unstable();
        seen.dedup();
        seen.iter().any(masked)
    }

    /// Whether the point at barycentrics (u, v) of `triangle` of instance `instance` is a
    /// hole of an alpha mask: its material is [`AlphaMode::Mask`] and its coverage
    /// (`baseColorFactor` alpha × base colour texture alpha × `COLOR_0` alpha) is below the
    /// cutoff (glTF 2.0 §3.9.6). Such points are not there for any ray.
    pub fn masked_out(&self, instance: usize, triangle: usize, u: f32, v: f32) -> bool {
        let Some(mat) = self.file_material(instance, triangle) else {
            return false;
        };
        let AlphaMode::Mask { cutoff } = mat.alpha_mode else {
            return false;
        };
        let m = &self.meshes[self.instances[instance].mesh];
        let corners = Corners::new(m, triangle, u, v);
        let alpha = mat.base_alpha
            * corners.color(m).w
            * mat
                .textures
                .base_color
                .map_or(1.0, |t| self.sample(m, &corners, &t).w);
        alpha < cutoff
    }

    /// `texture` sampled at the point `corners` describes.
    fn sample(&self, m: &TriangleMesh, corners: &Corners, t: &TextureRef) -> Vec4 {
        let uvs = if t.tex_coord == 1 { &m.uvs1 } else { &m.uvs };
        match (uvs.is_empty(), self.textures.get(t.texture)) {
            (false, Some(tex)) => {
                let uv = corners.interpolate2(uvs);
                tex.sample(t.transform.apply(uv))
            }
            _ => Vec4::ONE,
        }
    }

    /// Surface attributes at barycentrics (u, v) of `triangle` of instance `instance`: the
    /// world-space shading normal (interpolated vertex normals, perturbed by the normal
    /// texture, under the inverse transpose), the scene material index and what the file
    /// material's textures and vertex colours make of it there.
    pub fn surface(&self, instance: usize, triangle: usize, u: f32, v: f32) -> MeshSurface {
        let inst = &self.instances[instance];
        let m = &self.meshes[inst.mesh];
        let corners = Corners::new(m, triangle, u, v);
        let [a, b, c] = corners.index;
        let geometric = (m.positions[b] - m.positions[a]).cross(m.positions[c] - m.positions[a]);
        let interpolated = corners.interpolate3(&m.normals);
        let mut local_normal = if interpolated.length_squared() > 1e-20 {
            interpolated
        } else {
            geometric
        };
        let local_material = m.triangle_material.get(triangle).copied().unwrap_or(0);
        let material = inst
            .material_override
            .unwrap_or(inst.material_base + local_material);
        let mut sample = SurfaceSample::NONE;
        if let Some(mat) = self.file_material(instance, triangle) {
            let t = &mat.textures;
            let color = corners.color(m);
            let base = t
                .base_color
                .map_or(Vec4::ONE, |r| self.sample(m, &corners, &r))
                * color;
            sample.color = base.truncate();
            if mat.alpha_mode == AlphaMode::Blend {
                sample.alpha = base.w;
            }
            if let Some(r) = &t.metallic_roughness {
                // §3.9.2: "The metalness values are sampled from the B channel. The roughness
                // values are sampled from the G channel."
                let mr = self.sample(m, &corners, r);
                sample.metallic = mr.z;
                sample.roughness = mr.y;
            }
            if let Some((r, strength)) = &t.occlusion {
                // §3.9.4: occlusion = 1.0 + strength * (R - 1.0)
                sample.occlusion = 1.0 + strength * (self.sample(m, &corners, r).x - 1.0);
            }
            if let Some(r) = &t.emissive {
                sample.emissive = self.sample(m, &corners, r).truncate();
            }
            if let (Some((r, scale)), false) = (&t.normal, m.tangents.is_empty()) {
                let tangent = corners.interpolate4(&m.tangents);
                let texel = self.sample(m, &corners, r).truncate();
                local_normal = normal_mapped(local_normal, tangent, texel, *scale);
            }
        }
        let normal = (inst.normal_matrix * local_normal)
            .try_normalize()
            .unwrap_or(Vec3::Y);
        MeshSurface {
            normal,
            material,
            sample,
        }
    }
}

/// The vertices of one triangle and the barycentric weights of a point in it.
struct Corners {
    index: [usize; 3],
    weight: [f32; 3],
}

impl Corners {
    fn new(m: &TriangleMesh, triangle: usize, u: f32, v: f32) -> Self {
        Corners {
            index: m.triangles[triangle].map(|i| i as usize),
            weight: [1.0 - u - v, u, v],
        }
    }

    fn interpolate2(&self, values: &[Vec2]) -> Vec2 {
        (0..3).map(|k| self.weight[k] * values[self.index[k]]).sum()
    }

    fn interpolate3(&self, values: &[Vec3]) -> Vec3 {
        (0..3).map(|k| self.weight[k] * values[self.index[k]]).sum()
    }

    fn interpolate4(&self, values: &[Vec4]) -> Vec4 {
        (0..3).map(|k| self.weight[k] * values[self.index[k]]).sum()
    }

    /// The vertex colour (`COLOR_0`), white without one.
    fn color(&self, m: &TriangleMesh) -> Vec4 {
        if m.colors.is_empty() {
            Vec4::ONE
        } else {
            self.interpolate4(&m.colors)
        }
    }
}

/// Normal mapping (glTF 2.0 §3.9.3): the texel t decoded as 2t − 1, x and y scaled by
/// `scale`, taken in the frame (T, B, N) with B = w·(N × T) — `tangent` = (T, w), T made
/// orthogonal to N first (Gram–Schmidt, as MikkTSpace's consumers do). Everything is in the
/// mesh's object space; the result is not normalised.
///
/// The mapped normal is kept on the side of the surface `n` is on (at least a small angle
/// above its tangent plane): the integrator turns normals towards the viewer by `n`'s side,
/// so a map that tilted the normal past the tangent plane would light the back of the surface.
pub fn normal_mapped(n: Vec3, tangent: Vec4, texel: Vec3, scale: f32) -> Vec3 {
    let Some(n) = n.try_normalize() else {
        return n;
    };
    let t = tangent.truncate();
    let Some(t) = (t - n * n.dot(t)).try_normalize() else {
        return n;
    };
    let b = if tangent.w < 0.0 { -1.0 } else { 1.0 } * n.cross(t);
    let d = 2.0 * texel - Vec3::ONE;
    let mapped = t * (d.x * scale) + b * (d.y * scale) + n * d.z;
    let Some(mapped) = mapped.try_normalize() else {
        return n;
    };
    // no lower than ~3° above the tangent plane
    const MIN_COS: f32 = 0.05;
    let c = mapped.dot(n);
    if c >= MIN_COS {
        return mapped;
    }
    let along = mapped - n * c;
    (along.normalize_or_zero() * (1.0 - MIN_COS * MIN_COS).sqrt() + n * MIN_COS)
        .try_normalize()
        .unwrap_or(n)
}

/// What a mesh file material's textures and vertex colours make of it at one point: each
/// field multiplies the corresponding [`MaterialParams`] field (all 1 where there is no
/// texture).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceSample {
    /// Multiplies `color`: base colour texture × `COLOR_0`.
    pub color: Vec3,
    /// Multiplies `opacity` (BLEND materials only: texture alpha × `COLOR_0` alpha).
    pub alpha: f32,
    /// Multiplies `metallic` (metallic-roughness texture, blue).
    pub metallic: f32,
    /// Multiplies `roughness` (metallic-roughness texture, green).
    pub roughness: f32,
    /// Multiplies `occlusion` (occlusion texture with its strength).
    pub occlusion: f32,
    /// Multiplies `emissive` (emissive texture).
    pub emissive: Vec3,
}

impl SurfaceSample {
    /// No texture: changes nothing.
    pub const NONE: SurfaceSample = SurfaceSample {
        color: Vec3::ONE,
        alpha: 1.0,
        metallic: 1.0,
        roughness: 1.0,
        occlusion: 1.0,
        emissive: Vec3::ONE,
    };

    /// `params` modulated by the sample. The mirror reflectance of a metallic-roughness
    /// material follows its textured metalness and roughness as
    /// [`MaterialParams::metallic_roughness`] derives it from the factors.
    pub fn apply(&self, mut params: MaterialParams) -> MaterialParams {
        if *self == SurfaceSample::NONE {
            return params;
        }
        params.color *= self.color;
        params.opacity *= self.alpha;
        params.occlusion *= self.occlusion;
        params.emissive *= self.emissive;
        if self.metallic != 1.0 || self.roughness != 1.0 {
            let derived = |m: f32, r: f32| m * (1.0 - r) * (1.0 - r);
            let before = derived(params.metallic, params.roughness);
            params.metallic *= self.metallic;
            params.roughness *= self.roughness;
            // only a reflectance that came from the factors follows the texture
            if params.pbr > 0.0 && (params.reflectivity - before).abs() < 1e-6 {
                params.reflectivity = derived(params.metallic, params.roughness);
            }
        }
        params
    }
}

/// What the shader needs from a mesh hit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshSurface {
    /// World-space unit shading normal (as the file orients it, normal-mapped).
    pub normal: Vec3,
    /// Scene material index.
    pub material: u32,
    /// What the file material's textures make of the material here.
    pub sample: SurfaceSample,
}

/// A scene's `mesh:` path starts with `$NAME/` for a variable NAME that has no value.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("mesh path \"{path}\": environment variable {variable} is not set")]
pub struct UnsetVariable {
    /// The variable's name, without the `$`.
    pub variable: String,
    /// The mesh path as the scene file writes it.
    pub path: String,
}

/// Where a scene's `mesh:` path points.
///
/// A path that starts with `$NAME/`, where NAME is a letter or `_` followed by letters, digits
/// and `_` (a shell variable name), has `$NAME` replaced by `lookup(NAME)`, the value of that
/// environment variable in a scene load (so scenes can name files kept outside the
/// repository); the result is used as it stands, a relative value being relative to the
/// working directory. A NAME without a value is an [`UnsetVariable`] error. `$` anywhere else,
/// or not followed by a name and `/`, is an ordinary character. Other relative paths are
/// relative to the scene file's folder.
pub fn resolve_mesh_path(
    scene_file: &Path,
    mesh: &str,
    lookup: impl Fn(&str) -> Option<OsString>,
) -> Result<PathBuf, UnsetVariable> {
    if let Some((variable, rest)) = leading_variable(mesh) {
        let mut path = lookup(variable).ok_or_else(|| UnsetVariable {
            variable: variable.to_string(),
            path: mesh.to_string(),
        })?;
        // textual replacement of `$NAME` (not `Path::join`, which would drop the value
        // before a `rest` of `//...`)
        path.push(rest);
        return Ok(PathBuf::from(path));
    }
    let p = Path::new(mesh);
    Ok(if p.is_absolute() {
        p.to_path_buf()
    } else {
        scene_file.parent().unwrap_or(Path::new(".")).join(p)
    })
}

/// NAME and the rest from the `/` on, for a path that starts with `$NAME/`.
fn leading_variable(mesh: &str) -> Option<(&str, &str)> {
    let (name, _) = mesh.strip_prefix('$')?.split_once('/')?;
    let mut chars = name.chars();
    let first = chars.next()?;
    let valid = (first.is_ascii_alphabetic() || first == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_');
    valid.then_some((name, &mesh[1 + name.len()..]))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A lookup that knows only `ASSETS` (so the tests never read or change the process
    /// environment, which other tests share).
    fn lookup(name: &str) -> Option<OsString> {
        (name == "ASSETS").then(|| OsString::from("/data/models"))
    }

    fn resolve(mesh: &str) -> Result<PathBuf, UnsetVariable> {
        resolve_mesh_path(Path::new("scenes/a.ron"), mesh, lookup)
    }

    #[test]
    fn a_leading_variable_is_replaced_by_its_value() {
        assert_eq!(
            resolve("$ASSETS/obj/bunny.obj"),
            Ok("/data/models/obj/bunny.obj".into())
        );
        // the value replaces `$NAME` as text, even before a doubled `/`
        assert_eq!(resolve("$ASSETS//x.obj"), Ok("/data/models//x.obj".into()));
        // a relative value stays relative to the working directory, not to the scene file
        let relative = |_: &str| Some(OsString::from("../shared"));
        assert_eq!(
            resolve_mesh_path(Path::new("scenes/a.ron"), "$_A1/m.glb", relative),
            Ok("../shared/m.glb".into())
        );
    }

    #[test]
    fn an_unset_variable_is_an_error_naming_it() {
        let e = resolve("$MODELS/bunny.obj").unwrap_err();
        assert_eq!(
            e,
            UnsetVariable {
                variable: "MODELS".into(),
                path: "$MODELS/bunny.obj".into()
            }
        );
        assert_eq!(
            e.to_string(),
            "mesh path \"$MODELS/bunny.obj\": environment variable MODELS is not set"
        );
    }

    #[test]
    fn paths_without_a_leading_variable_are_plain_paths() {
        // no `$`: relative to the scene file's folder, or absolute
        assert_eq!(resolve("bunny.obj"), Ok("scenes/bunny.obj".into()));
        assert_eq!(resolve("/abs/bunny.obj"), Ok("/abs/bunny.obj".into()));
        // `$` later in the path
        assert_eq!(
            resolve("m/$ASSETS/x.obj"),
            Ok("scenes/m/$ASSETS/x.obj".into())
        );
        // `$` not followed by a name and `/`: an ordinary character, never looked up
        let never = |name: &str| -> Option<OsString> { panic!("looked up {name}") };
        for mesh in [
            "$1A/x.obj",
            "$/x.obj",
            "${ASSETS}/x.obj",
            "$A-B/x.obj",
            "$ASSETS",
            "$",
        ] {
            assert_eq!(
                resolve_mesh_path(Path::new("scenes/a.ron"), mesh, never),
                Ok(Path::new("scenes").join(mesh)),
                "{mesh}"
            );
        }
    }
}
