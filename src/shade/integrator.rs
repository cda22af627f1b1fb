//! The path a camera ray takes: local shading, then mirror reflection and refraction, followed
//! iteratively with a small explicit stack (no recursion, as a GPU needs) up to a bounce limit.
//!
//! At a surface with reflectivity r, transparency τ and index of refraction η, and Schlick
//! reflectances F_r (see [`mirror_reflectance`]: R₀ = r for Phong, r·F(f₀) for the
//! metallic-roughness model, a colour; only where r > 0) and F_t (R₀ = ((1−η)/(1+η))², total
//! internal reflection included), and the local share s = 1 − F_r for Phong, 1 for the
//! metallic-roughness model:
//!
//! ```text
//! L = α·{(1 − τ)·[s·L_local + F_r·L_reflected] + τ·[F_t·L_reflected + (1 − F_t)·albedo·L_transmitted]}
//!   + (1 − α)·L_behind
//! ```
//!
//! where α is the coverage of a glTF `BLEND` surface (1 for every other surface; a partly
//! covered surface is thin and does not refract, τ = 0) and L_behind the radiance of the ray
//! continued straight through it, which counts as a bounce.
//!
//! A refracted ray marches inside the object it entered (the others are ignored inside it)
//! with |f| and a step scale below 1 until it leaves, and splits again there into the
//! transmitted ray and the internally reflected one. Paths whose weight drops below 1/1000,
//! and paths beyond `shading.max_bounces`, are dropped.

use super::brdf::MetallicRoughness;
use super::optics::{reflect, refract, schlick};
use super::{ShadingTracer, SurfacePoint, shade, shade_with, surface_offset};
use crate::geom::Ray;
use crate::scene::MAX_BOUNCES;
use crate::scene::material::MaterialParams;
use crate::sdf::tape::MaterialVec;
use crate::trace::{Hit, Surface};
use arrayvec::ArrayVec;
use glam::Vec3;

/// What one camera sample sees: its radiance and the first hit's auxiliary values (AOVs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraSample {
    /// Linear radiance.
    pub radiance: Vec3,
    /// Distance to the first hit (infinite on a miss).
    pub depth: f32,
    /// Unit normal at the first hit (zero on a miss).
    pub normal: Vec3,
    /// Albedo at the first hit (zero on a miss).
    pub albedo: Vec3,
    /// Sphere-tracing steps of the camera ray.
    pub steps: u32,
    /// |∇f| at the first hit (zero on a miss).
    pub gradient: f32,
}

impl CameraSample {
    /// What a camera ray that meets nothing and sees no light carries: the start of every
    /// sample.
    pub const NOTHING: CameraSample = CameraSample {
        radiance: Vec3::ZERO,
        depth: f32::INFINITY,
        normal: Vec3::ZERO,
        albedo: Vec3::ZERO,
        steps: 0,
        gradient: 0.0,
    };
}

/// One pending ray of the path: where it goes, what fraction of it reaches the camera, how
/// many bounces it took, and the object it travels inside (for refracted rays).
#[derive(Debug, Clone, Copy)]
struct PendingRay {
    ray: Ray,
    weight: Vec3,
    bounces: u32,
    inside: Option<(Surface, f32)>,
}

/// The pending rays of one camera path, on the stack of the thread that follows it.
type PathStack = ArrayVec<PendingRay, { MAX_BOUNCES as usize + 2 }>;

/// Paths lighter than this are not followed.
const MIN_WEIGHT: f32 = 1e-3;

/// The local shading of hits whose lights' visibilities a caller answers later, together:
/// the CPU renderer collects a band's, then [`Self::settle`] asks
/// [`ShadingTracer::visibilities`] once for all their shadow rays (on our tracer, ray
/// bundles) and adds every term to its sample in the order its path made them, so that each
/// sample's sum is the one shading on the spot gives, bit for bit. (Shaded on the spot, one
/// shadow ray at a time, the reflections and refractions of glass.ron spent 40 % of its
/// frames in single-ray penumbra marches.)
///
/// Memory: the caller settles once [`SETTLE_AT`] surfaces wait, after the path that reached
/// it; one path has at most 2^(bounces + 1) − 1 hits (each pops one ray and pushes at most
/// two), so at most [`SETTLE_AT`] + 131,071 surfaces (about 20 MB) wait at any time.
#[derive(Debug, Default)]
pub struct DeferredShading {
    /// Radiance to add, in the order of the paths that made the terms.
    terms: Vec<Term>,
    /// The surfaces of the [`Term::Shade`] terms.
    points: Vec<SurfacePoint>,
    /// Scratch of [`Self::settle`]: the shadow rays, the surface and light each belongs to
    /// (surface · lights + light), their answers, and the visibilities by surface and light.
    queries: Vec<super::ShadowQuery>,
    owners: Vec<usize>,
    answers: Vec<f32>,
    visibility: Vec<f32>,
}

