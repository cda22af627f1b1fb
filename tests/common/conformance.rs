//! Conformance suites written once and instantiated per implementation, as fidget's test
//! macros are: [`sdf_conformance!`] makes one `#[test]` per (SDF case, evaluator) and
//! [`ray_query_conformance!`] one per (ray-query check, backend), so a failure names both.

use super::rays::{self, LightAt};
use hytrace::geom::Ray;
use hytrace::reference::validate::{mesh_dt_tolerance, sdf_dt_tolerance};
use hytrace::scene::Scene;
use hytrace::sdf::conformance::{CASES, Evaluator, check_case};
use hytrace::trace::SceneTracer;
use hytrace::trace::query::{ObjectId, QueryHit, RayQuery};
use std::path::Path;

/// Runs the conformance checks of the catalogue case named `name` on `ev`.
pub fn run_case<E: Evaluator>(ev: &E, name: &str) {
    let k = CASES
        .iter()
        .position(|c| c.name == name)
        .unwrap_or_else(|| panic!("no conformance case named `{name}`"));
    if let Err(e) = check_case(ev, k) {
        panic!("{e}");
    }
}

/// Asserts that `names` (a macro's case list) are exactly the catalogue's cases, so that a
/// case added to [`CASES`] cannot go untested.
pub fn assert_every_case_listed(names: &[&str]) {
    let mut listed: Vec<&str> = names.to_vec();
    let mut catalogue: Vec<&str> = CASES.iter().map(|c| c.name).collect();
    listed.sort_unstable();
    catalogue.sort_unstable();
    assert_eq!(listed, catalogue, "sdf_conformance! must list every case");
}

/// One `#[test]` per catalogue case ([`hytrace::sdf::conformance::CASES`]) on one evaluator,
/// in a module named after the evaluator: `sdf_conformance!(scalar => CpuEvaluator)` makes
/// `scalar::sphere`, `scalar::torus`, … The evaluator expression is evaluated in each test.
macro_rules! sdf_conformance {
    ($evaluator:ident => $make:expr) => {
        sdf_conformance!(@cases $evaluator => $make;
            sphere = "sphere",
            box_ = "box",
            round_box = "round box",
            plane = "plane",
            torus = "torus",
            cylinder = "cylinder",
            cone = "cone",
            pointed_cone = "pointed cone",
            capsule = "capsule",
            ellipsoid = "ellipsoid",
            octahedron = "octahedron",
            hex_prism = "hex prism",
            union = "union",
            intersection = "intersection",
            subtraction = "subtraction",
            smooth_union = "smooth union",
            smooth_intersection = "smooth intersection",
            smooth_subtraction = "smooth subtraction",
            round = "round",
            onion = "onion",
            transform = "transform",
            non_uniform_scale = "non-uniform scale",
            repeat = "repeat",
            repeat_limited = "repeat limited",
            twist = "twist",
            bend = "bend",
            implicit_sphere = "implicit sphere",
            implicit_squircle = "implicit squircle",
            implicit_gyroid = "implicit gyroid",
            implicit_given_lipschitz = "implicit given lipschitz",
        );
    };
    (@cases $evaluator:ident => $make:expr; $($case:ident = $name:literal),* $(,)?) => {
        mod $evaluator {
            #[allow(unused_imports)]
            use super::*;

            /// The cases this module tests, by catalogue name (one module's are checked
            /// against the catalogue).
            #[allow(dead_code)]
            pub const CASE_NAMES: &[&str] = &[$($name),*];

            $(
                #[test]
                fn $case() {
                    $crate::common::conformance::run_case(&$make, $name);
                }
            )*
        }
    };
}

/// fidget's float-slice evaluator (`F`: its VM or JIT) on our tapes converted by the bench's
/// [`hytrace::bench::peer::fidget::tape_to_tree`]: the peer the bench times, held to the
/// same suite.
#[cfg(feature = "fidget")]
pub struct FidgetEvaluator<F>(std::marker::PhantomData<F>);

#[cfg(feature = "fidget")]
impl<F> FidgetEvaluator<F> {
    /// The evaluator; tapes are converted and built per evaluation.
    pub fn new() -> Self {
        FidgetEvaluator(std::marker::PhantomData)
    }
}

