//! One ray-query interface, answered by every backend: our CPU tracer, the GPU tracer
//! (`gpu::query`) and Embree (`reference::embree`).
//!
//! The two queries are the ones a renderer needs: the closest hit in (tmin, tmax) and whether
//! anything lies in (tmin, tmax) (a shadow ray). `t` is in units of the ray's direction, which
//! [`Ray`] keeps unit length, so it is a world-space distance. Comparing backends through this
//! trait is what makes one of them a referee for the others.
//!
//! Known difference between backends: a ray that starts inside an SDF solid gets a hit at
//! `t = tmin` from the sphere tracer (the field is already below its threshold there), but the
//! exit crossing from Embree's closed-form user geometry. Comparisons cast rays from outside.

use super::{SceneTracer, Surface};
use crate::geom::Ray;
use glam::Vec3;

/// What a ray query hit, independent of the backend.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ObjectId {
    /// An SDF object: index into `Scene::objects`.
    Sdf(usize),
    /// A mesh instance: index into `SceneMeshes::instances`.
    MeshInstance(usize),
}

/// The closest hit of a ray query.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QueryHit {
    /// Ray parameter of the hit (a distance, as the ray's direction is unit length).
    pub t: f32,
    /// Unit surface normal: outward for SDF solids; for meshes the backend's choice (the CPU
    /// tracer's interpolated shading normal, Embree's geometric normal with the file's
    /// counter-clockwise front), so compare mesh normals only up to sign and smoothing.
    pub normal: Vec3,
    /// What was hit.
    pub object: ObjectId,
}

/// A backend answering ray queries against one scene.
pub trait RayQuery {
    /// The closest hit with `tmin < t < tmax`, if any.
    fn closest_hit(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<QueryHit>;
    /// Whether anything lies on the ray with `tmin < t < tmax`.
    fn occluded(&self, ray: &Ray, tmin: f32, tmax: f32) -> bool;
    /// [`RayQuery::closest_hit`] of every ray: one by one unless the backend batches (the
    /// GPU answers a batch in one dispatch, where one ray per dispatch is slow).
    fn closest_hit_many(&self, rays: &[Ray], tmin: f32, tmax: f32) -> Vec<Option<QueryHit>> {
        rays.iter()
            .map(|r| self.closest_hit(r, tmin, tmax))
            .collect()
    }
    /// [`RayQuery::occluded`] of every ray, batched as [`RayQuery::closest_hit_many`].
    fn occluded_many(&self, rays: &[Ray], tmin: f32, tmax: f32) -> Vec<bool> {
        rays.iter().map(|r| self.occluded(r, tmin, tmax)).collect()
    }
}

impl RayQuery for SceneTracer<'_> {
    fn closest_hit(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<QueryHit> {
        SceneTracer::closest_hit(self, ray, tmin, tmax).map(|h| QueryHit {
            t: h.t,
            normal: h.normal,
            object: match h.surface {
                Surface::Sdf(i) => ObjectId::Sdf(i),
                Surface::Mesh { instance, .. } => ObjectId::MeshInstance(instance as usize),
            },
        })
    }

    fn occluded(&self, ray: &Ray, tmin: f32, tmax: f32) -> bool {
        SceneTracer::occluded(self, ray, tmin, tmax)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Scene;
    use std::path::Path;

    fn scene() -> Scene {
        let src = "Scene(
            camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0), fov: 40),
            objects: [
                (shape: Sphere(radius: 1), translate: (0, 0, 0)),
                (shape: Box(half_extents: (0.5, 0.5, 0.5)), translate: (3, 0, 0)),
            ],
            tracer: (epsilon: 1e-5, epsilon_per_unit: 0),
        )";
        Scene::from_source(src, Path::new("query-test.ron")).unwrap_or_else(|e| panic!("{e}"))
    }

    #[test]
    fn cpu_tracer_answers_through_the_trait() {
        let scene = scene();
        let tracer = SceneTracer::new(&scene);
        let q: &dyn RayQuery = &tracer;

        let ray = Ray::new(Vec3::new(0.0, 0.0, 5.0), -Vec3::Z);
        let hit = q.closest_hit(&ray, 0.0, 100.0).expect("hits the sphere");
        assert_eq!(hit.object, ObjectId::Sdf(0));
        assert!((hit.t - 4.0).abs() < 1e-3, "t = {}", hit.t);
        assert!(hit.normal.dot(Vec3::Z) > 0.999, "normal {:?}", hit.normal);
        assert!(q.occluded(&ray, 0.0, 100.0));
        assert!(!q.occluded(&ray, 0.0, 3.5), "stops short of the sphere");

        let ray = Ray::new(Vec3::new(3.0, 0.0, 5.0), -Vec3::Z);
        let hit = q.closest_hit(&ray, 0.0, 100.0).expect("hits the box");
        assert_eq!(hit.object, ObjectId::Sdf(1));
        assert!((hit.t - 4.5).abs() < 1e-3, "t = {}", hit.t);

        let ray = Ray::new(Vec3::new(1.6, 0.0, 5.0), -Vec3::Z);
        assert!(q.closest_hit(&ray, 0.0, 100.0).is_none());
        assert!(!q.occluded(&ray, 0.0, 100.0));
    }
}
