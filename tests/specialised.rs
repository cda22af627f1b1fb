//! Rendering with region-specialised tapes (the default) against rendering with every object's
//! whole tape, on every shipped scene: the same hits up to where in the ε band each march
//! stops, the same pictures where the hits are the same; and trees far too large for a tape
//! are refused with a message, not a crash.

use glam::Vec3;
use hytrace::render::{Framebuffer, RenderOptions, cpu};
use hytrace::scene::{Scene, scene_files};
use hytrace::trace::{AccelOptions, SceneTracer, epsilon_at};
use std::path::Path;

fn render(scene: &Scene, options: AccelOptions, w: u32, h: u32) -> Framebuffer {
    let tracer = SceneTracer::with_options(scene, options);
    let opts = RenderOptions::single_sample(w, h);
    cpu::render_with(&tracer, &opts).unwrap()
}

/// Whether the scene's field along the camera ray through pixel (x, y) comes within ε of a
/// surface near t without crossing it deeper than ε (a silhouette or a sliver: one march may
/// sample that stretch inside the band, the other step over it).
fn grazes(scene: &Scene, x: u32, y: u32, w: u32, h: u32, t: f32) -> bool {
    let ray = scene.camera.ray(
        (x as f32 + 0.5) / w as f32,
        (y as f32 + 0.5) / h as f32,
        w as f32 / h as f32,
    );
    let e = epsilon_at(&scene.tracer, t);
    let field = |p: Vec3| {
        scene
            .objects
            .iter()
            .map(|o| o.lowered.distance.eval(p))
            .fold(f32::INFINITY, f32::min)
    };
    (0..=200)
        .map(|k| field(ray.at(t - 4.0 * e + 16.0 * e * k as f32 / 200.0)))
        .all(|f| f > -2.0 * e)
}

#[test]
fn shipped_scenes_render_as_with_whole_tapes() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/scenes");
    for file in scene_files(&dir).unwrap() {
        let scene = Scene::load(&file).unwrap_or_else(|e| panic!("{e}"));
        let (w, h) = (96, 72);
        let fast = render(&scene, AccelOptions::default(), w, h);
        let whole = render(
            &scene,
            AccelOptions {
                specialise: false,
                packets: false,
                ..Default::default()
            },
            w,
            h,
        );
        let name = file.file_stem().unwrap().to_string_lossy();
        let (mut identical, mut same_hit, mut grazing) = (0usize, 0usize, 0usize);
        for i in 0..(w * h) as usize {
            let (a, b) = (fast.depth[i], whole.depth[i]);
            if fast.pixels[i] == whole.pixels[i] && a.to_bits() == b.to_bits() {
                identical += 1;
                continue;
            }
            let (x, y) = (i as u32 % w, i as u32 / w);
            if a.is_finite() && b.is_finite() {
                // both hit: within the ε band of the surface, as far as the normal allows
                let cos = fast.normal[i]
                    .normalize_or_zero()
                    .dot(
                        scene
                            .camera
                            .ray(
                                (x as f32 + 0.5) / w as f32,
                                (y as f32 + 0.5) / h as f32,
                                w as f32 / h as f32,
                            )
                            .direction,
                    )
                    .abs()
                    .max(0.01);
                let band = (epsilon_at(&scene.tracer, a) + epsilon_at(&scene.tracer, b)) / cos;
                if (a - b).abs() <= band {
                    same_hit += 1;
                    continue;
                }
            }
            let t = if a.is_finite() { a } else { b };
            assert!(
                t.is_finite() && grazes(&scene, x, y, w, h, a.min(b)),
                "{name} pixel ({x}, {y}): depth {a} vs whole-tape {b}, not a grazing ray"
            );
            grazing += 1;
        }
        let n = (w * h) as usize;
        println!(
            "{name}: {identical} of {n} pixels identical, {same_hit} on the same hit in the ε band, \
             {grazing} grazing"
        );
        // the marches differ only in where they stop inside the band: most pixels agree to the
        // bit, and the others shade the same surface point to within the band
        assert!(
            grazing * 200 <= n,
            "{name}: {grazing} grazing disagreements of {n}"
        );
        let mean_difference: f32 = fast
            .pixels
            .iter()
            .zip(&whole.pixels)
            .map(|(a, b)| (*a - *b).abs().max_element())
            .sum::<f32>()
            / n as f32;
        assert!(
            mean_difference < 2e-3,
            "{name}: mean radiance difference {mean_difference}"
        );
    }
}

