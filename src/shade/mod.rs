//! Shading: the radiance leaving a surface point toward the eye, from materials and lights.
//!
//! The model (documented in `docs/scene-format.md`), in linear RGB:
//!
//! ```text
//! L = Σ_ambient albedo·kd·A + Σ_lights V·E·(albedo·kd·max(n·l, 0) + ks·max(r·v, 0)^s)
//! ```
//!
//! (light terms only where n·l > 0), with E = radiance/d² for a point light at distance d and E = radiance for a directional
//! light, V ∈ {0, 1} the hard-shadow visibility, r the mirror reflection of l about n
//! (Phong 1975) and v the direction to the eye.

pub mod material;

use crate::geom::Ray;
use crate::scene::Light;
use crate::trace::{SceneTracer, epsilon_at};
use glam::Vec3;
use material::MaterialParams;

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

/// Radiance from `sp` toward the eye.
pub fn shade(tracer: &SceneTracer, sp: &SurfacePoint) -> Vec3 {
    let scene = tracer.scene();
    let m = &sp.material;
    let n = sp.normal;
    let settings = &scene.tracer;
    // Shadow rays start a few ε above the surface: the tracer stopped within ε(t) of it, and
    // starting on the surface would report the surface itself as the occluder.
    let offset = 4.0 * epsilon_at(settings, sp.t);
    let origin = sp.position + n * offset;
    let mut out = Vec3::ZERO;
    for light in &scene.lights {
        let (l, dist, irradiance) = match *light {
            Light::Ambient { radiance } => {
                out += m.color * m.diffuse * radiance;
                continue;
            }
            Light::Point { position, radiance } => {
                let d = position - sp.position;
                let dist = d.length();
                if dist <= 0.0 {
                    continue;
                }
                (d / dist, dist, radiance / (dist * dist))
            }
            Light::Directional {
                direction,
                radiance,
            } => (-direction, f32::INFINITY, radiance),
        };
        let ndl = n.dot(l);
        if ndl <= 0.0 {
            continue;
        }
        if settings.shadows && tracer.occluded(&Ray::new(origin, l), 0.0, dist - offset) {
            continue;
        }
        let diffuse = m.color * m.diffuse * ndl;
        let r = (2.0 * ndl) * n - l;
        let spec = m.specular * r.dot(sp.to_eye).max(0.0).powf(m.shininess);
        out += irradiance * (diffuse + spec);
    }
    out
}