/// How many waiting surfaces make a caller of [`DeferredShading`] settle them (a few bands'
/// worth of reflections: the bundles stay full, the memory small).
pub const SETTLE_AT: usize = 1024;

/// One addition to a sample's radiance, put off by [`DeferredShading`].
#[derive(Debug, Clone, Copy)]
enum Term {
    /// `radiance` onto sample `slot`.
    Add { slot: usize, radiance: Vec3 },
    /// `weight`·(local shading of surface `point`) onto sample `slot`.
    Shade {
        slot: usize,
        weight: Vec3,
        point: usize,
    },
}

/// Where a path puts off its local shading: into `shading`, for the caller's sample `slot`.
pub struct Deferral<'d> {
    /// The terms of the caller's samples so far.
    pub shading: &'d mut DeferredShading,
    /// This path's sample, as the caller numbers them ([`DeferredShading::settle`]).
    pub slot: usize,
}

impl DeferredShading {
    /// The surfaces whose shading waits.
    pub fn waiting(&self) -> usize {
        self.points.len()
    }

    /// Answers the waiting surfaces' shadow rays together and adds every term to
    /// `samples[slot]`, in order; nothing waits afterwards.
    pub fn settle<T: ShadingTracer + ?Sized>(&mut self, tracer: &T, samples: &mut [CameraSample]) {
        if self.points.is_empty() {
            self.terms.clear();
            return;
        }
        let scene = tracer.scene();
        let lights = scene.lights.len();
        self.queries.clear();
        self.owners.clear();
        for light in 0..lights {
            for (j, point) in self.points.iter().enumerate() {
                if let Some(q) = super::shadow_query(scene, point, light) {
                    self.queries.push(q);
                    self.owners.push(j * lights + light);
                }
            }
        }
        self.answers.clear();
        self.answers.resize(self.queries.len(), 0.0);
        tracer.visibilities(&self.queries, &mut self.answers);
        // the entries no query asked for are not read
        self.visibility.clear();
        self.visibility.resize(self.points.len() * lights, 1.0);
        for (&at, &v) in self.owners.iter().zip(&self.answers) {
            self.visibility[at] = v;
        }
        for term in &self.terms {
            match *term {
                Term::Add { slot, radiance } => samples[slot].radiance += radiance,
                Term::Shade {
                    slot,
                    weight,
                    point,
                } => {
                    let v = &self.visibility[point * lights..(point + 1) * lights];
                    let local = shade_with(tracer, &self.points[point], None, |light, _| v[light]);
                    samples[slot].radiance += weight * local;
                }
            }
        }
        self.terms.clear();
        self.points.clear();
    }
}

/// Whether a path follows a ray it spawns with `weight` after `bounces` bounces (of at most
/// `max_bounces`): the one rule for what the integrator traces and what a caller may trace
/// ahead for it ([`first_reflection`]).
#[inline]
fn follows(bounces: u32, max_bounces: u32, weight: Vec3) -> bool {
    bounces < max_bounces && weight.max_element() >= MIN_WEIGHT
}

/// Follows the camera ray `ray` and everything it spawns. `materials` is the scene's material
/// table as the shading tapes expect it.
pub fn trace_camera_ray<T: ShadingTracer + ?Sized>(
    tracer: &T,
    materials: &[MaterialVec],
    ray: Ray,
) -> CameraSample {
    let mut sample = CameraSample::NOTHING;
    trace_camera_ray_from(tracer, materials, ray, None, &mut sample, None);
    sample
}

