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

/// 8-bit sRGB of a display-linear value as the transfer function gives it:
/// linear_to_srgb(v)·255 + ½, rounded down.
fn srgb8_by_formula(v: f32) -> u8 {
    (linear_to_srgb(v) * 255.0 + 0.5) as u8
}

/// Where the 8-bit sRGB levels start: the smallest display-linear value of each level from 1
/// to 255 ([`srgb8_by_formula`] steps up there), found once by bisection over the f32s of
/// [0, 1], and the level at each of 4,096 even steps of [0, 1], where a search starts.
///
/// A level is then a table read and a comparison or two instead of a `powf` (the viewer
/// converted every preview that way, a twelfth of a core on its window thread beside the
/// render threads): the same levels, since the formula does not decrease (tested over every
/// 61st f32 of [0, 1] and around every threshold). No step of 1/4,096 spans more than one
/// level (the curve rises at most 12.92·255 levels per unit, at its linear foot).
struct Srgb8Levels {
    starts: [f32; 255],
    at_step: [u8; STEPS + 1],
}

/// The even steps of [0, 1] [`Srgb8Levels`] keeps the level of.
const STEPS: usize = 4096;

fn srgb8_levels() -> &'static Srgb8Levels {
    static LEVELS: std::sync::OnceLock<Srgb8Levels> = std::sync::OnceLock::new();
    LEVELS.get_or_init(|| {
        let starts: [f32; 255] = std::array::from_fn(|i| {
            let level = i as u8 + 1;
            // bit patterns of non-negative floats are ordered as the floats
            let (mut lo, mut hi) = (0u32, 1.0f32.to_bits());
            while lo < hi {
                let mid = lo + (hi - lo) / 2;
                if srgb8_by_formula(f32::from_bits(mid)) >= level {
                    hi = mid;
                } else {
                    lo = mid + 1;
                }
            }
            f32::from_bits(lo)
        });
        let at_step = std::array::from_fn(|i| {
            let v = i as f32 / STEPS as f32;
            starts.partition_point(|&t| t <= v) as u8
        });
        Srgb8Levels { starts, at_step }
    })
}

/// 8-bit sRGB of a display-linear value: [`srgb8_by_formula`]'s level, from [`Srgb8Levels`].
#[inline]
pub fn srgb8(v: f32) -> u8 {
    // NaN and values at or below 0 are level 0, as the formula's clamp makes them
    if v.is_nan() || v <= 0.0 {
        return 0;
    }
    let levels = srgb8_levels();
    let v = v.min(1.0);
    // v·4,096 is exact (a power of two), so the step's value is at most v
    let mut level = levels.at_step[(v * STEPS as f32) as usize];
    while level < 255 && levels.starts[level as usize] <= v {
        level += 1;
    }
    level
}

/// 8-bit sRGB of a display-linear colour.
pub fn to_srgb8(c: Vec3) -> [u8; 3] {
    [srgb8(c.x), srgb8(c.y), srgb8(c.z)]
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
    fn levels_by_thresholds_are_the_formula_s() {
        // every 61st f32 of [0, 1], then 64 on either side of each threshold
        let one = 1.0f32.to_bits();
        let mut bits = (0..=one).step_by(61).chain([one]).collect::<Vec<u32>>();
        for &t in &srgb8_levels().starts {
            let b = t.to_bits();
            bits.extend(b.saturating_sub(64)..=(b + 64).min(one));
        }
        for b in bits {
            let v = f32::from_bits(b);
            assert_eq!(srgb8(v), srgb8_by_formula(v), "at {v} ({b:#x})");
        }
        for v in [-1.0, -0.0, 1.5, f32::INFINITY, f32::NEG_INFINITY, f32::NAN] {
            assert_eq!(srgb8(v), srgb8_by_formula(v), "at {v}");
        }
        // a search takes a comparison or two: no step spans more than one level
        let steps = &srgb8_levels().at_step;
        assert!(steps.windows(2).all(|w| w[1] - w[0] <= 1));
    }

    #[test]
    fn srgb_curve_endpoints() {
        assert_eq!(to_srgb8(Vec3::ZERO), [0, 0, 0]);
        assert_eq!(to_srgb8(Vec3::ONE), [255, 255, 255]);
        assert_eq!(to_srgb8(Vec3::splat(0.214_041_14)), [128, 128, 128]);
    }
}
