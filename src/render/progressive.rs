//! Progressive rendering's accumulator: per pixel the running sums of the samples so far, whose
//! mean is the framebuffer — the one place a pixel's samples are combined.

use super::{Framebuffer, Tile};
use crate::shade::integrator::CameraSample;
use glam::Vec3;

/// One pixel's samples so far: the sums of radiance, normal, albedo, steps and gradient, the
/// nearest depth and how many samples were added. Sums start at zero and grow in the order the
/// samples are added, so samples added in sample order give the same bits however they were
/// grouped (all of a pixel at once, or one pass over the image at a time).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelSums {
    /// Sum of linear radiance.
    pub radiance: Vec3,
    /// Nearest first-hit distance (∞ while every sample missed).
    pub depth: f32,
    /// Sum of first-hit normals.
    pub normal: Vec3,
    /// Sum of first-hit albedos.
    pub albedo: Vec3,
    /// Sum of the camera rays' sphere-tracing steps.
    pub steps: f32,
    /// Sum of |∇f| at the first hits.
    pub gradient: f32,
    /// Samples added.
    pub count: u32,
}

impl Default for PixelSums {
    fn default() -> Self {
        PixelSums {
            radiance: Vec3::ZERO,
            depth: f32::INFINITY,
            normal: Vec3::ZERO,
            albedo: Vec3::ZERO,
            steps: 0.0,
            gradient: 0.0,
            count: 0,
        }
    }
}

impl PixelSums {
    /// Adds one sample.
    pub fn add(&mut self, sample: &CameraSample) {
        self.radiance += sample.radiance;
        self.depth = self.depth.min(sample.depth);
        self.normal += sample.normal;
        self.albedo += sample.albedo;
        self.steps += sample.steps as f32;
        self.gradient += sample.gradient;
        self.count += 1;
    }

    /// The pixel's value: the sums divided by the count (by 1 when no sample was added,
    /// leaving black and all-miss), the nearest depth as it is.
    fn mean(&self) -> PixelMean {
        let n = self.count.max(1) as f32;
        PixelMean {
            radiance: self.radiance / n,
            depth: self.depth,
            normal: self.normal / n,
            albedo: self.albedo / n,
            steps: self.steps / n,
            gradient: self.gradient / n,
        }
    }

    /// Writes the mean ([`Self::mean`]) into pixel `i` of `fb`.
    pub(super) fn write_mean(&self, fb: &mut Framebuffer, i: usize) {
        fb.rows_mut().put(i, self.mean());
    }
}

/// Rows of a [`Framebuffer`]: each of its arrays' part from row `first_row` on, for a job
/// that writes those rows while others write the rest.
pub struct FramebufferRows<'a> {
    width: u32,
    first_row: u32,
    radiance: &'a mut [Vec3],
    depth: &'a mut [f32],
    normal: &'a mut [Vec3],
    albedo: &'a mut [Vec3],
    steps: &'a mut [f32],
    gradient: &'a mut [f32],
}

impl FramebufferRows<'_> {
    /// Writes the pixels of `tile` (within these rows) from their one sample each, row by
    /// row in `samples`: what [`SampleSums::mean`] gives after adding that sample to new
    /// sums, bit for bit (the sample is added to zero sums and divided by one, as there).
    pub fn write_single_samples(&mut self, tile: Tile, samples: &[CameraSample]) {
        self.write_tile(tile, samples, PixelMean::of_one);
    }

    /// Writes the pixels of `tile` (within these rows) from their sums, row by row in
    /// `sums`: the means [`SampleSums::mean`] gives for those sums, bit for bit.
    pub fn write_tile_means(&mut self, tile: Tile, sums: &[PixelSums]) {
        self.write_tile(tile, sums, PixelSums::mean);
    }

    /// Writes the pixels of `tile` (within these rows) from one value each, row by row in
    /// `values`, made into the pixel by `mean`.
    fn write_tile<V>(&mut self, tile: Tile, values: &[V], mean: impl Fn(&V) -> PixelMean) {
        assert_eq!(
            values.len(),
            (tile.w * tile.h) as usize,
            "one value a pixel"
        );
        for (j, row) in values.chunks_exact(tile.w as usize).enumerate() {
            let start = ((tile.y0 - self.first_row + j as u32) * self.width + tile.x0) as usize;
            for (k, value) in row.iter().enumerate() {
                self.put(start + k, mean(value));
            }
        }
    }

    /// Stores pixel `i` of these rows.
    #[inline]
    fn put(&mut self, i: usize, m: PixelMean) {
        self.radiance[i] = m.radiance;
        self.depth[i] = m.depth;
        self.normal[i] = m.normal;
        self.albedo[i] = m.albedo;
        self.steps[i] = m.steps;
        self.gradient[i] = m.gradient;
    }
}