/// A surface point the path meets, with what the integrator needs there.
#[derive(Debug, Clone, Copy)]
pub struct Surfaced {
    /// Position, normal on the side the ray arrives on, direction to the eye, material.
    pub point: SurfacePoint,
    /// Cosine between the normal and the reversed ray.
    pub cos_i: f32,
    /// Reflectance of the traced mirror reflection, [`mirror_reflectance`] (0 where the
    /// material reflects nothing).
    pub f_r: Vec3,
    /// Schlick reflectance of a dielectric's surface (0 where it is opaque).
    pub f_t: f32,
    /// The weight of local shading: α(1 − τ)·(the local share of [`mirror_reflectance`]), with
    /// α the coverage (glTF BLEND's alpha, 1 elsewhere); the remaining 1 − α continues
    /// straight through the surface.
    pub local_weight: f32,
}

/// The colour a traced mirror reflection is weighted by at incidence cosine `cos_i`, and the
/// weight left to local shading (before coverage and transparency).
///
/// Lambert + Phong: Schlick's Fresnel (1994) with R₀ = r, and local shading gets 1 − F_r (the
/// mirror takes its share of everything). Metallic-roughness: r·F, F = f₀ + (1 − f₀)(1 − cos)⁵
/// the BRDF's own Fresnel term, so a metal's reflections take its colour, as its highlights do,
/// and a dielectric reflects 4 % head-on; local shading keeps its full weight, because the
/// BRDF already leaves (1 − F) to the diffuse part and the lights' highlights are not in the
/// traced reflection; only the ambient specular share r·f₀ moves to the reflection (see
/// [`super::shade_with`]). A blend of the two models mixes both by the material's model weight.
/// Zero reflection where r = 0.
pub fn mirror_reflectance(m: &MaterialParams, cos_i: f32) -> (Vec3, f32) {
    let pbr_weight = m.pbr.clamp(0.0, 1.0);
    if m.reflectivity <= 0.0 {
        return (Vec3::ZERO, 1.0);
    }
    let grazing = (1.0 - cos_i).powi(5);
    let phong = m.reflectivity + (1.0 - m.reflectivity) * grazing;
    let f0 = MetallicRoughness::of(m).f0();
    let pbr = m.reflectivity * (f0 + (1.0 - f0) * grazing);
    let local = 1.0 - (1.0 - pbr_weight) * phong;
    (Vec3::splat(phong).lerp(pbr, pbr_weight), local)
}

/// What the integrator computes at a hit of `ray`.
pub fn surfaced<T: ShadingTracer + ?Sized>(
    tracer: &T,
    materials: &[MaterialVec],
    ray: &Ray,
    hit: &Hit,
) -> Surfaced {
    let material = tracer.material_at(hit, ray.at(hit.t), materials);
    surfaced_with(ray, hit, material)
}

/// [`surfaced`] with the material at the hit found by the caller
/// ([`ShadingTracer::material_at`] there, or [`ShadingTracer::blended_materials`] for many).
#[inline]
pub fn surfaced_with(ray: &Ray, hit: &Hit, material: MaterialParams) -> Surfaced {
    let p = ray.at(hit.t);
    let mut m = material;
    if m.opacity < 1.0 {
        // A partly covered surface is thin: what is not covered passes straight through, and
        // the covered part does not refract (its coverage replaces transmission).
        m.transparency = 0.0;
    }
    let d = ray.direction;
    // Shade the side the ray arrives on (rays can start inside a solid).
    let n = if hit.normal.dot(d) > 0.0 {
        -hit.normal
    } else {
        hit.normal
    };
    let cos_i = (-d.dot(n)).clamp(0.0, 1.0);
    let (f_r, local_share) = mirror_reflectance(&m, cos_i);
    let f_t = if m.transparency > 0.0 {
        schlick(cos_i, 1.0, m.ior)
    } else {
        0.0
    };
    Surfaced {
        point: SurfacePoint {
            position: p,
            normal: n,
            to_eye: -d,
            t: hit.t,
            material: m,
        },
        cos_i,
        f_r,
        f_t,
        local_weight: m.opacity.clamp(0.0, 1.0) * (1.0 - m.transparency) * local_share,
    }
}

