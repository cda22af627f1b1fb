//! Shading: the radiance leaving a surface point toward the eye, from materials and lights.
//!
//! The local model (documented in `docs/scene-format.md`), in linear RGB, for a material that
//! is a fraction w (`pbr`) metallic-roughness and 1 − w Lambert + Phong:
//!
//! ```text
//! L_local = emission
//!         + Σ_ambient mix(albedo·kd, a_pbr, w)·occlusion·A·ao
//!         + Σ_lights V·E·[(1 − w)·(albedo·kd·max(n·l, 0) + ks·max(r·v, 0)^s) + w·π·f(l, v)·(n·l)]
//! ```
//!
//! (light terms only where n·l > 0), with E = radiance/d² for a point or spot light at
//! distance d (times the spot's cone falloff and the light's range window) and E = radiance
//! for a directional light, V ∈ [0, 1] the light's visibility (hard or soft shadow), ao ∈
//! [0, 1] the ambient occlusion, r the mirror reflection of l about n (Phong 1975), v the
//! direction to the eye, f glTF's metallic-roughness BRDF and a_pbr its albedo at normal
//! incidence ([`brdf`]). [`integrator`] adds reflection, refraction and the light passing
//! through partly covered (glTF `BLEND`) surfaces.

pub mod brdf;
pub mod integrator;
pub mod optics;

use crate::geom::Ray;
use crate::scene::material::MaterialParams;
use crate::scene::{
    AmbientOcclusion, Light, Scene, Shadow, TracerSettings, range_window, spot_falloff,
};
use crate::sdf::tape::MaterialVec;
use crate::trace::{Hit, SceneTracer, ShadowQuery, Surface, epsilon_at};
use brdf::MetallicRoughness;
use glam::Vec3;