impl Framebuffer {
    /// A framebuffer of zeros (the depth too), allocated zeroed: its pages are first touched
    /// by whoever writes its pixels (see [`SampleSums::new`]).
    pub fn zeroed(width: u32, height: u32) -> Self {
        use bytemuck::zeroed_vec;
        let n = width as usize * height as usize;
        Framebuffer {
            width,
            height,
            pixels: zeroed_vec(n),
            depth: zeroed_vec(n),
            normal: zeroed_vec(n),
            albedo: zeroed_vec(n),
            steps: zeroed_vec(n),
            gradient: zeroed_vec(n),
        }
    }

    /// The whole framebuffer as one band of rows.
    fn rows_mut(&mut self) -> FramebufferRows<'_> {
        FramebufferRows {
            width: self.width,
            first_row: 0,
            radiance: &mut self.pixels,
            depth: &mut self.depth,
            normal: &mut self.normal,
            albedo: &mut self.albedo,
            steps: &mut self.steps,
            gradient: &mut self.gradient,
        }
    }

    /// The framebuffer cut into bands of `rows` rows, top to bottom.
    pub fn bands_mut(&mut self, rows: u32) -> Vec<FramebufferRows<'_>> {
        let width = self.width;
        // (an image without pixels has no bands)
        let n = (width * rows).max(1) as usize;
        self.pixels
            .chunks_mut(n)
            .zip(self.depth.chunks_mut(n))
            .zip(self.normal.chunks_mut(n))
            .zip(self.albedo.chunks_mut(n))
            .zip(self.steps.chunks_mut(n))
            .zip(self.gradient.chunks_mut(n))
            .enumerate()
            .map(
                |(band, (((((radiance, depth), normal), albedo), steps), gradient))| {
                    FramebufferRows {
                        width,
                        first_row: band as u32 * rows,
                        radiance,
                        depth,
                        normal,
                        albedo,
                        steps,
                        gradient,
                    }
                },
            )
            .collect()
    }
}

/// One pixel of a [`Framebuffer`], as [`PixelSums::mean`] gives it.
struct PixelMean {
    radiance: Vec3,
    depth: f32,
    normal: Vec3,
    albedo: Vec3,
    steps: f32,
    gradient: f32,
}

impl PixelMean {
    /// The mean of one sample: what [`PixelSums::mean`] gives after adding it to new sums,
    /// bit for bit, without the eleven divisions by one (which change no bit: x/1 = x, and
    /// the sums' 0 + x is kept, turning −0 into +0 as they do). They were a tenth of a
    /// one-sample frame of misses.
    #[inline]
    fn of_one(sample: &CameraSample) -> PixelMean {
        PixelMean {
            radiance: Vec3::ZERO + sample.radiance,
            depth: f32::INFINITY.min(sample.depth),
            normal: Vec3::ZERO + sample.normal,
            albedo: Vec3::ZERO + sample.albedo,
            steps: 0.0 + sample.steps as f32,
            gradient: 0.0 + sample.gradient,
        }
    }
}

/// Pixels per job, about, of the parallel loops over a whole image (whole rows: a 1024² image
/// is 64 jobs).
const PIXELS_PER_JOB: usize = 1 << 14;

/// Adds one sample to every pixel of `tile` in `rows`, the image's rows of `width` pixels
/// from row `first_row` on; `samples` holds them row by row.
fn add_to_rows(
    rows: &mut [PixelSums],
    width: u32,
    first_row: u32,
    tile: Tile,
    samples: &[CameraSample],
) {
    assert_eq!(
        samples.len(),
        (tile.w * tile.h) as usize,
        "one sample a pixel"
    );
    for (j, row) in samples.chunks_exact(tile.w as usize).enumerate() {
        let start = ((tile.y0 - first_row + j as u32) * width + tile.x0) as usize;
        for (sums, sample) in rows[start..start + row.len()].iter_mut().zip(row) {
            sums.add(sample);
        }
    }
}

/// Rows of a [`SampleSums`]: its pixels from row `first_row` on, for a job that adds tiles
/// to those rows while others add to the rest ([`SampleSums::bands_mut`]).
pub struct SumsRows<'a> {
    width: u32,
    first_row: u32,
    pixels: &'a mut [PixelSums],
}

