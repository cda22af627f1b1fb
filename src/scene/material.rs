//! Materials as the shader sees them, and their packing into the tape's blended-material lanes.

use super::file::{MaterialDesc, PbrDesc};
use crate::sdf::tape::{MATERIAL_FLOATS, MaterialVec};
use glam::Vec3;

/// Shading parameters of a surface point (possibly a blend of several scene materials).
///
/// Two reflection models share the struct: Lambert + Phong (`color`, `diffuse`, `specular`,
/// `shininess`) and glTF 2.0's metallic-roughness model (`color` as the base colour,
/// `metallic`, `roughness`); `pbr` says how much of each (0 Phong, 1 metallic-roughness). A
/// smooth union of a Phong and a metallic-roughness material blends the two models' radiance
/// with the same weight as every other lane.
///
/// Lanes in a [`MaterialVec`]: 0–2 colour, 3 diffuse, 4–6 specular colour, 7 shininess,
/// 8 reflectivity, 9 transparency, 10 index of refraction, 11 pbr, 12 metallic, 13 roughness,
/// 14–16 emission, 17 occlusion, 18 opacity, 19 unused. Blending is linear in these lanes
/// (smooth unions mix them with the smooth-min weight h).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MaterialParams {
    /// Albedo (the base colour of the metallic-roughness model), linear RGB.
    pub color: Vec3,
    /// Diffuse weight (Phong).
    pub diffuse: f32,
    /// Phong specular colour.
    pub specular: Vec3,
    /// Phong exponent.
    pub shininess: f32,
    /// Mirror reflectance at normal incidence.
    pub reflectivity: f32,
    /// Transmitted fraction.
    pub transparency: f32,
    /// Index of refraction.
    pub ior: f32,
    /// Weight of the metallic-roughness model against Phong, in [0, 1].
    pub pbr: f32,
    /// Metalness of the metallic-roughness model, in [0, 1].
    pub metallic: f32,
    /// Perceptual roughness of the metallic-roughness model, in [0, 1] (GGX α = roughness²).
    pub roughness: f32,
    /// Emitted radiance, linear RGB (added whatever the lights).
    pub emissive: Vec3,
    /// Ambient-light occlusion baked into the material (glTF's occlusion texture): 1 leaves the
    /// ambient light as it is.
    pub occlusion: f32,
    /// Coverage α of a glTF `BLEND` surface: the fraction shaded here, the rest passing straight
    /// through (1 for every other surface).
    pub opacity: f32,
}

impl MaterialParams {
    /// The material objects get when none is named.
    pub fn default_grey() -> Self {
        MaterialParams::from(&MaterialDesc::default())
    }

    /// A material whose scalar components hold 1, 2, …, 19 in declaration order (vectors
    /// component by component): packed, it shows which lane each field lands in, which is how
    /// the GPU's reader of the lanes is generated.
    pub fn numbered() -> Self {
        MaterialParams {
            color: Vec3::new(1.0, 2.0, 3.0),
            diffuse: 4.0,
            specular: Vec3::new(5.0, 6.0, 7.0),
            shininess: 8.0,
            reflectivity: 9.0,
            transparency: 10.0,
            ior: 11.0,
            pbr: 12.0,
            metallic: 13.0,
            roughness: 14.0,
            emissive: Vec3::new(15.0, 16.0, 17.0),
            occlusion: 18.0,
            opacity: 19.0,
        }
    }

    /// Packs into tape lanes.
    pub fn to_vec(&self) -> MaterialVec {
        let mut v = [0.0; MATERIAL_FLOATS];
        v[0..3].copy_from_slice(&self.color.to_array());
        v[3] = self.diffuse;
        v[4..7].copy_from_slice(&self.specular.to_array());
        v[7] = self.shininess;
        v[8] = self.reflectivity;
        v[9] = self.transparency;
        v[10] = self.ior;
        v[11] = self.pbr;
        v[12] = self.metallic;
        v[13] = self.roughness;
        v[14..17].copy_from_slice(&self.emissive.to_array());
        v[17] = self.occlusion;
        v[18] = self.opacity;
        v
    }

