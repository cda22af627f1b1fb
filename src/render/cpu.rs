//! The CPU backend: rayon over tiles, one camera path per sample; a whole image is rendered a
//! tile at a time, every sample of the tile at once, and the viewer's one sample pass at a time.

use super::progressive::{FramebufferRows, PixelSums, SampleSums, SumsRows};
use super::{Framebuffer, RenderOptions, TILE, Tile, sample_offset, tiles};
use crate::geom::Ray;
use crate::scene::Scene;
use crate::scene::camera::Camera;
use crate::sdf::tape::MaterialVec;
use crate::shade::integrator::Surfaced;
use crate::shade::integrator::{
    self, CameraSample, Deferral, DeferredShading, Primary, SETTLE_AT, trace_camera_ray_from,
};
use crate::shade::{
    ShadingTracer, occlusion_from, occlusion_reach, occlusion_sample, shadow_query,
};
use crate::trace::SceneTracer;
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use std::cell::RefCell;
use std::sync::Mutex;

/// Renders the scene on the CPU. Every pixel depends only on its own coordinates, so the image
/// is identical for any thread count and any run. The acceleration structures (the SDF
/// objects' octrees among them) are built on the same threads.
pub fn render(scene: &Scene, opts: &RenderOptions) -> anyhow::Result<Framebuffer> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(opts.threads.unwrap_or(0))
        .build()?;
    pool.install(|| render_with(&SceneTracer::new(scene), opts))
}

/// [`render`] with a tracer built by the caller (kept across frames, or built with other
/// [`crate::trace::AccelOptions`]), on the current rayon pool: bit for bit the passes 0..n of
/// [`render_pass`] with the scene's camera, averaged (rendered a tile at a time, every
/// sample of a tile at once).
pub fn render_with(tracer: &SceneTracer, opts: &RenderOptions) -> anyhow::Result<Framebuffer> {
    render_through(tracer, opts)
}

/// [`render_with`] through any [`ShadingTracer`]: the same tiles, camera rays, sample positions
/// and integrator, so with our [`SceneTracer`] it is `render`'s image bit for bit and with
/// another tracer (Embree's hits, for `compare`) a difference is that tracer's alone.
pub fn render_through<T: ShadingTracer + Sync + ?Sized>(
    tracer: &T,
    opts: &RenderOptions,
) -> anyhow::Result<Framebuffer> {
    let camera = &tracer.scene().camera;
    let tiles_per_pass = tiles(opts.width, opts.height, TILE).len() as u64;
    let bar = if opts.progress {
        let b = ProgressBar::new(tiles_per_pass * opts.samples as u64);
        b.set_style(
            ProgressStyle::with_template(
                "{spinner} rendering [{bar:40}] {percent:>3}% {pos}/{len} tiles, ETA {eta}",
            )?
            .progress_chars("=> "),
        );
        b
    } else {
        ProgressBar::hidden()
    };
    let fb = if opts.samples == 1 {
        single_pass(tracer, camera, opts, &|| false, &bar).expect("nobody cancels")
    } else {
        every_sample_by_tile(tracer, camera, opts, &bar)
    };
    bar.finish_and_clear();
    Ok(fb)
}

