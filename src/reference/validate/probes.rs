//! Which rays the validation casts: a camera ray through every pixel, random rays through the
//! scene's bounds, and shadow rays from the referee's camera-ray hits toward the lights.

use crate::geom::{Aabb, Ray};
use crate::rng::Rng;
use crate::scene::Scene;
use crate::sdf::tape::Registers;
use crate::shade::offset_from_surface;
use crate::trace::epsilon_at;
use crate::trace::query::QueryHit;
use glam::Vec3;

/// Which rays to cast.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Options {
    /// Camera rays: one through every pixel centre of a width × height image.
    pub width: u32,
    /// See `width`.
    pub height: u32,
    /// Random rays through the scene's bounds.
    pub random: usize,
    /// Seed of the random rays.
    pub seed: u64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            width: 320,
            height: 240,
            random: 10_000,
            seed: 1,
        }
    }
}

/// One ray to compare: the ray, and the pixel it belongs to (camera rays).
#[derive(Debug, Clone, Copy)]
pub(super) struct Probe {
    pub(super) ray: Ray,
    pub(super) pixel: Option<usize>,
}

/// A shadow ray from a camera ray's hit toward one light.
#[derive(Debug, Clone, Copy)]
pub(super) struct ShadowProbe {
    /// The camera-grid pixel whose hit it leaves.
    pub(super) pixel: usize,
    /// The ray, from the offset hit point toward the light.
    pub(super) ray: Ray,
    /// How far it is traced: to the light, or the tracer's range for a directional light.
    pub(super) len: f32,
    /// n·l at its origin.
    pub(super) cos: f32,
}

/// The finite bounds of the scene (SDF objects and meshes); around the camera when nothing is
/// finite (a scene of planes), so random rays still have somewhere to go.
pub fn scene_bounds(scene: &Scene) -> Aabb {
    let b = scene.finite_bounds().union(&scene.meshes.bounds());
    if b.is_empty() || !b.is_finite() {
        let c = scene.camera.position;
        Aabb::new(c, c).expand(1.0)
    } else {
        b
    }
}

/// Every pixel's camera ray, then `random` rays from a sphere around the bounds (1.5 × their
/// half-diagonal) toward uniform points inside them. Origins inside an SDF solid (below a ground
/// plane, say) are drawn again: there the sphere tracer reports a hit at t = 0 and a
/// closed-form referee the surface crossing, a known, intended difference.
pub(super) fn probes(scene: &Scene, options: &Options) -> Result<Vec<Probe>, String> {
    let (w, h) = (options.width, options.height);
    let aspect = w as f32 / h as f32;
    let mut out = Vec::with_capacity((w * h) as usize + options.random);
    for y in 0..h {
        for x in 0..w {
            let (u, v) = ((x as f32 + 0.5) / w as f32, (y as f32 + 0.5) / h as f32);
            out.push(Probe {
                ray: scene.camera.ray(u, v, aspect),
                pixel: Some((y * w + x) as usize),
            });
        }
    }
    let b = scene_bounds(scene);
    let (c, r) = (b.center(), 0.5 * b.diagonal().max(1e-6));
    let clearance = 4.0 * epsilon_at(&scene.tracer, 0.0);
    let mut regs = Registers::new();
    let outside = |p: Vec3, regs: &mut Registers| {
        scene
            .objects
            .iter()
            .all(|o| o.lowered.distance.eval_in(p, regs) > clearance)
    };
    let mut rng = Rng::new(options.seed);
    let mut attempts = 0usize;
    let budget = 1000 * options.random.max(1);
    for _ in 0..options.random {
        let o = loop {
            attempts += 1;
            if attempts > budget {
                return Err(format!(
                    "could not find {} random ray origins outside every object on the sphere of \
                     radius {:.4} around the scene's bounds",
                    options.random,
                    1.5 * r
                ));
            }
            let o = c + 1.5 * r * rng.direction();
            if outside(o, &mut regs) {
                break o;
            }
        };
        let target = rng.in_box(b.min, b.max);
        if (target - o).length_squared() > 0.0 {
            out.push(Probe {
                ray: Ray::new(o, target - o),
                pixel: None,
            });
        }
    }
    Ok(out)
}

/// The shadow rays from the referee's hit `hit` on the camera ray `ray` of `pixel` toward every
/// light, offset from the surface as the renderer offsets them (`shade::surface_offset`), only
/// toward lights in front of the surface (the renderer casts no others). A directional light's
/// ray stops at `tracer.max_distance`, where our tracer stops every ray.
///
/// `mesh_tolerance` is τ of a meshed hit (0 otherwise): a meshed hit lies up to τ from the true
/// surface, on either side, so started from the renderer's offset alone the shadow ray could
/// begin inside the true solid, where our tracer reports the surface itself as the occluder.
/// From a meshed hit the ray therefore starts 2τ further out (≥ τ off the true surface, ≥ τ off
/// the mesh); both sides trace the same ray.
pub(super) fn shadow_probes<'a>(
    scene: &'a Scene,
    pixel: usize,
    ray: Ray,
    hit: QueryHit,
    mesh_tolerance: f32,
) -> impl Iterator<Item = ShadowProbe> + 'a {
    let settings = &scene.tracer;
    let tmax = settings.max_distance;
    let p = ray.at(hit.t);
    let n = if hit.normal.dot(ray.direction) > 0.0 {
        -hit.normal
    } else {
        hit.normal
    };
    let offset = offset_from_surface(settings, hit.t, p) + 2.0 * mesh_tolerance;
    let origin = p + n * offset;
    scene.lights.iter().filter_map(move |light| {
        // the lights shading asks about: not ambient ones, nor points outside a spot's cone
        // or beyond a light's range
        let (l, dist, _, _) = crate::shade::light_at(light, p)?;
        let len = if dist.is_finite() {
            dist - offset
        } else {
            tmax
        };
        let cos = n.dot(l);
        if cos <= 0.0 || len <= 0.0 {
            return None;
        }
        Some(ShadowProbe {
            pixel,
            ray: Ray::new(origin, l),
            len,
            cos,
        })
    })
}
