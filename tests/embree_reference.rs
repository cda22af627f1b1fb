//! Embree 4 as the referee: our CPU tracer and Embree answer the same ray queries (through
//! [`RayQuery`]) on scenes of analytic SDF primitives, instanced meshes and both, and must agree
//! on hit/miss, hit distance and shadow-ray occlusion. A deliberately broken tracer must fail
//! the same comparison.
//!
//! Figures are printed (run with `--nocapture` to see them).
#![cfg(feature = "embree")]

mod common;
use common::rays::{self, bounds};

use glam::Vec3;
use hytrace::geom::Ray;
use hytrace::reference::analytic;
use hytrace::reference::embree::{
    DEFAULT_MESH_RESOLUTION, EmbreeScene, ReferenceOptions, SdfCheck,
};
use hytrace::reference::mesher::{MeshOptions, mesh_sdf};
use hytrace::reference::validate::{mesh_dt_tolerance, sdf_dt_tolerance};
use hytrace::scene::Scene;
use hytrace::trace::query::{ObjectId, QueryHit, RayQuery};
use hytrace::trace::{SceneTracer, epsilon_at};
use std::cell::Cell;
use std::path::{Path, PathBuf};

const GRID_W: u32 = 128;
const GRID_H: u32 = 96;
const RANDOM_RAYS: usize = 2000;
/// A disagreement is excused only where the ray grazes the surface: |n·d| below this.
const GRAZING: f32 = 0.05;

/// The referee with SDF objects without a closed form meshed (`validate --meshed`), as the
/// mesh tests below check it.
fn meshed() -> ReferenceOptions {
    ReferenceOptions {
        meshed: true,
        ..ReferenceOptions::default()
    }
}

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

