//! Reflection, refraction and Schlick's Fresnel approximation.

use glam::Vec3;

/// Mirror reflection of direction d about the unit normal n.
pub fn reflect(d: Vec3, n: Vec3) -> Vec3 {
    d - 2.0 * d.dot(n) * n
}

/// Refraction of the unit direction d through a surface with unit normal n facing against d
/// (d·n < 0), with eta = n₁/n₂ (Snell's law in vector form). `None` on total internal
/// reflection.
pub fn refract(d: Vec3, n: Vec3, eta: f32) -> Option<Vec3> {
    let cos_i = -d.dot(n);
    let k = 1.0 - eta * eta * (1.0 - cos_i * cos_i);
    (k >= 0.0).then(|| eta * d + (eta * cos_i - k.sqrt()) * n)
}

/// Schlick's approximation of the Fresnel reflectance (C. Schlick, "An inexpensive BRDF model
/// for physically-based rendering", 1994): R(θ) = R₀ + (1 − R₀)(1 − cos θ)⁵ with
/// R₀ = ((n₁ − n₂)/(n₁ + n₂))². `cos_i` is the cosine of the incidence angle in medium n₁.
/// Going from a denser to a lighter medium the cosine of the transmitted angle is used (the
/// approximation is symmetric in the two angles), and beyond the critical angle it is 1: total
/// internal reflection.
pub fn schlick(cos_i: f32, n1: f32, n2: f32) -> f32 {
    let r0 = ((n1 - n2) / (n1 + n2)).powi(2);
    let cos = if n1 > n2 {
        let eta = n1 / n2;
        let sin2_t = eta * eta * (1.0 - cos_i * cos_i);
        if sin2_t >= 1.0 {
            return 1.0;
        }
        (1.0 - sin2_t).sqrt()
    } else {
        cos_i
    };
    r0 + (1.0 - r0) * (1.0 - cos.clamp(0.0, 1.0)).powi(5)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_incidence_reflectance_is_r0() {
        for (n1, n2) in [(1.0, 1.5), (1.5, 1.0), (1.0, 2.4), (1.33, 1.0)] {
            let r0 = ((n1 - n2) / (n1 + n2)) * ((n1 - n2) / (n1 + n2));
            assert!((schlick(1.0, n1, n2) - r0).abs() < 1e-7, "{n1} → {n2}");
        }
        // glass: 4%
        assert!((schlick(1.0, 1.0, 1.5) - 0.04).abs() < 1e-6);
    }

    #[test]
    fn total_internal_reflection_beyond_the_critical_angle() {
        let (n1, n2) = (1.5f32, 1.0f32);
        let critical = (n2 / n1).asin();
        for deg in 1..89 {
            let theta = (deg as f32).to_radians();
            let r = schlick(theta.cos(), n1, n2);
            let d = Vec3::new(theta.sin(), -theta.cos(), 0.0);
            let t = refract(d, Vec3::Y, n1 / n2);
            if theta > critical + 1e-3 {
                assert_eq!(r, 1.0, "{deg}°");
                assert!(t.is_none(), "{deg}° refracts beyond the critical angle");
            } else if theta < critical - 1e-3 {
                assert!(r < 1.0);
                assert!(t.is_some());
            }
        }
        // grazing incidence from outside reflects everything
        assert!((schlick(0.0, 1.0, 1.5) - 1.0).abs() < 1e-6);
    }

    #[test]
    fn refraction_obeys_snell() {
        let theta = 0.6f32;
        let d = Vec3::new(theta.sin(), -theta.cos(), 0.0);
        let t = refract(d, Vec3::Y, 1.0 / 1.5).unwrap();
        assert!((t.length() - 1.0).abs() < 1e-6);
        let sin_t = t.x;
        assert!((theta.sin() - 1.5 * sin_t).abs() < 1e-6);
        let r = reflect(d, Vec3::Y);
        assert!((r - Vec3::new(d.x, -d.y, 0.0)).length() < 1e-7);
    }
}