/// The image of every sample of every pixel, a tile at a time: each tile's samples 0..n are
/// rendered one after the other and added to sums of that tile alone, whose means are written
/// into the framebuffer as soon as the tile is done. The sums are added in sample order, as
/// [`render_pass`] adds them, so the image is bit for bit the mean of passes 0..n over
/// [`SampleSums`], without those sums of the whole image (52 bytes a pixel, new to the
/// process and written every pass, then read once more for the means) and with a tile's
/// octree leaves and tapes still in the cache for its next sample: a 4-sample 1280×720
/// showcase frame took 6 % less time than pass by pass (measured).
fn every_sample_by_tile<T: ShadingTracer + Sync + ?Sized>(
    tracer: &T,
    camera: &Camera,
    opts: &RenderOptions,
    bar: &ProgressBar,
) -> Framebuffer {
    let materials = tracer.scene().material_table();
    let mut fb = Framebuffer::zeroed(opts.width, opts.height);
    let bands: Vec<Mutex<FramebufferRows>> =
        fb.bands_mut(TILE).into_iter().map(Mutex::new).collect();
    let render = |tile: Tile, buffers: &mut TileBuffers| {
        let TileBuffers { samples, sums } = buffers;
        sums.clear();
        sums.resize((tile.w * tile.h) as usize, PixelSums::default());
        for sample in 0..opts.samples {
            render_tile(tracer, &materials, camera, opts, tile, sample, samples);
            for (sum, s) in sums.iter_mut().zip(samples.iter()) {
                sum.add(s);
            }
            bar.inc(1);
        }
        bands[(tile.y0 / TILE) as usize]
            .lock()
            .expect("a band is never left half written")
            .write_tile_means(tile, sums);
    };
    // one tile per job, as in `render_pass`
    tiles(opts.width, opts.height, TILE)
        .into_par_iter()
        .with_max_len(1)
        .for_each(|tile| {
            with_tile_buffers(|buffers| render(tile, buffers));
        });
    drop(bands);
    fb
}

/// Renders sample `sample` of `opts.samples` of every pixel as `camera` sees the tracer's
/// scene, in parallel over the tiles on the current rayon pool, and adds it to `sums` (of
/// `opts.width`×`opts.height`). Returns false when `cancelled()` turned true: it is asked
/// before each tile, so an abandoned pass stops within one tile's time, and `sums` then hold
/// part of the pass, to be dropped. Passes 0..n added in order hold exactly what [`render`]
/// averages.
///
/// Each tile's samples are added to its band of the sums as soon as the tile is done, from a
/// buffer its thread keeps ([`with_tile_buffers`]). (A cancelled pass has added some of its tiles:
/// the viewer, the one caller that cancels, starts over from its new camera.)
pub fn render_pass(
    tracer: &SceneTracer,
    camera: &Camera,
    opts: &RenderOptions,
    sample: u32,
    sums: &mut SampleSums,
    cancelled: &(dyn Fn() -> bool + Sync),
) -> bool {
    assert_eq!(
        (sums.width, sums.height),
        (opts.width, opts.height),
        "the sums are of the image rendered"
    );
    let materials = tracer.scene().material_table();
    let bands: Vec<Mutex<SumsRows>> = sums.bands_mut(TILE).into_iter().map(Mutex::new).collect();
    let add = |tile: Tile, samples: &mut Vec<CameraSample>| {
        render_tile(tracer, &materials, camera, opts, tile, sample, samples);
        bands[(tile.y0 / TILE) as usize]
            .lock()
            .expect("a band is never left half added")
            .add_tile(tile, samples);
    };
    // rayon stops handing out tiles once one comes back None. Each tile is its own job:
    // rayon's adaptive splitting would otherwise hand a thread a run of dozens of tiles that
    // nobody can steal from, and the other threads sit idle through that run's tail (a tenth
    // of every pass at 1280×720 on two cores, measured)
    tiles(opts.width, opts.height, TILE)
        .into_par_iter()
        .with_max_len(1)
        .try_for_each(|tile| {
            if cancelled() {
                return None;
            }
            with_tile_buffers(|buffers| add(tile, &mut buffers.samples));
            Some(())
        })
        .is_some()
}

