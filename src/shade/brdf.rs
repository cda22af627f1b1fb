//! glTF 2.0's metallic-roughness BRDF (the specification's Appendix B): Trowbridge-Reitz (GGX)
//! microfacets with Smith's separable masking-shadowing and Schlick's Fresnel, and the
//! metal/dielectric mix.
//!
//! With α = roughness², h the half vector of l and v, and the cosines written n·x:
//!
//! ```text
//! D   = α² / (π ((n·h)²(α² − 1) + 1)²)                                  (Walter et al. 2007)
//! Vis = 1 / ((n·l + √(α² + (1 − α²)(n·l)²)) (n·v + √(α² + (1 − α²)(n·v)²)))   = G / (4 n·l n·v)
//! F   = f₀ + (1 − f₀)(1 − v·h)⁵                                         (Schlick 1994)
//! f₀  = mix(0.04, base, metallic),  c_diff = mix(base, 0, metallic)
//! f   = (1 − F) c_diff / π + F·D·Vis
//! ```
//!
//! The renderer's lights are scaled so that a white Lambert surface facing a light of
//! irradiance E shows E (the Phong model has no 1/π), so [`reflected`] returns π·f·(n·l): the
//! two models agree on a rough dielectric's diffuse part.

use crate::scene::material::MaterialParams;
use glam::Vec3;
use std::f32::consts::PI;

/// Reflectance at normal incidence of a dielectric of index 1.5, the specification's 0.04.
pub const DIELECTRIC_F0: f32 = 0.04;

/// The BRDF's inputs at a surface point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MetallicRoughness {
    /// Base colour, linear RGB.
    pub base_color: Vec3,
    /// Metalness in [0, 1].
    pub metallic: f32,
    /// Perceptual roughness in [0, 1].
    pub roughness: f32,
}

impl MetallicRoughness {
    /// The BRDF's inputs of a material's metallic-roughness lanes.
    pub fn of(m: &MaterialParams) -> Self {
        MetallicRoughness {
            base_color: m.color,
            metallic: m.metallic,
            roughness: m.roughness,
        }
    }

    /// Specular reflectance at normal incidence, f₀.
    pub fn f0(&self) -> Vec3 {
        Vec3::splat(DIELECTRIC_F0).lerp(self.base_color, self.metallic)
    }

    /// Diffuse colour c_diff (a metal has none).
    pub fn diffuse_color(&self) -> Vec3 {
        self.base_color * (1.0 - self.metallic)
    }

    /// The fraction of uniform ambient light reflected, as the renderer applies it: the
    /// BRDF's albedo at normal incidence for a smooth surface, (1 − f₀)·c_diff + f₀.
    pub fn ambient_albedo(&self) -> Vec3 {
        let f0 = self.f0();
        (Vec3::ONE - f0) * self.diffuse_color() + f0
    }

