//! Per-frame CPU render time with the acceleration structures built once, as the viewer
//! renders: `cargo run --release --example frame_time -- [scene.ron or model] [width] [height] [frames]
//! [native|interpreted] [pass|image] [merged|instanced]` (no scene: the built-in showcase; tapes
//! as native code by default; `instanced`: the meshes placed once each under its own instance
//! instead of merged into one tree). Prints the build time and the minimum and median of the frames' times, each one
//! pass of [`cpu::render_pass`] at one sample per pixel into sums made before the clock starts
//! (`pass`, the default), or a whole one-sample image as `hytrace render` and the bench's steady
//! frame make it: the sums, the pass and the framebuffer of their means (`image`).

use hytrace::render::progressive::SampleSums;
use hytrace::render::{RenderOptions, cpu};
use hytrace::scene::Scene;
use hytrace::trace::{AccelOptions, SceneTracer};
use std::path::Path;
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let scene = match args.first().map(String::as_str) {
        Some(path) if path.ends_with(".ron") => Scene::load(Path::new(path))?,
        // a model file on its own, as `hytrace render MODEL` frames and lights it
        Some(path) if path != "-" => Scene::from_model(Path::new(path), None)?,
        _ => Scene::load(Path::new("assets/scenes/showcase.ron"))?,
    };
    let number = |i: usize, default: u32| args.get(i).map_or(Ok(default), |a| a.parse());
    let (width, height, frames) = (number(1, 640)?, number(2, 360)?, number(3, 10)?);
    let opts = RenderOptions::single_sample(width, height);
    let start = Instant::now();
    let native = match args.get(4).map(String::as_str) {
        None | Some("native") => true,
        Some("interpreted") => false,
        Some(other) => anyhow::bail!("expected native or interpreted, not {other}"),
    };
    let merge_meshes = match args.get(6).map(String::as_str) {
        None | Some("merged") => true,
        Some("instanced") => false,
        Some(other) => anyhow::bail!("expected merged or instanced, not {other}"),
    };
    let tracer = SceneTracer::with_options(
        &scene,
        AccelOptions {
            mesh_quality: scene.tracer.bvh,
            native,
            merge_meshes,
            ..Default::default()
        },
    );
    println!("build {:.1} ms", start.elapsed().as_secs_f64() * 1e3);
    let whole_image = match args.get(5).map(String::as_str) {
        None | Some("pass") => false,
        Some("image") => true,
        Some(other) => anyhow::bail!("expected pass or image, not {other}"),
    };
    let mut times = Vec::new();
    for _ in 0..frames {
        if whole_image {
            let start = Instant::now();
            let image = cpu::render_with(&tracer, &opts)?;
            times.push(start.elapsed().as_secs_f64() * 1e3);
            assert_eq!(image.depth.len(), (width * height) as usize);
            continue;
        }
        let mut sums = SampleSums::new(width, height);
        let start = Instant::now();
        let finished = cpu::render_pass(&tracer, &scene.camera, &opts, 0, &mut sums, &|| false);
        times.push(start.elapsed().as_secs_f64() * 1e3);
        assert!(finished, "nobody cancels the pass");
    }
    times.sort_by(f64::total_cmp);
    println!(
        "{width}x{height}: min {:.1} ms, median {:.1} ms over {frames} frames",
        times[0],
        times[times.len() / 2]
    );
    Ok(())
}
