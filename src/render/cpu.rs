//! The CPU backend: rayon over tiles, one camera path per sample.

use super::{Framebuffer, RenderOptions, Tile, sample_offset, tiles};
use crate::scene::Scene;
use crate::sdf::tape::MaterialVec;
use crate::shade::integrator::{CameraSample, trace_camera_ray};
use crate::trace::SceneTracer;
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
    let done: Vec<(Tile, Vec<Vec<CameraSample>>)> = pool.install(|| {
        all.par_iter()
            .map(|&tile| {
                let px = render_tile(&tracer, &materials, opts, tile);
                bar.inc(1);
                (tile, px)
            })
            .collect()
    });
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

fn render_tile(
    tracer: &SceneTracer,
    materials: &[MaterialVec],
    opts: &RenderOptions,
    tile: Tile,
) -> Vec<Vec<CameraSample>> {
    let mut out = Vec::with_capacity((tile.w * tile.h) as usize);
    for y in tile.y0..tile.y0 + tile.h {
        for x in tile.x0..tile.x0 + tile.w {
            let samples = (0..opts.samples)
                .map(|s| {
                    let (dx, dy) = sample_offset(x, y, s, opts.samples);
                    camera_sample(tracer, materials, opts, x as f32 + dx, y as f32 + dy)
                })
                .collect();
            out.push(samples);
        }
    }
    out
}

/// What the camera ray through image position (px, py), in pixels, sees.
pub fn camera_sample(
    tracer: &SceneTracer,
    materials: &[MaterialVec],
    opts: &RenderOptions,
    px: f32,
    py: f32,
) -> CameraSample {
    let aspect = opts.width as f32 / opts.height as f32;
    let ray = tracer
        .scene()
        .camera
        .ray(px / opts.width as f32, py / opts.height as f32, aspect);
    trace_camera_ray(tracer, materials, ray)
}
