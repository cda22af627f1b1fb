//! The GPU tracing core against the CPU: the field octrees' point location, leaf tapes and ray
//! walk against `FieldOctree` and `RayWalk`, the shading queries against `SceneTracer`'s, and
//! chunked dispatch independent of the chunk size. The ray queries every backend answers
//! (closest hits and shadow rays, of every shipped scene and of instanced bunnies) are in
//! tests/ray_query.rs, the SDF conformance suite on the WGSL interpreter in
//! tests/sdf_conformance.rs.
//!
//! These tests need a GPU adapter; on machines without a GPU that is Mesa's lavapipe (Debian
//! package `mesa-vulkan-drivers`). A missing adapter fails the tests, it does not skip them.
//! Figures are printed (run with `--nocapture` to see them).
#![cfg(feature = "gpu")]

mod common;
use common::gpu::ctx;
use common::rays;

use hytrace::geom::Ray;
use hytrace::gpu::GpuQuery;
use hytrace::reference::validate::{mesh_dt_tolerance, sdf_dt_tolerance};
use hytrace::rng::Rng;
use hytrace::scene::Scene;
use hytrace::trace::{SceneTracer, epsilon_at};
use std::path::PathBuf;

fn scenes_dir() -> PathBuf {
    common::root().join("assets/scenes")
}

#[test]
fn many_chunks_equal_few_chunks_bit_for_bit() {
    let scene = Scene::load(&scenes_dir().join("primitives.ron")).unwrap_or_else(|e| panic!("{e}"));
    let rays: Vec<hytrace::gpu::records::QueryRay> = common::conformance::agreement_rays(&scene, 3)
        .iter()
        .map(|r| hytrace::gpu::records::QueryRay {
            origin: r.origin.to_array(),
            tmin: 0.0,
            direction: r.direction.to_array(),
            tmax: scene.tracer.max_distance,
        })
        .collect();
    let mode = hytrace::gpu::shaders::QUERY_CLOSEST | hytrace::gpu::shaders::QUERY_OCCLUDED;
    let few = GpuQuery::new(ctx(), &scene).unwrap().with_chunk(1 << 20);
    let many = GpuQuery::new(ctx(), &scene).unwrap().with_chunk(61);
    let a = few.run(&rays, mode).unwrap();
    let b = many.run(&rays, mode).unwrap();
    assert_eq!(a.len(), rays.len());
    assert!(rays.len() > 50 * 61, "many chunks");
    assert!(
        bytemuck::cast_slice::<_, u8>(&a) == bytemuck::cast_slice::<_, u8>(&b),
        "results differ between chunk sizes"
    );
    assert!(a.iter().any(|r| r.kind != 0), "something is hit");
}

/// A smooth union of 30 capsules: its leaves' tapes are a thousand instructions long, so a
/// SIMD group of camera rays spends llvmpipe's 65,535 loop iterations per invocation (after
/// which every loop of the kernel stops at its first iteration: 3.7 % of these rays came back
/// with hits where there is nothing). The kernel tells (`loops_were_cut`), the host runs those
/// rays again alone, and what is still cut is an error: never a wrong answer.
#[test]
fn answers_the_driver_cut_short_are_run_again_or_refused() {
    let capsules: Vec<String> = (0..30)
        .map(|i| {
            let a = i as f32 * 0.3;
            format!(
                "Transform(translate: ({:.3}, {:.3}, {:.3}), shape: Capsule(a: (0, 0, 0), \
                 b: (0.3, 0.2, 0.1), radius: 0.15))",
                1.5 * a.cos(),
                -0.5 + i as f32 * 0.03,
                1.5 * a.sin()
            )
        })
        .collect();
    let src = format!(
        "Scene(camera: Perspective(position: (0, 5, 11), look_at: (0, 0.5, 0), fov: 22), \
         objects: [(shape: SmoothUnion(k: 0.25, shapes: [{}]))])",
        capsules.join(", ")
    );
    let scene = Scene::from_source(&src, std::path::Path::new("capsules.ron"))
        .unwrap_or_else(|e| panic!("{e}"));
    let cpu = SceneTracer::new(&scene);
    let (w, h) = (64u32, 48u32);
    let rays: Vec<Ray> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
            scene
                .camera
                .ray(x / w as f32, y / h as f32, w as f32 / h as f32)
        })
        .collect();
    let gpu = GpuQuery::with_tracer(ctx(), &cpu).unwrap();
    match gpu.closest_hits(&rays, 0.0, f32::INFINITY) {
        Ok(hits) => {
            let agree = rays
                .iter()
                .zip(&hits)
                .filter(|(r, g)| match (cpu.closest_hit(r, 0.0, f32::INFINITY), g) {
                    (Some(c), Some(g)) => (c.t - g.t).abs() <= 1e-3 * c.t.max(1.0),
                    (None, None) => true,
                    _ => false,
                })
                .count();
            println!(
                "{} of {} rays agree; {} run again alone",
                agree,
                rays.len(),
                gpu.rays_rerun()
            );
            assert!(agree as f64 >= 0.999 * rays.len() as f64, "{agree} agree");
        }
        Err(e) => {
            println!("refused: {e} ({} run again alone)", gpu.rays_rerun());
            assert!(matches!(e, hytrace::gpu::GpuError::LoopsCut { .. }), "{e}");
        }
    }
    // the scene does spend the budget, or this test tests nothing
    assert!(gpu.rays_rerun() > 0, "no ray was cut short");
}