#[cfg(feature = "fidget")]
impl<F> Default for FidgetEvaluator<F> {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(feature = "fidget")]
impl<F> Evaluator for FidgetEvaluator<F>
where
    F: fidget::eval::Function + fidget::eval::MathFunction + Clone,
{
    fn eval(&self, tape: &hytrace::sdf::tape::Tape, points: &[glam::Vec3]) -> Vec<f32> {
        use fidget::eval::BulkEvaluator as _;
        use fidget::shape::Shape;
        let tree = hytrace::bench::peer::fidget::tape_to_tree(tape)
            .unwrap_or_else(|e| panic!("the tape does not convert: {e}"));
        let mut ctx = fidget::context::Context::new();
        let node = ctx.import(&tree);
        let shape = Shape::<F>::new(&ctx, node).unwrap_or_else(|e| panic!("fidget: {e}"));
        let t = shape.float_slice_tape(Default::default());
        let mut eval = Shape::<F>::new_float_slice_eval();
        let (x, y, z): (Vec<f32>, Vec<f32>, Vec<f32>) = (
            points.iter().map(|p| p.x).collect(),
            points.iter().map(|p| p.y).collect(),
            points.iter().map(|p| p.z).collect(),
        );
        eval.eval(&t, &x, &y, &z)
            .unwrap_or_else(|e| panic!("fidget float-slice evaluation: {e}"))
            .to_vec()
    }
}

/// How closely a backend must agree with the CPU tracer over a scene's rays.
#[derive(Debug, Default)]
pub struct Agreement {
    /// Rays cast.
    pub rays: usize,
    /// Rays both hit or both miss.
    pub hit_miss_agree: usize,
    /// Rays both hit.
    pub both_hit: usize,
    /// Rays both hit, on different objects.
    pub object_differs: usize,
    /// Rays both hit with |Δt| over the tolerance.
    pub dt_over: usize,
    /// The largest |Δt| / tolerance.
    pub dt_max_ratio: f32,
    /// The largest |Δt|.
    pub dt_max: f32,
    /// The smallest cosine between the normals of hits on the same object.
    pub normal_min_cos: f32,
    /// Shadow rays cast from the CPU's hits toward the lights.
    pub shadow_rays: usize,
    /// Shadow rays both call occluded or both call free.
    pub shadow_agree: usize,
    /// Rays whose any-hit answers (over the whole range) agree.
    pub any_hit_agree: usize,
}

impl Agreement {
    fn hit_miss(&self) -> f64 {
        self.hit_miss_agree as f64 / self.rays as f64
    }
    fn shadows(&self) -> f64 {
        self.shadow_agree as f64 / self.shadow_rays.max(1) as f64
    }
    fn any_hit(&self) -> f64 {
        self.any_hit_agree as f64 / self.rays as f64
    }

    /// The acceptance criteria: 99.9 % hit/miss, occlusion and shadow agreement, and at most
    /// 0.1 % of the rays with |Δt| over the tolerance.
    pub fn check(&self, name: &str) {
        let mut why = Vec::new();
        if self.hit_miss() < 0.999 {
            why.push(format!(
                "hit/miss agreement {:.4}% < 99.9%",
                100.0 * self.hit_miss()
            ));
        }
        if self.dt_over as f64 > 0.001 * self.rays as f64 {
            why.push(format!("{} hits with |dt| over tolerance", self.dt_over));
        }
        if self.shadows() < 0.999 {
            why.push(format!(
                "shadow agreement {:.4}% < 99.9%",
                100.0 * self.shadows()
            ));
        }
        if self.any_hit() < 0.999 {
            why.push(format!(
                "occlusion agreement {:.4}% < 99.9%",
                100.0 * self.any_hit()
            ));
        }
        assert!(why.is_empty(), "{name}: {}", why.join("; "));
    }
}