/// A scene of one object, the union of `shapes`, seen along −z by an orthographic camera of
/// the given height; `material` is empty or the object's `material: "glass", ` (a
/// transparent material, which keeps the union one field).
fn one_union(shapes: &[String], height: f32, material: &str, file: &str) -> Scene {
    let src = format!(
        "Scene(camera: Orthographic(position: (0, 0, 3), look_at: (0, 0, 0), height: {height}),
               materials: {{ \"glass\": (transparency: 0.5) }},
               objects: [({material}shape: Union([{}]))])",
        shapes.join(", ")
    );
    Scene::from_source(&src, Path::new(file)).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn huge_and_exploding_trees_render_or_are_refused_with_the_limit() {
    // 100,000 spheres in one union: lowered as a balanced tree, it fits (a few live values per
    // level); it loads, builds its octrees within the memory bound, and renders (a few pixels:
    // so dense a union is not pruned by intervals over boxes wider than its spacing, and each
    // sample evaluates long tapes).
    let mut shapes = Vec::with_capacity(100_000);
    for i in 0..100_000 {
        let (x, y, z) = (
            (i % 100) as f32,
            ((i / 100) % 100) as f32,
            (i / 10_000) as f32,
        );
        shapes.push(format!(
            "Transform(translate: ({}, {}, {}), shape: Sphere(radius: 0.004))",
            x * 0.01 - 0.5,
            y * 0.01 - 0.5,
            z * 0.01 - 0.05
        ));
    }
    // Opaque, the union is traced as groups of neighbouring spheres; transparent, it stays one
    // field, whose octree is held to its memory bound.
    for material in ["", "material: \"glass\", "] {
        let scene = one_union(&shapes, 1.2, material, "many.ron");
        assert_eq!(scene.sdf_object_count(), 1);
        let parts = scene.objects.len();
        if material.is_empty() {
            assert!(
                (2..=hytrace::sdf::parts::MAX_PARTS).contains(&parts),
                "{parts}"
            );
        } else {
            assert_eq!(parts, 1);
        }
        let tracer = SceneTracer::new(&scene);
        let bytes: usize = (tracer.fields().iter())
            .map(|f| f.octree.as_ref().map_or(0, |t| t.stats().bytes))
            .sum();
        assert!(
            bytes < 200 << 20,
            "{bytes} bytes of octrees in {parts} parts"
        );
        let fb = cpu::render_with(&tracer, &RenderOptions::single_sample(8, 8)).unwrap();
        assert_eq!(fb.depth.len(), 64);
        let centre = scene.camera.ray(0.5, 0.5, 1.0);
        assert!(tracer.closest_hit(&centre, 0.0, f32::INFINITY).is_some());
    }
    // Repetition nested twelve deep would copy its sphere 8¹² times: refused at the node where
    // the program outgrows its limit, naming the file and the limit, with no memory blow-up.
    let mut node = "Sphere(radius: 0.1)".to_string();
    for level in 0..12 {
        let period = 0.5 * 3f32.powi(level);
        node = format!(
            "RepeatLimited(period: ({period}, {period}, {period}), copies_each_side: (1, 1, 1), shape: {node})"
        );
    }
    let src = format!(
        "Scene(camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0), fov: 40),
               objects: [(shape: {node})])"
    );
    let msg = match Scene::from_source(&src, Path::new("nested.ron")) {
        Ok(_) => panic!("twelve nested repetitions should be refused"),
        Err(e) => e.to_string(),
    };
    assert!(
        msg.contains("nested.ron") && msg.contains("too complex") && msg.contains("operations"),
        "{msg}"
    );
}

#[test]
fn the_parts_of_a_split_union_share_the_object_s_budget_of_tapes() {
    // 20,000 boxes in 90 orientations under the object's rotation: a thousand parts of 20
    // boxes, each part's tape some 500 instructions. Each part gets a thousandth of the
    // object's budget; the octree's top levels, split whatever their children gain, used to
    // store 64 tapes per part regardless (346 MiB here, 1.5 GB for 100,000 boxes).
    let shapes: Vec<String> = (0..20_000)
        .map(|i| {
            let h = |k: u32| ((i as u32).wrapping_mul(2_654_435_761).rotate_left(k) % 1000) as f32;
            format!(
                "Transform(translate: ({}, {}, {}), rotate: ({}, {}, 0), \
                 shape: Box(half_extents: (0.02, 0.015, 0.025)))",
                h(0) * 0.008 - 4.0,
                h(11) * 0.003 - 0.8,
                h(22) * 0.006 - 4.0,
                i % 90,
                i % 45
            )
        })
        .collect();
    let src = format!(
        "Scene(camera: Perspective(position: (0, 5, 11), look_at: (0, 0.5, 0), fov: 45),
               objects: [(rotate: (0, 20, 0), scale: 0.9, shape: Union([{}]))])",
        shapes.join(", ")
    );
    let scene =
        Scene::from_source(&src, Path::new("orientations.ron")).unwrap_or_else(|e| panic!("{e}"));
    assert!(scene.objects.len() > 500, "{} parts", scene.objects.len());
    let tracer = SceneTracer::new(&scene);
    let bytes: usize = (tracer.fields().iter())
        .map(|f| f.octree.as_ref().map_or(0, |t| t.stats().bytes))
        .sum();
    // the object's budget: MAX_INSTRUCTIONS of 8 bytes
    let budget = hytrace::accel::field::MAX_INSTRUCTIONS * 8;
    assert!(bytes <= budget, "{bytes} bytes of octrees, budget {budget}");
    let fb = cpu::render_with(&tracer, &RenderOptions::single_sample(16, 12)).unwrap();
    assert!(fb.depth.iter().any(|d| d.is_finite()), "something is hit");
}

