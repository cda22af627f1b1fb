//! Shading on top of Embree's hits: a [`ShadingTracer`] whose ray queries (camera, reflected
//! and refracted closest hits, the exit of a refracted ray, hard shadow rays) are answered by
//! Embree 4, so `hytrace compare` can render the same integrator over both backends.
//!
//! What still comes from our side, and why:
//! * **Soft-shadow penumbrae and ambient occlusion** need a distance field, which Embree does
//!   not have: where Embree finds a shadow ray unblocked, the penumbra is our SDF's estimate
//!   along that ray; ambient occlusion samples our SDF along the normal at Embree's hit point.
//! * **Mesh attributes** (interpolated shading normal, material, texture): Embree reports the
//!   instance and the hit distance; the triangle and barycentrics there are looked up with our
//!   mesh BVH on the ray segment t ± 1e-4·D (D the scene's diameter) around Embree's t. When
//!   no triangle of ours lies there (a hit only Embree sees), the geometric normal Embree
//!   reports is used with the instance's first triangle's material; [`EmbreeTracer::fallbacks`]
//!   counts these.
//! * **SDF normals**: Embree's normal for analytic objects (exact); for objects the referee
//!   meshed, our field's gradient at Embree's hit point (the facets are an artefact of the
//!   referee's representation, not of the surface).
//! * **SDF materials** are evaluated from our shading tape at Embree's hit point.
//!
//! Shadow rays leaving a meshed object skip their first 2τ/|n·d| (τ the mesh's tolerance):
//! the facets stand up to τ off the true surface and would otherwise shadow the mesh itself.

use super::embree::{EmbreeScene, SdfCheck};
use crate::accel::field::FieldCursor;
use crate::geom::Ray;
use crate::scene::material::MaterialParams;
use crate::scene::{Scene, Shadow};
use crate::sdf::tape::{MaterialVec, Registers};
use crate::shade::ShadingTracer;
use crate::trace::query::{ObjectId, QueryHit, RayQuery};
use crate::trace::{Hit, SceneTracer, Surface, normal};
use glam::Vec3;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Most surfaces a ray travelling inside a solid may cross (other objects' surfaces) before
/// its exit is given up.
const MAX_CROSSINGS: usize = 64;

/// Embree's hits with our shading (see the module documentation).
pub struct EmbreeTracer<'a> {
    embree: &'a EmbreeScene,
    ours: &'a SceneTracer<'a>,
    /// Half-width of the segment on which a mesh hit's triangle is looked up.
    window: f32,
    fallbacks: AtomicUsize,
    mesh_hits: AtomicUsize,
}

impl<'a> EmbreeTracer<'a> {
    /// Shading over `embree`'s hits, with `ours` for distance-field quantities and mesh
    /// attributes (both built from the same scene).
    pub fn new(embree: &'a EmbreeScene, ours: &'a SceneTracer<'a>) -> Self {
        let scene = ours.scene();
        let diameter = super::validate::scene_bounds(scene).diagonal();
        EmbreeTracer {
            embree,
            ours,
            window: super::validate::MESH_DT_OF_DIAMETER * diameter,
            fallbacks: AtomicUsize::new(0),
            mesh_hits: AtomicUsize::new(0),
        }
    }

    /// (mesh hits whose triangle was not found on our side, mesh hits) so far.
    pub fn fallbacks(&self) -> (usize, usize) {
        (
            self.fallbacks.load(Ordering::Relaxed),
            self.mesh_hits.load(Ordering::Relaxed),
        )
    }

    /// Our [`Hit`] for Embree's `QueryHit` on `ray`.
    fn hit(&self, ray: &Ray, q: QueryHit) -> Hit {
        let scene = self.ours.scene();
        match q.object {
            ObjectId::Sdf(i) => {
                let normal = match self.embree.checks.get(i) {
                    Some(SdfCheck::Meshed { .. }) => {
                        let s = &scene.tracer;
                        let mut regs = Registers::new();
                        let p = ray.at(q.t);
                        normal::estimate(
                            &mut FieldCursor::whole(&scene.objects[i].lowered.distance, &mut regs),
                            p,
                            normal::step_for(s, q.t, p),
                            s.normals,
                        )
                        .0
                    }
                    _ => q.normal,
                };
                Hit {
                    t: q.t,
                    surface: Surface::Sdf(i),
                    normal,
                    gradient: 1.0,
                    steps: 0,
                }
            }
            ObjectId::MeshInstance(k) => {
                self.mesh_hits.fetch_add(1, Ordering::Relaxed);
                let accel = self.ours.mesh_accel();
                let found = accel.tlas.closest_hit_filtered(
                    &accel.blas,
                    ray,
                    (q.t - self.window).max(0.0),
                    q.t + self.window,
                    &accel.alpha_test(&scene.meshes),
                );
                let (instance, triangle, u, v) = match found {
                    Some(h) => (h.instance, h.triangle, h.u, h.v),
                    None => {
                        self.fallbacks.fetch_add(1, Ordering::Relaxed);
                        (k as u32, 0, 0.0, 0.0)
                    }
                };
                let surf = scene
                    .meshes
                    .surface(instance as usize, triangle as usize, u, v);
                Hit {
                    t: q.t,
                    surface: Surface::Mesh {
                        instance,
                        triangle,
                        u,
                        v,
                        material: surf.material,
                        sample: surf.sample,
                    },
                    normal: if found.is_some() {
                        surf.normal
                    } else {
                        q.normal
                    },
                    gradient: 1.0,
                    steps: 0,
                }
            }
        }
    }
}

