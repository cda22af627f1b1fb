//! What instance boundaries cost the mesh walks: a model's bench rays traced through its
//! two-level tree (a tree per mesh, instances over them, as `MeshAccel::new` builds it) and
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

use glam::{Affine3A, Vec3};
use hytrace::accel::MeshAccel;
use hytrace::accel::bvh::{BuildQuality, Instance, InstanceBvh, MeshBvh};
use hytrace::bench::rays::{self, QueryRay};
use hytrace::geom::Ray;
use hytrace::scene::Scene;

/// Best Mrays/s over the timed passes of `set`, and the number of rays that hit (closest hit)
/// or are blocked (any hit).
fn trace(accel: &MeshAccel, set: &[QueryRay], closest: bool, seconds: f64) -> (f64, usize) {
    let rays: Vec<Ray> = set.iter().map(|q| q.ray).collect();
    let tmax: Vec<f32> = set.iter().map(|q| q.tmax).collect();
    let mut hits = vec![None; set.len()];
    let mut blocked = vec![false; set.len()];
    let (mut best, mut passes) = (f64::INFINITY, 0);
    let start = Instant::now();
    while passes < 2 || start.elapsed().as_secs_f64() < seconds {
        let pass = Instant::now();
        // In the bench's chunks of 64 rays.
        for c in (0..set.len()).step_by(64) {
            let r = c..(c + 64).min(set.len());
            if closest {
                let out = &mut hits[r.clone()];
                accel
                    .tlas
                    .closest_hits(&accel.blas, &rays[r.clone()], 0.0, &tmax[r], out);
            } else {
                let out = &mut blocked[r.clone()];
                accel
                    .tlas
                    .any_hits(&accel.blas, &rays[r.clone()], 0.0, &tmax[r], out);
            }
        }
        best = best.min(pass.elapsed().as_secs_f64());
        passes += 1;
    }
    let count = if closest {
        hits.iter().filter(|h| h.is_some()).count()
    } else {
        blocked.iter().filter(|&&b| b).count()
    };
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
    let instanced = MeshAccel::new(&scene.meshes, quality);

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
        let (mut two, mut one) = ((0.0f64, 0), (0.0f64, 0));
        for _ in 0..3 {
            let a = trace(&instanced, set, closest, seconds);
            let b = trace(&baked, set, closest, seconds);
            two = (two.0.max(a.0), a.1);
            one = (one.0.max(b.0), b.1);
        }
        println!(
            "| {name} | {:.2} ({}) | {:.2} ({}) | {:.2} |",
            two.0,
            two.1,
            one.0,
            one.1,
            one.0 / two.0
        );
    }
    Ok(())
}