#[test]
fn a_union_of_thousands_of_translated_boxes_fits_in_registers_and_traces_right() {
    // 60 × 40 boxes tiling [-0.9, 0.9]², row by row, of 97 different depths: the column
    // offsets x − cᵢ and the depth terms |z| − hₖ are shared across the union, so without
    // recomputing them near their readers more than the tape's 256 registers would be alive
    // at once.
    let (nx, ny) = (60, 40);
    let (wx, wy) = (1.8 / nx as f32, 1.8 / ny as f32);
    let depth = |i: usize, j: usize| 0.05 + 0.001 * ((i * 7919 + j * 104_729) % 97) as f32;
    let mut shapes = Vec::new();
    for j in 0..ny {
        for i in 0..nx {
            shapes.push(format!(
                "Transform(translate: ({}, {}, 0), shape: Box(half_extents: ({}, {}, {})))",
                -0.9 + (i as f32 + 0.5) * wx,
                -0.9 + (j as f32 + 0.5) * wy,
                0.5 * wx,
                0.5 * wy,
                depth(i, j)
            ));
        }
    }
    // transparent, the union is one tape (the case of the registers); opaque, its parts
    for material in ["material: \"glass\", ", ""] {
        let scene = one_union(&shapes, 2.0, material, "tiles.ron");
        assert_eq!(scene.objects.len() == 1, !material.is_empty());
        traces_tiles_right(&scene, wx, wy, &depth);
    }
}

/// Camera rays onto the tiles of [`a_union_of_thousands_of_translated_boxes_fits_in_registers_and_traces_right`]
/// hit the top of the tile below them.
fn traces_tiles_right(scene: &Scene, wx: f32, wy: f32, depth: &dyn Fn(usize, usize) -> f32) {
    let tracer = SceneTracer::new(scene);
    for k in 0..400 {
        // off the tiles' edges, where the taller neighbour may be hit first
        let (u, v) = (
            ((k % 20) as f32 + 0.37) / 20.0,
            ((k / 20) as f32 + 0.41) / 20.0,
        );
        let ray = scene.camera.ray(u, v, 1.0);
        let o = ray.origin;
        let inside = o.x.abs() < 0.9 && o.y.abs() < 0.9;
        let hit = tracer.closest_hit(&ray, 0.0, f32::INFINITY);
        match hit {
            Some(h) if inside => {
                let (i, j) = (((o.x + 0.9) / wx) as usize, ((o.y + 0.9) / wy) as usize);
                let top = 3.0 - depth(i, j);
                assert!((h.t - top).abs() < 1e-3, "{k}: {} for {top}", h.t);
            }
            None if !inside => {}
            other => panic!("{k} at {:?}: {:?}", ray.origin, other.map(|h| h.t)),
        }
    }
}