/// Compares `candidate` with the CPU tracer `cpu` on `rays`: closest hits, occlusion along
/// the same rays, and shadow rays from the CPU's hits toward every light. |Δt| is held to the
/// library's tolerances: [`sdf_dt_tolerance`] (with no mesh tolerance: both trace the field)
/// on SDF hits, [`mesh_dt_tolerance`] of the scene's diameter on triangles.
pub fn agreement(
    name: &str,
    cpu: &SceneTracer,
    candidate: &dyn RayQuery,
    rays: &[Ray],
) -> Agreement {
    let scene = cpu.scene();
    let s = &scene.tracer;
    let diameter = rays::bounds(scene).diagonal();
    let tmax = s.max_distance;
    let debug = std::env::var_os("RAY_QUERY_DEBUG").is_some();
    let hits = candidate.closest_hit_many(rays, 0.0, tmax);
    let any = candidate.occluded_many(rays, 0.0, tmax);
    let mut a = Agreement {
        normal_min_cos: 1.0,
        ..Default::default()
    };
    let lights = rays::lights(scene);
    let mut shadow_rays = Vec::new();
    for (i, ray) in rays.iter().enumerate() {
        a.rays += 1;
        let c: Option<QueryHit> = RayQuery::closest_hit(cpu, ray, 0.0, tmax);
        let g = hits[i];
        if cpu.occluded(ray, 0.0, tmax) == any[i] {
            a.any_hit_agree += 1;
        }
        match (&c, &g) {
            (None, None) => a.hit_miss_agree += 1,
            (Some(x), Some(y)) => {
                a.hit_miss_agree += 1;
                a.both_hit += 1;
                let tol = match x.object {
                    ObjectId::Sdf(_) => {
                        sdf_dt_tolerance(s, x.t, x.normal.dot(ray.direction).abs(), 0.0)
                    }
                    ObjectId::MeshInstance(_) => mesh_dt_tolerance(diameter),
                };
                let d = (x.t - y.t).abs();
                if x.object != y.object {
                    a.object_differs += 1;
                }
                if d > tol {
                    a.dt_over += 1;
                    if debug {
                        println!("  {name}: dt over: {ray:?}: cpu {x:?} candidate {y:?}");
                    }
                }
                a.dt_max = a.dt_max.max(d);
                a.dt_max_ratio = a.dt_max_ratio.max(d / tol);
                if x.object == y.object {
                    a.normal_min_cos = a.normal_min_cos.min(x.normal.dot(y.normal));
                }
            }
            _ => {
                if debug {
                    println!("  {name}: hit/miss: {ray:?}: cpu {c:?} candidate {g:?}");
                }
            }
        }
        if let Some(h) = c {
            let o = rays::shadow_origin(ray, h.t, h.normal, rays::shadow_offset(scene, h.t));
            for &light in &lights {
                shadow_rays.push(rays::toward(o, light));
            }
        }
    }
    // Shadow rays of different lengths: one batch per length, as one batch per ray is slow
    // on the GPU.
    let mut by_len: std::collections::BTreeMap<u32, Vec<Ray>> = Default::default();
    for (r, d) in &shadow_rays {
        by_len.entry(d.to_bits()).or_default().push(*r);
    }
    for (bits, batch) in &by_len {
        let dist = f32::from_bits(*bits);
        let blocked = candidate.occluded_many(batch, 0.0, dist);
        for (r, b) in batch.iter().zip(blocked) {
            a.shadow_rays += 1;
            if cpu.occluded(r, 0.0, dist) == b {
                a.shadow_agree += 1;
            }
        }
    }
    println!(
        "{name:<18} rays {:>5} hit/miss {:>8.4}%  both-hit {:>5} (other object {}) |dt| max \
         {:.2e} = {:.3} of tolerance, over {}  normals min cos {:.5}  any-hit {:>8.4}%  \
         shadow rays {:>5} agree {:>8.4}%",
        a.rays,
        100.0 * a.hit_miss(),
        a.both_hit,
        a.object_differs,
        a.dt_max,
        a.dt_max_ratio,
        a.dt_over,
        a.normal_min_cos,
        100.0 * a.any_hit(),
        a.shadow_rays,
        100.0 * a.shadows()
    );
    a
}

/// The camera grid of the scene-agreement checks (small: lavapipe runs on the CPU's cores).
pub const GRID_W: u32 = 64;
/// See [`GRID_W`].
pub const GRID_H: u32 = 48;
/// Random rays of the scene-agreement checks, besides the grid.
pub const RANDOM_RAYS: usize = 600;

