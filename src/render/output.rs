//! Writing images: linear radiance → exposure → tone mapping → sRGB PNG.

use crate::scene::file::ToneMap;
use anyhow::Context;
use glam::Vec3;
use std::path::Path;

/// Exposure and tone-mapping operator: linear radiance to display-linear values in [0, 1].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToneMapping {
    /// Exposure in stops: radiance is multiplied by 2^exposure first.
    pub exposure: f32,
    /// The operator.
    pub operator: ToneMap,
}

impl ToneMapping {
    /// Display-linear value of a linear radiance.
    pub fn apply(&self, radiance: Vec3) -> Vec3 {
        let x = radiance.max(Vec3::ZERO) * self.exposure.exp2();
        match self.operator {
            ToneMap::Clamp => x.min(Vec3::ONE),
            // Reinhard, Stark, Shirley & Ferwerda, "Photographic tone reproduction", 2002:
            // x/(1 + x), per channel.
            ToneMap::Reinhard => x / (Vec3::ONE + x),
            // K. Narkowicz, "ACES filmic tone mapping curve", 2015:
            // (x(2.51x + 0.03))/(x(2.43x + 0.59) + 0.14), per channel.
            ToneMap::Aces => {
                let num = x * (2.51 * x + 0.03);
                let den = x * (2.43 * x + 0.59) + 0.14;
                (num / den).clamp(Vec3::ZERO, Vec3::ONE)
            }
        }
    }
}

/// The sRGB transfer function (IEC 61966-2-1) of a display-linear value clamped to [0, 1].
pub fn linear_to_srgb(v: f32) -> f32 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// 8-bit sRGB of a display-linear colour.
pub fn to_srgb8(c: Vec3) -> [u8; 3] {
    let q = |v: f32| (linear_to_srgb(v) * 255.0 + 0.5) as u8;
    [q(c.x), q(c.y), q(c.z)]
}

/// Writes a picture as PNG.
pub fn save_png(img: &image::RgbImage, path: &Path) -> anyhow::Result<()> {
    img.save_with_format(path, image::ImageFormat::Png)
        .with_context(|| format!("{}: cannot write PNG", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tone_maps_are_monotone_and_bounded() {
        for op in [ToneMap::Clamp, ToneMap::Reinhard, ToneMap::Aces] {
            let t = ToneMapping {
                exposure: 0.0,
                operator: op,
            };
            let mut last = -1.0;
            for i in 0..200 {
                let v = t.apply(Vec3::splat(i as f32 * 0.05)).x;
                assert!((0.0..=1.0).contains(&v));
                assert!(v >= last, "{op:?} decreases at {i}");
                last = v;
            }
        }
        let one_stop = ToneMapping {
            exposure: 1.0,
            operator: ToneMap::Clamp,
        };
        assert_eq!(one_stop.apply(Vec3::splat(0.25)), Vec3::splat(0.5));
        assert!(
            (ToneMapping {
                exposure: 0.0,
                operator: ToneMap::Reinhard
            }
            .apply(Vec3::ONE)
            .x - 0.5)
                .abs()
                < 1e-6
        );
    }

    #[test]
    fn srgb_curve_endpoints() {
        assert_eq!(to_srgb8(Vec3::ZERO), [0, 0, 0]);
        assert_eq!(to_srgb8(Vec3::ONE), [255, 255, 255]);
        assert_eq!(to_srgb8(Vec3::splat(0.214_041_14)), [128, 128, 128]);
    }
}
