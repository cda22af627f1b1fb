//! Embree 4 as the referee: our CPU tracer and Embree answer the same ray queries (through
//! [`RayQuery`]) on scenes of analytic SDF primitives, instanced meshes and both, and must agree
//! on hit/miss, hit distance and shadow-ray occlusion. A deliberately broken tracer must fail
//! the same comparison.
//!
//! Figures are printed (run with `--nocapture` to see them).
#![cfg(feature = "embree")]

use glam::Vec3;
use hytrace::geom::{Aabb, Ray};
use hytrace::reference::embree::EmbreeScene;
use hytrace::reference::query::{ObjectId, QueryHit, RayQuery};
use hytrace::rng::Rng;
use hytrace::scene::{Light, Scene};
use hytrace::trace::{SceneTracer, epsilon_at};
use std::cell::Cell;
use std::path::{Path, PathBuf};

const GRID_W: u32 = 128;
const GRID_H: u32 = 96;
const RANDOM_RAYS: usize = 2000;
/// A disagreement is excused only where the ray grazes the surface: |n·d| below this.
const GRAZING: f32 = 0.05;

fn scene(objects: &str) -> Scene {
    let src = format!(
        "Scene(
            image: (width: {GRID_W}, height: {GRID_H}),
            camera: Perspective(position: (1.5, 3, 7), look_at: (0, 0, 0), fov: 45),
            lights: [Point(position: (3, 6, 4), intensity: 20)],
            materials: {{ \"red\": (color: (0.8, 0.1, 0.1)) }},
            objects: [{objects}],
            tracer: (epsilon: 1e-4, epsilon_per_unit: 1e-4, max_distance: 60, max_steps: 2048),
        )"
    );
    Scene::from_source(&src, Path::new("embree-reference.ron")).unwrap_or_else(|e| panic!("{e}"))
}

fn temp_dir() -> PathBuf {
    let d = std::env::temp_dir().join(format!("hytrace-embree-ref-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A unit icosphere (icosahedron subdivided twice, 320 triangles) as an OBJ file,
/// counter-clockwise seen from outside.
fn write_icosphere(dir: &Path) -> PathBuf {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let mut v: Vec<Vec3> = [
        (-1.0, t, 0.0),
        (1.0, t, 0.0),
        (-1.0, -t, 0.0),
        (1.0, -t, 0.0),
        (0.0, -1.0, t),
        (0.0, 1.0, t),
        (0.0, -1.0, -t),
        (0.0, 1.0, -t),
        (t, 0.0, -1.0),
        (t, 0.0, 1.0),
        (-t, 0.0, -1.0),
        (-t, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| Vec3::new(x, y, z).normalize())
    .collect();
    let mut f: Vec<[usize; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..2 {
        let mut cache = std::collections::HashMap::new();
        let mut mid = |a: usize, b: usize, v: &mut Vec<Vec3>| {
            *cache.entry((a.min(b), a.max(b))).or_insert_with(|| {
                v.push((v[a] + v[b]).normalize());
                v.len() - 1
            })
        };
        let mut g = Vec::new();
        for [a, b, c] in f {
            let (ab, bc, ca) = (mid(a, b, &mut v), mid(b, c, &mut v), mid(c, a, &mut v));
            g.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        f = g;
    }
    let mut s = String::new();
    for p in &v {
        s += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    for [a, b, c] in &f {
        let n = (v[*b] - v[*a]).cross(v[*c] - v[*a]);
        let (b, c) = if n.dot(v[*a]) > 0.0 { (b, c) } else { (c, b) };
        s += &format!("f {} {} {}\n", a + 1, b + 1, c + 1);
    }
    let path = dir.join("icosphere.obj");
    std::fs::write(&path, s).unwrap();
    path
}

/// Bounds of everything finite: SDF objects and mesh instances.
fn bounds(scene: &Scene) -> Aabb {
    let b = scene.finite_bounds().union(&scene.meshes.bounds());
    if b.is_empty() {
        Aabb::symmetric(Vec3::splat(2.0))
    } else {
        b
    }
}

/// Primary rays through a camera grid, then random rays from a sphere around the scene's
/// bounds toward random points in them. Random origins inside a solid (below a ground plane)
/// are drawn again: there the tracer reports a hit at t = tmin, Embree the surface crossing.
fn rays(scene: &Scene, seed: u64) -> Vec<Ray> {
    let tracer = SceneTracer::new(scene);
    let aspect = GRID_W as f32 / GRID_H as f32;
    let mut out = Vec::new();
    for j in 0..GRID_H {
        for i in 0..GRID_W {
            let (u, v) = (
                (i as f32 + 0.5) / GRID_W as f32,
                (j as f32 + 0.5) / GRID_H as f32,
            );
            out.push(scene.camera.ray(u, v, aspect));
        }
    }
    let b = bounds(scene);
    let (c, r) = (b.center(), 0.5 * b.diagonal());
    let mut rng = Rng::new(seed);
    for _ in 0..RANDOM_RAYS {
        let o = loop {
            let o = c + 1.5 * r * rng.direction();
            if tracer.distance(o, f32::INFINITY) > 1e-3 {
                break o;
            }
        };
        let target = rng.in_box(b.min, b.max);
        out.push(Ray::new(o, target - o));
    }
    out
}

/// Agreement between a candidate and the referee over one scene's rays.
#[derive(Debug, Default)]
struct Report {
    rays: usize,
    agree: usize,
    /// Hit/miss disagreements where the referee's hit grazes the surface (|n·d| < GRAZING)
    /// or the candidate's hit is within 3·ε(t) of the referee's surface (a near miss).
    excused: usize,
    /// Hit/miss disagreements elsewhere.
    unexcused: usize,
    /// |Δt| of rays both hit, with the tolerance that applies.
    dt: Vec<(f32, f32)>,
    /// Both hit but |Δt| over tolerance.
    dt_over: usize,
    /// The smallest cosine between the two normals where both hit the same SDF object.
    normal_min_dot: Option<f32>,
    shadow_rays: usize,
    shadow_agree: usize,
    /// Shadow-ray disagreements where the ray leaves the surface at a grazing angle.
    shadow_grazing: usize,
}

impl Report {
    fn agreement(&self) -> f64 {
        self.agree as f64 / self.rays as f64
    }
    fn shadow_agreement(&self) -> f64 {
        if self.shadow_rays == 0 {
            1.0
        } else {
            self.shadow_agree as f64 / self.shadow_rays as f64
        }
    }
    fn dt_stats(&self) -> (f32, f32, f32) {
        let mut d: Vec<f32> = self.dt.iter().map(|x| x.0).collect();
        d.sort_by(f32::total_cmp);
        let max = d.last().copied().unwrap_or(0.0);
        let p99 = if d.is_empty() {
            0.0
        } else {
            d[((d.len() - 1) as f64 * 0.99) as usize]
        };
        let worst = self
            .dt
            .iter()
            .map(|&(d, tol)| d / tol)
            .fold(0.0f32, f32::max);
        (max, p99, worst)
    }

    fn print(&self, name: &str) {
        let (max, p99, worst) = self.dt_stats();
        println!(
            "{name:<28} rays {:>5}  hit/miss agree {:>8.4}% (excused {}, other {})  \
             both-hit {:>5}  |dt| max {max:.3e} p99 {p99:.3e} (max {worst:.2} of tolerance, \
             {} over)  shadow rays {:>5} agree {:>8.4}% (grazing {})  SDF normals min cos {}",
            self.rays,
            100.0 * self.agreement(),
            self.excused,
            self.unexcused,
            self.dt.len(),
            self.dt_over,
            self.shadow_rays,
            100.0 * self.shadow_agreement(),
            self.shadow_grazing,
            self.normal_min_dot
                .map_or("-".to_string(), |c| format!("{c:.5}")),
        );
    }

    /// The acceptance criteria: `min_agree` for hit/miss, no unexcused hit/miss
    /// disagreement, every |Δt| within tolerance, ≥ 99.9 % shadow agreement.
    fn check(&self, min_agree: f64) -> Result<(), String> {
        let mut why = Vec::new();
        if self.agreement() < min_agree {
            why.push(format!(
                "hit/miss agreement {:.4}% < {:.4}%",
                100.0 * self.agreement(),
                100.0 * min_agree
            ));
        }
        if self.unexcused > 0 {
            why.push(format!(
                "{} unexcused hit/miss disagreements",
                self.unexcused
            ));
        }
        if self.dt_over > 0 {
            why.push(format!("{} hits with |dt| over tolerance", self.dt_over));
        }
        if self.shadow_agreement() < 0.999 {
            why.push(format!(
                "shadow agreement {:.4}% < 99.9%",
                100.0 * self.shadow_agreement()
            ));
        }
        if why.is_empty() {
            Ok(())
        } else {
            Err(why.join("; "))
        }
    }
}

/// Compares `candidate` with `referee` on `scene`'s rays, and shadow rays toward its first
/// point light from every hit of the candidate.
///
/// Tolerance of |Δt|: 10·ε(t) for SDF hits, widened to 2·ε(t)/|n·d| where the ray meets the
/// surface at a shallow angle, since a sphere tracer stops where the field drops below ε(t),
/// up to ε(t)/|n·d| before the surface along the ray; 1e-4 × the scene's diameter for meshes.
fn compare(scene: &Scene, candidate: &dyn RayQuery, referee: &dyn RayQuery, seed: u64) -> Report {
    let s = &scene.tracer;
    let diameter = bounds(scene).diagonal();
    let light = scene
        .lights
        .iter()
        .find_map(|l| match l {
            Light::Point { position, .. } => Some(*position),
            _ => None,
        })
        .expect("a point light");
    let tmax = s.max_distance;
    let mut r = Report::default();
    for ray in &rays(scene, seed) {
        r.rays += 1;
        let a = candidate.closest_hit(ray, 0.0, tmax);
        let b = referee.closest_hit(ray, 0.0, tmax);
        let debug = std::env::var_os("EMBREE_REF_DEBUG").is_some();
        // An excused disagreement: the referee's hit grazes the surface, or the candidate's
        // hit is a sphere tracer's near miss, a point within 3·ε(t) of the true surface.
        let grazing = |h: &QueryHit| h.normal.dot(ray.direction).abs() < GRAZING;
        let near_miss = |h: &QueryHit| {
            let e = 3.0 * epsilon_at(s, h.t);
            let p = ray.at(h.t);
            referee.occluded(&Ray::new(p + e * h.normal, -h.normal), 0.0, 2.0 * e)
        };
        let disagree = |excused: bool, r: &mut Report| {
            if excused {
                r.excused += 1;
            } else {
                if debug {
                    println!("  disagreement: ray {ray:?}: candidate {a:?}, referee {b:?}");
                }
                r.unexcused += 1;
            }
        };
        match (&a, &b) {
            (None, None) => r.agree += 1,
            (Some(x), Some(y)) => {
                let tol = match y.object {
                    ObjectId::Sdf(_) => {
                        let e = epsilon_at(s, y.t);
                        (10.0 * e).max(2.0 * e / y.normal.dot(ray.direction).abs())
                    }
                    ObjectId::MeshInstance(_) => 1e-4 * diameter,
                };
                let d = (x.t - y.t).abs();
                if x.object != y.object && d > tol {
                    // Different surfaces: a hit/miss disagreement on the nearer one.
                    let excused = if x.t < y.t { near_miss(x) } else { grazing(y) };
                    disagree(excused, &mut r);
                } else {
                    r.agree += 1;
                    r.dt.push((d, tol));
                    if matches!(y.object, ObjectId::Sdf(_)) && x.object == y.object {
                        let c = x.normal.dot(y.normal);
                        r.normal_min_dot = Some(r.normal_min_dot.map_or(c, |m| m.min(c)));
                    }
                    if d > tol {
                        if debug && r.dt_over < 5 {
                            println!("  dt over: ray {ray:?}: candidate {x:?}, referee {y:?}");
                        }
                        r.dt_over += 1;
                    }
                }
            }
            (Some(x), None) => disagree(near_miss(x), &mut r),
            (None, Some(y)) => disagree(grazing(y), &mut r),
        }
        // Shadow ray from the candidate's hit, 4·ε(t) off the surface on the side the ray came
        // from, as the renderer casts it.
        {
            if let Some(h) = a {
                let n = if h.normal.dot(ray.direction) > 0.0 {
                    -h.normal
                } else {
                    h.normal
                };
                let o = ray.at(h.t) + 4.0 * epsilon_at(s, h.t) * n;
                let to_light = light - o;
                let dist = to_light.length();
                let shadow = Ray::new(o, to_light);
                r.shadow_rays += 1;
                if candidate.occluded(&shadow, 0.0, dist) == referee.occluded(&shadow, 0.0, dist) {
                    r.shadow_agree += 1;
                } else if n.dot(shadow.direction).abs() < GRAZING {
                    r.shadow_grazing += 1;
                } else if debug {
                    println!("  shadow: from {ray:?} hit {h:?}: {shadow:?} to {dist}");
                }
            }
        }
    }
    r
}

/// Builds the Embree scene, checks that nothing was skipped, compares and checks.
fn referee(name: &str, scene: &Scene, min_agree: f64, seed: u64) -> Report {
    let embree = EmbreeScene::build(scene).unwrap_or_else(|e| panic!("{name}: {e}"));
    assert!(
        embree.skipped().is_empty(),
        "{name}: skipped {:?}",
        embree.skipped()
    );
    let tracer = SceneTracer::new(scene);
    let r = compare(scene, &tracer, &embree, seed);
    r.print(name);
    if let Err(e) = r.check(min_agree) {
        panic!("{name}: {e}");
    }
    r
}

const SDF_AGREE: f64 = 0.999;
const MESH_AGREE: f64 = 0.9999;

/// Every analytic primitive under a non-trivial transform (nested `Transform` and `Material`
/// wrappers included), each in its own scene.
#[test]
fn analytic_primitives_agree_with_embree() {
    let cases = [
        (
            "sphere",
            "(shape: Sphere(radius: 1.1), translate: (0.3, -0.2, 0.1), scale: 1.3)",
        ),
        (
            "box",
            "(shape: Box(half_extents: (1.2, 0.6, 0.9)), rotate: (20, 35, -10), translate: (0.2, 0.1, -0.3))",
        ),
        (
            "plane",
            "(shape: Plane(normal: (0.1, 1, 0.2), offset: -0.5), rotate: (5, 10, -8), translate: (0, -0.3, 0))",
        ),
        (
            "torus",
            "(shape: Torus(major: 1.2, minor: 0.35), rotate: (60, 20, 0), scale: 1.2)",
        ),
        (
            "cylinder",
            "(shape: Cylinder(half_height: 0.9, radius: 0.6), rotate: (0, 30, 40), translate: (0.1, 0.2, 0))",
        ),
        (
            "cone",
            "(shape: Cone(half_height: 1.0, bottom_radius: 0.9, top_radius: 0.2), rotate: (-25, 0, 15), scale: 1.4)",
        ),
        (
            "capsule (nested transform)",
            "(shape: Transform(rotate: (0, 0, 30), translate: (0.2, 0, 0), \
             shape: Capsule(a: (-0.8, -0.4, 0), b: (0.7, 0.5, 0.2), radius: 0.45)), \
             rotate: (10, 50, 0), scale: 0.9)",
        ),
        (
            "ellipsoid (material)",
            "(shape: Material(name: \"red\", shape: Ellipsoid(radii: (1.3, 0.6, 0.8))), \
             rotate: (30, -20, 10), translate: (0, 0.2, 0.1))",
        ),
    ];
    for (k, (name, object)) in cases.iter().enumerate() {
        let scene = scene(object);
        referee(name, &scene, SDF_AGREE, 100 + k as u64);
    }
}

fn two_icospheres(path: &Path) -> String {
    let p = path.display();
    format!(
        "(name: \"a\", mesh: \"{p}\", rotate: (20, 30, 0), scale: 0.9, translate: (-1.1, 0, 0)),
         (name: \"b\", mesh: \"{p}\", rotate: (-10, 0, 45), scale: 1.3, translate: (1.2, 0.3, -0.5))"
    )
}

/// One mesh file placed twice with different transforms: Embree instances it.
#[test]
fn instanced_meshes_agree_with_embree() {
    let path = write_icosphere(&temp_dir());
    let scene = scene(&two_icospheres(&path));
    assert_eq!(scene.meshes.meshes.len(), 1);
    assert_eq!(scene.meshes.instances.len(), 2);
    let r = referee("two icosphere instances", &scene, MESH_AGREE, 200);
    // Both instances are seen.
    let embree = EmbreeScene::build(&scene).unwrap();
    let mut seen = [false; 2];
    for ray in rays(&scene, 201) {
        if let Some(QueryHit {
            object: ObjectId::MeshInstance(i),
            ..
        }) = embree.closest_hit(&ray, 0.0, 60.0)
        {
            seen[i] = true;
        }
    }
    assert_eq!(seen, [true, true]);
    assert!(
        r.dt.len() > 500,
        "too few hits to mean much: {}",
        r.dt.len()
    );
}

/// Embree's mesh normals (geometric, counter-clockwise front) agree with the tracer's shading
/// normals up to the smoothing of a 320-triangle sphere.
#[test]
fn mesh_normals_agree_with_embree() {
    let path = write_icosphere(&temp_dir());
    let scene = scene(&two_icospheres(&path));
    let embree = EmbreeScene::build(&scene).unwrap();
    let tracer = SceneTracer::new(&scene);
    let mut n = 0;
    for ray in rays(&scene, 300) {
        if let (Some(a), Some(b)) = (
            RayQuery::closest_hit(&tracer, &ray, 0.0, 60.0),
            embree.closest_hit(&ray, 0.0, 60.0),
        ) {
            assert!(a.normal.dot(b.normal) > 0.95, "ray {ray:?}: {a:?} vs {b:?}");
            n += 1;
        }
    }
    assert!(n > 500);
}

/// SDF primitives, instanced meshes and an (infinite) ground plane together.
#[test]
fn mixed_scene_agrees_with_embree() {
    let path = write_icosphere(&temp_dir());
    let objects = format!(
        "{},
         (shape: Torus(major: 0.7, minor: 0.2), rotate: (70, 0, 0), translate: (0, 0.4, 1.2)),
         (shape: Box(half_extents: (0.4, 0.4, 0.4)), rotate: (0, 45, 0), translate: (0, -0.2, -1.5)),
         (shape: Sphere(radius: 0.5), translate: (0, 1.5, 0), material: \"red\"),
         (shape: Plane(normal: (0, 1, 0), offset: -1.3))",
        two_icospheres(&path)
    );
    let scene = scene(&objects);
    referee("mixed", &scene, SDF_AGREE, 400);
}

/// Objects Embree cannot take yet are listed, not silently dropped.
#[test]
fn unsupported_objects_are_listed() {
    let scene = scene(
        "(shape: Sphere(radius: 1)),
         (shape: Subtraction(base: Box(half_extents: (1, 1, 1)), cut: Sphere(radius: 1.2))),
         (shape: Octahedron(size: 1), translate: (3, 0, 0))",
    );
    let embree = EmbreeScene::build(&scene).unwrap();
    let idx: Vec<usize> = embree.skipped().iter().map(|s| s.0).collect();
    assert_eq!(idx, [1, 2], "{:?}", embree.skipped());
    assert!(
        embree.skipped()[0].1.contains("Subtraction"),
        "{:?}",
        embree.skipped()
    );
    assert!(
        embree.skipped()[1].1.contains("Octahedron"),
        "{:?}",
        embree.skipped()
    );
}

/// A tracer that is off by 20·ε(t) on every hit, or that drops every 50th hit.
struct Broken<'a> {
    tracer: SceneTracer<'a>,
    shift_t: bool,
    calls: Cell<usize>,
}

impl RayQuery for Broken<'_> {
    fn closest_hit(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<QueryHit> {
        let mut h = RayQuery::closest_hit(&self.tracer, ray, tmin, tmax)?;
        if self.shift_t {
            h.t += 20.0 * epsilon_at(&self.tracer.scene().tracer, h.t);
            return Some(h);
        }
        let n = self.calls.get() + 1;
        self.calls.set(n);
        (n % 50 != 0).then_some(h)
    }
    fn occluded(&self, ray: &Ray, tmin: f32, tmax: f32) -> bool {
        RayQuery::occluded(&self.tracer, ray, tmin, tmax)
    }
}

/// The referee has teeth: both kinds of broken tracer fail the comparison the real one passes.
#[test]
fn referee_catches_a_broken_tracer() {
    let scene = scene(
        "(shape: Torus(major: 1.2, minor: 0.35), rotate: (60, 20, 0)),
         (shape: Box(half_extents: (0.5, 0.5, 0.5)), rotate: (10, 20, 30), translate: (0, -1, 0.5))",
    );
    let embree = EmbreeScene::build(&scene).unwrap();
    for shift_t in [true, false] {
        let broken = Broken {
            tracer: SceneTracer::new(&scene),
            shift_t,
            calls: Cell::new(0),
        };
        let r = compare(&scene, &broken, &embree, 500);
        let name = if shift_t {
            "broken: t + 20 eps"
        } else {
            "broken: drops 1 hit in 50"
        };
        r.print(name);
        let err = r
            .check(SDF_AGREE)
            .expect_err("the referee must reject a broken tracer");
        println!("    rejected: {err}");
    }
}
