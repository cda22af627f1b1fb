//! Acceleration: which objects a ray can meet, and over which parametric interval.
//!
//! SDF objects: every object has conservative world bounds, and a ray sphere-traces an object
//! only inside the interval where it crosses them. The bounds sit in a BVH ([`bvh::AabbBvh`]);
//! unbounded objects (planes, infinite repetition) are kept apart and span the whole ray. A
//! linear scan over the same bounds remains available to check the BVH against.
//! Meshes: a BVH per mesh ([`bvh::MeshBvh`]) under a BVH over instances
//! ([`bvh::InstanceBvh`]), with a watertight triangle test ([`triangle`]); the meshes placed
//! only once are baked into world space and merged into one tree ([`merge`]).

pub mod bvh;
pub mod field;
pub mod merge;
pub mod triangle;

use crate::geom::{Aabb, Ray};
use crate::scene::{SceneMeshes, SdfObject};
use std::ops::ControlFlow;

/// Culling structure over the SDF objects of a scene.
#[derive(Debug, Clone)]
pub enum SdfAccel {
    /// Every object's bounds tested in turn (the reference for the BVH).
    Linear(Vec<Aabb>),
    /// A BVH over the bounded objects, the unbounded ones apart.
    Bvh(bvh::AabbBvh),
}

impl SdfAccel {
    /// Builds a BVH over the objects' world bounds.
    pub fn new(objects: &[SdfObject]) -> Self {
        SdfAccel::Bvh(bvh::AabbBvh::build(
            &objects.iter().map(|o| o.bounds()).collect::<Vec<_>>(),
        ))
    }

    /// The linear scan over the same bounds.
    pub fn linear(objects: &[SdfObject]) -> Self {
        SdfAccel::Linear(objects.iter().map(|o| o.bounds()).collect())
    }

    /// Calls `visit(object, t_enter, t_exit, tmax)` for every object whose bounds the ray
    /// crosses within [tmin, tmax]; `visit` may lower `tmax` (closest hit: farther objects are
    /// then skipped) or stop the walk (any hit).
    pub fn visit(
        &self,
        ray: &Ray,
        tmin: f32,
        tmax: &mut f32,
        visit: impl FnMut(usize, f32, f32, &mut f32) -> ControlFlow<()>,
    ) {
        self.visit_within(ray, tmin, tmax, 0.0, visit)
    }

    /// Like [`SdfAccel::visit`], with every object's bounds grown by `margin`: queries that
    /// look at the field *near* surfaces (soft-shadow penumbrae) need the rays that pass
    /// close to an object, not only those that cross its bounds.
    pub fn visit_within(
        &self,
        ray: &Ray,
        tmin: f32,
        tmax: &mut f32,
        margin: f32,
        mut visit: impl FnMut(usize, f32, f32, &mut f32) -> ControlFlow<()>,
    ) {
        match self {
            SdfAccel::Bvh(b) => b.visit_within(ray, tmin, tmax, margin, visit),
            SdfAccel::Linear(bounds) => {
                for (i, b) in bounds.iter().enumerate() {
                    let b = if margin > 0.0 { b.expand(margin) } else { *b };
                    if let Some((t0, t1)) = b.ray_interval(ray, tmin, *tmax)
                        && visit(i, t0, t1, tmax).is_break()
                    {
                        return;
                    }
                }
            }
        }
    }

    /// [`SdfAccel::visit_within`] for many rays, ray after ray ([`bvh::AabbBvh::visit_rays_within`]
    /// for the BVH): `visit(ray, object, t_enter, t_exit)` for every object whose bounds,
    /// grown by `margin(ray)`, ray `r` crosses within `[tmins[r], tmaxs[r]]`.
    pub fn visit_rays_within(
        &self,
        rays: &[Ray],
        tmins: &[f32],
        tmaxs: &[f32],
        margin: impl Fn(usize) -> f32,
        mut visit: impl FnMut(usize, usize, f32, f32),
    ) {
        match self {
            SdfAccel::Bvh(b) => b.visit_rays_within(rays, tmins, tmaxs, margin, visit),
            SdfAccel::Linear(_) => {
                for (r, ray) in rays.iter().enumerate() {
                    let mut tmax = tmaxs[r];
                    self.visit_within(ray, tmins[r], &mut tmax, margin(r), |i, t0, t1, _| {
                        visit(r, i, t0, t1);
                        ControlFlow::Continue(())
                    });
                }
            }
        }
    }