impl SumsRows<'_> {
    /// Adds one sample to every pixel of `tile` (within these rows); `samples` holds them row
    /// by row.
    pub fn add_tile(&mut self, tile: Tile, samples: &[CameraSample]) {
        add_to_rows(self.pixels, self.width, self.first_row, tile, samples);
    }
}

/// The running [`PixelSums`] of every pixel of a `width`×`height` image, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct SampleSums {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Row-major sums.
    pub pixels: Vec<PixelSums>,
}

impl SampleSums {
    /// No samples yet. The sums are written in parallel: a new image's memory is new to the
    /// process, and each page of it costs the kernel a fault and a zeroing on first touch
    /// (on one thread, with the means' framebuffer, a sixth of a one-sample 1024² frame).
    pub fn new(width: u32, height: u32) -> Self {
        use rayon::prelude::*;
        let mut pixels = Vec::new();
        (0..width as usize * height as usize)
            .into_par_iter()
            .with_min_len(PIXELS_PER_JOB)
            .map(|_| PixelSums::default())
            .collect_into_vec(&mut pixels);
        SampleSums {
            width,
            height,
            pixels,
        }
    }

    /// Back to no samples, in the memory these sums already hold (see [`Self::new`]).
    pub fn clear(&mut self) {
        use rayon::prelude::*;
        self.pixels
            .par_chunks_mut(PIXELS_PER_JOB)
            .for_each(|chunk| chunk.fill(PixelSums::default()));
    }

    /// Adds a sample to pixel (x, y).
    pub fn add(&mut self, x: u32, y: u32, sample: &CameraSample) {
        self.pixels[(y * self.width + x) as usize].add(sample);
    }

    /// Adds one sample to every pixel of `tile`; `samples` holds them row by row.
    pub fn add_tile(&mut self, tile: Tile, samples: &[CameraSample]) {
        add_to_rows(&mut self.pixels, self.width, 0, tile, samples);
    }

