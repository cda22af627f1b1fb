//! Image metrics for comparing renderers: PSNR, SSIM, NVIDIA's ꟻLIP (with the `flip`
//! feature), per-pixel differences, and the pictures that show them (difference and ꟻLIP
//! heatmaps, a labelled sheet).

use super::draw;
use super::view::turbo;
use image::RgbImage;

/// Differences at or above this (on the 0..1 sRGB scale) saturate the difference heatmap.
pub const HEATMAP_SCALE: f32 = 0.25;

#[cfg(feature = "flip")]
/// How two pictures differ.
#[derive(Debug, Clone, serde::Serialize, PartialEq)]
pub struct Metrics {
    /// Name of the reference picture.
    pub reference: String,
    /// Name of the compared picture.
    pub other: String,
    /// Peak signal-to-noise ratio over the 8-bit sRGB channels, dB (None when identical).
    pub psnr_db: Option<f64>,
    /// Mean structural similarity on luma.
    pub ssim: f64,
    /// Mean of the LDR-ꟻLIP error map (0 = identical, 1 = the largest perceived difference).
    pub flip_mean: f64,
    /// Share of pixels with a channel differing by more than the threshold, percent.
    pub percent_over_threshold: f64,
    /// The threshold (sRGB, 0..1).
    pub threshold: f32,
    /// Largest channel difference (sRGB, 0..1).
    pub max_difference: f32,
}

#[cfg(feature = "flip")]
/// The metrics of `other` (named `other_name`) against `reference`, with the ꟻLIP error map
/// they were taken from.
pub fn measure(
    reference_name: &str,
    reference: &RgbImage,
    other_name: &str,
    other: &RgbImage,
    threshold: f32,
) -> (Metrics, FlipMap) {
    let diff = difference(reference, other);
    let over = diff.iter().filter(|&&d| d > threshold).count();
    let map = flip(reference, other);
    let metrics = Metrics {
        reference: reference_name.into(),
        other: other_name.into(),
        psnr_db: psnr(reference, other),
        ssim: ssim(reference, other),
        flip_mean: map.mean(),
        percent_over_threshold: 100.0 * over as f64 / diff.len().max(1) as f64,
        threshold,
        max_difference: diff.iter().copied().fold(0.0, f32::max),
    };
    (metrics, map)
}

#[cfg(feature = "flip")]
/// A ꟻLIP error map: one value in [0, 1] per pixel, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct FlipMap {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// The error per pixel.
    pub values: Vec<f32>,
}

#[cfg(feature = "flip")]
impl FlipMap {
    /// The mean error, the one figure the ꟻLIP authors recommend reporting.
    pub fn mean(&self) -> f64 {
        self.values.iter().map(|&v| v as f64).sum::<f64>() / self.values.len().max(1) as f64
    }

    /// The map in the magma colour map, as ꟻLIP's own tool shows it.
    pub fn picture(&self) -> RgbImage {
        let map = nv_flip::FlipImageFloat::with_data(self.width, self.height, &self.values);
        let rgb = map.apply_color_lut(&nv_flip::magma_lut());
        RgbImage::from_raw(self.width, self.height, rgb.to_vec())
            .expect("the colour map has the map's size")
    }
}

#[cfg(feature = "flip")]
/// LDR-ꟻLIP (Andersson, Nilsson, Akenine-Möller, Oskarsson, Åström & Fairchild, "ꟻLIP: A
/// Difference Evaluator for Alternating Images", HPG 2020) of `test` against `reference`, both
/// sRGB, at the paper's default of 67 pixels per degree (a 0.7 m viewing distance from a 24"
/// 4K monitor). NVIDIA's own implementation, through the `nv-flip` crate: the metric is a
/// pipeline of colour-space filters and feature detectors whose published test images only
/// its reference code is known to reproduce.
pub fn flip(reference: &RgbImage, test: &RgbImage) -> FlipMap {
    let (w, h) = reference.dimensions();
    let a = nv_flip::FlipImageRgb8::with_data(w, h, reference.as_raw());
    let b = nv_flip::FlipImageRgb8::with_data(w, h, test.as_raw());
    let map = nv_flip::flip(a, b, nv_flip::DEFAULT_PIXELS_PER_DEGREE);
    FlipMap {
        width: w,
        height: h,
        values: map.to_vec(),
    }
}

/// PSNR = 10·log10(255² / MSE) over every channel of every pixel; None when the images are
/// identical (MSE = 0).
pub fn psnr(a: &RgbImage, b: &RgbImage) -> Option<f64> {
    let (sum, n) = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .fold((0f64, 0usize), |(s, n), (&x, &y)| {
            let d = x as f64 - y as f64;
            (s + d * d, n + 1)
        });
    let mse = sum / n.max(1) as f64;
    (mse > 0.0).then(|| 10.0 * (255.0f64 * 255.0 / mse).log10())
}

