//! Render backends and what they share: options, the framebuffer and the sample sums it is
//! the mean of, sample positions and output.

pub mod cpu;
pub mod draw;
pub mod exr;
pub mod metrics;
pub mod output;
pub mod progressive;
pub mod report;
pub mod slice;
pub mod view;
pub mod write;

use crate::shade::integrator::CameraSample;
use glam::Vec3;

/// What to render, beyond the scene itself.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderOptions {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Samples per pixel.
    pub samples: u32,
    /// Worker threads (None: all cores).
    pub threads: Option<usize>,
    /// Show a progress bar on the terminal.
    pub progress: bool,
}

impl RenderOptions {
    /// One sample per pixel at `width`×`height` on all cores, without a progress bar: what the
    /// bench and the tests render.
    pub fn single_sample(width: u32, height: u32) -> Self {
        RenderOptions {
            width,
            height,
            samples: 1,
            threads: None,
            progress: false,
        }
    }
}

/// Side of the square tiles the image is cut into.
pub const TILE: u32 = 32;

/// A rendered image: linear radiance and, per pixel, the first hit's auxiliary values
/// (AOVs) that the debug views and EXR output use. Over a pixel's samples radiance, normal,
/// albedo, steps and gradient are averaged; depth is the nearest sample's (∞ if all missed).
#[derive(Debug, Clone, PartialEq)]
pub struct Framebuffer {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Row-major linear radiance.
    pub pixels: Vec<Vec3>,
    /// Distance to the first hit along the camera ray.
    pub depth: Vec<f32>,
    /// Surface normal at the first hit.
    pub normal: Vec<Vec3>,
    /// Albedo at the first hit.
    pub albedo: Vec<Vec3>,
    /// Sphere-tracing steps of the camera ray.
    pub steps: Vec<f32>,
    /// |∇f| at the first hit.
    pub gradient: Vec<f32>,
}

impl Framebuffer {
    /// An empty (black, all-miss) framebuffer.
    pub fn new(width: u32, height: u32) -> Self {
        let n = (width * height) as usize;
        Framebuffer {
            width,
            height,
            pixels: vec![Vec3::ZERO; n],
            depth: vec![f32::INFINITY; n],
            normal: vec![Vec3::ZERO; n],
            albedo: vec![Vec3::ZERO; n],
            steps: vec![0.0; n],
            gradient: vec![0.0; n],
        }
    }

    /// The radiance at (x, y).
    pub fn get(&self, x: u32, y: u32) -> Vec3 {
        self.pixels[(y * self.width + x) as usize]
    }

    /// Stores the pixel value combined from its samples (see the type's documentation), as
    /// [`progressive::SampleSums`] combines them.
    pub fn set(&mut self, x: u32, y: u32, samples: &[CameraSample]) {
        let mut sums = progressive::PixelSums::default();
        for sample in samples {
            sums.add(sample);
        }
        sums.write_mean(self, (y * self.width + x) as usize);
    }
}

/// One tile of the image: its corner and size.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Tile {
    /// Left column.
    pub x0: u32,
    /// Top row.
    pub y0: u32,
    /// Width.
    pub w: u32,
    /// Height.
    pub h: u32,
}

/// The image cut into square tiles of side `side` (the CPU renders in [`TILE`]s, the GPU in
/// larger ones), row by row; the last column and row are cut to the image.
pub fn tiles(width: u32, height: u32, side: u32) -> Vec<Tile> {
    let mut v = Vec::new();
    for y0 in (0..height).step_by(side as usize) {
        for x0 in (0..width).step_by(side as usize) {
            v.push(Tile {
                x0,
                y0,
                w: side.min(width - x0),
                h: side.min(height - y0),
            });
        }
    }
    v
}

/// Sub-pixel position of sample `s` of `n` in pixel (x, y): stratified on a grid of
/// ⌈√n⌉ columns and ⌈n/columns⌉ rows with a jitter inside each stratum drawn from a hash of
/// (pixel, sample), so every run, thread count and backend produces the same positions. A
/// single sample sits at the pixel centre.
pub fn sample_offset(x: u32, y: u32, s: u32, n: u32) -> (f32, f32) {
    if n <= 1 {
        return (0.5, 0.5);
    }
    let cols = (n as f32).sqrt().ceil() as u32;
    let rows = n.div_ceil(cols);
    let (cx, cy) = (s % cols, (s / cols) % rows);
    let h = hash3(x, y, s);
    let jx = (h & 0xffff) as f32 / 65536.0;
    let jy = (h >> 16) as f32 / 65536.0;
    (
        (cx as f32 + jx) / cols as f32,
        (cy as f32 + jy) / rows as f32,
    )
}

/// A 32-bit integer hash of three values (PCG-style output permutation; Jarzynski & Olano,
/// "Hash functions for GPU rendering", JCGT 2020, pcg3d reduced to one output).
pub fn hash3(x: u32, y: u32, z: u32) -> u32 {
    let mut v = [
        x.wrapping_mul(1664525).wrapping_add(1013904223),
        y.wrapping_mul(1664525).wrapping_add(1013904223),
        z.wrapping_mul(1664525).wrapping_add(1013904223),
    ];
    v[0] = v[0].wrapping_add(v[1].wrapping_mul(v[2]));
    v[1] = v[1].wrapping_add(v[2].wrapping_mul(v[0]));
    v[2] = v[2].wrapping_add(v[0].wrapping_mul(v[1]));
    v[0] ^= v[0] >> 16;
    v[1] ^= v[1] >> 16;
    v[2] ^= v[2] >> 16;
    v[0] = v[0].wrapping_add(v[1].wrapping_mul(v[2]));
    v[0]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_cover_the_image_once() {
        for (w, h, side) in [(128, 96, 64), (130, 7, 8), (1, 1, 64), (65, 64, 64)] {
            let mut covered = vec![0u32; (w * h) as usize];
            for t in tiles(w, h, side) {
                assert!(t.w >= 1 && t.h >= 1 && t.w <= side && t.h <= side);
                for y in t.y0..t.y0 + t.h {
                    for x in t.x0..t.x0 + t.w {
                        covered[(y * w + x) as usize] += 1;
                    }
                }
            }
            assert!(
                covered.iter().all(|&c| c == 1),
                "{w}×{h} in tiles of {side}"
            );
        }
    }
}
