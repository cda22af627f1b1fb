//! Meshes placed once, baked into world space and traced as one mesh.
//!
//! A two-level BVH pays at every instance a ray reaches: its box in the instance tree (boxes of
//! a model's parts overlap a lot, and a transformed object box is looser than the part), the
//! ray mapped into object space and set up again, and a walk of the part's tree from its root.
//! Measured on the bench's instanced glTF models (`hytrace bench --only mesh`, one thread),
//! tracing their single-use meshes as one tree of world-space triangles made primary, shadow
//! and AO rays 4–16 % faster and the CAD models' incoherent rays 4–8 % (BENCHMARKS.md, "Meshes
//! placed once, traced as one tree"). A mesh placed several times keeps its one tree under its instances (baking it
//! would copy it once per placement), as renderers that flatten scenes do (Blender's Cycles
//! bakes the transforms of objects that are not instanced).
//!
//! What is merged: every instance that is its mesh's only placement, with a finite invertible
//! transform, whose baked vertices are finite and which no alpha mask tests (the alpha test
//! looks up the instance's own materials; the merged tree's hits are turned back into the
//! instance's before anyone sees them, but the walk's filter is asked per instance), provided
//! there are at least two of them (one alone keeps its own tree: nothing to merge it with).
//! The merged triangles are ordered by instance and then by triangle, so that the smaller
//! merged index is the smaller (instance, triangle): the tie rule of the two-level walk.

use crate::scene::SceneMeshes;
use glam::Vec3;

/// The triangles of the merged instances, in world space, and where each came from.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MergedMeshes {
    /// Vertex positions, each instance's mapped by its transform (`Affine3A::transform_point3`,
    /// the same `f32` arithmetic in every consumer: the CPU's and the GPU's tree and Embree's
    /// mirror are built from these same values).
    pub positions: Vec<Vec3>,
    /// Triangles as indices into `positions`.
    pub triangles: Vec<[u32; 3]>,
    /// Per triangle: (scene instance, triangle of its mesh), in increasing order.
    pub origin: Vec<(u32, u32)>,
    /// Per scene instance, whether it is merged.
    pub merged: Vec<bool>,
}

/// Fewest instances worth merging.
const MIN_MERGED: usize = 2;

impl MergedMeshes {
    /// The single-use meshes of `meshes` merged (see the module notes), or `None` when fewer
    /// than two qualify.
    pub fn of(meshes: &SceneMeshes) -> Option<MergedMeshes> {
        use rayon::prelude::*;
        let mut uses = vec![0usize; meshes.meshes.len()];
        for inst in &meshes.instances {
            if let Some(u) = uses.get_mut(inst.mesh) {
                *u += 1;
            }
        }
        // Per instance, its baked vertices when it qualifies (baked on the rayon pool: one
        // pass over every vertex of the merged meshes).
        let baked: Vec<Option<Vec<Vec3>>> = (0..meshes.instances.len())
            .into_par_iter()
            .map(|k| {
                let inst = &meshes.instances[k];
                let mesh = meshes.meshes.get(inst.mesh)?;
                let m = inst.transform;
                let qualifies = uses[inst.mesh] == 1
                    && !mesh.triangles.is_empty()
                    && crate::accel::bvh::placeable(&m)
                    && !meshes.alpha_tested(k);
                if !qualifies {
                    return None;
                }
                let positions: Vec<Vec3> = mesh
                    .positions
                    .iter()
                    .map(|&p| m.transform_point3(p))
                    .collect();
                positions.iter().all(|p| p.is_finite()).then_some(positions)
            })
            .collect();
        if baked.iter().filter(|b| b.is_some()).count() < MIN_MERGED {
            return None;
        }
        let mut out = MergedMeshes {
            merged: baked.iter().map(Option::is_some).collect(),
            ..Default::default()
        };
        for (k, positions) in baked.into_iter().enumerate() {
            let Some(positions) = positions else {
                continue;
            };
            let mesh = &meshes.meshes[meshes.instances[k].mesh];
            // Indices past u32 cannot be written; such a scene keeps its instances.
            let base = u32::try_from(out.positions.len()).ok()?;
            u32::try_from(out.positions.len() + positions.len()).ok()?;
            u32::try_from(out.triangles.len() + mesh.triangles.len()).ok()?;
            let count = positions.len();
            out.positions.extend(positions);
            // An index past the mesh's positions stays past them (the tree drops the
            // triangle, as it would in the mesh's own tree).
            out.triangles.extend(mesh.triangles.iter().map(|t| {
                t.map(|v| {
                    if (v as usize) < count {
                        v + base
                    } else {
                        u32::MAX
                    }
                })
            }));
            out.origin
                .extend((0..mesh.triangles.len() as u32).map(|t| (k as u32, t)));
        }
        Some(out)
    }
}

