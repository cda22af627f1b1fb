//! Materials as the shader sees them, and their packing into the tape's blended-material lanes.

use super::file::MaterialDesc;
use crate::sdf::tape::{MATERIAL_FLOATS, MaterialVec};
use glam::Vec3;

/// Shading parameters of a surface point (possibly a blend of several scene materials).
///
/// Lanes in a [`MaterialVec`]: 0–2 colour, 3 diffuse, 4–6 specular colour, 7 shininess,
/// 8 reflectivity, 9 transparency, 10 index of refraction, 11 unused. Blending is linear in
/// these lanes (smooth unions mix them with the smooth-min weight h).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MaterialParams {
    /// Albedo, linear RGB.
    pub color: Vec3,
    /// Diffuse weight.
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
}

impl MaterialParams {
    /// The material objects get when none is named.
    pub fn default_grey() -> Self {
        MaterialParams::from(&MaterialDesc::default())
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
        }
    }
}
