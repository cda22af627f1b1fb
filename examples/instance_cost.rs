//! What instance boundaries cost the mesh walks: a model's bench rays traced through its
//! two-level tree (a tree per mesh, every instance over them: `MeshAccel::with_merging` without
//! merging the meshes placed once, which `MeshAccel::new` does) and
//! through one tree over all its triangles baked into world space under one instance:
//! `cargo run --release --example instance_cost -- MODEL [seconds] [--obj PATH]`.
//!
//! The ray sets are the mesh bench's (`hytrace bench`): primary rays 1920×1080, AO and shadow
//! rays from their hits, 2^20 incoherent rays, all made with the two-level tree. Both trees
//! are Medium builds, traced in turns for three rounds of at least `seconds` (default 1) per
//! set, one thread; the best Mrays/s of each is printed with its hit count (baked in `f32`,
//! the world-space triangles are not bit for bit the instanced ones, so a count may differ by
//! a ray or two). `--obj PATH` also writes the baked triangles as an OBJ file, for tracing them
//! against Embree with `hytrace bench`.

use std::io::Write;
use std::path::Path;
use std::time::Instant;

use arrayvec::ArrayVec;
use glam::{Affine3A, Vec3};
use hytrace::accel::MeshAccel;
use hytrace::accel::bvh::{BuildQuality, Instance, InstanceBvh, MeshBvh};
use hytrace::bench::rays::{self, QueryRay};
use hytrace::bench::{CHUNK, Workers};
use hytrace::geom::Ray;
use hytrace::scene::Scene;

/// Best Mrays/s over the timed passes of `set`, each pass the bench's: the rays in chunks of
/// [`CHUNK`], each chunk's rays and limits handed to the batch query as two slices. Also the
/// number of rays that hit (closest hit) or are blocked (any hit).
fn trace(
    workers: &Workers,
    accel: &MeshAccel,
    set: &[QueryRay],
    closest: bool,
    seconds: f64,
) -> (f64, usize) {
    // The bench's own query (`ours_query` in the bench) is private to it and also looks up the
    // geometric normal of each hit; this is its tracing part only, as the bench hands rays over.
    let query = |chunk: &[QueryRay], out: &mut [bool]| {
        let rays: ArrayVec<Ray, CHUNK> = chunk.iter().map(|q| q.ray).collect();
        let tmax: ArrayVec<f32, CHUNK> = chunk.iter().map(|q| q.tmax).collect();
        if closest {
            let mut hits = [None; CHUNK];
            let hits = &mut hits[..chunk.len()];
            accel
                .tlas
                .closest_hits(&accel.blas, &rays, 0.0, &tmax, hits);
            for (o, h) in out.iter_mut().zip(hits) {
                *o = h.is_some();
            }
        } else {
            accel.tlas.any_hits(&accel.blas, &rays, 0.0, &tmax, out);
        }
    };
    let mut hit = vec![false; set.len()];
    let (mut best, mut passes, start) = (f64::INFINITY, 0, Instant::now());
    while passes < 2 || start.elapsed().as_secs_f64() < seconds {
        best = best.min(workers.map_chunks(set, &mut hit, query));
        passes += 1;
    }
    let count = hit.iter().filter(|&&h| h).count();
    (set.len() as f64 / best / 1e6, count)
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(model) = args.first() else {
        anyhow::bail!("usage: instance_cost MODEL [seconds] [--obj PATH]");
    };
    let seconds: f64 = match args.get(1).filter(|a| !a.starts_with("--")) {
        Some(s) => s.parse()?,
        None => 1.0,
    };
    let obj = args
        .iter()
        .position(|a| a == "--obj")
        .map(|i| args.get(i + 1).cloned())
        .map(|p| p.ok_or_else(|| anyhow::anyhow!("--obj needs a path")))
        .transpose()?;
    let scene = Scene::from_model(Path::new(model), None)?;
    let quality = BuildQuality::Medium;
    let instanced = MeshAccel::with_merging(&scene.meshes, quality, false);

    // Every instance's triangles in world space, one mesh.
    let (mut positions, mut triangles): (Vec<Vec3>, Vec<[u32; 3]>) = (Vec::new(), Vec::new());
    for inst in &scene.meshes.instances {
        let mesh = &scene.meshes.meshes[inst.mesh];
        let base = u32::try_from(positions.len())?;
        positions.extend(
            mesh.positions
                .iter()
                .map(|&p| inst.transform.transform_point3(p)),
        );
        triangles.extend(mesh.triangles.iter().map(|t| t.map(|v| v + base)));
    }
    let start = Instant::now();
    let blas = vec![MeshBvh::build(&positions, &triangles, quality)];
    let one = [Instance {
        mesh: 0,
        transform: Affine3A::IDENTITY,
    }];
    let tlas = InstanceBvh::build(&blas, &one, quality);
    let baked = MeshAccel {
        blas,
        tlas,
        build_time: start.elapsed(),
        alpha_tested: vec![false],
    };
    if let Some(path) = obj {
        let mut f = std::io::BufWriter::new(std::fs::File::create(&path)?);
        // `{:e}` writes the shortest digits that read back as the same f32.
        for p in &positions {
            writeln!(f, "v {:e} {:e} {:e}", p.x, p.y, p.z)?;
        }
        for t in &triangles {
            writeln!(f, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
        }
        f.flush()?;
        eprintln!("wrote {} triangles to {path}", triangles.len());
    }

    let camera = rays::framing_camera(&scene, 1920.0 / 1080.0);
    let primary = rays::primary_from(&camera, 1920, 1080);
    let (ao, shadow) = rays::secondary(&scene, &instanced, &primary);
    let incoherent = rays::incoherent(&scene, 1 << 20);
    let workers = Workers::new(1)?;
    println!(
        "{}: {} instances of {} meshes, {} triangles",
        model,
        scene.meshes.instances.len(),
        scene.meshes.meshes.len(),
        triangles.len()
    );
    println!(
        "build ms: two-level {:.1}, baked {:.1}",
        instanced.build_time.as_secs_f64() * 1e3,
        baked.build_time.as_secs_f64() * 1e3
    );
    println!("| rays | two-level Mrays/s (hits) | baked Mrays/s (hits) | baked / two-level |");
    println!("|---|---|---|---|");
    let sets = [
        ("primary", &primary, true),
        ("ao", &ao, true),
        ("shadow", &shadow, false),
        ("incoherent", &incoherent, true),
    ];
    for (name, set, closest) in sets {
        // (best Mrays/s, hits) of the two-level tree and of the baked one
        let (mut two_level, mut baked_best) = ((0.0f64, 0), (0.0f64, 0));
        for _ in 0..3 {
            let a = trace(&workers, &instanced, set, closest, seconds);
            let b = trace(&workers, &baked, set, closest, seconds);
            two_level = (two_level.0.max(a.0), a.1);
            baked_best = (baked_best.0.max(b.0), b.1);
        }
        println!(
            "| {name} | {:.2} ({}) | {:.2} ({}) | {:.2} |",
            two_level.0,
            two_level.1,
            baked_best.0,
            baked_best.1,
            baked_best.0 / two_level.0
        );
    }
    Ok(())
}