    /// π·f(l, v)·(n·l): the radiance toward `v` per unit of irradiance from `l` (all unit
    /// vectors, n·l > 0 and n·v > 0 assumed; zero otherwise).
    pub fn reflected(&self, n: Vec3, v: Vec3, l: Vec3) -> Vec3 {
        let n_l = n.dot(l);
        let n_v = n.dot(v);
        if n_l <= 0.0 || n_v <= 0.0 {
            return Vec3::ZERO;
        }
        let h = (l + v).normalize_or_zero();
        let n_h = n.dot(h).max(0.0);
        let v_h = v.dot(h).abs();
        // α below 10⁻³ makes D a spike narrower than f32 can sample; the floor changes nothing
        // visible (a highlight of a point light on a perfect mirror is a single point anyway).
        let alpha = (self.roughness * self.roughness).max(1e-3);
        let a2 = alpha * alpha;
        let d_denominator = n_h * n_h * (a2 - 1.0) + 1.0;
        let distribution = a2 / (PI * d_denominator * d_denominator);
        let smith = |c: f32| c + (a2 + (1.0 - a2) * c * c).sqrt();
        let visibility = 1.0 / (smith(n_l) * smith(n_v));
        let f0 = self.f0();
        let fresnel = f0 + (Vec3::ONE - f0) * (1.0 - v_h).powi(5);
        let diffuse = (Vec3::ONE - fresnel) * self.diffuse_color() / PI;
        let specular = fresnel * (distribution * visibility);
        PI * (diffuse + specular) * n_l
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(theta: f32, phi: f32) -> Vec3 {
        Vec3::new(
            theta.sin() * phi.cos(),
            theta.cos(),
            theta.sin() * phi.sin(),
        )
    }

    /// ∫ f(l, v) cos θ_l dω_l over the hemisphere, by sampling half vectors from D(h)(n·h)
    /// on a stratified grid (the lobe of a smooth surface is far too narrow for a uniform
    /// grid): l = reflect(−v, h) has density D(h)(n·h)/(4 v·h) (Walter et al. 2007, eq. 14).
    fn albedo(m: &MetallicRoughness, v: Vec3) -> Vec3 {
        let alpha = (m.roughness * m.roughness).max(1e-3);
        let a2 = alpha * alpha;
        let k = 400;
        let mut sum = Vec3::ZERO;
        for i in 0..k {
            for j in 0..k {
                let u1 = (i as f32 + 0.5) / k as f32;
                let u2 = (j as f32 + 0.5) / k as f32;
                let cos_h = ((1.0 - u1) / (1.0 + (a2 - 1.0) * u1)).sqrt();
                let h = dir(cos_h.acos(), 2.0 * PI * u2);
                let l = 2.0 * v.dot(h) * h - v;
                let n_h = h.y;
                let d = a2 / (PI * (n_h * n_h * (a2 - 1.0) + 1.0).powi(2));
                let pdf = d * n_h / (4.0 * v.dot(h).abs());
                if l.y > 0.0 && pdf > 0.0 {
                    sum += m.reflected(Vec3::Y, v, l) / PI / pdf;
                }
            }
        }
        sum / (k * k) as f32
    }

    #[test]
    fn the_distribution_is_normalised() {
        // ∫ D (n·h) dω_h = 1 over the hemisphere (Walter et al. 2007, eq. 4), for every α.
        for roughness in [0.2f32, 0.5, 0.9] {
            let a2 = (roughness * roughness).powi(2);
            let n = 20000;
            let mut sum = 0.0f64;
            for i in 0..n {
                let c = (i as f64 + 0.5) / n as f64;
                let d =
                    a2 as f64 / (std::f64::consts::PI * (c * c * (a2 as f64 - 1.0) + 1.0).powi(2));
                sum += d * c * 2.0 * std::f64::consts::PI / n as f64;
            }
            assert!((sum - 1.0).abs() < 1e-3, "roughness {roughness}: {sum}");
        }
    }

    #[test]
    fn a_white_furnace_loses_energy_never_gains_it() {
        // A white metal reflects at most what arrives, and a rough one loses a little to the
        // single-scattering model's missing inter-reflections.
        for roughness in [0.1f32, 0.5, 1.0] {
            let m = MetallicRoughness {
                base_color: Vec3::ONE,
                metallic: 1.0,
                roughness,
            };
            for theta in [0.0f32, 0.6, 1.2] {
                let a = albedo(&m, dir(theta, 0.3));
                assert!(a.x <= 1.01, "roughness {roughness}, θ {theta}: albedo {a}");
                if roughness <= 0.5 && theta < 1.0 {
                    assert!(a.x > 0.85, "roughness {roughness}, θ {theta}: albedo {a}");
                }
            }
        }
    }

    #[test]
    fn a_rough_dielectric_is_lambert_scaled_by_the_fresnel_complement() {
        let m = MetallicRoughness {
            base_color: Vec3::new(0.5, 0.2, 0.8),
            metallic: 0.0,
            roughness: 1.0,
        };
        // at normal incidence on both sides h = n, F = 0.04: diffuse (1 − 0.04)·c, plus a
        // specular lobe of D·Vis·0.04 with α = 1 (D = 1/π, Vis = 1/4)
        let r = m.reflected(Vec3::Y, Vec3::Y, Vec3::Y);
        let expected = 0.96 * m.base_color + Vec3::splat(PI * 0.04 / (4.0 * PI));
        assert!(
            (r - expected).abs().max_element() < 1e-5,
            "{r} vs {expected}"
        );
    }

    #[test]
    fn metals_take_their_base_colour_in_the_highlight() {
        let m = MetallicRoughness {
            base_color: Vec3::new(1.0, 0.7, 0.2),
            metallic: 1.0,
            roughness: 0.3,
        };
        let r = m.reflected(Vec3::Y, Vec3::Y, Vec3::Y);
        // F = f₀ = base at v·h = 1, and there is no diffuse part
        let ratio = r / r.x;
        assert!((ratio - m.base_color).abs().max_element() < 1e-5, "{r}");
    }

    #[test]
    fn below_the_horizon_nothing_is_reflected() {
        let m = MetallicRoughness {
            base_color: Vec3::ONE,
            metallic: 0.5,
            roughness: 0.5,
        };
        assert_eq!(m.reflected(Vec3::Y, Vec3::Y, -Vec3::Y), Vec3::ZERO);
        assert_eq!(m.reflected(Vec3::Y, -Vec3::Y, Vec3::Y), Vec3::ZERO);
    }
}