/// The rays of the scene-agreement checks: the camera grid at the scene's aspect, then
/// random rays.
pub fn agreement_rays(scene: &Scene, seed: u64) -> Vec<Ray> {
    let aspect = scene.image.width as f32 / scene.image.height as f32;
    rays::scene_rays(scene, GRID_W, GRID_H, aspect, RANDOM_RAYS, seed)
}

/// The scene files of `assets/scenes`, by name.
pub fn shipped_scenes() -> Vec<std::path::PathBuf> {
    let dir = super::root().join("assets/scenes");
    let files = hytrace::scene::scene_files(&dir).unwrap_or_else(|e| panic!("{e}"));
    assert!(!files.is_empty(), "no scenes in {}", dir.display());
    files
}

/// Two Stanford bunnies (the shared assets'), one instanced under a rotation, beside an
/// analytic sphere on an analytic ground plane; None (said loudly) without the assets.
pub fn bunnies() -> Option<Scene> {
    let bunny = super::assets_or_skip("the instanced bunnies")?
        .join("obj/common-3d-test-models/stanford-bunny.obj");
    assert!(bunny.exists(), "the bunny is missing: {}", bunny.display());
    let src = format!(
        "Scene(
            image: (width: {GRID_W}, height: {GRID_H}),
            camera: Perspective(position: (0, 1.5, 4), look_at: (0, 0.6, 0), fov: 45),
            lights: [Point(position: (2, 5, 3), intensity: 20)],
            objects: [
                (mesh: \"{b}\", scale: 10, translate: (-0.8, -0.3, 0)),
                (mesh: \"{b}\", scale: 7, rotate: (0, 120, 0), translate: (0.9, -0.2, -0.5)),
                (shape: Sphere(radius: 0.4), translate: (0, 1.4, 0)),
                (shape: Plane(normal: (0, 1, 0), offset: 0.0)),
            ],
            tracer: (epsilon: 1e-4, epsilon_per_unit: 1e-4, max_distance: 40),
        )",
        b = bunny.display()
    );
    let scene =
        Scene::from_source(&src, Path::new("bunnies.ron")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.meshes.instances.len(), 2);
    Some(scene)
}

/// A scene of `objects` (scene syntax) seen from +z, with a point light and a fine ε.
pub fn small_scene(objects: &str) -> Scene {
    let src = format!(
        "Scene(
            camera: Perspective(position: (0, 0, 5), look_at: (0, 0, 0), fov: 40),
            lights: [Point(position: (0, 0, 8), intensity: 10)],
            objects: [{objects}],
            tracer: (epsilon: 1e-5, epsilon_per_unit: 0),
        )"
    );
    Scene::from_source(&src, Path::new("ray-query.ron")).unwrap_or_else(|e| panic!("{e}"))
}

/// Asserts a closest hit at the closed-form distance `t` on `object` (within the library's
/// tolerance for the kind of object), with the normal `normal` up to sign for meshes.
pub fn assert_hit(
    scene: &Scene,
    q: &dyn RayQuery,
    ray: &Ray,
    t: f32,
    object: ObjectId,
    normal: glam::Vec3,
) {
    let hit = q
        .closest_hit(ray, 0.0, 100.0)
        .unwrap_or_else(|| panic!("{ray:?} misses; expected a hit at {t}"));
    assert_eq!(hit.object, object, "{ray:?}: {hit:?}");
    let cos = normal.dot(ray.direction).abs();
    let tol = match object {
        ObjectId::Sdf(_) => sdf_dt_tolerance(&scene.tracer, t, cos, 0.0),
        ObjectId::MeshInstance(_) => mesh_dt_tolerance(rays::bounds(scene).diagonal()),
    };
    assert!(
        (hit.t - t).abs() <= tol,
        "{ray:?}: t = {}, closed form {t}, |dt| {:.2e} over the tolerance {tol:.2e}",
        hit.t,
        (hit.t - t).abs()
    );
    let c = hit.normal.dot(normal);
    let c = if matches!(object, ObjectId::MeshInstance(_)) {
        c.abs()
    } else {
        c
    };
    assert!(
        c > 0.999,
        "{ray:?}: normal {:?}, expected {normal:?}",
        hit.normal
    );
}