/// Largest differences between the GPU's and the CPU's shading queries over some rays.
#[derive(Debug, Default)]
struct ProbeReport {
    rays: usize,
    /// Rays llvmpipe could not run even alone (its loop budget): no GPU answer.
    cut: usize,
    kind_agree: usize,
    material_max: f32,
    material_over: usize,
    exits: usize,
    exit_presence_differs: usize,
    exit_dt_over: usize,
    exit_dt_max: f32,
    visibility_max: f32,
    visibility_over: usize,
    distance_max: f32,
    distance_over: usize,
}

/// The shading queries of `scene.wgsl` (material, exit, soft visibility, distance) against
/// `SceneTracer`'s, along primary rays and shadow rays from their hits toward the lights.
fn probe(name: &str, scene: &Scene, seed: u64) -> ProbeReport {
    use hytrace::gpu::records::QueryRay;
    use hytrace::scene::Shadow;
    let cpu = SceneTracer::new(scene);
    let gpu = GpuQuery::with_tracer(ctx(), &cpu).unwrap_or_else(|e| panic!("{name}: {e}"));
    let s = &scene.tracer;
    let materials: Vec<_> = scene.materials.iter().map(|m| m.to_vec()).collect();
    let tmax = s.max_distance;
    let mut probes: Vec<(Ray, f32)> = Vec::new();
    for ray in common::conformance::agreement_rays(scene, seed) {
        probes.push((ray, tmax));
        if let Some(h) = cpu.closest_hit(&ray, 0.0, tmax) {
            let o = rays::shadow_origin(&ray, h.t, h.normal, rays::shadow_offset(scene, h.t));
            for &light in &rays::lights(scene) {
                probes.push(rays::toward(o, light));
            }
        }
    }
    let k = 8.0;
    let batch: Vec<QueryRay> = probes
        .iter()
        .map(|(r, t)| QueryRay {
            origin: r.origin.to_array(),
            tmin: 0.0,
            direction: r.direction.to_array(),
            tmax: *t,
        })
        .collect();
    let out = gpu
        .probe(&batch, k)
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    let mut r = ProbeReport::default();
    for ((ray, t1), g) in probes.iter().zip(&out) {
        r.rays += 1;
        // a ray whose own work outruns llvmpipe's loop budget has no GPU answer to compare
        if g.cut != 0 {
            r.cut += 1;
            continue;
        }
        for (shadow, gv) in [
            (Shadow::Soft(k), g.soft),
            (Shadow::SoftImproved(k), g.soft_improved),
        ] {
            let d = (cpu.visibility(ray, 0.0, *t1, shadow) - gv).abs();
            if d > 1e-3 && std::env::var_os("GPU_CORE_DEBUG").is_some() && r.visibility_over < 30 {
                println!(
                    "  {name}: {shadow:?} o {:?} d {:?} t1 {t1}: cpu {} gpu {gv}",
                    ray.origin,
                    ray.direction,
                    cpu.visibility(ray, 0.0, *t1, shadow)
                );
            }
            r.visibility_max = r.visibility_max.max(d);
            if d > 1e-3 {
                r.visibility_over += 1;
            }
        }
        let d = (cpu.distance(ray.origin, 1.0) - g.distance).abs();
        r.distance_max = r.distance_max.max(d);
        if d > 1e-5 && std::env::var_os("GPU_CORE_DEBUG").is_some() && r.distance_over < 5 {
            println!(
                "  {name}: distance at {:?}: cpu {} gpu {}",
                ray.origin,
                cpu.distance(ray.origin, 1.0),
                g.distance
            );
        }
        if d > 1e-5 {
            r.distance_over += 1;
        }
        let hit = cpu.closest_hit(ray, 0.0, *t1);
        let cpu_kind = match hit.map(|h| h.surface) {
            None => 0,
            Some(hytrace::trace::Surface::Sdf(_)) => 1,
            Some(hytrace::trace::Surface::Mesh { .. }) => 2,
        };
        if cpu_kind != g.kind {
            continue;
        }
        r.kind_agree += 1;
        let Some(h) = hit else { continue };
        let p = ray.at(h.t);
        let m = cpu.material_at(&h, p, &materials).to_vec();
        let gm: Vec<f32> = g.material.iter().flatten().copied().collect();
        let d = m
            .iter()
            .zip(&gm)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        r.material_max = r.material_max.max(d);
        if d > 1e-3 {
            r.material_over += 1;
        }
        let inside = Ray {
            origin: p + ray.direction * (4.0 * epsilon_at(s, h.t)),
            direction: ray.direction,
        };
        let exit = cpu.exit(h.surface, &inside, *t1);
        let gpu_exit = (g.exit[0] >= 0.0).then_some(g.exit[0]);
        r.exits += 1;
        match (exit, gpu_exit) {
            (Some((t, _)), Some(gt)) => {
                let d = (t - gt).abs();
                r.exit_dt_max = r.exit_dt_max.max(d);
                // An exit is marched from inside as a hit from outside is, so twice the
                // library's head-on tolerance (ten times its triangle one on meshes).
                let diameter = rays::bounds(scene).diagonal();
                let tol =
                    2.0 * sdf_dt_tolerance(s, t, 1.0, 0.0).max(10.0 * mesh_dt_tolerance(diameter));
                if d > tol {
                    r.exit_dt_over += 1;
                }
            }
            (None, None) => {}
            _ => r.exit_presence_differs += 1,
        }
    }
    println!(
        "{name:<12} probes {:>5} (cut by the driver {}) kind agree {:>5}  material max |d| {:.2e} (over {})  exits {} \
         (presence differs {}, |dt| max {:.2e}, over {})  soft visibility max |d| {:.2e} \
         (over {})  distance max |d| {:.2e} (over {})",
        r.rays,
        r.cut,
        r.kind_agree,
        r.material_max,
        r.material_over,
        r.exits,
        r.exit_presence_differs,
        r.exit_dt_max,
        r.exit_dt_over,
        r.visibility_max,
        r.visibility_over,
        r.distance_max,
        r.distance_over
    );
    r
}

