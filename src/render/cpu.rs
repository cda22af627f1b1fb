//! The CPU backend: rayon over tiles, one sphere-traced camera ray per sample.

use super::{Framebuffer, RenderOptions, Tile, sample_offset, tiles};
use crate::scene::Scene;
use crate::shade::{self, SurfacePoint, material::MaterialParams};
use crate::trace::SceneTracer;
use glam::Vec3;
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;

/// Renders the scene on the CPU. Every pixel depends only on its own coordinates, so the image
/// is identical for any thread count and any run.
pub fn render(scene: &Scene, opts: &RenderOptions) -> anyhow::Result<Framebuffer> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(opts.threads.unwrap_or(0))
        .build()?;
    let tracer = SceneTracer::new(scene);
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
    let done: Vec<(Tile, Vec<Vec3>)> = pool.install(|| {
        all.par_iter()
            .map(|&tile| {
                let px = render_tile(&tracer, &materials, opts, tile);
                bar.inc(1);
                (tile, px)
            })
            .collect()
    });
    bar.finish_and_clear();
    let mut fb = Framebuffer {
        width: opts.width,
        height: opts.height,
        pixels: vec![Vec3::ZERO; (opts.width * opts.height) as usize],
    };
    for (tile, px) in done {
        for j in 0..tile.h {
            for i in 0..tile.w {
                fb.pixels[((tile.y0 + j) * opts.width + tile.x0 + i) as usize] =
                    px[(j * tile.w + i) as usize];
            }
        }
    }
    Ok(fb)
}

fn render_tile(
    tracer: &SceneTracer,
    materials: &[crate::sdf::tape::MaterialVec],
    opts: &RenderOptions,
    tile: Tile,
) -> Vec<Vec3> {
    let mut out = Vec::with_capacity((tile.w * tile.h) as usize);
    for y in tile.y0..tile.y0 + tile.h {
        for x in tile.x0..tile.x0 + tile.w {
            let mut sum = Vec3::ZERO;
            for s in 0..opts.samples {
                let (dx, dy) = sample_offset(x, y, s, opts.samples);
                sum += radiance(tracer, materials, opts, x as f32 + dx, y as f32 + dy);
            }
            out.push(sum / opts.samples as f32);
        }
    }
    out
}

/// Radiance along the camera ray through image position (px, py) in pixels.
pub fn radiance(
    tracer: &SceneTracer,
    materials: &[crate::sdf::tape::MaterialVec],
    opts: &RenderOptions,
    px: f32,
    py: f32,
) -> Vec3 {
    let scene = tracer.scene();
    let aspect = opts.width as f32 / opts.height as f32;
    let ray = scene
        .camera
        .ray(px / opts.width as f32, py / opts.height as f32, aspect);
    match tracer.closest_hit(&ray, 0.0, f32::INFINITY) {
        None => scene.image.background,
        Some(hit) => {
            let p = ray.at(hit.t);
            let (_, m) = scene.objects[hit.object]
                .lowered
                .shading
                .eval_material(p, materials);
            shade::shade(
                tracer,
                &SurfacePoint {
                    position: p,
                    normal: hit.normal,
                    to_eye: -ray.direction,
                    t: hit.t,
                    material: MaterialParams::from_vec(&m),
                },
            )
        }
    }
}