/// Per mesh of `meshes`, whether some instance that is not merged places it: the meshes
/// that need a tree (a scene of their own in Embree's mirror) besides the merged one.
pub fn own_tree_needed(meshes: &SceneMeshes, merged: Option<&MergedMeshes>) -> Vec<bool> {
    let mut needed = vec![false; meshes.meshes.len()];
    for (k, inst) in meshes.instances.iter().enumerate() {
        if merged.is_none_or(|m| !m.merged[k])
            && let Some(n) = needed.get_mut(inst.mesh)
        {
            *n = true;
        }
    }
    needed
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::mesh::TriangleMesh;
    use crate::scene::meshes::SceneInstance;
    use glam::{Affine3A, Mat3A};

    fn instance(mesh: usize, transform: Affine3A) -> SceneInstance {
        SceneInstance {
            mesh,
            transform,
            normal_matrix: Mat3A::IDENTITY,
            material_base: 0,
            material_override: None,
            name: String::new(),
        }
    }

    fn triangle_mesh() -> TriangleMesh {
        TriangleMesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            triangles: vec![[0, 1, 2]],
            ..Default::default()
        }
    }

    #[test]
    fn single_use_meshes_are_baked_in_instance_order() {
        let mut meshes = SceneMeshes::new(0);
        meshes.meshes = vec![triangle_mesh(), triangle_mesh(), triangle_mesh()];
        let shift = Affine3A::from_translation(Vec3::new(5.0, 0.0, 0.0));
        meshes.instances = vec![
            instance(2, shift),
            instance(0, Affine3A::IDENTITY),
            // mesh 1 placed twice: kept as instances
            instance(1, Affine3A::IDENTITY),
            instance(1, shift),
            // singular: kept (and dropped by the instance tree, as before)
            instance(0, Affine3A::from_scale(Vec3::ZERO)),
        ];
        // mesh 0 is placed twice too (once singular)
        let m = MergedMeshes::of(&meshes);
        assert_eq!(m, None, "only one single-use mesh: nothing to merge");
        meshes.instances.pop();
        let m = MergedMeshes::of(&meshes).expect("two single-use meshes");
        assert_eq!(m.merged, vec![true, true, false, false]);
        assert_eq!(m.origin, vec![(0, 0), (1, 0)]);
        assert_eq!(m.triangles, vec![[0, 1, 2], [3, 4, 5]]);
        assert_eq!(m.positions[0], Vec3::new(5.0, 0.0, 0.0));
        assert_eq!(m.positions[3], Vec3::ZERO);
    }

    #[test]
    fn alpha_masked_instances_keep_their_own_tree() {
        use crate::scene::material::MaterialParams;
        use crate::scene::mesh::{AlphaMode, MeshMaterial};
        let mut meshes = SceneMeshes::new(0);
        let mut masked = triangle_mesh();
        masked.triangle_material = vec![1];
        meshes.meshes = vec![triangle_mesh(), triangle_mesh(), masked];
        let material = |alpha_mode| MeshMaterial {
            name: String::new(),
            params: MaterialParams::default_grey(),
            textures: Default::default(),
            alpha_mode,
            base_alpha: 1.0,
        };
        meshes.materials = vec![
            material(AlphaMode::Opaque),
            material(AlphaMode::Mask { cutoff: 0.5 }),
        ];
        meshes.instances = vec![
            instance(0, Affine3A::IDENTITY),
            instance(1, Affine3A::IDENTITY),
            instance(2, Affine3A::IDENTITY),
        ];
        assert!(meshes.alpha_tested(2) && !meshes.alpha_tested(0));
        let m = MergedMeshes::of(&meshes).expect("two unmasked ones");
        assert_eq!(m.merged, vec![true, true, false]);
    }

    #[test]
    fn non_finite_bakes_are_not_merged() {
        let mut meshes = SceneMeshes::new(0);
        let mut big = triangle_mesh();
        big.positions[1] = Vec3::splat(3e38);
        meshes.meshes = vec![triangle_mesh(), triangle_mesh(), big];
        meshes.instances = vec![
            instance(0, Affine3A::IDENTITY),
            instance(1, Affine3A::IDENTITY),
            instance(2, Affine3A::from_scale(Vec3::splat(10.0))),
        ];
        let m = MergedMeshes::of(&meshes).expect("two finite ones");
        assert_eq!(m.merged, vec![true, true, false]);
    }
}