/// The shading queries on the scenes with soft shadows, blended materials, textures and
/// refraction.
#[test]
fn shading_queries_agree_with_the_cpu() {
    shading_queries_on(&["shadows.ron", "smooth.ron", "hybrid.ron"]);
}

/// glass.ron, apart: its rays grazing the checkerboard floor march hundreds of steps, and a
/// probe that shared a SIMD group with one of them used to read wrong (21 of 9,484 soft
/// visibilities): llvmpipe ends every loop of an invocation once its SIMD group has spent
/// 65,535 iterations. The kernel now tells when that happened (`loops_were_cut`) and the
/// host probes those rays again one by one.
#[test]
fn shading_queries_agree_with_the_cpu_on_glass() {
    shading_queries_on(&["glass.ron"]);
}

fn shading_queries_on(files: &[&str]) {
    let mut failures = Vec::new();
    for (k, file) in files.iter().enumerate() {
        let scene = Scene::load(&scenes_dir().join(file)).unwrap_or_else(|e| panic!("{e}"));
        let r = probe(file, &scene, 40 + k as u64);
        let limit = |n: usize| n as f64 <= 0.001 * r.rays as f64;
        let mut why = Vec::new();
        if !limit(r.cut) {
            why.push("rays the driver cut short");
        }
        if (r.kind_agree as f64) < 0.999 * (r.rays - r.cut) as f64 {
            why.push("hit kinds");
        }
        if !limit(r.material_over) {
            why.push("materials");
        }
        if !limit(r.exit_presence_differs + r.exit_dt_over) {
            why.push("exits");
        }
        if !limit(r.visibility_over) {
            why.push("soft visibility");
        }
        if !limit(r.distance_over) {
            why.push("distance");
        }
        if !why.is_empty() {
            failures.push(format!("{file}: {}", why.join(", ")));
        }
    }
    assert!(
        failures.is_empty(),
        "disagreements: {}",
        failures.join("; ")
    );
}

