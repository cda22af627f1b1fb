//! The rays that the backend comparisons cast: a camera grid, random rays into the scene's
//! bounds from outside every solid, and shadow rays from hits toward the lights. One copy, so
//! the CPU, GPU and Embree comparisons all cast the same kinds of ray.

use glam::Vec3;
use hytrace::geom::{Aabb, Ray};
use hytrace::rng::Rng;
use hytrace::scene::{Light, Scene};
use hytrace::trace::{SceneTracer, epsilon_at};

/// Bounds of everything finite (SDF objects and mesh instances); a box of half-size 2 about
/// the origin for a scene with nothing finite, so that random rays still have a target.
pub fn bounds(scene: &Scene) -> Aabb {
    let b = scene.finite_bounds().union(&scene.meshes.bounds());
    if b.is_empty() {
        Aabb::symmetric(Vec3::splat(2.0))
    } else {
        b
    }
}

/// Primary rays through the centres of a `w`×`h` grid of the scene's camera, row by row.
pub fn camera_grid(scene: &Scene, w: u32, h: u32, aspect: f32) -> Vec<Ray> {
    (0..w * h)
        .map(|k| {
            let (i, j) = (k % w, k / w);
            let (u, v) = ((i as f32 + 0.5) / w as f32, (j as f32 + 0.5) / h as f32);
            scene.camera.ray(u, v, aspect)
        })
        .collect()
}

/// `n` rays from a sphere around the scene's bounds (1.5 × its half-diagonal) toward random
/// points in them. Origins inside a solid (below a ground plane) are drawn again: there the
/// sphere tracer reports a hit at t = tmin and Embree the surface crossing, so a comparison
/// casts from outside.
pub fn random_rays(scene: &Scene, n: usize, seed: u64) -> Vec<Ray> {
    let tracer = SceneTracer::new(scene);
    let b = bounds(scene);
    let (c, r) = (b.center(), 0.5 * b.diagonal());
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| {
            let o = loop {
                let o = c + 1.5 * r * rng.direction();
                if tracer.distance(o, f32::INFINITY) > 1e-3 {
                    break o;
                }
            };
            let target = rng.in_box(b.min, b.max);
            Ray::new(o, target - o)
        })
        .collect()
}

/// [`camera_grid`] then [`random_rays`]: what the backend comparisons cast.
pub fn scene_rays(scene: &Scene, w: u32, h: u32, aspect: f32, n: usize, seed: u64) -> Vec<Ray> {
    let mut rays = camera_grid(scene, w, h, aspect);
    rays.extend(random_rays(scene, n, seed));
    rays
}

/// Where a light is, for a shadow ray.
#[derive(Debug, Clone, Copy)]
pub enum LightAt {
    /// A point light at this position.
    Point(Vec3),
    /// A directional light: toward it along this (unit) direction, up to this distance.
    Far(Vec3, f32),
}

/// The scene's point and directional lights; a directional light is reached at half the
/// tracer's range (the renderer's shadow rays stop there too).
pub fn lights(scene: &Scene) -> Vec<LightAt> {
    let far = 0.5 * scene.tracer.max_distance;
    scene
        .lights
        .iter()
        .filter_map(|l| match l {
            Light::Point { position, .. } => Some(LightAt::Point(*position)),
            Light::Directional { direction, .. } => Some(LightAt::Far(-direction.normalize(), far)),
            _ => None,
        })
        .collect()
}

/// The origin of a shadow ray from the hit at `t` of `ray` with surface normal `normal`:
/// `offset` off the surface on the side the ray came from, as the renderer casts it (else
/// the ray could start behind the surface).
pub fn shadow_origin(ray: &Ray, t: f32, normal: Vec3, offset: f32) -> Vec3 {
    ray.at(t) + offset * facing(ray, normal)
}

/// `normal` turned toward the side `ray` comes from.
pub fn facing(ray: &Ray, normal: Vec3) -> Vec3 {
    if normal.dot(ray.direction) > 0.0 {
        -normal
    } else {
        normal
    }
}

/// The renderer's shadow-ray offset at distance `t`: 4·ε(t).
pub fn shadow_offset(scene: &Scene, t: f32) -> f32 {
    4.0 * epsilon_at(&scene.tracer, t)
}

/// A shadow ray from `o` toward `light`, with the distance at which it reaches the light.
pub fn toward(o: Vec3, light: LightAt) -> (Ray, f32) {
    match light {
        LightAt::Point(p) => (Ray::new(o, p - o), (p - o).length()),
        LightAt::Far(d, far) => (Ray::new(o, d), far),
    }
}
