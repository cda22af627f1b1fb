//! The ray-query checks (`tests/common/conformance.rs`) on every backend of
//! [`RayQuery`](hytrace::trace::query::RayQuery): the CPU tracer, the GPU tracer (feature
//! `gpu`; on machines without a GPU, Mesa's lavapipe) and Embree 4 (feature `embree`). Each
//! meets the same closed-form hits, misses and shadow rays; the GPU and Embree are also
//! compared ray by ray with the CPU tracer on scenes and on the shared assets' bunnies.
//!
//! Figures are printed (run with `--nocapture` to see them; `RAY_QUERY_DEBUG=1` prints the
//! disagreeing rays).

#[macro_use]
mod common;

use hytrace::scene::Scene;
use hytrace::trace::SceneTracer;
use hytrace::trace::query::RayQuery;

fn cpu<'a>(tracer: &'a SceneTracer<'a>) -> Box<dyn RayQuery + 'a> {
    Box::new(SceneTracer::new(tracer.scene()))
}

ray_query_conformance!(cpu => cpu);

#[cfg(feature = "gpu")]
fn gpu<'a>(tracer: &'a SceneTracer<'a>) -> Box<dyn RayQuery + 'a> {
    Box::new(
        hytrace::gpu::GpuQuery::with_tracer(common::gpu::ctx(), tracer)
            .unwrap_or_else(|e| panic!("{e}")),
    )
}

/// A scene of primitives with closed forms (which Embree intersects exactly, not as meshes)
/// under transforms, on a ground plane.
#[cfg(feature = "embree")]
fn closed_forms() -> (String, Scene) {
    let src = "Scene(
        image: (width: 64, height: 48),
        camera: Perspective(position: (1.5, 3, 7), look_at: (0, 0, 0), fov: 45),
        lights: [Point(position: (3, 6, 4), intensity: 20), Directional(direction: (0.3, -1, 0.2), intensity: 0.8)],
        objects: [
            (shape: Sphere(radius: 0.8), translate: (-1.5, 0.2, 0)),
            (shape: Box(half_extents: (0.6, 0.4, 0.5)), rotate: (20, 35, -10), translate: (1.4, 0, 0.3)),
            (shape: Torus(major: 0.8, minor: 0.25), rotate: (60, 20, 0), translate: (0, 0.3, -1.5)),
            (shape: Cylinder(half_height: 0.6, radius: 0.4), rotate: (0, 30, 40), translate: (0, 0, 1.5)),
            (shape: Plane(normal: (0, 1, 0), offset: -1)),
        ],
        tracer: (epsilon: 1e-4, epsilon_per_unit: 1e-4, max_distance: 60, max_steps: 2048),
    )";
    let scene = Scene::from_source(src, std::path::Path::new("closed-forms.ron"))
        .unwrap_or_else(|e| panic!("{e}"));
    ("closed forms".to_string(), scene)
}

/// Every shipped scene by file name (its primitives scene holds the closed forms; another
/// scene would lengthen the GPU's run on lavapipe for nothing new).
#[cfg(feature = "gpu")]
fn shipped() -> Vec<(String, Scene)> {
    common::conformance::shipped_scenes()
        .iter()
        .map(|p| {
            let name = p.file_stem().unwrap().to_string_lossy().into_owned();
            (name, Scene::load(p).unwrap_or_else(|e| panic!("{e}")))
        })
        .collect()
}

#[cfg(feature = "gpu")]
ray_query_conformance!(gpu => gpu, agrees_with_cpu: shipped());

#[cfg(feature = "embree")]
fn embree<'a>(tracer: &'a SceneTracer<'a>) -> Box<dyn RayQuery + 'a> {
    let e = hytrace::reference::embree::EmbreeScene::build(tracer.scene())
        .unwrap_or_else(|e| panic!("{e}"));
    assert!(e.skipped().is_empty(), "Embree skipped {:?}", e.skipped());
    Box::new(e)
}

// Embree meets the shipped scenes' composite objects as meshes, whose comparison needs the
// excuses of tests/embree_reference.rs; here it meets the closed forms and the bunnies.
#[cfg(feature = "embree")]
ray_query_conformance!(embree => embree, agrees_with_cpu: vec![closed_forms()]);