/// What the field probe kernel and the CPU agree on over one object's rays.
#[derive(Debug, Default)]
struct FieldReport {
    rays: usize,
    /// Origins inside the octree's box.
    inside: usize,
    leaf_agree: usize,
    value_over: usize,
    value_max: f32,
    walk_agree: usize,
    /// Leaves met, summed over the rays (the CPU's walk).
    leaves_met: usize,
    /// Rays whose walk meets a leaf that is not empty.
    surface_rays: usize,
}

/// Origins in and around the octree's box (a fifth outside it), with random directions; a
/// tenth have a zero direction component (the walk's TINY_DIRECTION), some a later tmin or
/// an earlier tmax.
fn field_rays(tree: &hytrace::accel::field::FieldOctree, seed: u64) -> Vec<(Ray, f32, f32)> {
    let b = tree.bounds();
    let size = b.max - b.min;
    let diag = size.length();
    let mut rng = Rng::new(seed);
    (0..1500)
        .map(|i| {
            let o = if i % 5 == 4 {
                rng.in_box(b.min - 0.25 * size, b.max + 0.25 * size)
            } else {
                rng.in_box(b.min, b.max)
            };
            let mut d = rng.direction();
            if i % 10 == 3 {
                d[rng.below(3) as usize] = 0.0;
            }
            let (tmin, tmax) = match i % 4 {
                0 => (0.0, rng.range_f32(0.0, diag)),
                1 => (rng.range_f32(0.0, 0.5 * diag), 3.0 * diag),
                _ => (0.0, 3.0 * diag),
            };
            (Ray::new(o, d), tmin, tmax)
        })
        .collect()
}