/// A camera ray's first hit found ahead by the caller, and, where the caller also computed
/// it, the local shading's surface and the visibility of each light there (indexed by light;
/// only the entries [`super::shadow_query`] asks for are read).
///
/// It borrows what the caller holds: copying a hit and its surface (some 250 bytes) into the
/// path, field by field after they were written whole, cost a sixth of a frame in `memcpy`.
#[derive(Debug, Clone, Copy)]
pub struct Primary<'a> {
    /// The closest hit over [0, ∞), as `tracer.closest_hit` answers it.
    pub hit: Option<&'a Hit>,
    /// [`surfaced`] at the hit, with the lights' visibilities.
    pub shading: Option<(&'a Surfaced, &'a [f32])>,
    /// The ambient occlusion at the hit, where the caller found it ahead
    /// ([`super::ambient_occlusion`]'s value).
    pub occlusion: Option<f32>,
    /// The mirror reflection of the hit ([`first_reflection`]) and its closest hit over
    /// [0, ∞), where the caller traced it ahead with others; used only if the path sends
    /// exactly that ray.
    pub reflection: Option<(Ray, Option<&'a Hit>)>,
}

/// The weight a surface's traced mirror reflection carries (before the path's weight):
/// coverage·((1 − τ)·F_r + τ·F_t), the opaque part's mirror and a dielectric's reflection.
#[inline]
pub fn mirror_weight(surf: &Surfaced) -> Vec3 {
    let m = &surf.point.material;
    let coverage = m.opacity.clamp(0.0, 1.0);
    coverage * ((1.0 - m.transparency) * surf.f_r + m.transparency * surf.f_t)
}

/// The mirror reflection leaving a surface that a ray along `d` met, from just above it.
#[inline]
pub fn mirror_ray<T: ShadingTracer + ?Sized>(tracer: &T, surf: &Surfaced, d: Vec3) -> Ray {
    let (p, n) = (surf.point.position, surf.point.normal);
    let offset = surface_offset(tracer, surf.point.t, p);
    Ray::new(p + n * offset, reflect(d, n))
}

/// The mirror reflection a camera ray's path follows from its first hit (the camera ray
/// along `d` met `surf`), or `None` where it follows none: what a caller traces ahead for
/// [`Primary::reflection`].
pub fn first_reflection<T: ShadingTracer + ?Sized>(
    tracer: &T,
    surf: &Surfaced,
    d: Vec3,
) -> Option<Ray> {
    let max_bounces = tracer.scene().shading.max_bounces.min(MAX_BOUNCES);
    // the camera ray's weight is 1, so the reflection's is `mirror_weight`
    follows(0, max_bounces, mirror_weight(surf)).then(|| mirror_ray(tracer, surf, d))
}