#[test]
fn forty_thousand_small_objects_share_their_native_code_and_render_as_interpreted() {
    // Compiled object by object, each object's tapes took two executable buffers of their own,
    // at least a page each (200,000 such objects held 2.1 GB, and the build spent most of its
    // time in `mprotect`). Compiled together, they share a few buffers.
    let objects: Vec<String> = (0..40_000)
        .map(|i| {
            let (x, y) = ((i % 200) as f32 * 0.05 - 5.0, (i / 200) as f32 * 0.05 - 5.0);
            format!("(translate: ({x}, {y}, 0), shape: Sphere(radius: 0.02))")
        })
        .collect();
    let src = format!(
        "Scene(camera: Orthographic(position: (0, 0, 3), look_at: (0, 0, 0), height: 10.5),
               objects: [{}])",
        objects.join(", ")
    );
    let scene = Scene::from_source(&src, Path::new("many.ron")).unwrap_or_else(|e| panic!("{e}"));
    let fields = hytrace::trace::build_fields(&scene, true, true);
    if hytrace::sdf::jit::available() {
        let mut regs = hytrace::sdf::tape::Registers::new();
        let buffers: Option<std::collections::HashSet<usize>> = fields
            .iter()
            .map(|f| {
                let code = f.cursor(&mut regs).whole_tape().native_code();
                code.map(|n| n.buffer_address())
            })
            .collect();
        let buffers = buffers.expect("every object's tape has native code");
        assert!(
            buffers.len() < 100,
            "{} executable buffers for 40,000 objects",
            buffers.len()
        );
    }
    drop(fields);
    let native = render(&scene, AccelOptions::default(), 96, 96);
    let interpreted = render(
        &scene,
        AccelOptions {
            native: false,
            ..Default::default()
        },
        96,
        96,
    );
    assert!(
        native.pixels == interpreted.pixels,
        "native and interpreted renders differ"
    );
    assert!(
        native.pixels.iter().any(|c| *c != native.pixels[0]),
        "the spheres are not in the picture"
    );
}

#[test]
fn a_scene_of_many_small_csg_objects_keeps_only_the_trees_its_march_walks() {
    use hytrace::scene::generate::{Shapes, many_objects_of};
    // 3,000 such objects built 1.9 M nodes and held 570 MiB of leaf tapes and native code
    // that Hart's march never walked; a scene of few keeps them for its point evaluations
    let scene = Scene::from_source(&many_objects_of(400, Shapes::Csg), Path::new("csg.ron"))
        .unwrap_or_else(|e| panic!("{e}"));
    let fields = hytrace::trace::build_fields(&scene, true, false);
    let trees: Vec<_> = fields.iter().filter_map(|f| f.octree.as_ref()).collect();
    let whole = trees.iter().filter(|t| t.marched_whole()).count();
    assert!(whole > 300, "{whole} trees marched whole");
    for t in &trees {
        assert!(
            !t.marched_whole() || t.stats().nodes == 1,
            "a tree marched whole kept {:?}",
            t.stats()
        );
    }
    let few = Scene::from_source(&many_objects_of(40, Shapes::Csg), Path::new("csg.ron"))
        .unwrap_or_else(|e| panic!("{e}"));
    let fields = hytrace::trace::build_fields(&few, true, false);
    assert!(
        fields
            .iter()
            .filter_map(|f| f.octree.as_ref())
            .any(|t| t.marched_whole() && t.stats().nodes > 73),
        "a scene of 40 keeps the trees its march takes whole"
    );
    // the same pictures as with every object's whole tape
    let (w, h) = (64, 48);
    let lean = render(&scene, AccelOptions::default(), w, h);
    let whole = render(
        &scene,
        AccelOptions {
            specialise: false,
            ..Default::default()
        },
        w,
        h,
    );
    assert_eq!(lean.pixels, whole.pixels);
}