/// The field probe of object `object` over `rays` against the CPU: the leaf holding each
/// origin, the field there (the leaf's tape, or the whole one outside the box) and the
/// leaves the walk meets in order (with the first that is not empty and its parameters).
fn field_report(
    gpu: &GpuQuery,
    source: Option<&str>,
    fields: &[hytrace::accel::field::ObjectField],
    object: usize,
    rays: &[(Ray, f32, f32)],
) -> FieldReport {
    use hytrace::accel::field::{Leaf, RayWalk, WalkStack};
    use hytrace::gpu::records::{FIELD_PROBE_LEAVES, NONE, QueryRay};
    use hytrace::sdf::simplify::Verdict;
    let field = &fields[object];
    let tree = field.octree.as_ref().expect("an octree");
    // the GPU's leaf buffer holds the objects' leaves one octree after the other
    let base: usize = fields[..object]
        .iter()
        .filter_map(|f| f.octree.as_ref())
        .map(|t| t.leaves().len())
        .sum();
    let index = |l: &Leaf| {
        (base + (l as *const Leaf as usize - tree.leaves().as_ptr() as usize) / size_of::<Leaf>())
            as u32
    };
    let batch: Vec<QueryRay> = rays
        .iter()
        .map(|(r, tmin, tmax)| QueryRay {
            origin: r.origin.to_array(),
            tmin: *tmin,
            direction: r.direction.to_array(),
            tmax: *tmax,
        })
        .collect();
    let out = match source {
        Some(src) => gpu.field_probe_source(src, &batch, object as u32),
        None => gpu.field_probe(&batch, object as u32),
    }
    .unwrap_or_else(|e| panic!("{e}"));
    let mut regs = hytrace::sdf::tape::Registers::new();
    let mut r = FieldReport::default();
    for ((ray, tmin, tmax), g) in rays.iter().zip(&out) {
        r.rays += 1;
        let o = ray.origin;
        let cell = tree.locate(o);
        r.inside += cell.is_some() as usize;
        if cell.map_or(NONE, |c| index(c.leaf)) == g.leaf {
            r.leaf_agree += 1;
        }
        let tape = cell.map_or(&field.whole, |c| c.tape);
        let v = tape.eval_in(o, &mut regs);
        let dv = (v - g.value).abs();
        r.value_max = r.value_max.max(dv);
        if dv > 1e-4 * v.abs().max(1.0) {
            r.value_over += 1;
        }
        let mut stack = WalkStack::new();
        let mut walk = RayWalk::new(tree, ray, *tmin, *tmax, &mut stack);
        let mut leaves = Vec::new();
        let mut first = None;
        while let Some(x) = walk.next_leaf() {
            leaves.push(index(x.leaf));
            if first.is_none() && x.leaf.verdict != Verdict::Empty {
                first = Some((index(x.leaf), x.enter, x.exit));
            }
        }
        r.leaves_met += leaves.len();
        r.surface_rays += first.is_some() as usize;
        let recorded: Vec<u32> = g.leaves.iter().flatten().copied().collect();
        let n = leaves.len().min(FIELD_PROBE_LEAVES as usize);
        let close = |a: f32, b: f32| (a - b).abs() <= 1e-5 * a.abs().max(1.0);
        let same_first = match first {
            None => g.first_surface == NONE,
            Some((leaf, enter, exit)) => {
                leaf == g.first_surface && close(enter, g.first_enter) && close(exit, g.first_exit)
            }
        };
        if g.count as usize == leaves.len() && recorded[..n] == leaves[..n] && same_first {
            r.walk_agree += 1;
        } else if std::env::var_os("GPU_CORE_DEBUG").is_some() {
            println!(
                "  walk differs: {ray:?} [{tmin}, {tmax}]: cpu {} leaves {:?} first {first:?}, \
                 gpu {} leaves {:?} first {} [{}, {}]",
                leaves.len(),
                &leaves[..n.min(8)],
                g.count,
                &recorded[..n.min(8)],
                g.first_surface,
                g.first_enter,
                g.first_exit
            );
        }
    }
    r
}