/// [`trace_camera_ray`] when the caller has already found the camera ray's closest hit
/// (and perhaps its lights' visibilities): the CPU renderer traces a tile row's camera rays
/// and shadow rays together (see [`crate::trace::SceneTracer::closest_hits`] and
/// [`crate::trace::SceneTracer::visibilities`]). The answers are those of tracing the ray
/// alone. The sample is written to `slot` (the caller's place for it: returned by value, it
/// was copied over in wider words than it was written in before those stores could forward,
/// a stall on every pixel). With `defer`, the local shading of hits other than the prepared
/// first one, and every radiance term after it, go to the deferral instead
/// ([`DeferredShading`]): the sample written holds the sum before them.
pub fn trace_camera_ray_from<T: ShadingTracer + ?Sized>(
    tracer: &T,
    materials: &[MaterialVec],
    ray: Ray,
    mut first: Option<Primary>,
    slot: &mut CameraSample,
    mut defer: Option<Deferral>,
) {
    let scene = tracer.scene();
    let mut sample = CameraSample::NOTHING;
    // A camera ray found to miss sees the background and spawns nothing: what the loop below
    // gives it, without setting up a path (the sky is a large part of most frames).
    if first.as_ref().is_some_and(|f| f.hit.is_none()) {
        sample.radiance = scene.image.background;
        *slot = sample;
        return;
    }
    let max_bounces = scene.shading.max_bounces.min(MAX_BOUNCES);
    // Depth-first: each step pops one ray and pushes at most two, so the stack never holds
    // more than max_bounces + 1 entries (a fixed array of MAX_BOUNCES + 2 here, as on the GPU).
    let mut stack = PathStack::new();
    stack.push(PendingRay {
        ray,
        weight: Vec3::ONE,
        bounces: 0,
        inside: None,
    });
    let mut reflection = first.and_then(|f| f.reflection);
    let mut first_occlusion = first.and_then(|f| f.occlusion);
    let mut primary = true;
    // Once a term went to the deferral, the later ones follow it there, in order.
    let mut deferring = false;
    while let Some(item) = stack.pop() {
        let spawn = |stack: &mut PathStack, ray: Ray, weight: Vec3, inside| {
            if follows(item.bounces, max_bounces, weight) {
                stack.push(PendingRay {
                    ray,
                    weight,
                    bounces: item.bounces + 1,
                    inside,
                });
            }
        };
        if let Some((object, ior)) = item.inside {
            // Travelling inside a transparent object: find where it leaves.
            let Some((t, n)) = tracer.exit(object, &item.ray, f32::INFINITY) else {
                continue;
            };
            let p = item.ray.at(t);
            let d = item.ray.direction;
            let offset = surface_offset(tracer, t, p);
            let cos_i = d.dot(n).clamp(0.0, 1.0);
            let f = schlick(cos_i, ior, 1.0);
            if let Some(out) = refract(d, -n, ior) {
                spawn(
                    &mut stack,
                    Ray::new(p + n * offset, out),
                    item.weight * (1.0 - f),
                    None,
                );
            }
            spawn(
                &mut stack,
                Ray::new(p - n * offset, reflect(d, -n)),
                item.weight * f,
                Some((object, ior)),
            );
            continue;
        }
        let traced;
        let (hit, prepared) = match first.take() {
            Some(f) if primary => (f.hit, f.shading),
            // the ray traced ahead, if this is it (the same ray has the same closest hit)
            _ => match reflection {
                Some((ray, hit)) if ray == item.ray => {
                    reflection = None;
                    (hit, None)
                }
                _ => {
                    traced = tracer.closest_hit(&item.ray, 0.0, f32::INFINITY);
                    (traced.as_ref(), None)
                }
            },
        };
        if primary {
            sample.steps = hit.map_or(0, |h| h.steps);
        }
        let Some(hit) = hit else {
            add_radiance(
                &mut sample,
                &mut defer,
                deferring,
                item.weight * scene.image.background,
            );
            primary = false;
            continue;
        };
        let found;
        let (surf, visibility) = match prepared {
            Some((surf, v)) => (surf, Some(v)),
            None => {
                found = surfaced(tracer, materials, &item.ray, hit);
                (&found, None)
            }
        };
        let (p, n, m) = (surf.point.position, surf.point.normal, surf.point.material);
        let d = item.ray.direction;
        if primary {
            sample.depth = hit.t;
            sample.normal = n;
            sample.albedo = m.color;
            sample.gradient = hit.gradient;
            primary = false;
        }
        if hit.t == 0.0 && matches!(hit.surface, Surface::Sdf(_)) && m.transparency > 0.0 {
            // The ray starts inside a transparent solid (the eye in a glass dome): there is no
            // surface at its origin to refract at, so it travels inside the solid as a ray
            // refracted into it would, tinted as one (the GPU's render.wgsl alike). Its first
            // hit, the AOVs' surface, stays the solid at t = 0, as the tracer reports it.
            spawn(
                &mut stack,
                item.ray,
                item.weight * m.color,
                Some((hit.surface, m.ior)),
            );
            continue;
        }
        let (f_t, local_weight) = (surf.f_t, surf.local_weight);
        let coverage = m.opacity.clamp(0.0, 1.0);
        let offset = surface_offset(tracer, hit.t, p);
        if m.opacity < 1.0 {
            // A partly covered (glTF BLEND) surface: the uncovered fraction goes on straight
            // through, as if the surface were not there (see `Surfaced::local_weight`).
            spawn(
                &mut stack,
                Ray::new(p - n * offset, d),
                item.weight * (1.0 - m.opacity.max(0.0)),
                None,
            );
        }
        if local_weight > 0.0 {
            match (visibility, defer.as_mut()) {
                (Some(v), _) => {
                    let occlusion = first_occlusion.take();
                    let local = shade_with(tracer, &surf.point, occlusion, |light, _| v[light]);
                    add_radiance(
                        &mut sample,
                        &mut defer,
                        deferring,
                        item.weight * local_weight * local,
                    );
                }
                (None, Some(d)) => {
                    d.shading.terms.push(Term::Shade {
                        slot: d.slot,
                        weight: item.weight * local_weight,
                        point: d.shading.points.len(),
                    });
                    d.shading.points.push(surf.point);
                    deferring = true;
                }
                (None, None) => {
                    let local = shade(tracer, &surf.point);
                    add_radiance(
                        &mut sample,
                        &mut defer,
                        deferring,
                        item.weight * local_weight * local,
                    );
                }
            }
        }
        let reflect_weight = mirror_weight(surf);
        if reflect_weight.max_element() > 0.0 {
            spawn(
                &mut stack,
                mirror_ray(tracer, surf, d),
                item.weight * reflect_weight,
                None,
            );
        }
        let transmit_weight = coverage * m.transparency * (1.0 - f_t);
        if transmit_weight > 0.0
            && let Some(t) = refract(d, n, 1.0 / m.ior)
        {
            spawn(
                &mut stack,
                Ray::new(p - n * offset, t),
                item.weight * transmit_weight * m.color,
                Some((hit.surface, m.ior)),
            );
        }
    }
    *slot = sample;
}

