//! Criterion benchmarks of the inner loops: the watertight triangle test, one 8-child node
//! test, one SDF tape evaluation, and one closest-hit traversal of the Stanford bunny.
//!
//! Run with `cargo bench --bench inner_loops` (the bunny is read from `$HYTRACE_ASSETS`,
//! default `../shared/assets`; without it that benchmark says so and is not run).

use criterion::{Criterion, black_box, criterion_group, criterion_main};
use glam::Vec3;
use hytrace::accel::bvh::{AabbBvh, BuildQuality, Instance, InstanceBvh, MeshBvh};
use hytrace::accel::triangle::WatertightRay;
use hytrace::geom::{Aabb, Ray};
use hytrace::rng::Rng;
use hytrace::scene::Scene;
use hytrace::sdf::tape::Registers;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

fn triangle_test(c: &mut Criterion) {
    let mut rng = Rng::new(1);
    let tris: Vec<[Vec3; 3]> = (0..1024)
        .map(|_| {
            let a = rng.vec3_in(-1.0, 1.0);
            [a, a + rng.vec3_in(-0.5, 0.5), a + rng.vec3_in(-0.5, 0.5)]
        })
        .collect();
    let rays: Vec<WatertightRay> = (0..1024)
        .map(|_| WatertightRay::new(rng.vec3_in(-3.0, 3.0), rng.direction()))
        .collect();
    c.bench_function("triangle test (Woop watertight), 1024 pairs", |b| {
        b.iter(|| {
            let mut hits = 0u32;
            for (r, t) in rays.iter().zip(&tris) {
                hits += u32::from(
                    r.intersect_nondegenerate(t[0], t[1], t[2], 0.0, f32::INFINITY)
                        .is_some(),
                );
            }
            black_box(hits)
        })
    });
}

fn node_test(c: &mut Criterion) {
    // Eight boxes are scanned (a scene's handful of SDF objects); nine make a tree, so one
    // visit is the walk's node tests plus the leaf calls.
    for (count, name) in [
        (8, "box visit: eight boxes, scanned, 1024 rays"),
        (
            9,
            "box visit: nine boxes, walked (8-child nodes and their leaf boxes), 1024 rays",
        ),
    ] {
        let boxes: Vec<Aabb> = (0..count)
            .map(|i| {
                let lo = Vec3::new(i as f32, 0.0, 0.0);
                Aabb::new(lo, lo + Vec3::splat(0.8))
            })
            .collect();
        let bvh = AabbBvh::build(&boxes);
        let mut rng = Rng::new(2);
        let rays: Vec<Ray> = (0..1024)
            .map(|_| {
                let o = rng.vec3_in(-2.0, 10.0).with_z(-5.0);
                Ray::new(o, Vec3::new(4.0, 0.4, 5.0) - o)
            })
            .collect();
        c.bench_function(name, |b| {
            b.iter(|| {
                let mut n = 0u32;
                for r in &rays {
                    let mut tmax = f32::INFINITY;
                    bvh.visit(r, 0.0, &mut tmax, |_, _, _, _| {
                        n += 1;
                        ControlFlow::Continue(())
                    });
                }
                black_box(n)
            })
        });
    }
}

fn tape_eval(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/scenes/showcase.ron");
    let scene = Scene::load(&path).expect("the showcase scene loads");
    let tape = scene
        .objects
        .iter()
        .map(|o| &o.lowered.distance)
        .max_by_key(|t| t.len())
        .expect("the showcase has objects");
    let mut rng = Rng::new(3);
    let points: Vec<Vec3> = (0..1024).map(|_| rng.vec3_in(-3.0, 3.0)).collect();
    let mut regs = Registers::new();
    c.bench_function(
        &format!(
            "tape eval (largest showcase object, {} instructions), 1024 points",
            tape.len()
        ),
        |b| {
            b.iter(|| {
                let mut s = 0.0f32;
                for p in &points {
                    s += tape.eval_in(*p, &mut regs);
                }
                black_box(s)
            })
        },
    );
}

fn traversal(c: &mut Criterion) {
    let assets = std::env::var_os("HYTRACE_ASSETS")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/assets"));
    let path = assets.join("obj/common-3d-test-models/stanford-bunny.obj");
    let scene = match Scene::from_model(&path, None) {
        Ok(s) => s,
        Err(e) => {
            eprintln!(
                "traversal benchmark NOT RUN: {} ({e}); set HYTRACE_ASSETS",
                path.display()
            );
            return;
        }
    };
    let mesh = &scene.meshes.meshes[0];
    let bvh = MeshBvh::build(&mesh.positions, &mesh.triangles, BuildQuality::Medium);
    let (w, h) = (64u32, 64u32);
    let rays: Vec<Ray> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            scene.camera.ray(
                (x as f32 + 0.5) / w as f32,
                (y as f32 + 0.5) / h as f32,
                1.0,
            )
        })
        .collect();
    c.bench_function("closest-hit traversal, bunny, 64×64 primary rays", |b| {
        b.iter(|| {
            let mut hits = 0u32;
            for r in &rays {
                hits += u32::from(bvh.closest_hit(r, 0.0, f32::INFINITY).is_some());
            }
            black_box(hits)
        })
    });
    // Through the instance tree (one untransformed instance), one by one and as 32-ray
    // packets (half an image row each): the 64×64 image above, whose neighbouring rays are far
    // apart at the scale of the bunny's triangles (the packets split early), and a 64×64 crop
    // of the centre of a 1920×1080 image (neighbours as close as in a real frame).
    let meshes = vec![bvh];
    let tlas = InstanceBvh::build(
        &meshes,
        &[Instance::from((0, glam::Affine3A::IDENTITY))],
        BuildQuality::Medium,
    );
    let crop: Vec<Ray> = (0..w * h)
        .map(|i| {
            let (x, y) = (928 + i % w, 508 + i / w);
            scene.camera.ray(
                (x as f32 + 0.5) / 1920.0,
                (y as f32 + 0.5) / 1080.0,
                1920.0 / 1080.0,
            )
        })
        .collect();
    for (label, rays) in [("64×64 image", &rays), ("64×64 crop of 1920×1080", &crop)] {
        c.bench_function(&format!("instance tree, bunny, {label}, one by one"), |b| {
            b.iter(|| {
                let mut hits = 0u32;
                for r in rays.iter() {
                    hits += u32::from(tlas.closest_hit(&meshes, r, 0.0, f32::INFINITY).is_some());
                }
                black_box(hits)
            })
        });
        let tmax = vec![f32::INFINITY; rays.len()];
        let mut out = vec![None; rays.len()];
        c.bench_function(&format!("instance tree, bunny, {label}, packets"), |b| {
            b.iter(|| {
                tlas.closest_hits(&meshes, rays, 0.0, &tmax, &mut out);
                black_box(out.iter().filter(|h| h.is_some()).count())
            })
        });
    }
}

criterion_group!(inner_loops, triangle_test, node_test, tape_eval, traversal);
criterion_main!(inner_loops);