/// Every sample of each pixel (x, y) of `pixels`, in place of what `sums` held for it: there,
/// the sums [`render`] adds. (For the GPU backend's pixels its driver could not trace, see
/// `crate::gpu::render`.)
pub fn render_pixels(
    tracer: &SceneTracer,
    camera: &Camera,
    opts: &RenderOptions,
    pixels: &[(u32, u32)],
    sums: &mut SampleSums,
) {
    let materials = tracer.scene().material_table();
    let mut samples = Vec::new();
    for &(x, y) in pixels {
        sums.pixels[(y * sums.width + x) as usize] = PixelSums::default();
        let alone = Tile {
            x0: x,
            y0: y,
            w: 1,
            h: 1,
        };
        for sample in 0..opts.samples.max(1) {
            render_tile(
                tracer,
                &materials,
                camera,
                opts,
                alone,
                sample,
                &mut samples,
            );
            sums.add(x, y, &samples[0]);
        }
    }
}

/// A tile's samples and, for [`every_sample_by_tile`], its sums: memory kept by the thread that
/// renders tiles ([`with_tile_buffers`]).
#[derive(Default)]
struct TileBuffers {
    samples: Vec<CameraSample>,
    sums: Vec<PixelSums>,
}

thread_local! {
    static TILE_BUFFERS: RefCell<TileBuffers> = RefCell::new(TileBuffers::default());
}

/// Runs `f` with this thread's [`TileBuffers`], or with new ones when they are in use (a
/// tracer that runs rayon jobs inside a tile may start another tile on the same thread).
fn with_tile_buffers(f: impl FnOnce(&mut TileBuffers)) {
    TILE_BUFFERS.with(|buffers| match buffers.try_borrow_mut() {
        Ok(mut mine) => f(&mut mine),
        Err(_) => f(&mut TileBuffers::default()),
    });
}

/// The image of sample 0 alone of every pixel as `camera` sees the tracer's scene, in
/// parallel over the tiles on the current rayon pool: bit for bit the mean of new sums after
/// [`render_pass`] 0, without the sums (the viewer's previews, whose one sample is the whole
/// image). `None` once `cancelled()` turned true: it is asked before each tile.
pub fn render_single_pass(
    tracer: &SceneTracer,
    camera: &Camera,
    opts: &RenderOptions,
    cancelled: &(dyn Fn() -> bool + Sync),
) -> Option<Framebuffer> {
    single_pass(tracer, camera, opts, cancelled, &ProgressBar::hidden())
}

/// The image of one sample per pixel (sample 0), each tile's samples written into its band of
/// the framebuffer ([`FramebufferRows::write_single_samples`]) as soon as the tile is done,
/// from a buffer its thread keeps: bit for bit the means of the sums of [`render_pass`], without
/// the sums (they and the memory they take, new to the process every frame, were a sixth of
/// a one-sample 1024² frame). `None` once `cancelled()` turned true.
fn single_pass<T: ShadingTracer + Sync + ?Sized>(
    tracer: &T,
    camera: &Camera,
    opts: &RenderOptions,
    cancelled: &(dyn Fn() -> bool + Sync),
    bar: &ProgressBar,
) -> Option<Framebuffer> {
    let materials = tracer.scene().material_table();
    let mut fb = Framebuffer::zeroed(opts.width, opts.height);
    let bands: Vec<Mutex<FramebufferRows>> =
        fb.bands_mut(TILE).into_iter().map(Mutex::new).collect();
    let write = |tile: Tile, samples: &mut Vec<CameraSample>| {
        render_tile(tracer, &materials, camera, opts, tile, 0, samples);
        bands[(tile.y0 / TILE) as usize]
            .lock()
            .expect("a band is never left half written")
            .write_single_samples(tile, samples);
    };
    // one tile per job, as in `render_pass`
    let finished = tiles(opts.width, opts.height, TILE)
        .into_par_iter()
        .with_max_len(1)
        .try_for_each(|tile| {
            if cancelled() {
                return None;
            }
            with_tile_buffers(|buffers| write(tile, &mut buffers.samples));
            bar.inc(1);
            Some(())
        });
    drop(bands);
    finished.map(|()| fb)
}

/// Rows of a tile whose camera rays are traced together: a band of 4 rows of 32 pixels fills a
/// ray bundle ([`crate::trace::packet::BUNDLE`]), whose lanes share SIMD passes wherever they
/// stand in one leaf, across the rows as along them.
const BAND_ROWS: u32 = 4;