/// The queries shading asks of a backend: closest hits (camera, reflected and refracted rays),
/// where a ray leaves the solid it travels in, the visibility of a light, the scene's distance
/// field (ambient occlusion) and the material at a hit. [`SceneTracer`] answers them all on the
/// CPU; `reference::shading` answers the ray queries with Embree, so the same shading code runs
/// on top of either backend's hits. Functions take the tracer generically, so the CPU path is
/// compiled exactly as before (no dynamic dispatch).
pub trait ShadingTracer {
    /// The scene being traced.
    fn scene(&self) -> &Scene;
    /// The closest hit in (tmin, tmax), with its normal.
    fn closest_hit(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<Hit>;
    /// Where a ray starting inside the solid of `surface` leaves it, with the outward normal.
    fn exit(&self, surface: Surface, ray: &Ray, tmax: f32) -> Option<(f32, Vec3)>;
    /// The fraction of light arriving along a shadow ray over (tmin, tmax).
    fn visibility(&self, ray: &Ray, tmin: f32, tmax: f32, shadow: Shadow) -> f32;
    /// The scene's distance field at p, clamped to `reach`.
    fn distance(&self, p: Vec3, reach: f32) -> f32;
    /// The material at a hit (`materials` is the scene's table as the tapes expect it).
    fn material_at(&self, hit: &Hit, p: Vec3, materials: &[MaterialVec]) -> MaterialParams;
    /// [`ShadingTracer::closest_hit`] of every ray over (tmin, tmax), into `out` (of the same
    /// length). A tracer may answer coherent rays together (the CPU's ray bundles), but the
    /// answers must be those of asking one ray at a time.
    fn closest_hits(&self, rays: &[Ray], tmin: f32, tmax: f32, out: &mut [Option<Hit>]) {
        for (ray, o) in rays.iter().zip(out) {
            *o = self.closest_hit(ray, tmin, tmax);
        }
    }
    /// [`ShadingTracer::visibility`] of every shadow query, into `out`; as with
    /// [`ShadingTracer::closest_hits`], the answers of asking one at a time.
    fn visibilities(&self, queries: &[ShadowQuery], out: &mut [f32]) {
        for (q, o) in queries.iter().zip(out) {
            *o = self.visibility(&q.ray, q.tmin, q.tmax, q.shadow);
        }
    }
    /// [`ShadingTracer::distance`] at every point, clamped to `reach`, into `out` (of the same
    /// length); as with [`ShadingTracer::closest_hits`], the answers of asking one at a time.
    fn distances(&self, points: &[Vec3], reach: f32, out: &mut [f32]) {
        for (p, o) in points.iter().zip(out) {
            *o = self.distance(*p, reach);
        }
    }
    /// The hits among `hits` (of `rays`) whose material a shading tape blends at the point,
    /// with that material ([`ShadingTracer::material_at`] at `rays[i].at(t)`, the same bits),
    /// in increasing `i`, into `out` (cleared first): a tracer may evaluate those together.
    /// None by default: every material is then found by `material_at`.
    fn blended_materials(
        &self,
        rays: &[Ray],
        hits: &[Option<Hit>],
        materials: &[MaterialVec],
        out: &mut Vec<(usize, MaterialParams)>,
    ) {
        let _ = (rays, hits, materials);
        out.clear();
    }
}

impl ShadingTracer for SceneTracer<'_> {
    fn scene(&self) -> &Scene {
        SceneTracer::scene(self)
    }
    fn closest_hit(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<Hit> {
        SceneTracer::closest_hit(self, ray, tmin, tmax)
    }
    fn exit(&self, surface: Surface, ray: &Ray, tmax: f32) -> Option<(f32, Vec3)> {
        SceneTracer::exit(self, surface, ray, tmax)
    }
    fn visibility(&self, ray: &Ray, tmin: f32, tmax: f32, shadow: Shadow) -> f32 {
        SceneTracer::visibility(self, ray, tmin, tmax, shadow)
    }
    fn distance(&self, p: Vec3, reach: f32) -> f32 {
        SceneTracer::distance(self, p, reach)
    }
    fn material_at(&self, hit: &Hit, p: Vec3, materials: &[MaterialVec]) -> MaterialParams {
        SceneTracer::material_at(self, hit, p, materials)
    }
    fn closest_hits(&self, rays: &[Ray], tmin: f32, tmax: f32, out: &mut [Option<Hit>]) {
        SceneTracer::closest_hits(self, rays, tmin, tmax, out)
    }
    fn visibilities(&self, queries: &[ShadowQuery], out: &mut [f32]) {
        SceneTracer::visibilities(self, queries, out)
    }
    fn blended_materials(
        &self,
        rays: &[Ray],
        hits: &[Option<Hit>],
        materials: &[MaterialVec],
        out: &mut Vec<(usize, MaterialParams)>,
    ) {
        SceneTracer::blended_materials(self, rays, hits, materials, out)
    }
    fn distances(&self, points: &[Vec3], reach: f32, out: &mut [f32]) {
        SceneTracer::distances(self, points, reach, out)
    }
}

/// Everything the shader needs to know about a surface point.
#[derive(Debug, Clone, Copy)]
pub struct SurfacePoint {
    /// Position.
    pub position: Vec3,
    /// Unit normal.
    pub normal: Vec3,
    /// Unit direction from the point toward the viewer.
    pub to_eye: Vec3,
    /// Ray distance at which it was found (sets the self-intersection offset).
    pub t: f32,
    /// Material there.
    pub material: MaterialParams,
}

/// The offset that moves secondary-ray origins off a surface found at ray distance t at
/// point p: the tracer stopped within ε(t) of an SDF surface, so a few ε clear it; and a
/// triangle hit is exact only to the f32 rounding of p's coordinates, so the offset also grows
/// with |p| (2⁻¹⁶ relative, well above f32's 2⁻²⁴) and scales with the scene.
pub fn surface_offset<T: ShadingTracer + ?Sized>(tracer: &T, t: f32, p: Vec3) -> f32 {
    offset_from_surface(&tracer.scene().tracer, t, p)
}

/// [`surface_offset`] from the tracer settings alone (what `reference::validate` uses to cast
/// shadow rays exactly as the renderer does).
#[inline]
pub fn offset_from_surface(settings: &TracerSettings, t: f32, p: Vec3) -> f32 {
    4.0 * epsilon_at(settings, t) + p.abs().max_element() * (1.0 / 65536.0)
}

/// Local (direct) radiance from `sp` toward the eye.
pub fn shade<T: ShadingTracer + ?Sized>(tracer: &T, sp: &SurfacePoint) -> Vec3 {
    shade_with(tracer, sp, None, |_, q| {
        tracer.visibility(&q.ray, q.tmin, q.tmax, q.shadow)
    })
}

/// The shadow ray [`shade`] casts from `sp` toward light `light`, if it casts one (the light
/// is not ambient, faces the surface, and shadows are on). Inlined: returned through memory,
/// the query was read back in wider words than it was written in, a stall on every lit pixel.
#[inline]
pub fn shadow_query(scene: &Scene, sp: &SurfacePoint, light: usize) -> Option<ShadowQuery> {
    if !scene.tracer.shadows {
        return None;
    }
    let (l, dist, _, shadow) = light_at(&scene.lights[light], sp.position)?;
    shadow_query_toward(scene, sp, l, dist, shadow)
}

/// [`shadow_query`] once the light's direction `l`, distance and shadow kind at `sp` are
/// known ([`light_at`]).
#[inline]
fn shadow_query_toward(
    scene: &Scene,
    sp: &SurfacePoint,
    l: Vec3,
    dist: f32,
    shadow: Shadow,
) -> Option<ShadowQuery> {
    if !scene.tracer.shadows || sp.normal.dot(l) <= 0.0 {
        return None;
    }
    let offset = offset_from_surface(&scene.tracer, sp.t, sp.position);
    Some(ShadowQuery {
        ray: Ray::new(sp.position + sp.normal * offset, l),
        tmin: 0.0,
        tmax: dist - offset,
        shadow,
    })
}

/// Direction to a light from p, its distance, the irradiance it brings (with a spot light's
/// cone and a light's range window applied) and its shadow kind; `None` for ambient lights, a
/// light at p, and points outside a spot light's cone or beyond a light's range.
// Always inlined: called, it returns its tuple through memory, which the caller then reads
// back with other widths than it was written with (a store-forwarding stall on every light
// of every shaded point: 2–3 % of a hybrid.ron or showcase frame).
#[inline(always)]
pub fn light_at(light: &Light, p: Vec3) -> Option<(Vec3, f32, Vec3, Shadow)> {
    match *light {
        Light::Ambient { .. } => None,
        Light::Point {
            position,
            radiance,
            range,
            shadow,
        } => {
            let d = position - p;
            let dist = d.length();
            let window = range_window(dist, range);
            (dist > 0.0 && window > 0.0)
                .then(|| (d / dist, dist, radiance * (window / (dist * dist)), shadow))
        }
        Light::Spot {
            position,
            direction,
            radiance,
            cos_inner,
            cos_outer,
            range,
            shadow,
        } => {
            let d = position - p;
            let dist = d.length();
            if dist <= 0.0 {
                return None;
            }
            let l = d / dist;
            let falloff =
                spot_falloff(-l.dot(direction), cos_inner, cos_outer) * range_window(dist, range);
            (falloff > 0.0).then(|| (l, dist, radiance * (falloff / (dist * dist)), shadow))
        }
        Light::Directional {
            direction,
            radiance,
            shadow,
        } => Some((-direction, f32::INFINITY, radiance, shadow)),
    }
}

/// [`shade`] with the lights' visibilities from `visibility(light, query)`, called for the
/// queries [`shadow_query`] gives (so a caller may have answered them ahead, in packets), and
/// the ambient occlusion at the point where the caller found it ahead (else it is found here,
/// if the scene asks for it).
pub fn shade_with<T: ShadingTracer + ?Sized>(
    tracer: &T,
    sp: &SurfacePoint,
    occlusion: Option<f32>,
    mut visibility: impl FnMut(usize, &ShadowQuery) -> f32,
) -> Vec3 {
    let scene = tracer.scene();
    let m = &sp.material;
    let n = sp.normal;
    let pbr = m.pbr.clamp(0.0, 1.0);
    let brdf = MetallicRoughness::of(m);
    // The ambient light each model reflects: Lambert's albedo·kd, or the metallic-roughness
    // albedo at normal incidence (see `brdf`) less the specular share r·f₀ that the traced
    // mirror reflection brings instead (see `integrator::mirror_reflectance`); the material's
    // own occlusion darkens both.
    let pbr_ambient = brdf.ambient_albedo() - m.reflectivity.clamp(0.0, 1.0) * brdf.f0();
    let ambient_reflectance = (m.color * m.diffuse).lerp(pbr_ambient, pbr) * m.occlusion;
    let mut out = m.emissive;
    for (i, light) in scene.lights.iter().enumerate() {
        if let Light::Ambient { radiance } = *light {
            let ao = match (scene.shading.ambient_occlusion, occlusion) {
                (None, _) => 1.0,
                (Some(_), Some(found)) => found,
                (Some(a), None) => ambient_occlusion(tracer, sp.position, n, &a),
            };
            out += ambient_reflectance * radiance * ao;
            continue;
        }
        let Some((l, dist, irradiance, shadow)) = light_at(light, sp.position) else {
            continue;
        };
        let ndl = n.dot(l);
        if ndl <= 0.0 {
            continue;
        }
        let visibility = match shadow_query_toward(scene, sp, l, dist, shadow) {
            Some(q) => visibility(i, &q),
            None => 1.0,
        };
        if visibility <= 0.0 {
            continue;
        }
        let mut reflected = Vec3::ZERO;
        if pbr < 1.0 {
            let diffuse = m.color * m.diffuse * ndl;
            // A material without a highlight (the default) skips its power, 3–5 % of a
            // hybrid.ron frame: the term it would add is exactly zero, (r·v)ⁿ being finite.
            let spec = if m.specular == Vec3::ZERO {
                Vec3::ZERO
            } else {
                let r = (2.0 * ndl) * n - l;
                m.specular * r.dot(sp.to_eye).max(0.0).powf(m.shininess)
            };
            reflected += (1.0 - pbr) * (diffuse + spec);
        }
        if pbr > 0.0 {
            reflected += pbr * brdf.reflected(n, sp.to_eye, l);
        }
        out += visibility * irradiance * reflected;
    }
    out
}

/// Ambient occlusion from the distance field: sample d at p + n·i·δ for i = 1..steps; an
/// unoccluded point has d = i·δ there, and each shortfall darkens by 2⁻ⁱ (nearer samples weigh
/// more). ao = clamp(1 − strength·Σ 2⁻ⁱ (i·δ − d)/δ, 0, 1) (Evans 2006; the CS171 report's
/// form, made scale-free by the division by δ).
pub fn ambient_occlusion<T: ShadingTracer + ?Sized>(
    tracer: &T,
    p: Vec3,
    n: Vec3,
    ao: &AmbientOcclusion,
) -> f32 {
    let reach = occlusion_reach(ao);
    occlusion_from(ao, |i| {
        tracer.distance(occlusion_sample(p, n, ao, i), reach)
    })
}

/// How far [`ambient_occlusion`]'s distances look: its farthest sample's height.
#[inline]
pub fn occlusion_reach(ao: &AmbientOcclusion) -> f32 {
    ao.step * ao.steps as f32
}

/// Sample i (1..=steps) of [`ambient_occlusion`] above p along n.
#[inline]
pub fn occlusion_sample(p: Vec3, n: Vec3, ao: &AmbientOcclusion, i: u32) -> Vec3 {
    p + n * (ao.step * i as f32)
}

/// [`ambient_occlusion`] from the distance at each sample, `distance(i)` for i = 1..=steps in
/// order (the renderer finds a band's distances together).
pub fn occlusion_from(ao: &AmbientOcclusion, mut distance: impl FnMut(u32) -> f32) -> f32 {
    let mut occlusion = 0.0;
    let mut weight = 0.5;
    for i in 1..=ao.steps {
        let h = ao.step * i as f32;
        let d = distance(i);
        occlusion += weight * (h - d).max(0.0);
        weight *= 0.5;
    }
    (1.0 - ao.strength * occlusion / ao.step).clamp(0.0, 1.0)
}