/// Every shipped object with a field octree: the GPU locates the same leaf as
/// `FieldOctree::locate` at points in and around its box, evaluates the same field there (the
/// leaf's tape inside, the whole tape outside, within f32 tolerance), and its walk meets the
/// same leaves in the same order as `RayWalk`, with the same first non-empty leaf and slab
/// parameters. Then the same comparison with deliberately broken walks (mirroring ignored;
/// the nearest exit plane taken as the farthest) must fail, so the test can.
#[test]
fn field_octrees_locate_evaluate_and_walk_as_on_the_cpu() {
    let files = common::conformance::shipped_scenes();
    let mut failures = Vec::new();
    let mut objects = 0;
    // one object, kept for the broken walks
    let mut sample: Option<(Scene, usize)> = None;
    for path in &files {
        let name = path.file_stem().unwrap().to_string_lossy().to_string();
        let scene = Scene::load(path).unwrap_or_else(|e| panic!("{e}"));
        let cpu = SceneTracer::new(&scene);
        let gpu = GpuQuery::with_tracer(ctx(), &cpu).unwrap_or_else(|e| panic!("{name}: {e}"));
        for (i, field) in cpu.fields().iter().enumerate() {
            let Some(tree) = &field.octree else { continue };
            objects += 1;
            let rays = field_rays(tree, 1000 + objects as u64);
            let r = field_report(&gpu, None, cpu.fields(), i, &rays);
            println!(
                "{name:<14} object {i}: {} leaves, rays {} (origins inside {}), leaf agree {}, \
                 value max |d| {:.2e} (over {}), walks agree {} (leaves met {}, rays reaching \
                 a non-empty leaf {})",
                tree.leaves().len(),
                r.rays,
                r.inside,
                r.leaf_agree,
                r.value_max,
                r.value_over,
                r.walk_agree,
                r.leaves_met,
                r.surface_rays
            );
            let allowed = r.rays / 1000;
            if r.rays - r.leaf_agree > allowed
                || r.value_over > allowed
                || r.rays - r.walk_agree > allowed
            {
                failures.push(format!("{name} object {i}: {r:?}"));
            }
            if sample.is_none() && tree.leaves().len() > 64 && r.surface_rays > r.rays / 4 {
                sample = Some((scene.clone(), i));
            }
        }
    }
    assert!(
        objects >= 3,
        "only {objects} shipped objects have an octree"
    );
    assert!(failures.is_empty(), "{}", failures.join("\n"));

    let (scene, i) = sample.expect("a shipped object with a deep octree");
    let cpu = SceneTracer::new(&scene);
    let gpu = GpuQuery::with_tracer(ctx(), &cpu).unwrap();
    let rays = field_rays(cpu.fields()[i].octree.as_ref().unwrap(), 5);
    let source = hytrace::gpu::shaders::FIELD_PROBE_KERNEL.module();
    for (what, from, to) in [
        (
            "mirroring ignored",
            "field_nodes[f.node + (c ^ field_walk.mirror)]",
            "field_nodes[f.node + c]",
        ),
        (
            "the farthest exit plane",
            "if ct1.x <= ct1.y && ct1.x <= ct1.z {",
            "if ct1.x >= ct1.y && ct1.x >= ct1.z {",
        ),
    ] {
        assert_eq!(source.matches(from).count(), 1, "{what}: `{from}`");
        let broken = source.replace(from, to);
        let r = field_report(&gpu, Some(&broken), cpu.fields(), i, &rays);
        println!(
            "broken walk ({what}): walks agree {} of {}",
            r.walk_agree, r.rays
        );
        assert!(
            r.walk_agree < r.rays * 9 / 10,
            "a broken walk ({what}) went unnoticed: {r:?}"
        );
    }
}

/// A context compiles a module's pipeline once: a second request for the same text and entry
/// point gets the same pipeline and layouts, another text or entry point its own, and a
/// module the device rejects fails on every request, naming it.
#[test]
fn pipelines_are_compiled_once_per_context() {
    let ctx = ctx();
    let source = "@group(0) @binding(0) var<storage, read_write> out: array<u32>;
        @compute @workgroup_size(1) fn first() { out[0] = 1u; }
        @compute @workgroup_size(1) fn second() { out[0] = 2u; }";
    let layouts = || {
        vec![
            ctx.device
                .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                    label: Some("one output"),
                    entries: &[wgpu::BindGroupLayoutEntry {
                        binding: 0,
                        visibility: wgpu::ShaderStages::COMPUTE,
                        ty: wgpu::BindingType::Buffer {
                            ty: wgpu::BufferBindingType::Storage { read_only: false },
                            has_dynamic_offset: false,
                            min_binding_size: None,
                        },
                        count: None,
                    }],
                }),
        ]
    };
    let get = |source: &str, entry: &str| ctx.compute_pipeline("tiny", source, entry, layouts);
    let a = get(source, "first").unwrap_or_else(|e| panic!("{e}"));
    let again = get(source, "first").unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(a.pipeline, again.pipeline, "the same pipeline twice");
    assert_eq!(
        a.layouts, again.layouts,
        "with the layouts it was made with"
    );
    // a clone of the context shares its pipelines
    let clone = ctx.clone();
    let b = clone
        .compute_pipeline("tiny", source, "first", layouts)
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(a.pipeline, b.pipeline);
    let other_entry = get(source, "second").unwrap_or_else(|e| panic!("{e}"));
    assert_ne!(a.pipeline, other_entry.pipeline);
    let other_text = get(&source.replace("1u;", "3u;"), "first").unwrap_or_else(|e| panic!("{e}"));
    assert_ne!(a.pipeline, other_text.pipeline);
    let broken = source.replace("out[0] = 1u;", "out[0] = undefined_name;");
    for _ in 0..2 {
        let e = get(&broken, "first").expect_err("a module that does not validate");
        assert!(
            matches!(e, hytrace::gpu::GpuError::Shader { ref name, .. } if name == "tiny"),
            "{e}"
        );
    }
}