/// Sample `sample` of every pixel of a tile as `camera` sees it, in row order, into `out`
/// (cleared first). Each sample's camera rays are traced a band of [`BAND_ROWS`] tile rows at
/// a time: the band's closest hits come from one [`ShadingTracer::closest_hits`] call and
/// the shadow rays of their local shading from one [`ShadingTracer::visibilities`] call (on
/// our tracer, ray bundles:
/// [`SceneTracer::closest_hits`]), and so do the mirror reflections the paths follow from
/// those hits ([`integrator::first_reflection`]); then each ray's path is followed on its
/// own, putting off the local shading of its later hits ([`DeferredShading`]), whose shadow
/// rays are then answered by one more call for the band (or sooner, once
/// [`SETTLE_AT`] surfaces wait). The answers are those of tracing
/// every ray alone, so the image does not depend on this grouping.
fn render_tile<T: ShadingTracer + Sync + ?Sized>(
    tracer: &T,
    materials: &[MaterialVec],
    camera: &Camera,
    opts: &RenderOptions,
    tile: Tile,
    sample: u32,
    out: &mut Vec<CameraSample>,
) {
    let scene = tracer.scene();
    let lights = scene.lights.len();
    out.clear();
    out.reserve((tile.w * tile.h) as usize);
    let band = (tile.w * BAND_ROWS) as usize;
    let mut rays = Vec::with_capacity(band);
    let mut hits = Vec::with_capacity(band);
    let mut surfaces = Vec::with_capacity(band);
    let mut blended = Vec::new();
    let mut occlusion = Vec::with_capacity(band);
    let mut occlusion_points = Vec::new();
    let mut occlusion_distances = Vec::new();
    let mut queries = Vec::new();
    let mut owners = Vec::new();
    let mut answers = Vec::new();
    let mut mirrors = Vec::new();
    let mut mirror_of = Vec::with_capacity(band);
    let mut mirror_hits = Vec::new();
    let mut visibility = vec![1.0f32; band * lights];
    // the local shading of the paths' later hits, lit together once the band's paths are done
    let mut deferred = DeferredShading::default();
    for y0 in (tile.y0..tile.y0 + tile.h).step_by(BAND_ROWS as usize) {
        rays.clear();
        for y in y0..(y0 + BAND_ROWS).min(tile.y0 + tile.h) {
            for x in tile.x0..tile.x0 + tile.w {
                let (dx, dy) = sample_offset(x, y, sample, opts.samples);
                rays.push(camera_ray(camera, opts, x as f32 + dx, y as f32 + dy));
            }
        }
        hits.clear();
        hits.resize(rays.len(), None);
        tracer.closest_hits(&rays, 0.0, f32::INFINITY, &mut hits);
        // the band's shadow rays, light by light (rays toward one light are coherent)
        // the materials that shading tapes blend, together (eight at a time); the others as
        // each surface is made
        tracer.blended_materials(&rays, &hits, materials, &mut blended);
        let mut blended_at = blended.iter().peekable();
        surfaces.clear();
        for (i, (ray, hit)) in rays.iter().zip(&hits).enumerate() {
            // a miss is pushed as a bare `None`: made in the map of an `extend`, each of the
            // 144-byte options went through a call to memcpy (8 % of a frame of misses)
            let Some(hit) = hit else {
                surfaces.push(None);
                continue;
            };
            surfaces.push(Some(match blended_at.next_if(|b| b.0 == i) {
                Some(&(_, m)) => integrator::surfaced_with(ray, hit, m),
                None => integrator::surfaced(tracer, materials, ray, hit),
            }));
        }
        // the band's ambient occlusion together, where the scene asks for it
        occlusion.clear();
        if let Some(ao) = scene.shading.ambient_occlusion.filter(|_| {
            (scene.lights.iter()).any(|l| matches!(l, crate::scene::Light::Ambient { .. }))
        }) {
            let shaded =
                |s: &Option<Surfaced>| s.as_ref().filter(|s| s.local_weight > 0.0).is_some();
            occlusion_points.clear();
            for s in surfaces.iter().flatten().filter(|s| s.local_weight > 0.0) {
                let (p, n) = (s.point.position, s.point.normal);
                occlusion_points.extend((1..=ao.steps).map(|i| occlusion_sample(p, n, &ao, i)));
            }
            occlusion_distances.resize(occlusion_points.len(), 0.0);
            tracer.distances(
                &occlusion_points,
                occlusion_reach(&ao),
                &mut occlusion_distances,
            );
            let mut at = 0;
            for s in &surfaces {
                occlusion.push(shaded(s).then(|| {
                    let value = occlusion_from(&ao, |i| occlusion_distances[at + i as usize - 1]);
                    at += ao.steps as usize;
                    value
                }));
            }
        }
        queries.clear();
        owners.clear();
        for light in 0..lights {
            for (i, surf) in surfaces.iter().enumerate() {
                if let Some(q) = surf
                    .as_ref()
                    .filter(|s| s.local_weight > 0.0)
                    .and_then(|s| shadow_query(scene, &s.point, light))
                {
                    queries.push(q);
                    owners.push(i * lights + light);
                }
            }
        }
        // the band's mirror reflections, traced together like the camera rays
        mirrors.clear();
        mirror_of.clear();
        for (surf, ray) in surfaces.iter().zip(&rays) {
            let mirror = surf
                .as_ref()
                .and_then(|s| integrator::first_reflection(tracer, s, ray.direction));
            mirror_of.push(mirror.map(|m| {
                mirrors.push(m);
                mirrors.len() - 1
            }));
        }
        mirror_hits.clear();
        mirror_hits.resize(mirrors.len(), None);
        if !mirrors.is_empty() {
            tracer.closest_hits(&mirrors, 0.0, f32::INFINITY, &mut mirror_hits);
        }
        answers.resize(queries.len(), 0.0);
        tracer.visibilities(&queries, &mut answers);
        for (&at, &v) in owners.iter().zip(&answers) {
            visibility[at] = v;
        }
        for (i, (ray, hit)) in rays.iter().zip(&hits).enumerate() {
            let first = Primary {
                hit: hit.as_ref(),
                occlusion: occlusion.get(i).copied().flatten(),
                shading: surfaces[i]
                    .as_ref()
                    .map(|s| (s, &visibility[i * lights..(i + 1) * lights])),
                reflection: mirror_of[i].map(|m| (mirrors[m], mirror_hits[m].as_ref())),
            };
            out.push(CameraSample::NOTHING);
            let slot = out.len() - 1;
            let defer = Deferral {
                shading: &mut deferred,
                slot,
            };
            trace_camera_ray_from(
                tracer,
                materials,
                *ray,
                Some(first),
                &mut out[slot],
                Some(defer),
            );
            if deferred.waiting() >= SETTLE_AT {
                deferred.settle(tracer, out);
            }
        }
        deferred.settle(tracer, out);
    }
}