/// Adds `radiance` to the path's sample, or to its deferral once the path is `deferring`.
#[inline]
fn add_radiance(
    sample: &mut CameraSample,
    defer: &mut Option<Deferral>,
    deferring: bool,
    radiance: Vec3,
) {
    match defer {
        Some(d) if deferring => d.shading.terms.push(Term::Add {
            slot: d.slot,
            radiance,
        }),
        _ => sample.radiance += radiance,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_metal_mirrors_in_its_own_colour_and_keeps_its_local_shading() {
        let gold = Vec3::new(1.0, 0.766, 0.336);
        let m = MaterialParams::metallic_roughness(gold, 1.0, 0.0, None);
        let (f_r, local) = mirror_reflectance(&m, 1.0);
        // head-on, a smooth metal mirrors f₀ = its base colour
        assert!((f_r - gold).abs().max_element() < 1e-6, "{f_r}");
        assert_eq!(local, 1.0);
        // at grazing incidence every colour goes to 1 (Schlick)
        let (grazing, _) = mirror_reflectance(&m, 0.0);
        assert!(
            (grazing - Vec3::ONE).abs().max_element() < 1e-6,
            "{grazing}"
        );
    }

    #[test]
    fn a_dielectric_mirrors_four_percent_head_on() {
        let m = MaterialParams::metallic_roughness(Vec3::new(0.1, 0.2, 0.6), 0.0, 0.0, Some(1.0));
        let (f_r, local) = mirror_reflectance(&m, 1.0);
        assert!(
            (f_r - Vec3::splat(0.04)).abs().max_element() < 1e-6,
            "{f_r}"
        );
        assert_eq!(local, 1.0);
        // a rough metal and a dielectric without reflectivity mirror nothing by default
        let rough = MaterialParams::metallic_roughness(Vec3::ONE, 1.0, 1.0, None);
        assert_eq!(mirror_reflectance(&rough, 1.0), (Vec3::ZERO, 1.0));
    }

    #[test]
    fn a_phong_mirror_takes_its_share_from_local_shading() {
        let m = MaterialParams {
            reflectivity: 0.5,
            ..MaterialParams::default_grey()
        };
        let (f_r, local) = mirror_reflectance(&m, 1.0);
        assert_eq!(f_r, Vec3::splat(0.5));
        assert_eq!(local, 0.5);
        // an even blend of the two models mixes both answers
        let pbr = MaterialParams::metallic_roughness(Vec3::ONE, 1.0, 0.0, Some(0.5));
        let (a, b) = (m.to_vec(), pbr.to_vec());
        let half = MaterialParams::from_vec(&std::array::from_fn(|i| 0.5 * (a[i] + b[i])));
        let (f_r, local) = mirror_reflectance(&half, 1.0);
        // blended: r = 0.5, colour 0.9, metallic 0.5, so f₀ = 0.04 + 0.5·(0.9 − 0.04) = 0.47
        let expected = 0.5 * 0.5 + 0.5 * (0.5 * 0.47);
        assert!(
            (f_r - Vec3::splat(expected)).abs().max_element() < 1e-5,
            "{f_r}"
        );
        assert!((local - 0.75).abs() < 1e-6, "{local}");
    }
}