impl EmbreeTracer<'_> {
    /// How far along a ray leaving a meshed SDF object's surface Embree must not look for a
    /// blocker: the mesh lies up to its tolerance τ off the true surface, so its own facets
    /// can stand across the first part of the ray (shadow acne on the facets). A ray starting
    /// within 2τ of meshed object i (|f_i| ≤ 2τ) skips 2τ/|n·d| (n the field's normal there,
    /// |n·d| at least 0.05) — the same 2τ that `validate` adds to shadow rays from meshed hits.
    fn mesh_clearance(&self, ray: &Ray) -> f32 {
        let scene = self.ours.scene();
        let mut regs = Registers::new();
        let mut clearance = 0.0f32;
        for (i, check) in self.embree.checks.iter().enumerate() {
            let SdfCheck::Meshed { tolerance, .. } = check else {
                continue;
            };
            let field = &scene.objects[i].lowered.distance;
            if field.eval_in(ray.origin, &mut regs).abs() > 2.0 * tolerance {
                continue;
            }
            let s = &scene.tracer;
            let (n, _) = normal::estimate(
                &mut FieldCursor::whole(field, &mut regs),
                ray.origin,
                normal::step_for(s, 0.0, ray.origin),
                s.normals,
            );
            let cos = n.dot(ray.direction).abs().max(0.05);
            clearance = clearance.max(2.0 * tolerance / cos);
        }
        clearance
    }
}

impl ShadingTracer for EmbreeTracer<'_> {
    fn scene(&self) -> &Scene {
        self.ours.scene()
    }

    /// Embree's closest hit, stopped at `tracer.max_distance` as our tracer stops.
    fn closest_hit(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<Hit> {
        let limit = tmax.min(self.scene().tracer.max_distance);
        let q = self.embree.closest_hit(ray, tmin, limit)?;
        Some(self.hit(ray, q))
    }

    /// The next crossing of the object's own surface along the ray (other objects' surfaces
    /// are skipped, as our tracer ignores them inside a solid); for a mesh, the next mesh
    /// surface. The outward normal points along the ray.
    fn exit(&self, surface: Surface, ray: &Ray, tmax: f32) -> Option<(f32, Vec3)> {
        let limit = tmax.min(self.scene().tracer.max_distance);
        let mut tmin = 0.0;
        for _ in 0..MAX_CROSSINGS {
            let q = self.embree.closest_hit(ray, tmin, limit)?;
            let same = match (surface, q.object) {
                (Surface::Sdf(i), ObjectId::Sdf(j)) => i == j,
                (Surface::Mesh { .. }, ObjectId::MeshInstance(_)) => true,
                _ => false,
            };
            if same {
                let n = self.hit(ray, q).normal;
                return Some((q.t, if n.dot(ray.direction) < 0.0 { -n } else { n }));
            }
            // Step past the other surface; the next query starts just beyond it.
            tmin = q.t * (1.0 + f32::EPSILON) + f32::MIN_POSITIVE;
        }
        None
    }

    /// Embree decides whether the ray is blocked; an unblocked ray gets our SDF penumbra for
    /// soft shadows.
    fn visibility(&self, ray: &Ray, tmin: f32, tmax: f32, shadow: Shadow) -> f32 {
        if shadow == Shadow::None {
            return 1.0;
        }
        let limit = tmax.min(self.scene().tracer.max_distance);
        let tmin = tmin + self.mesh_clearance(ray);
        if tmin < limit && self.embree.occluded(ray, tmin, limit) {
            return 0.0;
        }
        match shadow {
            Shadow::Soft(_) | Shadow::SoftImproved(_) => {
                self.ours.visibility(ray, tmin, tmax, shadow)
            }
            _ => 1.0,
        }
    }

    fn distance(&self, p: Vec3, reach: f32) -> f32 {
        self.ours.distance(p, reach)
    }

    fn material_at(&self, hit: &Hit, p: Vec3, materials: &[MaterialVec]) -> MaterialParams {
        self.ours.material_at(hit, p, materials)
    }
}