/// Luma Y' = 0.2126 R' + 0.7152 G' + 0.0722 B' (Rec. 709 weights on the sRGB-encoded values),
/// in [0, 1].
fn luma(img: &RgbImage) -> Vec<f64> {
    img.pixels()
        .map(|p| {
            let [r, g, b] = p.0.map(|c| c as f64 / 255.0);
            0.2126 * r + 0.7152 * g + 0.0722 * b
        })
        .collect()
}

/// Mean SSIM on luma (Wang, Bovik, Sheikh & Simoncelli, "Image quality assessment: from error
/// visibility to structural similarity", IEEE TIP 2004): local means, variances and covariance
/// under an 11×11 Gaussian window with σ = 1.5, C₁ = (0.01·L)², C₂ = (0.03·L)² with L = 1,
/// averaged over the window positions that fit inside the image (the whole image as one
/// window when it is smaller than 11 pixels).
pub fn ssim(a: &RgbImage, b: &RgbImage) -> f64 {
    const RADIUS: usize = 5;
    const SIGMA: f64 = 1.5;
    let (w, h) = (a.width() as usize, a.height() as usize);
    let (x, y) = (luma(a), luma(b));
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let index = |mx: f64, my: f64, vx: f64, vy: f64, cxy: f64| {
        ((2.0 * mx * my + c1) * (2.0 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
    };
    let size = 2 * RADIUS + 1;
    if w < size || h < size {
        let n = (w * h).max(1) as f64;
        let mx = x.iter().sum::<f64>() / n;
        let my = y.iter().sum::<f64>() / n;
        let vx = x.iter().map(|v| (v - mx).powi(2)).sum::<f64>() / n;
        let vy = y.iter().map(|v| (v - my).powi(2)).sum::<f64>() / n;
        let cxy = x
            .iter()
            .zip(&y)
            .map(|(p, q)| (p - mx) * (q - my))
            .sum::<f64>()
            / n;
        return index(mx, my, vx, vy, cxy);
    }
    let kernel: Vec<f64> = {
        let k: Vec<f64> = (0..size)
            .map(|i| {
                let d = i as f64 - RADIUS as f64;
                (-d * d / (2.0 * SIGMA * SIGMA)).exp()
            })
            .collect();
        let s: f64 = k.iter().sum();
        k.into_iter().map(|v| v / s).collect()
    };
    // Separable filtering of the five fields, keeping only positions where the window fits.
    let filter = |f: &dyn Fn(usize) -> f64| -> Vec<f64> {
        let (ow, oh) = (w - 2 * RADIUS, h - 2 * RADIUS);
        let mut rows = vec![0.0; ow * h];
        for j in 0..h {
            for i in 0..ow {
                rows[j * ow + i] = (0..size).map(|k| kernel[k] * f(j * w + i + k)).sum();
            }
        }
        let mut out = vec![0.0; ow * oh];
        for j in 0..oh {
            for i in 0..ow {
                out[j * ow + i] = (0..size).map(|k| kernel[k] * rows[(j + k) * ow + i]).sum();
            }
        }
        out
    };
    let mx = filter(&|i| x[i]);
    let my = filter(&|i| y[i]);
    let sxx = filter(&|i| x[i] * x[i]);
    let syy = filter(&|i| y[i] * y[i]);
    let sxy = filter(&|i| x[i] * y[i]);
    let n = mx.len();
    (0..n)
        .map(|i| {
            let (a, b) = (mx[i], my[i]);
            index(a, b, sxx[i] - a * a, syy[i] - b * b, sxy[i] - a * b)
        })
        .sum::<f64>()
        / n as f64
}

/// Per pixel, the largest |difference| of the three sRGB channels, in [0, 1].
pub fn difference(a: &RgbImage, b: &RgbImage) -> Vec<f32> {
    a.pixels()
        .zip(b.pixels())
        .map(|(p, q)| {
            (0..3)
                .map(|c| (p.0[c] as f32 - q.0[c] as f32).abs() / 255.0)
                .fold(0.0, f32::max)
        })
        .collect()
}

/// The difference heatmap of two pictures (Turbo colour map over [0, HEATMAP_SCALE]) with a
/// numbered colour bar below it.
pub fn heatmap(a: &RgbImage, b: &RgbImage) -> RgbImage {
    let diff = difference(a, b);
    let (w, h) = a.dimensions();
    let bar_h = 3 * draw::LINE + 10;
    let width = w.max(220);
    let mut img = RgbImage::from_pixel(width, h + bar_h, image::Rgb([0, 0, 0]));
    for y in 0..h {
        for x in 0..w {
            let d = diff[(y * w + x) as usize];
            img.put_pixel(x, y, image::Rgb(draw::to_u8(turbo(d / HEATMAP_SCALE))));
        }
    }
    draw::colour_bar(
        &mut img,
        4,
        h + 3,
        width - 8,
        "max |sRGB diff| per pixel",
        0.0,
        HEATMAP_SCALE,
        4,
        turbo,
    );
    img
}

/// The pictures side by side, each with its label above, on one sheet.
pub fn sheet(panels: &[(String, &RgbImage)]) -> RgbImage {
    let gap = 6;
    let label_h = draw::LINE + 6;
    let w: u32 =
        panels.iter().map(|(_, i)| i.width()).sum::<u32>() + gap * (panels.len() as u32 + 1);
    let h = panels.iter().map(|(_, i)| i.height()).max().unwrap_or(0) + label_h + 2 * gap;
    let mut img = RgbImage::from_pixel(w, h, image::Rgb([32, 32, 32]));
    let mut x = gap;
    for (label, panel) in panels {
        draw::text(&mut img, x, gap, label, [240, 240, 240]);
        image::imageops::replace(&mut img, *panel, x as i64, (gap + label_h) as i64);
        x += panel.width() + gap;
    }
    img
}

/// A grey picture of constant value, for the tests.
#[cfg(test)]
fn flat(w: u32, h: u32, v: u8) -> RgbImage {
    RgbImage::from_pixel(w, h, image::Rgb([v, v, v]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn noisy(w: u32, h: u32, seed: u64, amplitude: f32) -> RgbImage {
        let mut rng = Rng::new(seed);
        RgbImage::from_fn(w, h, |x, y| {
            let base = 128.0 + 60.0 * ((x as f32 * 0.2).sin() + (y as f32 * 0.15).cos());
            let v = (base + amplitude * (rng.next_f32() - 0.5)).clamp(0.0, 255.0) as u8;
            image::Rgb([v, v, v])
        })
    }

    #[test]
    fn identical_images() {
        let a = noisy(64, 48, 1, 0.0);
        assert_eq!(psnr(&a, &a), None);
        assert!((ssim(&a, &a) - 1.0).abs() < 1e-12);
        assert!(difference(&a, &a).iter().all(|&d| d == 0.0));
    }

    /// A uniform offset of 16 levels: MSE = 256, PSNR = 10·log10(255²/256) = 24.048 dB.
    #[test]
    fn psnr_of_a_known_offset() {
        let p = psnr(&flat(20, 20, 100), &flat(20, 20, 116)).unwrap();
        assert!((p - 24.0484).abs() < 1e-3, "{p}");
    }

    /// SSIM falls as noise grows, and stays within [-1, 1].
    #[test]
    fn ssim_orders_noise() {
        let a = noisy(80, 60, 1, 0.0);
        let mild = ssim(&a, &noisy(80, 60, 2, 20.0));
        let strong = ssim(&a, &noisy(80, 60, 3, 120.0));
        assert!(
            mild < 1.0 && strong < mild && strong > -1.0,
            "{mild} {strong}"
        );
        // Tiny images use one window over the whole picture.
        assert!((ssim(&flat(5, 5, 9), &flat(5, 5, 9)) - 1.0).abs() < 1e-12);
    }

    #[cfg(feature = "flip")]
    /// ꟻLIP: zero for identical pictures, rising with the noise added, near its top for black
    /// against white, and a magma picture of the map's size.
    #[test]
    fn flip_orders_differences() {
        let a = noisy(64, 48, 1, 0.0);
        let same = flip(&a, &a);
        assert_eq!((same.width, same.height), (64, 48));
        assert!(same.values.iter().all(|&v| v == 0.0));
        let mild = flip(&a, &noisy(64, 48, 2, 20.0)).mean();
        let strong = flip(&a, &noisy(64, 48, 3, 120.0)).mean();
        assert!(
            0.0 < mild && mild < strong && strong < 1.0,
            "{mild} {strong}"
        );
        let extreme = flip(&flat(32, 32, 0), &flat(32, 32, 255));
        assert!(extreme.mean() > 0.9, "{}", extreme.mean());
        assert!(extreme.values.iter().all(|&v| (0.0..=1.0).contains(&v)));
        let picture = extreme.picture();
        assert_eq!(picture.dimensions(), (32, 32));
        // magma runs from near black (no error) to a pale yellow (the largest)
        let zero = same.picture().get_pixel(0, 0).0;
        assert!(zero.iter().all(|&c| c < 16), "{zero:?}");
        let (m, map) = measure("a", &a, "b", &noisy(64, 48, 2, 20.0), 0.05);
        assert_eq!(m.flip_mean, map.mean());
        assert_eq!(m.flip_mean, mild);
    }

    #[test]
    fn heatmap_and_sheet_sizes() {
        let a = flat(40, 30, 10);
        let b = flat(40, 30, 200);
        let map = heatmap(&a, &b);
        assert!(map.width() >= 40 && map.height() > 30);
        // a difference of 190/255 > HEATMAP_SCALE saturates to Turbo's top colour
        let top = draw::to_u8(turbo(1.0));
        assert_eq!(map.get_pixel(5, 5).0, top);
        let s = sheet(&[("a".into(), &a), ("b".into(), &b)]);
        assert_eq!(s.width(), 40 + 40 + 3 * 6);
    }
}
