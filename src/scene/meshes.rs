//! The triangle meshes of a scene: files loaded once, placed any number of times.

use super::mesh::{self, MeshError, MeshMaterial, Texture, TriangleMesh};
use crate::geom::Aabb;
use glam::{Affine3A, Mat3A, Vec2, Vec3};
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
    /// Textures from the files; `MeshMaterial::base_color_texture` indexes here.
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
                    m.base_color_texture = m.base_color_texture.map(|t| t + texture_base);
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
        for (mesh, local, node) in &file.instances {
            let world = transform * *local;
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

    /// Surface attributes at barycentrics (u, v) of `triangle` of instance `instance`: the
    /// world-space shading normal (interpolated vertex normals under the inverse transpose),
    /// the scene material index and the base-colour multiplier from the texture.
    pub fn surface(&self, instance: usize, triangle: usize, u: f32, v: f32) -> MeshSurface {
        let inst = &self.instances[instance];
        let m = &self.meshes[inst.mesh];
        let [a, b, c] = m.triangles[triangle].map(|i| i as usize);
        let w = 1.0 - u - v;
        let geometric = (m.positions[b] - m.positions[a]).cross(m.positions[c] - m.positions[a]);
        let local_normal = {
            let n = w * m.normals[a] + u * m.normals[b] + v * m.normals[c];
            if n.length_squared() > 1e-20 {
                n
            } else {
                geometric
            }
        };
        let normal = (inst.normal_matrix * local_normal)
            .try_normalize()
            .unwrap_or(Vec3::Y);
        let local_material = m.triangle_material.get(triangle).copied().unwrap_or(0);
        let material = inst
            .material_override
            .unwrap_or(inst.material_base + local_material);
        let tint = if inst.material_override.is_none() && !m.uvs.is_empty() {
            let mat = &self.materials
                [(inst.material_base - self.material_offset + local_material) as usize];
            mat.base_color_texture.map_or(Vec3::ONE, |t| {
                let uv: Vec2 = w * m.uvs[a] + u * m.uvs[b] + v * m.uvs[c];
                self.textures[t].sample(uv).truncate()
            })
        } else {
            Vec3::ONE
        };
        MeshSurface {
            normal,
            material,
            tint,
        }
    }
}

/// What the shader needs from a mesh hit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshSurface {
    /// World-space unit shading normal (as the file orients it).
    pub normal: Vec3,
    /// Scene material index.
    pub material: u32,
    /// Multiplier of the material's colour from its base-colour texture (1 without one).
    pub tint: Vec3,
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