/// A unit square in the plane z = 0 (two triangles, counter-clockwise seen from +z) written as
/// an OBJ file in `dir`.
pub fn write_square(dir: &Path) -> std::path::PathBuf {
    let path = dir.join("square.obj");
    std::fs::write(
        &path,
        "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nf 1 2 3\nf 1 3 4\n",
    )
    .unwrap();
    path
}

/// Shadow rays toward `light` from `o` and the answer each backend must give.
pub fn assert_shadow(q: &dyn RayQuery, o: glam::Vec3, light: LightAt, occluded: bool) {
    let (ray, dist) = rays::toward(o, light);
    assert_eq!(
        q.occluded(&ray, 0.0, dist),
        occluded,
        "shadow ray {ray:?} to {dist}"
    );
    // the batched answer is the same
    assert_eq!(q.occluded_many(&[ray], 0.0, dist), vec![occluded]);
}

/// The ray-query checks, one `#[test]` each, on one backend, in a module named after it:
/// `ray_query_conformance!(gpu => make)` where `make` is a
/// `fn<'a>(&'a SceneTracer<'a>) -> Box<dyn RayQuery + 'a>` building the backend for the
/// tracer's scene. With `agrees_with_cpu: SCENES` (an expression giving `(name, Scene)`
/// pairs) the backend is also compared ray by ray with the CPU tracer on those scenes and on
/// the instanced bunnies of the shared assets.
macro_rules! ray_query_conformance {
    ($backend:ident => $make:path $(, agrees_with_cpu: $scenes:expr)? $(,)?) => {
        mod $backend {
            #[allow(unused_imports)]
            use super::*;
            use glam::Vec3;
            use hytrace::geom::Ray;
            use hytrace::trace::SceneTracer;
            use hytrace::trace::query::{ObjectId, RayQuery};
            use $crate::common::conformance as c;
            use $crate::common::rays::LightAt;

            /// Closed forms: a sphere and a box hit at their distances with their normals, a
            /// ray between them missing, occlusion stopping at tmax.
            #[test]
            fn sdf_hits_are_at_their_closed_form_distances() {
                let scene = c::small_scene(
                    "(shape: Sphere(radius: 1), translate: (0, 0, 0)),
                     (shape: Box(half_extents: (0.5, 0.5, 0.5)), translate: (3, 0, 0))",
                );
                let tracer = SceneTracer::new(&scene);
                let q = $make(&tracer);
                let q: &dyn RayQuery = &*q;
                let down = -Vec3::Z;
                let ray = Ray::new(Vec3::new(0.0, 0.0, 5.0), down);
                c::assert_hit(&scene, q, &ray, 4.0, ObjectId::Sdf(0), Vec3::Z);
                assert!(q.occluded(&ray, 0.0, 100.0));
                assert!(!q.occluded(&ray, 0.0, 3.5), "stops short of the sphere");
                assert!(q.closest_hit(&ray, 0.0, 3.5).is_none(), "stops short of the sphere");
                // oblique: the closed form of a unit sphere from (0.6, 0, 5) straight down
                let ray = Ray::new(Vec3::new(0.6, 0.0, 5.0), down);
                c::assert_hit(&scene, q, &ray, 4.2, ObjectId::Sdf(0), Vec3::new(0.6, 0.0, 0.8));
                let ray = Ray::new(Vec3::new(3.0, 0.0, 5.0), down);
                c::assert_hit(&scene, q, &ray, 4.5, ObjectId::Sdf(1), Vec3::Z);
                let ray = Ray::new(Vec3::new(1.6, 0.0, 5.0), down);
                assert!(q.closest_hit(&ray, 0.0, 100.0).is_none());
                assert!(!q.occluded(&ray, 0.0, 100.0));
            }

            /// A triangle mesh (a square, and the same file instanced under a rotation and a
            /// shift): hits at the plane's distance, misses beside it.
            #[test]
            fn mesh_hits_are_at_their_plane_distances() {
                let dir = $crate::common::temp_dir("ray-query-mesh");
                let square = c::write_square(dir.path());
                let scene = c::small_scene(&format!(
                    "(mesh: \"{p}\"),
                     (mesh: \"{p}\", rotate: (0, 90, 0), translate: (3, 0, 0))",
                    p = square.display()
                ));
                let tracer = SceneTracer::new(&scene);
                let q = $make(&tracer);
                let q: &dyn RayQuery = &*q;
                let ray = Ray::new(Vec3::new(0.3, -0.4, 5.0), -Vec3::Z);
                c::assert_hit(&scene, q, &ray, 5.0, ObjectId::MeshInstance(0), Vec3::Z);
                // oblique: 3 / cos from z = 3
                let d = Vec3::new(0.3, 0.2, -1.0).normalize();
                let ray = Ray::new(Vec3::new(-0.5, -0.5, 3.0), d);
                c::assert_hit(&scene, q, &ray, 3.0 / -d.z, ObjectId::MeshInstance(0), Vec3::Z);
                // the rotated copy stands in the plane x = 3
                let ray = Ray::new(Vec3::new(5.0, 0.2, 0.1), -Vec3::X);
                c::assert_hit(&scene, q, &ray, 2.0, ObjectId::MeshInstance(1), Vec3::X);
                let ray = Ray::new(Vec3::new(1.5, 0.0, 5.0), -Vec3::Z);
                assert!(q.closest_hit(&ray, 0.0, 100.0).is_none(), "beside the square");
                assert!(!q.occluded(&ray, 0.0, 100.0), "beside the square");
            }

            /// Shadow rays: blocked by a sphere and by a square between the point and the
            /// light, free beside them and when the light is in front of the blocker.
            #[test]
            fn shadow_rays_answer_any_hit() {
                let dir = $crate::common::temp_dir("ray-query-shadow");
                let square = c::write_square(dir.path());
                let scene = c::small_scene(&format!(
                    "(shape: Sphere(radius: 0.5), translate: (0, 0, 2)),
                     (mesh: \"{}\", translate: (4, 0, 2))",
                    square.display()
                ));
                let tracer = SceneTracer::new(&scene);
                let q = $make(&tracer);
                let q: &dyn RayQuery = &*q;
                let up = |x: f32| LightAt::Point(Vec3::new(x, 0.0, 6.0));
                c::assert_shadow(q, Vec3::ZERO, up(0.0), true);
                c::assert_shadow(q, Vec3::new(4.0, 0.0, 0.0), up(4.0), true);
                c::assert_shadow(q, Vec3::new(2.0, 0.0, 0.0), up(2.0), false);
                // the light between the point and the blocker: nothing in the way
                c::assert_shadow(q, Vec3::ZERO, LightAt::Point(Vec3::new(0.0, 0.0, 1.0)), false);
                c::assert_shadow(q, Vec3::new(4.0, 0.0, 0.0), LightAt::Far(Vec3::Z, 1.5), false);
                c::assert_shadow(q, Vec3::new(4.0, 0.0, 0.0), LightAt::Far(Vec3::Z, 50.0), true);
            }

            $(
                /// Every listed scene, ray by ray against the CPU tracer.
                #[test]
                fn scenes_agree_with_the_cpu() {
                    let scenes: Vec<(String, hytrace::scene::Scene)> = $scenes;
                    assert!(!scenes.is_empty(), "no scenes to compare");
                    for (k, (name, scene)) in scenes.iter().enumerate() {
                        let tracer = SceneTracer::new(scene);
                        let q = $make(&tracer);
                        let rays = c::agreement_rays(scene, 100 + k as u64);
                        c::agreement(name, &tracer, &*q, &rays).check(name);
                    }
                }

                /// The shared assets' bunnies, instanced, beside analytic SDFs.
                #[test]
                fn instanced_bunnies_agree_with_the_cpu() {
                    let Some(scene) = c::bunnies() else { return };
                    let tracer = SceneTracer::new(&scene);
                    let q = $make(&tracer);
                    let rays = c::agreement_rays(&scene, 7);
                    let a = c::agreement("instanced bunnies", &tracer, &*q, &rays);
                    a.check("instanced bunnies");
                    assert!(a.both_hit > 1000, "the bunnies and the sphere are in view");
                }
            )?
        }
    };
}