    /// Nodes of the BVH (0 for the linear scan).
    pub fn node_count(&self) -> usize {
        match self {
            SdfAccel::Bvh(b) => b.node_count(),
            SdfAccel::Linear(_) => 0,
        }
    }
}

/// The meshes' two-level BVH.
#[derive(Debug, Clone)]
pub struct MeshAccel {
    /// One BVH per scene mesh, in object space (empty for a mesh whose one instance is
    /// merged), then, when instances are merged, the merged mesh's in world space (see
    /// [`bvh::InstanceBvh::merged`]).
    pub blas: Vec<bvh::MeshBvh>,
    /// The BVH over instances.
    pub tlas: bvh::InstanceBvh,
    /// Wall-clock time of the whole build.
    pub build_time: std::time::Duration,
    /// Per scene instance, whether it has alpha-masked triangles ([`AlphaTest`] tests them).
    pub alpha_tested: Vec<bool>,
}

/// The scene's alpha masks as a [`bvh::HitFilter`]: a hit on a glTF `MASK` material where the
/// coverage is below the cutoff does not count, for every query (glTF 2.0 §3.9.6: the
/// surface is not there).
#[derive(Clone, Copy)]
pub struct AlphaTest<'a> {
    meshes: &'a SceneMeshes,
    tested: &'a [bool],
}

impl bvh::HitFilter for AlphaTest<'_> {
    #[inline]
    fn tests(&self, instance: u32) -> bool {
        self.tested.get(instance as usize).copied().unwrap_or(false)
    }
    fn accept(&self, instance: u32, triangle: u32, u: f32, v: f32) -> bool {
        !self
            .meshes
            .masked_out(instance as usize, triangle as usize, u, v)
    }
}

impl MeshAccel {
    /// Builds the BVHs of a scene's meshes, the meshes placed once merged into one tree
    /// ([`merge`]). The trees are built side by side on the rayon pool, each large one in
    /// parallel itself; every tree is a function of its mesh alone, the same on any number of
    /// threads.
    pub fn new(meshes: &SceneMeshes, quality: bvh::BuildQuality) -> Self {
        Self::with_merging(meshes, quality, true)
    }

    /// [`Self::new`], merging the single-use meshes ([`merge`]) only when `merge`: the
    /// two-level tree of every instance otherwise (what the merged tree is checked against).
    pub fn with_merging(meshes: &SceneMeshes, quality: bvh::BuildQuality, merge: bool) -> Self {
        use rayon::prelude::*;
        let start = std::time::Instant::now();
        let merged = merge.then(|| merge::MergedMeshes::of(meshes)).flatten();
        // Meshes whose one instance is merged need no tree of their own.
        let needed = merge::own_tree_needed(meshes, merged.as_ref());
        let empty: (&[glam::Vec3], &[[u32; 3]]) = (&[], &[]);
        let mut jobs: Vec<(&[glam::Vec3], &[[u32; 3]])> = meshes
            .meshes
            .iter()
            .zip(&needed)
            .map(|(m, &n)| {
                if n {
                    (&m.positions[..], &m.triangles[..])
                } else {
                    empty
                }
            })
            .collect();
        if let Some(m) = &merged {
            jobs.push((&m.positions, &m.triangles));
        }
        let blas: Vec<_> = jobs
            .par_iter()
            .map(|&(positions, triangles)| bvh::MeshBvh::build(positions, triangles, quality))
            .collect();
        let instances: Vec<bvh::Instance> = meshes
            .instances
            .iter()
            .map(|i| bvh::Instance {
                mesh: i.mesh,
                transform: i.transform,
            })
            .collect();
        let tlas = bvh::InstanceBvh::build_merged(
            &blas,
            &instances,
            merged.map(|m| bvh::Merged {
                mesh: meshes.meshes.len(),
                origin: m.origin,
            }),
            quality,
        );
        let alpha_tested = (0..meshes.instances.len())
            .map(|i| meshes.alpha_tested(i))
            .collect();
        MeshAccel {
            blas,
            tlas,
            build_time: start.elapsed(),
            alpha_tested,
        }
    }

    /// The alpha test of `meshes` (the meshes this was built from).
    pub fn alpha_test<'a>(&'a self, meshes: &'a SceneMeshes) -> AlphaTest<'a> {
        AlphaTest {
            meshes,
            tested: &self.alpha_tested,
        }
    }

    /// Whether there is anything to hit.
    pub fn is_empty(&self) -> bool {
        self.blas.is_empty()
    }
}
