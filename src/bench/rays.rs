//! The ray sets of the mesh benchmark, generated once and fed unchanged to every backend.

use crate::accel::MeshAccel;
use crate::geom::Ray;
use crate::rng::Rng;
use crate::scene::Scene;
use crate::scene::camera::{Camera, Projection};
use glam::Vec3;

/// One query: a ray over `[0, tmax]`.
#[derive(Debug, Clone, Copy)]
pub struct QueryRay {
    /// The ray (unit direction).
    pub ray: Ray,
    /// End of the interval.
    pub tmax: f32,
}

/// What a ray set asks: the closest hit, or whether anything blocks the ray.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Query {
    /// Closest hit (`rtcIntersect1`).
    Closest,
    /// Any hit (`rtcOccluded1`).
    Occluded,
}

/// A named set of rays and the query it is traced with.
#[derive(Debug, Clone)]
pub struct RaySet {
    /// "primary", "ao", "shadow" or "incoherent".
    pub kind: &'static str,
    /// The query.
    pub query: Query,
    /// The rays.
    pub rays: Vec<QueryRay>,
}

/// A pinhole camera (vertical field of view 40°) looking at the centre of the meshes' bounds
/// from the direction (0.55, 0.45, 1), as close as it can while all eight corners of the
/// bounds stay inside an image of the given aspect ratio: the model fills the frame (the
/// files' default framing uses the bounding sphere, which leaves long models small).
pub fn framing_camera(scene: &Scene, aspect: f32) -> Camera {
    let b = scene.meshes.bounds();
    let centre = b.center();
    let tan_half = 20f32.to_radians().tan();
    let forward = -Vec3::new(0.55, 0.45, 1.0).normalize();
    let right = forward.cross(Vec3::Y).normalize();
    let up = right.cross(forward);
    // Corner c at depth D + z (z along forward) fits when |x| ≤ (D + z)·tan·aspect and
    // |y| ≤ (D + z)·tan.
    let distance = b
        .corners()
        .iter()
        .map(|&c| {
            let r = c - centre;
            let (x, y, z) = (r.dot(right), r.dot(up), r.dot(forward));
            (x.abs() / (tan_half * aspect)).max(y.abs() / tan_half) - z
        })
        .fold(0.0f32, f32::max)
        .max(1e-6);
    Camera::look_at(
        centre - distance * forward,
        centre,
        Vec3::Y,
        Projection::Perspective {
            tan_half_fov: tan_half,
        },
    )
    .expect("the framing direction is never vertical")
}

/// Primary rays of the scene's pinhole camera through the centres of a `width`×`height` image,
/// in the order the CPU renderer traces them (see [`primary_from`]).
pub fn primary(scene: &Scene, width: u32, height: u32) -> Vec<QueryRay> {
    primary_from(&scene.camera, width, height)
}

/// Primary rays of `camera` through the centres of a `width`×`height` image, in the order the
/// CPU renderer traces them: tile by tile ([`crate::render::tiles`], 32×32 pixels), row by row
/// inside a tile. Neighbouring rays then walk mostly the same nodes, as they do in a render;
/// both backends get the same array in the same order.
pub fn primary_from(camera: &Camera, width: u32, height: u32) -> Vec<QueryRay> {
    let aspect = width as f32 / height as f32;
    let mut rays = Vec::with_capacity((width * height) as usize);
    for tile in crate::render::tiles(width, height, crate::render::TILE) {
        for y in tile.y0..tile.y0 + tile.h {
            for x in tile.x0..tile.x0 + tile.w {
                let u = (x as f32 + 0.5) / width as f32;
                let v = (y as f32 + 0.5) / height as f32;
                rays.push(QueryRay {
                    ray: camera.ray(u, v, aspect),
                    tmax: f32::INFINITY,
                });
            }
        }
    }
    rays
}

/// A unit vector orthogonal to `n` (Duff et al., "Building an Orthonormal Basis, Revisited",
/// JCGT 6(1), 2017), and the third axis.
fn basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1.0f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// The secondary ray sets, from the hits of the primary rays on our BVH: per hit, one
/// cosine-distributed ray over the hemisphere facing the camera (closest hit within the
/// scene's radius: ambient occlusion) and one shadow ray to a point light above the model
/// (occlusion up to the light). Origins are moved off the surface by 10⁻⁴ of the scene's
/// radius along the geometric normal. Seeded: the same scene gives the same rays.
pub fn secondary(
    scene: &Scene,
    accel: &MeshAccel,
    primary: &[QueryRay],
) -> (Vec<QueryRay>, Vec<QueryRay>) {
    let bounds = scene.meshes.bounds();
    let radius = 0.5 * bounds.diagonal();
    let light = bounds.center() + 2.0 * radius * Vec3::new(0.3, 1.0, 0.4).normalize();
    let offset = 1e-4 * radius;
    let mut rng = Rng::new(0x005e_eda0);
    let (mut ao, mut shadow) = (Vec::new(), Vec::new());
    for q in primary {
        let Some(h) = accel.tlas.closest_hit(&accel.blas, &q.ray, 0.0, q.tmax) else {
            continue;
        };
        let inst = &scene.meshes.instances[h.instance as usize];
        let mesh = &scene.meshes.meshes[inst.mesh];
        let [a, b, c] = mesh.triangles[h.triangle as usize].map(|i| mesh.positions[i as usize]);
        let mut n = (inst.normal_matrix * (b - a).cross(c - a)).normalize_or_zero();
        if n == Vec3::ZERO {
            continue;
        }
        if n.dot(q.ray.direction) > 0.0 {
            n = -n;
        }
        let p = q.ray.at(h.t) + offset * n;
        // Cosine-weighted hemisphere (Malley's method: uniform disc, projected up).
        let (r, phi) = (
            rng.next_f32().sqrt(),
            std::f32::consts::TAU * rng.next_f32(),
        );
        let (t1, t2) = basis(n);
        let z = (1.0 - r * r).max(0.0).sqrt();
        let d = r * phi.cos() * t1 + r * phi.sin() * t2 + z * n;
        ao.push(QueryRay {
            ray: Ray::new(p, d),
            tmax: radius,
        });
        let to_light = light - p;
        shadow.push(QueryRay {
            ray: Ray::new(p, to_light),
            tmax: to_light.length(),
        });
    }
    (ao, shadow)
}

/// `count` rays from uniform random points of the scene's bounds in uniform random
/// directions (closest hit, unbounded).
pub fn incoherent(scene: &Scene, count: usize) -> Vec<QueryRay> {
    let b = scene.meshes.bounds();
    let mut rng = Rng::new(0x01c0_04e7);
    (0..count)
        .map(|_| QueryRay {
            ray: Ray::new(rng.in_box(b.min, b.max), rng.direction()),
            tmax: f32::INFINITY,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn basis_is_orthonormal() {
        let mut rng = Rng::new(1);
        for _ in 0..1000 {
            let n = rng.direction();
            let (a, b) = basis(n);
            assert!((a.length() - 1.0).abs() < 1e-5 && (b.length() - 1.0).abs() < 1e-5);
            assert!(a.dot(n).abs() < 1e-5 && b.dot(n).abs() < 1e-5 && a.dot(b).abs() < 1e-5);
        }
    }
}
