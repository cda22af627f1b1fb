//! The CPU backend: rayon over tiles, one camera path per sample.

use super::{Framebuffer, RenderOptions, Tile, sample_offset, tiles};
use crate::geom::Ray;
use crate::scene::Scene;
use crate::sdf::tape::MaterialVec;
use crate::shade::integrator::{self, CameraSample, Primary, trace_camera_ray_from};
use crate::shade::shadow_query;
use crate::trace::SceneTracer;
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;

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
/// [`crate::trace::AccelOptions`]), on the current rayon pool.
pub fn render_with(tracer: &SceneTracer, opts: &RenderOptions) -> anyhow::Result<Framebuffer> {
    let scene = tracer.scene();
    let materials = scene.material_table();
    let all = tiles(opts.width, opts.height);
    let bar = if opts.progress {
        let b = ProgressBar::new(all.len() as u64);
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
    let done: Vec<(Tile, Vec<Vec<CameraSample>>)> = all
        .par_iter()
        .map(|&tile| {
            let px = render_tile(tracer, &materials, opts, tile);
            bar.inc(1);
            (tile, px)
        })
        .collect();
    bar.finish_and_clear();
    let mut fb = Framebuffer::new(opts.width, opts.height);
    for (tile, px) in done {
        for j in 0..tile.h {
            for i in 0..tile.w {
                fb.set(tile.x0 + i, tile.y0 + j, &px[(j * tile.w + i) as usize]);
            }
        }
    }
    Ok(fb)
}

/// A tile's samples, per pixel in row order. Each sample's camera rays are traced a tile row
/// at a time: the row's closest hits come from one [`SceneTracer::closest_hits`] call and the
/// shadow rays of their local shading from one [`SceneTracer::visibilities`] call (packets),
/// then each ray's path is followed on its own. The answers are those of tracing every ray
/// alone, so the image does not depend on this grouping.
fn render_tile(
    tracer: &SceneTracer,
    materials: &[MaterialVec],
    opts: &RenderOptions,
    tile: Tile,
) -> Vec<Vec<CameraSample>> {
    let scene = tracer.scene();
    let lights = scene.lights.len();
    let mut out: Vec<Vec<CameraSample>> = (0..tile.w * tile.h)
        .map(|_| Vec::with_capacity(opts.samples as usize))
        .collect();
    let mut rays = Vec::with_capacity(tile.w as usize);
    let mut hits = vec![None; tile.w as usize];
    let mut surfaces = Vec::with_capacity(tile.w as usize);
    let mut queries = Vec::new();
    let mut owners = Vec::new();
    let mut answers = Vec::new();
    let mut visibility = vec![1.0f32; tile.w as usize * lights];
    for s in 0..opts.samples {
        for y in tile.y0..tile.y0 + tile.h {
            rays.clear();
            for x in tile.x0..tile.x0 + tile.w {
                let (dx, dy) = sample_offset(x, y, s, opts.samples);
                rays.push(camera_ray(tracer, opts, x as f32 + dx, y as f32 + dy));
            }
            tracer.closest_hits(&rays, 0.0, f32::INFINITY, &mut hits);
            // the row's shadow rays, light by light (rays toward one light are coherent)
            surfaces.clear();
            surfaces.extend(rays.iter().zip(&hits).map(|(ray, hit)| {
                hit.map(|h| integrator::surfaced(tracer, materials, ray, &h))
                    .filter(|s| s.local_weight > 0.0)
            }));
            queries.clear();
            owners.clear();
            for light in 0..lights {
                for (i, surf) in surfaces.iter().enumerate() {
                    if let Some(q) = surf.and_then(|s| shadow_query(scene, &s.point, light)) {
                        queries.push(q);
                        owners.push(i * lights + light);
                    }
                }
            }
            answers.resize(queries.len(), 0.0);
            tracer.visibilities(&queries, &mut answers);
            for (&at, &v) in owners.iter().zip(&answers) {
                visibility[at] = v;
            }
            let row = ((y - tile.y0) * tile.w) as usize;
            for (i, (ray, hit)) in rays.iter().zip(&hits).enumerate() {
                let first = Primary {
                    hit: *hit,
                    shading: surfaces[i].map(|s| (s, &visibility[i * lights..(i + 1) * lights])),
                };
                let sample = trace_camera_ray_from(tracer, materials, *ray, Some(first));
                out[row + i].push(sample);
            }
        }
    }
    out
}

/// The camera ray through image position (px, py), in pixels.
fn camera_ray(tracer: &SceneTracer, opts: &RenderOptions, px: f32, py: f32) -> Ray {
    let aspect = opts.width as f32 / opts.height as f32;
    tracer
        .scene()
        .camera
        .ray(px / opts.width as f32, py / opts.height as f32, aspect)
}