    /// Unpacks tape lanes.
    pub fn from_vec(v: &MaterialVec) -> Self {
        MaterialParams {
            color: Vec3::new(v[0], v[1], v[2]),
            diffuse: v[3],
            specular: Vec3::new(v[4], v[5], v[6]),
            shininess: v[7],
            reflectivity: v[8],
            transparency: v[9],
            ior: v[10],
            pbr: v[11],
            metallic: v[12],
            roughness: v[13],
            emissive: Vec3::new(v[14], v[15], v[16]),
            occlusion: v[17],
            opacity: v[18],
        }
    }

    /// A metallic-roughness material (glTF 2.0's model). Factors outside their ranges are
    /// clamped (non-finite ones take glTF's defaults). The mirror reflectance the integrator
    /// follows is `reflectivity`, or, when `None`, metallic·(1 − roughness)²: a smooth metal
    /// mirrors the scene, a rough one or a dielectric only shows its highlights.
    pub fn metallic_roughness(
        base_color: Vec3,
        metallic: f32,
        roughness: f32,
        reflectivity: Option<f32>,
    ) -> Self {
        let clamp01 = |x: f32, fallback: f32| {
            if x.is_finite() {
                x.clamp(0.0, 1.0)
            } else {
                fallback
            }
        };
        let base = Vec3::new(
            clamp01(base_color.x, 1.0),
            clamp01(base_color.y, 1.0),
            clamp01(base_color.z, 1.0),
        );
        let metallic = clamp01(metallic, 1.0);
        let roughness = clamp01(roughness, 1.0);
        MaterialParams {
            color: base,
            // The Phong lanes stay those of a plain grey so that a blend with a Phong material
            // mixes sensible values; with pbr = 1 they are not read.
            diffuse: 1.0,
            specular: Vec3::ZERO,
            shininess: 32.0,
            reflectivity: reflectivity
                .map_or(metallic * (1.0 - roughness) * (1.0 - roughness), |r| {
                    clamp01(r, 0.0)
                }),
            transparency: 0.0,
            ior: 1.5,
            pbr: 1.0,
            metallic,
            roughness,
            emissive: Vec3::ZERO,
            occlusion: 1.0,
            opacity: 1.0,
        }
    }
}

impl From<&MaterialDesc> for MaterialParams {
    fn from(d: &MaterialDesc) -> Self {
        MaterialParams {
            color: d.color.0,
            diffuse: d.diffuse.0,
            specular: d.specular.0,
            shininess: d.shininess.0,
            reflectivity: d.reflectivity.0,
            transparency: d.transparency.0,
            ior: d.ior.0,
            pbr: 0.0,
            metallic: 0.0,
            roughness: 1.0,
            emissive: d.emissive.0,
            occlusion: 1.0,
            opacity: 1.0,
        }
    }
}

impl From<&PbrDesc> for MaterialParams {
    fn from(d: &PbrDesc) -> Self {
        MaterialParams {
            transparency: d.transparency.0,
            ior: d.ior.0,
            emissive: d.emissive.0,
            ..MaterialParams::metallic_roughness(
                d.base_color.0,
                d.metallic.0,
                d.roughness.0,
                d.reflectivity.map(|r| r.0),
            )
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_field_has_a_lane_of_its_own() {
        let m = MaterialParams::numbered();
        assert_eq!(MaterialParams::from_vec(&m.to_vec()), m);
        let mut lanes = m.to_vec().to_vec();
        lanes.retain(|&l| l != 0.0);
        lanes.sort_by(f32::total_cmp);
        lanes.dedup();
        assert_eq!(lanes.len(), 19, "two fields share a lane");
    }
}