    /// The sums cut into bands of `side` rows, top to bottom, for jobs that each add the tiles
    /// of one band (cut by [`super::tiles`] with the same side): the tiles of a band write
    /// only its rows, so a pass adds each tile as soon as it is rendered, on the thread that
    /// rendered it. (Holding a whole pass's samples until it ended cost a 1280×720 pass 44 MB
    /// of memory new to the process, and its page faults a tenth of the pass's time; adding
    /// them afterwards on one thread while the others waited was a thirtieth of a hybrid.ron
    /// frame on two cores.)
    pub fn bands_mut(&mut self, side: u32) -> Vec<SumsRows<'_>> {
        let width = self.width;
        // (an image without pixels has no bands)
        let n = (width * side).max(1) as usize;
        self.pixels
            .chunks_mut(n)
            .enumerate()
            .map(|(band, pixels)| SumsRows {
                width,
                first_row: band as u32 * side,
                pixels,
            })
            .collect()
    }

    /// Adds a pass: one sample for every pixel of the image, row by row.
    pub fn add_pass(&mut self, samples: &[CameraSample]) {
        let whole = Tile {
            x0: 0,
            y0: 0,
            w: self.width,
            h: self.height,
        };
        self.add_tile(whole, samples);
    }

    /// The image of the samples so far: per pixel the means and the nearest depth (see
    /// [`Framebuffer`]).
    ///
    /// Computed in parallel, into memory allocated zeroed and first touched by the loop that
    /// writes the means (see [`Self::new`]).
    pub fn mean(&self) -> Framebuffer {
        use rayon::prelude::*;
        let mut fb = Framebuffer::zeroed(self.width, self.height);
        let rows = (PIXELS_PER_JOB as u32 / self.width.max(1)).max(1);
        fb.bands_mut(rows)
            .into_par_iter()
            .zip(self.pixels.par_chunks((rows * self.width).max(1) as usize))
            .for_each(|(mut band, sums)| {
                for (i, s) in sums.iter().enumerate() {
                    band.put(i, s.mean());
                }
            });
        fb
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::hash3;

    /// A varied sample: hashed values with misses, negative zeros and large and tiny
    /// magnitudes, so that summation order and rounding show.
    fn sample(pixel: u32, s: u32) -> CameraSample {
        let f = |k: u32| {
            let h = hash3(pixel, s, k);
            (h % 20000) as f32 / 997.0 - 10.0
        };
        let miss = hash3(pixel, s, 99).is_multiple_of(4);
        CameraSample {
            radiance: Vec3::new(f(0) * 1e3, f(1), f(2) * 1e-4),
            depth: if miss { f32::INFINITY } else { f(3).abs() },
            normal: if miss {
                Vec3::ZERO
            } else {
                Vec3::new(f(4), -0.0, f(5))
            },
            albedo: Vec3::new(f(6).abs(), f(7).abs(), 0.1),
            steps: hash3(pixel, s, 8) % 300,
            gradient: f(9).abs(),
        }
    }

    /// The per-sample average written out: sums from zero in sample order, divided by the count.
    fn average(samples: &[CameraSample]) -> [u32; 12] {
        let n = samples.len() as f32;
        let sum3 =
            |f: fn(&CameraSample) -> Vec3| samples.iter().map(f).fold(Vec3::ZERO, |a, b| a + b) / n;
        let sum1 = |f: fn(&CameraSample) -> f32| samples.iter().map(f).fold(0.0, |a, b| a + b) / n;
        let depth = samples
            .iter()
            .map(|s| s.depth)
            .fold(f32::INFINITY, f32::min);
        let r = sum3(|s| s.radiance);
        let nn = sum3(|s| s.normal);
        let a = sum3(|s| s.albedo);
        [
            r.x,
            r.y,
            r.z,
            depth,
            nn.x,
            nn.y,
            nn.z,
            a.x,
            a.y,
            a.z,
            sum1(|s| s.steps as f32),
            sum1(|s| s.gradient),
        ]
        .map(f32::to_bits)
    }

    fn bits(fb: &Framebuffer, i: usize) -> [u32; 12] {
        let (r, n, a) = (fb.pixels[i], fb.normal[i], fb.albedo[i]);
        [
            r.x,
            r.y,
            r.z,
            fb.depth[i],
            n.x,
            n.y,
            n.z,
            a.x,
            a.y,
            a.z,
            fb.steps[i],
            fb.gradient[i],
        ]
        .map(f32::to_bits)
    }

    #[test]
    fn passes_average_like_the_per_sample_formula() {
        let (w, h, n) = (7, 5, 9);
        let mut passes = SampleSums::new(w, h);
        for s in 0..n {
            let pass: Vec<_> = (0..w * h).map(|p| sample(p, s)).collect();
            passes.add_pass(&pass);
        }
        let fb = passes.mean();
        let mut by_pixel = Framebuffer::new(w, h);
        for p in 0..w * h {
            let samples: Vec<_> = (0..n).map(|s| sample(p, s)).collect();
            assert_eq!(bits(&fb, p as usize), average(&samples), "pixel {p}");
            by_pixel.set(p % w, p / w, &samples);
            assert_eq!(passes.pixels[p as usize].count, n);
        }
        assert_eq!(fb, by_pixel);
    }

    #[test]
    fn an_image_of_several_jobs_is_averaged_like_pixel_by_pixel() {
        // two and a bit parallel jobs' worth of rows, the last job partial; pixels left
        // without samples too
        let (w, h) = (181, 200);
        let rows = PIXELS_PER_JOB as u32 / w;
        assert!(h > 2 * rows && h % rows != 0);
        for (w, h) in [(0, 5), (5, 0)] {
            let none = SampleSums::new(w, h).mean();
            assert!(none.pixels.is_empty() && none.depth.is_empty(), "{w}×{h}");
        }
        let mut sums = SampleSums::new(w, h);
        assert!(sums.pixels.iter().all(|p| *p == PixelSums::default()));
        let with_samples = |p: u32| p % 7 != 3;
        for s in 0..2 {
            for p in (0..w * h).filter(|&p| with_samples(p)) {
                sums.add(p % w, p / w, &sample(p, s));
            }
        }
        let fb = sums.mean();
        let mut by_pixel = Framebuffer::new(w, h);
        for p in (0..w * h).filter(|&p| with_samples(p)) {
            by_pixel.set(p % w, p / w, &[sample(p, 0), sample(p, 1)]);
        }
        assert_eq!(fb, by_pixel);
    }

    #[test]
    fn single_samples_written_by_band_make_the_image_their_sums_would() {
        // partial tiles on the right and at the bottom; negative zeros, misses and large and
        // tiny values in the samples (see `sample`); the tiles written out of order
        let (w, h, side) = (75, 53, 16);
        let done: Vec<(Tile, Vec<CameraSample>)> = crate::render::tiles(w, h, side)
            .into_iter()
            .map(|t| {
                let samples = (0..t.h)
                    .flat_map(|y| (0..t.w).map(move |x| (t.y0 + y) * w + t.x0 + x))
                    .map(|p| sample(p, 3))
                    .collect();
                (t, samples)
            })
            .collect();
        let mut sums = SampleSums::new(w, h);
        let mut sum_bands = sums.bands_mut(side);
        for (tile, samples) in &done {
            sum_bands[(tile.y0 / side) as usize].add_tile(*tile, samples);
        }
        let by_sums = sums.mean();
        let mut direct = Framebuffer::zeroed(w, h);
        let mut bands = direct.bands_mut(side);
        assert_eq!(bands.len() as u32, h.div_ceil(side));
        for (tile, samples) in done.iter().rev() {
            bands[(tile.y0 / side) as usize].write_single_samples(*tile, samples);
        }
        for i in 0..(w * h) as usize {
            assert_eq!(bits(&direct, i), bits(&by_sums, i), "pixel {i}");
        }
        assert!(
            by_sums.normal.iter().any(|n| n.y.to_bits() == 0),
            "a normal whose sum turned a negative zero positive"
        );
    }

    #[test]
    fn the_order_of_samples_shows_in_the_bits() {
        // What makes the bit-exact comparisons of progressive rendering meaningful: f32 sums
        // depend on their order, so passes accumulated out of order are caught.
        let (w, h, n) = (7, 5, 9);
        let mut forward = SampleSums::new(w, h);
        let mut backward = SampleSums::new(w, h);
        for s in 0..n {
            for p in 0..w * h {
                forward.add(p % w, p / w, &sample(p, s));
                backward.add(p % w, p / w, &sample(p, n - 1 - s));
            }
        }
        assert_ne!(forward.mean().pixels, backward.mean().pixels);
    }

    #[test]
    fn a_pass_of_tiles_added_in_bands_is_the_tiles_added_one_by_one() {
        // an image the tiles do not divide: cut tiles in the last column and row
        let (w, h, side, n) = (23, 17, 5, 3);
        let (mut banded, mut alone) = (SampleSums::new(w, h), SampleSums::new(w, h));
        for s in 0..n {
            let done: Vec<(Tile, Vec<CameraSample>)> = crate::render::tiles(w, h, side)
                .into_iter()
                .map(|t| {
                    let px = (0..t.h)
                        .flat_map(|y| (0..t.w).map(move |x| (t.y0 + y) * w + t.x0 + x))
                        .map(|p| sample(p, s))
                        .collect();
                    (t, px)
                })
                .collect();
            let mut bands = banded.bands_mut(side);
            assert_eq!(bands.len() as u32, h.div_ceil(side));
            // the tiles out of order, as a pass's threads finish them (each writes only its
            // own pixels, once a pass)
            for (tile, px) in done.iter().rev() {
                bands[(tile.y0 / side) as usize].add_tile(*tile, px);
            }
            for (t, px) in &done {
                alone.add_tile(*t, px);
            }
        }
        assert_eq!(banded.mean(), alone.mean());
        for p in 0..w * h {
            let samples: Vec<_> = (0..n).map(|s| sample(p, s)).collect();
            assert_eq!(
                bits(&banded.mean(), p as usize),
                average(&samples),
                "pixel {p}"
            );
        }
    }

    #[test]
    fn tiles_land_on_their_pixels() {
        let mut sums = SampleSums::new(6, 4);
        let tile = Tile {
            x0: 2,
            y0: 1,
            w: 3,
            h: 2,
        };
        let samples: Vec<_> = (0..6).map(|p| sample(p, 0)).collect();
        sums.add_tile(tile, &samples);
        for y in 0..4 {
            for x in 0..6 {
                let inside = (2..5).contains(&x) && (1..3).contains(&y);
                let p = &sums.pixels[(y * 6 + x) as usize];
                assert_eq!(p.count, inside as u32, "({x}, {y})");
                if inside {
                    let s = &samples[((y - 1) * 3 + x - 2) as usize];
                    assert_eq!(p.radiance, s.radiance);
                }
            }
        }
    }

    #[test]
    fn cleared_sums_are_new_sums() {
        // more pixels than a job of the parallel clear, and a cut last job
        let (w, h) = (301, 67);
        let mut sums = SampleSums::new(w, h);
        for p in 0..w * h {
            sums.add(p % w, p / w, &sample(p, 0));
        }
        sums.clear();
        assert_eq!(sums, SampleSums::new(w, h));
    }

    #[test]
    fn no_samples_is_black_and_all_miss() {
        let fb = SampleSums::new(3, 2).mean();
        assert_eq!(fb, Framebuffer::new(3, 2));
    }
}