/// A unit icosphere (icosahedron subdivided twice, 320 triangles) as an OBJ file,
/// counter-clockwise seen from outside.
fn write_icosphere(dir: &Path) -> PathBuf {
    let (v, f) = hytrace::geom::icosphere(2);
    let mut s = String::new();
    for p in &v {
        s += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    for &[a, b, c] in &f {
        let [pa, pb, pc] = [a, b, c].map(|i| v[i as usize]);
        let (b, c) = if (pb - pa).cross(pc - pa).dot(pa) > 0.0 {
            (b, c)
        } else {
            (c, b)
        };
        s += &format!("f {} {} {}\n", a + 1, b + 1, c + 1);
    }
    let path = dir.join("icosphere.obj");
    std::fs::write(&path, s).unwrap();
    path
}

/// Primary rays through a camera grid, then random rays from outside every solid
/// ([`rays::scene_rays`]).
fn rays(scene: &Scene, seed: u64) -> Vec<Ray> {
    let aspect = GRID_W as f32 / GRID_H as f32;
    rays::scene_rays(scene, GRID_W, GRID_H, aspect, RANDOM_RAYS, seed)
}

/// Agreement between a candidate and the referee over one scene's rays.
#[derive(Debug, Default)]
struct Report {
    rays: usize,
    agree: usize,
    /// Hit/miss disagreements where the referee's hit grazes the surface (|n·d| < GRAZING)
    /// or the candidate's hit is within 3·ε(t) of the referee's surface (a near miss).
    excused: usize,
    /// Hit/miss disagreements where the referee hit a mesh of an SDF object at a point within
    /// the mesh's stated tolerance of the true surface (the field there is at most the
    /// tolerance): the ray passes that close to the surface.
    excused_by_mesh: usize,
    /// Hit/miss disagreements elsewhere.
    unexcused: usize,
    /// Rays left out: the candidate's hit (or, for a shadow ray the two disagree on, its
    /// blocker) lies on a clipped (unbounded) meshed object outside the box its mesh covers.
    outside_mesh: usize,
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
    /// Shadow-ray disagreements on a meshed blocker the ray passes within its tolerance of.
    shadow_excused_by_mesh: usize,
}

impl Report {
    fn agreement(&self) -> f64 {
        self.agree as f64 / self.rays as f64
    }
    /// Agreement of shadow rays, counting those excused by a mesh's tolerance as agreeing.
    fn shadow_agreement(&self) -> f64 {
        if self.shadow_rays == 0 {
            1.0
        } else {
            (self.shadow_agree + self.shadow_excused_by_mesh) as f64 / self.shadow_rays as f64
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

    fn dt_over_fraction(&self) -> f64 {
        self.dt_over as f64 / self.dt.len().max(1) as f64
    }

    fn print(&self, name: &str) {
        let (max, p99, worst) = self.dt_stats();
        println!(
            "{name:<28} rays {:>5} (left out {})  hit/miss agree {:>8.4}% (excused {}, within \
             mesh tolerance {}, other {})  both-hit {:>5}  |dt| max {max:.3e} p99 {p99:.3e} \
             (max {worst:.2} of tolerance, {} over)  shadow rays {:>5} agree {:>8.4}% \
             (grazing {}, within mesh tolerance {})  SDF normals min cos {}",
            self.rays,
            self.outside_mesh,
            100.0 * self.agreement(),
            self.excused,
            self.excused_by_mesh,
            self.unexcused,
            self.dt.len(),
            self.dt_over,
            self.shadow_rays,
            100.0 * self.shadow_agreement(),
            self.shadow_grazing,
            self.shadow_excused_by_mesh,
            self.normal_min_dot
                .map_or("-".to_string(), |c| format!("{c:.5}")),
        );
    }

    /// The acceptance criteria: `min_agree` for hit/miss, no unexcused hit/miss
    /// disagreement, every |Δt| within tolerance, ≥ 99.9 % shadow agreement.
    fn check(&self, min_agree: f64) -> Result<(), String> {
        self.check_with(min_agree, 0.0, 0)
    }

    /// As [`Report::check`], but allowing a fraction `dt_over_allowed` of the rays both hit to
    /// exceed the tolerance and `unexcused_allowed` unexcused hit/miss disagreements.
    fn check_with(
        &self,
        min_agree: f64,
        dt_over_allowed: f64,
        unexcused_allowed: usize,
    ) -> Result<(), String> {
        let mut why = Vec::new();
        if self.agreement() < min_agree {
            why.push(format!(
                "hit/miss agreement {:.4}% < {:.4}%",
                100.0 * self.agreement(),
                100.0 * min_agree
            ));
        }
        if self.unexcused > unexcused_allowed {
            why.push(format!(
                "{} unexcused hit/miss disagreements (at most {unexcused_allowed} allowed)",
                self.unexcused
            ));
        }
        if self.dt_over_fraction() > dt_over_allowed {
            why.push(format!(
                "{} hits with |dt| over tolerance ({:.4}% of {}, at most {:.4}% allowed)",
                self.dt_over,
                100.0 * self.dt_over_fraction(),
                self.dt.len(),
                100.0 * dt_over_allowed
            ));
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

/// The stated tolerance of the referee's mesh of SDF object `object` (0 for closed forms and
/// mesh instances).
fn mesh_tolerance(referee: &EmbreeScene, object: ObjectId) -> f32 {
    match object {
        ObjectId::Sdf(i) => match referee.checks[i] {
            SdfCheck::Meshed { tolerance, .. } => tolerance,
            _ => 0.0,
        },
        ObjectId::MeshInstance(_) => 0.0,
    }
}

/// Whether `p`, a hit of the true surface of `object`, lies where the referee has no mesh of
/// it: outside the clip box of an unbounded meshed object, or within one cell of its faces
/// (where the open mesh ends).
fn outside_mesh(referee: &EmbreeScene, object: ObjectId, p: Vec3) -> bool {
    let ObjectId::Sdf(i) = object else {
        return false;
    };
    let (Some(region), SdfCheck::Meshed { cell, .. }) =
        (referee.mesh_region(i), &referee.checks[i])
    else {
        return false;
    };
    let inner = region.bounds.expand(-*cell);
    region.clipped && !(p.cmpge(inner.min).all() && p.cmple(inner.max).all())
}

/// Compares `candidate` with `referee` on `scene`'s rays, and shadow rays toward its first
/// point light from every hit of the candidate.
///
/// Tolerance of |Δt|: 10·ε(t) for SDF hits, widened to (2·ε(t) + τ)/|n·d| where the ray meets
/// the surface at a shallow angle, since a sphere tracer stops where the field drops below
/// ε(t), up to ε(t)/|n·d| before the surface along the ray, and the referee's mesh of the
/// object (if it is meshed) lies within its stated tolerance τ of the surface (τ = 0 for
/// closed forms); n is the candidate's normal when both hit the same SDF object (the mesh's
/// face normal is off near creases). 1e-4 × the scene's diameter for triangle meshes.
fn compare(scene: &Scene, candidate: &dyn RayQuery, referee: &EmbreeScene, seed: u64) -> Report {
    let s = &scene.tracer;
    let diameter = bounds(scene).diagonal();
    let light = rays::lights(scene)
        .into_iter()
        .find(|l| matches!(l, rays::LightAt::Point(_)))
        .expect("a point light");
    let tmax = s.max_distance;
    let tau = |o: ObjectId| mesh_tolerance(referee, o);
    let mut r = Report::default();
    for ray in &rays(scene, seed) {
        let a = candidate.closest_hit(ray, 0.0, tmax);
        let b = referee.closest_hit(ray, 0.0, tmax);
        if let Some(x) = &a
            && outside_mesh(referee, x.object, ray.at(x.t))
        {
            r.outside_mesh += 1;
            continue;
        }
        r.rays += 1;
        let debug = std::env::var_os("EMBREE_REF_DEBUG").is_some();
        // An excused disagreement: the referee's hit grazes the surface or clips a sliver, or
        // the candidate's hit is a sphere tracer's near miss, a point within 3·ε(t) (plus the tolerance of a
        // meshed object) of the referee's surface.
        let grazing = |h: &QueryHit| h.normal.dot(ray.direction).abs() < GRAZING;
        // A sphere tracer stops where f < ε(t), which is within ε(t)/|∇f| of the surface
        // for a locally linear field: 3ε(t) for an exact field, more where a bound field's
        // gradient is weak (an implicit surface divided by a Lipschitz bound λ far above
        // |∇f| near the surface).
        let near_miss_on = |ray: &Ray, h: &QueryHit| {
            let weakness = match h.object {
                ObjectId::Sdf(i) => {
                    let g = scene.objects[i]
                        .lowered
                        .distance
                        .gradient(ray.at(h.t), 1e-3)
                        .length();
                    1.0 / g.clamp(0.02, 1.0)
                }
                ObjectId::MeshInstance(_) => 1.0,
            };
            let e = 3.0 * epsilon_at(s, h.t) * weakness + tau(h.object);
            let p = ray.at(h.t);
            referee.occluded(&Ray::new(p + e * h.normal, -h.normal), 0.0, 2.0 * e)
        };
        let near_miss = |h: &QueryHit| near_miss_on(ray, h);
        // The referee's ray only clips the solid: along it the field never gets deeper than
        // ε(t) inside (a corner or rim cut by a chord shorter than the band). A sphere tracer
        // confirms a candidate by probing about ε ahead (`trace::crossing`), so it may step
        // over such a sliver by design, wherever its samples happen to fall.
        let sliver = |h: &QueryHit| match h.object {
            ObjectId::Sdf(i) => {
                let tape = &scene.objects[i].lowered.distance;
                let e = epsilon_at(s, h.t);
                (0..=256).all(|k| {
                    let t = h.t - 2.0 * e + 12.0 * e * k as f32 / 256.0;
                    tape.eval(ray.at(t)) > -e
                })
            }
            ObjectId::MeshInstance(_) => false,
        };
        // The referee hit a mesh of an SDF object where the object's field is within the
        // mesh's tolerance (1-Lipschitz: |f| ≤ distance to the surface).
        let within_mesh_tolerance_on = |ray: &Ray, h: &QueryHit| match h.object {
            ObjectId::Sdf(i) if tau(h.object) > 0.0 => {
                let f = scene.objects[i].lowered.distance.eval(ray.at(h.t));
                f.abs() <= tau(h.object) + epsilon_at(s, h.t)
            }
            _ => false,
        };
        let within_mesh_tolerance = |h: &QueryHit| within_mesh_tolerance_on(ray, h);
        let disagree = |excused: bool, by_mesh: bool, r: &mut Report| {
            if excused {
                r.excused += 1;
            } else if by_mesh {
                r.excused_by_mesh += 1;
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
                        let n = if x.object == y.object {
                            x.normal
                        } else {
                            y.normal
                        };
                        sdf_dt_tolerance(s, y.t, n.dot(ray.direction).abs(), tau(y.object))
                    }
                    ObjectId::MeshInstance(_) => mesh_dt_tolerance(diameter),
                };
                let d = (x.t - y.t).abs();
                // The candidate stopped short on the same object: a sphere tracer's near miss
                // of a thin part (a rim, a seam) that the ray passes within ε(t) of.
                let near_miss_same = x.object == y.object && d > tol && x.t < y.t && near_miss(x);
                if (x.object != y.object && d > tol) || near_miss_same {
                    // Different surfaces: a hit/miss disagreement on the nearer one.
                    if x.t < y.t {
                        disagree(near_miss(x), false, &mut r);
                    } else {
                        disagree(grazing(y) || sliver(y), within_mesh_tolerance(y), &mut r);
                    }
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
            (Some(x), None) => disagree(near_miss(x), false, &mut r),
            (None, Some(y)) => disagree(grazing(y) || sliver(y), within_mesh_tolerance(y), &mut r),
        }
        // Shadow ray from the candidate's hit, 4·ε(t) off the surface on the side the ray came
        // from, as the renderer casts it, plus twice the tolerance of the referee's mesh of
        // the object hit (else the ray could start behind that mesh).
        if let Some(h) = a {
            let n = rays::facing(ray, h.normal);
            let offset = rays::shadow_offset(scene, h.t) + 2.0 * tau(h.object);
            let o = rays::shadow_origin(ray, h.t, h.normal, offset);
            let (shadow, dist) = rays::toward(o, light);
            // The blocker is a meshed object the shadow ray passes within its tolerance of: the
            // referee's blocker lies within the tolerance of the true surface, or the
            // candidate's blocker within 3·ε(t) + tolerance of the referee's mesh.
            let blocker_within_mesh_tolerance = || {
                let (x, y) = (
                    candidate.closest_hit(&shadow, 0.0, dist),
                    referee.closest_hit(&shadow, 0.0, dist),
                );
                match (&x, &y) {
                    (None, Some(y)) => within_mesh_tolerance_on(&shadow, y),
                    (Some(x), None) => tau(x.object) > 0.0 && near_miss_on(&shadow, x),
                    _ => false,
                }
            };
            let agree =
                candidate.occluded(&shadow, 0.0, dist) == referee.occluded(&shadow, 0.0, dist);
            // The candidate's blocker lies where the referee has no mesh of a clipped object:
            // nothing to compare (counted with the primary rays left out).
            if !agree
                && candidate
                    .closest_hit(&shadow, 0.0, dist)
                    .is_some_and(|x| outside_mesh(referee, x.object, shadow.at(x.t)))
            {
                r.outside_mesh += 1;
                continue;
            }
            r.shadow_rays += 1;
            if agree {
                r.shadow_agree += 1;
            } else if n.dot(shadow.direction).abs() < GRAZING {
                r.shadow_grazing += 1;
            } else if blocker_within_mesh_tolerance() {
                r.shadow_excused_by_mesh += 1;
            } else if debug {
                println!("  shadow: from {ray:?} hit {h:?}: {shadow:?} to {dist}");
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
    let dir = common::temp_dir("embree-reference");
    let path = write_icosphere(dir.path());
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
    let dir = common::temp_dir("embree-reference");
    let path = write_icosphere(dir.path());
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
    let dir = common::temp_dir("embree-reference");
    let path = write_icosphere(dir.path());
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

/// Objects without a closed form are meshed, not skipped: the analytic sphere keeps its
/// closed form, the CSG subtraction and the octahedron become meshes with a stated tolerance
/// of about one cell.
#[test]
fn composite_objects_are_meshed() {
    let scene = scene(
        "(shape: Sphere(radius: 1)),
         (shape: Subtraction(base: Box(half_extents: (1, 1, 1)), cut: Sphere(radius: 1.2))),
         (shape: Octahedron(size: 1), translate: (3, 0, 0))",
    );
    let embree = EmbreeScene::build_with(&scene, &meshed()).unwrap();
    assert!(embree.skipped().is_empty(), "{:?}", embree.skipped());
    assert_eq!(embree.checks[0], SdfCheck::Analytic);
    for i in [1, 2] {
        let SdfCheck::Meshed {
            resolution,
            cell,
            tolerance,
            triangles,
            clipped_to: None,
        } = embree.checks[i]
        else {
            panic!("object {i}: {:?}", embree.checks[i]);
        };
        assert_eq!(resolution, DEFAULT_MESH_RESOLUTION);
        let side = (scene.objects[i].bounds().max - scene.objects[i].bounds().min).max_element();
        assert!(
            (cell - side / resolution as f32).abs() < 1e-6 * side,
            "{cell}"
        );
        assert!(
            tolerance >= cell && tolerance < 1.01 * cell,
            "{tolerance} vs {cell}"
        );
        assert!(triangles > 10_000, "{triangles}");
        let region = embree.mesh_region(i).unwrap();
        assert!(!region.clipped);
    }
    assert!(embree.mesh_region(0).is_none());
}

/// Meshes every object of every shipped scene at the default resolution and prints, per
/// scene, how many objects are analytic and meshed, their triangles and the build time.
#[test]
fn shipped_scenes_build_with_meshes() {
    let paths = common::conformance::shipped_scenes();
    assert!(paths.len() >= 9, "{paths:?}");
    let mut total = std::time::Duration::ZERO;
    for path in &paths {
        let scene = match Scene::load(path) {
            Ok(s) => s,
            // A scene naming shared mesh assets that are not installed (see tests/hybrid.rs).
            Err(e) if common::assets_or_skip(&format!("{}", path.display())).is_none() => {
                println!(
                    "{}: not loaded without the shared assets: {e}",
                    path.display()
                );
                continue;
            }
            Err(e) => panic!("{e}"),
        };
        let start = std::time::Instant::now();
        let embree = EmbreeScene::build_with(&scene, &meshed()).unwrap_or_else(|e| panic!("{e}"));
        let took = start.elapsed();
        total += took;
        assert!(embree.skipped().is_empty(), "{:?}", embree.skipped());
        let analytic = embree
            .checks
            .iter()
            .filter(|c| **c == SdfCheck::Analytic)
            .count();
        let meshed: Vec<_> = embree
            .checks
            .iter()
            .filter_map(|c| match c {
                SdfCheck::Meshed {
                    triangles,
                    tolerance,
                    ..
                } => Some((*triangles, *tolerance)),
                _ => None,
            })
            .collect();
        let triangles: usize = meshed.iter().map(|m| m.0).sum();
        let worst_tolerance = meshed.iter().map(|m| m.1).fold(0f32, f32::max);
        println!(
            "{:<18} objects {:>2}: analytic {:>2}, meshed {:>2} ({:>9} triangles, largest \
             tolerance {worst_tolerance:.4}), build {:>6.2} s",
            path.file_name().unwrap().to_string_lossy(),
            scene.objects.len(),
            analytic,
            meshed.len(),
            triangles,
            took.as_secs_f64()
        );
        for (i, c) in embree.checks.iter().enumerate() {
            if let SdfCheck::Meshed {
                resolution,
                cell,
                tolerance,
                triangles,
                clipped_to,
            } = c
            {
                assert_eq!(clipped_to.is_some(), embree.mesh_region(i).unwrap().clipped);
                println!(
                    "    {:<28} res {resolution:>3} cell {cell:.4} tolerance {tolerance:.4} \
                     triangles {triangles:>8}{}",
                    scene.objects[i].name,
                    if embree.mesh_region(i).unwrap().clipped {
                        " (clipped)"
                    } else {
                        ""
                    }
                );
            }
        }
    }
    println!("all shipped scenes: {:.2} s", total.as_secs_f64());
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
        (!n.is_multiple_of(50)).then_some(h)
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

/// A sphere that only a mesh can represent (a rounded smaller sphere, so not a closed-form
/// primitive), meshed at rising resolutions and compared with the sphere's closed form: every
/// hit is within the stated tolerance / |n·d|, and the tolerance shrinks as the resolution
/// grows.
#[test]
fn meshed_sphere_matches_its_closed_form() {
    let centre = Vec3::new(0.2, -0.1, 0.3);
    let scene = scene(
        "(shape: Round(radius: 0.3, shape: Sphere(radius: 0.7)), translate: (0.2, -0.1, 0.3))",
    );
    let mut previous = f32::INFINITY;
    for resolution in [32, 64, 128, 256] {
        let options = ReferenceOptions {
            mesh_resolution: resolution,
            ..meshed()
        };
        let embree = EmbreeScene::build_with(&scene, &options).unwrap();
        let SdfCheck::Meshed { tolerance, .. } = embree.checks[0] else {
            panic!("{:?}", embree.checks[0]);
        };
        // The mesh itself: its vertices lie on the sphere.
        let object = &scene.objects[0];
        let clip = object.bounds();
        let mesh = mesh_sdf(
            &object.lowered.distance,
            &object.bounds(),
            &clip,
            &MeshOptions {
                resolution,
                ..MeshOptions::default()
            },
        )
        .unwrap();
        let vertex_error = mesh
            .positions
            .iter()
            .map(|p| ((*p - centre).length() - 1.0).abs())
            .fold(0f32, f32::max);
        let (mut max_dt, mut worst, mut hits, mut misses_near) = (0f32, 0f32, 0, 0);
        for ray in rays(&scene, 700) {
            let exact = analytic::sphere(
                (ray.origin - centre).as_dvec3(),
                ray.direction.as_dvec3(),
                1.0,
                0.0,
                60.0,
            );
            let got = embree.closest_hit(&ray, 0.0, 60.0);
            match (exact, got) {
                (Some(e), Some(g)) => {
                    let cos = (e.normal.as_vec3().dot(ray.direction)).abs();
                    let dt = (e.t as f32 - g.t).abs();
                    max_dt = max_dt.max(dt);
                    worst = worst.max(dt * cos / tolerance);
                    hits += 1;
                }
                (None, None) => {}
                _ => {
                    // a silhouette ray: it passes within the tolerance of the sphere
                    let o = ray.origin - centre;
                    let closest = (o - o.dot(ray.direction) * ray.direction).length();
                    assert!(
                        (closest - 1.0).abs() <= tolerance,
                        "resolution {resolution}: hit/miss disagreement {:.2e} from the \
                         silhouette, tolerance {tolerance:.2e}",
                        (closest - 1.0).abs()
                    );
                    misses_near += 1;
                }
            }
        }
        println!(
            "meshed sphere res {resolution:>3}: tolerance {tolerance:.2e}, max vertex error \
             {vertex_error:.2e}, {hits} hits, max |dt| {max_dt:.2e}, max |dt|·|n·d| = \
             {worst:.3} of tolerance, {misses_near} silhouette disagreements"
        );
        assert!(hits > 1000, "{hits}");
        assert!(
            worst <= 1.0,
            "resolution {resolution}: {worst} of tolerance"
        );
        assert!(vertex_error <= 0.01 * tolerance, "{vertex_error}");
        assert!(tolerance < 0.6 * previous, "{tolerance} vs {previous}");
        previous = tolerance;
    }
}

fn asset_scene(name: &str) -> Scene {
    let path = common::root().join(format!("assets/scenes/{name}.ron"));
    Scene::load(&path).unwrap_or_else(|e| panic!("{e}"))
}

/// Hit/miss agreement required with meshed objects: excused disagreements (grazing rays, the
/// tracer's near misses of thin rims, rays within the mesh tolerance of a silhouette) are
/// more frequent than with closed forms, as the mesh tolerance widens the band they fall in.
const MESHED_AGREE: f64 = 0.98;

/// At most this fraction of the rays both backends hit may exceed |Δt| ≤ tolerance/|n·d| on
/// meshed objects.
const MESH_DT_OVER: f64 = 0.001;

/// Builds the Embree scene with meshes at the default resolution, compares it with the
/// tracer, prints and checks the result (at least `min_agree` hit/miss agreement, at most
/// `dt_over` of the rays both hit over the |Δt| tolerance, at most 0.1 % unexcused hit/miss
/// disagreements).
fn referee_meshed(name: &str, scene: &Scene, seed: u64, min_agree: f64, dt_over: f64) -> Report {
    let embree =
        EmbreeScene::build_with(scene, &meshed()).unwrap_or_else(|e| panic!("{name}: {e}"));
    assert!(
        embree.skipped().is_empty(),
        "{name}: {:?}",
        embree.skipped()
    );
    let meshed = embree
        .checks
        .iter()
        .filter(|c| matches!(c, SdfCheck::Meshed { .. }))
        .count();
    assert!(meshed > 0, "{name}: nothing meshed");
    let tracer = SceneTracer::new(scene);
    let r = compare(scene, &tracer, &embree, seed);
    r.print(name);
    if let Err(e) = r.check_with(min_agree, dt_over, r.rays / 1000) {
        panic!("{name}: {e}");
    }
    r
}

/// The shipped feature scenes, whose composite objects (CSG, smooth operators, domain
/// repetition, twist and bend, implicit surfaces) the referee meshes, agree ray by ray with
/// the tracer.
#[test]
fn meshed_feature_scenes_agree_with_embree() {
    for (k, name) in ["csg", "smooth", "domain"].iter().enumerate() {
        let scene = asset_scene(name);
        let r = referee_meshed(name, &scene, 800 + k as u64, MESHED_AGREE, MESH_DT_OVER);
        assert!(r.dt.len() > 5000, "{name}: {} rays both hit", r.dt.len());
    }
}

/// The implicit surfaces of the shipped scene against their meshes. Looser than the other
/// scenes, and knowingly so: the quartic torus and the blobby sum are traced as f/λ with an
/// estimated λ far above |∇f| near parts of the surface, so the field stays below the tracer's
/// hit threshold ε(t) over a band much wider than ε(t) around the surface and the tracer stops
/// there, up to ~1 unit before the true surface that the mesh (and the field's own sign
/// change) puts behind it. Those hits are excused as near misses only where the band is
/// explained by the weak gradient; the rest are what the looser figures allow (measured: 97.1 %
/// agreement, 0.14 % of |Δt| over tolerance).
#[test]
fn meshed_implicit_scene_agrees_with_embree_within_the_tracer_band() {
    let scene = asset_scene("implicit");
    referee_meshed("implicit", &scene, 803, 0.96, 0.005);
}

/// The referee's meshes have teeth: the same object meshed 3× its tolerance too large (the
/// tape rounded by that much, so the surface moves out by it) fails the comparison that the
/// true mesh passes.
#[test]
fn offset_mesh_is_rejected() {
    let shape = "Subtraction(base: Box(half_extents: (0.9, 0.9, 0.9)), cut: Union([\
                 Transform(translate: (0.9, 0.9, 0.9), shape: Sphere(radius: 0.8)), \
                 Transform(rotate: (90, 0, 0), shape: Cylinder(half_height: 1.2, radius: 0.4))]))";
    let object = |shape: &str| format!("(shape: {shape}, rotate: (10, -25, 5))");
    let true_scene = scene(&object(shape));
    let embree = EmbreeScene::build_with(&true_scene, &meshed()).unwrap();
    let SdfCheck::Meshed { tolerance, .. } = embree.checks[0] else {
        panic!("{:?}", embree.checks[0]);
    };
    let tracer = SceneTracer::new(&true_scene);
    let r = compare(&true_scene, &tracer, &embree, 900);
    r.print("subtraction, true mesh");
    r.check_with(MESHED_AGREE, MESH_DT_OVER, r.rays / 1000)
        .unwrap_or_else(|e| panic!("the true mesh must pass: {e}"));

    let offset = scene(&object(&format!(
        "Round(radius: {}, shape: {shape})",
        3.0 * tolerance
    )));
    let embree_offset = EmbreeScene::build_with(&offset, &meshed()).unwrap();
    let r = compare(&true_scene, &tracer, &embree_offset, 900);
    r.print("subtraction, mesh offset 3τ");
    let err = r
        .check_with(MESHED_AGREE, MESH_DT_OVER, r.rays / 1000)
        .expect_err("a mesh offset by 3× its tolerance must be rejected");
    println!("    rejected: {err}");
    assert!(r.dt_over_fraction() > 0.5, "{}", r.dt_over_fraction());
}