/// The ray of `camera` through image position (px, py), in pixels.
fn camera_ray(camera: &Camera, opts: &RenderOptions, px: f32, py: f32) -> Ray {
    let aspect = opts.width as f32 / opts.height as f32;
    camera.ray(px / opts.width as f32, py / opts.height as f32, aspect)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// A sphere over a plane, lit, at 3 spp: 96×64 is six tiles.
    fn setup() -> (Scene, RenderOptions) {
        let src = "Scene(
            image: (width: 96, height: 64, samples: 3),
            camera: Perspective(position: (0, 1, 4), look_at: (0, 0.5, 0)),
            lights: [Point(position: (2, 4, 3), color: (1, 1, 1), intensity: 20)],
            objects: [(shape: Plane(normal: (0, 1, 0), offset: 0)),
                      (shape: Sphere(radius: 0.5), translate: (0, 0.5, 0))],
        )";
        let scene =
            Scene::from_source(src, Path::new("test.ron")).unwrap_or_else(|e| panic!("{e}"));
        let opts = RenderOptions {
            samples: 3,
            ..RenderOptions::single_sample(96, 64)
        };
        (scene, opts)
    }

    /// New sums with pass 0 added.
    fn first_pass(tracer: &SceneTracer, scene: &Scene, opts: &RenderOptions) -> SampleSums {
        let mut sums = SampleSums::new(opts.width, opts.height);
        assert!(render_pass(
            tracer,
            &scene.camera,
            opts,
            0,
            &mut sums,
            &|| false
        ));
        sums
    }

    #[test]
    fn a_single_pass_is_the_mean_of_new_sums_after_pass_zero() {
        let (scene, opts) = setup();
        let opts = RenderOptions { samples: 1, ..opts };
        let tracer = SceneTracer::new(&scene);
        let single =
            render_single_pass(&tracer, &scene.camera, &opts, &|| false).expect("nobody cancels");
        assert_eq!(single, first_pass(&tracer, &scene, &opts).mean());
        let asked = AtomicUsize::new(0);
        let cancelled = || asked.fetch_add(1, Ordering::Relaxed) >= 1;
        assert!(render_single_pass(&tracer, &scene.camera, &opts, &cancelled).is_none());
    }

    #[test]
    fn a_cancelled_pass_stops_and_says_so() {
        let (scene, opts) = setup();
        let tracer = SceneTracer::new(&scene);
        let mut sums = first_pass(&tracer, &scene, &opts);
        // cancelled once the first tile asked: that tile is added, no other
        let asked = AtomicUsize::new(0);
        let cancelled = || asked.fetch_add(1, Ordering::Relaxed) >= 1;
        assert!(!render_pass(
            &tracer,
            &scene.camera,
            &opts,
            1,
            &mut sums,
            &cancelled
        ));
        let twice = sums.pixels.iter().filter(|p| p.count == 2).count();
        assert_eq!(
            twice,
            (TILE * TILE) as usize,
            "one whole tile of the cancelled pass"
        );
        assert!(sums.pixels.iter().all(|p| (1..=2).contains(&p.count)));
    }

    #[test]
    fn an_image_rendered_tile_by_tile_is_its_passes_averaged() {
        // every sample of a tile at once, as `render` does, against the viewer's passes over
        // the whole image: the same sums in the same order, so the same bits
        let (scene, opts) = setup();
        let tracer = SceneTracer::new(&scene);
        let mut sums = first_pass(&tracer, &scene, &opts);
        for sample in 1..opts.samples {
            assert!(render_pass(
                &tracer,
                &scene.camera,
                &opts,
                sample,
                &mut sums,
                &|| false
            ));
        }
        let image = render_with(&tracer, &opts).unwrap_or_else(|e| panic!("{e}"));
        assert!(image.depth.iter().any(|d| d.is_finite()) && image.depth.contains(&f32::INFINITY));
        assert_eq!(image, sums.mean());
        // and the samples differ, so the order they are added in shows
        assert_ne!(image, first_pass(&tracer, &scene, &opts).mean());
    }

    #[test]
    fn a_one_sample_image_is_its_pass_averaged() {
        // written tile by tile into the framebuffer, it is what the viewer's first pass shows
        let (scene, opts) = setup();
        let opts = RenderOptions { samples: 1, ..opts };
        let tracer = SceneTracer::new(&scene);
        let sums = first_pass(&tracer, &scene, &opts);
        let image = render_with(&tracer, &opts).unwrap_or_else(|e| panic!("{e}"));
        assert!(image.depth.iter().any(|d| d.is_finite()) && image.depth.contains(&f32::INFINITY));
        assert_eq!(image, sums.mean());
    }
}
