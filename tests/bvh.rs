//! Mesh acceleration: `MeshBvh`, `InstanceBvh` and `AabbBvh` against brute force, watertightness
//! on the Stanford bunny (with a control showing that a non-watertight test leaks on the same
//! rays), instancing against flattened geometry, the tmin/tmax contract, and bad input.
//!
//! The bunny is read from `$HYTRACE_ASSETS/obj/common-3d-test-models/stanford-bunny.obj`
//! (`HYTRACE_ASSETS` defaults to `../shared/assets` beside the crate); when it is missing the
//! test says so loudly, and fails under `CI=true`.

mod common;

use std::collections::HashMap;
use std::ops::ControlFlow;
use std::path::PathBuf;

use glam::{Affine3A, Quat, Vec3};
use hytrace::accel::bvh::{
    AabbBvh, BuildQuality, Instance, InstanceBvh, MeshBvh, MeshHit, ray_box_interval,
};
use hytrace::accel::triangle::{self, WatertightRay};
use hytrace::geom::{Aabb, Ray};
use rayon::prelude::*;

const QUALITIES: [BuildQuality; 4] = [
    BuildQuality::Fast,
    BuildQuality::Medium,
    BuildQuality::High,
    BuildQuality::Highest,
];

use hytrace::rng::Rng;

/// Closest hit over every triangle with the same watertight test and the same tie-break
/// (smallest t, then smallest index) as the BVH.
fn brute_closest(
    pos: &[Vec3],
    tris: &[[u32; 3]],
    o: Vec3,
    d: Vec3,
    tmin: f32,
    tmax: f32,
) -> Option<MeshHit> {
    let r = WatertightRay::new(o, d);
    let mut best: Option<MeshHit> = None;
    let mut tmax = tmax;
    for (i, t) in tris.iter().enumerate() {
        let [a, b, c] = t.map(|k| pos[k as usize]);
        if !triangle::is_finite(a, b, c) {
            continue;
        }
        if let Some(h) = triangle::intersect(&r, a, b, c, tmin, tmax)
            && best.is_none_or(|b| h.t < b.t)
        {
            best = Some(MeshHit {
                t: h.t,
                triangle: i as u32,
                u: h.u,
                v: h.v,
            });
            tmax = h.t;
        }
    }
    best
}

fn brute_any(pos: &[Vec3], tris: &[[u32; 3]], o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
    let r = WatertightRay::new(o, d);
    tris.iter().any(|t| {
        let [a, b, c] = t.map(|k| pos[k as usize]);
        triangle::is_finite(a, b, c) && triangle::intersect(&r, a, b, c, tmin, tmax).is_some()
    })
}

fn ray(o: Vec3, d: Vec3) -> Ray {
    // Deliberately not normalised here: the BVH accepts any non-zero direction.
    Ray {
        origin: o,
        direction: d,
    }
}

/// A soup of random triangles of very different sizes in [-1, 1]³, plus a few shared-edge
/// strips (so rays through shared edges and vertices occur) and axis-aligned triangles (so
/// axis-parallel rays run exactly along box faces).
fn soup(rng: &mut Rng, n: usize) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let mut pos = Vec::new();
    let mut tris = Vec::new();
    for i in 0..n {
        let size = [0.02, 0.1, 0.5][i % 3];
        let c = rng.vec3_in(-1.0, 1.0);
        let base = pos.len() as u32;
        if i % 17 == 0 {
            // Axis-aligned right triangle in a coordinate plane through c.
            let axis = i % 3;
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let mut e1 = Vec3::ZERO;
            e1[u] = size;
            let mut e2 = Vec3::ZERO;
            e2[v] = size;
            pos.extend([c, c + e1, c + e2]);
        } else {
            pos.extend([
                c,
                c + rng.vec3_in(-size, size),
                c + rng.vec3_in(-size, size),
            ]);
        }
        tris.push([base, base + 1, base + 2]);
    }
    // Strips: a row of quads sharing edges.
    for _ in 0..20 {
        let o = rng.vec3_in(-1.0, 1.0);
        let (e1, e2) = (rng.vec3_in(-0.1, 0.1), rng.vec3_in(-0.1, 0.1));
        let base = pos.len() as u32;
        for k in 0..10 {
            pos.push(o + k as f32 * e1);
            pos.push(o + k as f32 * e1 + e2);
        }
        for k in 0..9 {
            let q = base + 2 * k;
            tris.push([q, q + 2, q + 1]);
            tris.push([q + 1, q + 2, q + 3]);
        }
    }
    (pos, tris)
}

/// Rays of every kind: from outside at points inside, from inside, from points on triangles
/// (tmin = 0), along the axes (from vertices, so exactly on box planes), short and long.
fn soup_rays(
    rng: &mut Rng,
    pos: &[Vec3],
    tris: &[[u32; 3]],
    n: usize,
) -> Vec<(Vec3, Vec3, f32, f32)> {
    let mut rays = Vec::with_capacity(n);
    for i in 0..n {
        let (o, d, tmin, tmax) = match i % 6 {
            0 => {
                let o = rng.direction() * 3.0;
                (o, rng.vec3_in(-1.0, 1.0) - o, 0.0, f32::INFINITY)
            }
            1 => (rng.vec3_in(-1.0, 1.0), rng.direction(), 0.0, f32::INFINITY),
            2 => {
                // Origin on a triangle (rounded, so on it up to an ulp).
                let t = tris[rng.below(tris.len() as u64) as usize].map(|k| pos[k as usize]);
                let (mut u, mut v) = (rng.next_f32(), rng.next_f32());
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                let o = (1.0 - u - v) * t[0] + u * t[1] + v * t[2];
                (
                    o,
                    rng.direction() * rng.range_f32(0.5, 2.0),
                    0.0,
                    f32::INFINITY,
                )
            }
            3 => {
                // Axis-parallel, from a vertex (on the planes of its triangle's boxes).
                let o = pos[rng.below(pos.len() as u64) as usize];
                let mut d = Vec3::ZERO;
                d[rng.below(3) as usize] = if rng.next_f32() < 0.5 { 1.0 } else { -1.0 };
                (o, d, 0.0, f32::INFINITY)
            }
            4 => {
                // Bounded segment with tmin > 0.
                let o = rng.vec3_in(-1.5, 1.5);
                (
                    o,
                    rng.direction(),
                    rng.range_f32(0.0, 0.3),
                    rng.range_f32(0.3, 1.5),
                )
            }
            _ => {
                // Ray at a vertex from far away (through a shared vertex in the strips).
                let p = pos[rng.below(pos.len() as u64) as usize];
                let o = rng.direction() * 4.0;
                (o, (p - o).normalize(), 0.0, f32::INFINITY)
            }
        };
        rays.push((o, d, tmin, tmax));
    }
    rays
}

#[test]
fn random_soups_match_brute_force_for_every_quality() {
    for seed in [1u64, 2] {
        let mut rng = Rng::new(seed);
        let (pos, tris) = soup(&mut rng, 4000);
        let rays = soup_rays(&mut rng, &pos, &tris, 12_000);
        let expected: Vec<(Option<MeshHit>, bool)> = rays
            .par_iter()
            .map(|&(o, d, tmin, tmax)| {
                (
                    brute_closest(&pos, &tris, o, d, tmin, tmax),
                    brute_any(&pos, &tris, o, d, tmin, tmax),
                )
            })
            .collect();
        let hits = expected.iter().filter(|e| e.0.is_some()).count();
        assert!(hits > 3000, "the rays must hit something: {hits}");
        for q in QUALITIES {
            let bvh = MeshBvh::build(&pos, &tris, q);
            assert_eq!(bvh.stats().kept, tris.len());
            for (&(o, d, tmin, tmax), (closest, any)) in rays.iter().zip(&expected) {
                let r = ray(o, d);
                // Exact equality: same test, same tie-break, nothing lost by the tree.
                assert_eq!(
                    bvh.closest_hit(&r, tmin, tmax),
                    *closest,
                    "{q:?} closest: o={o} d={d} [{tmin}, {tmax}]"
                );
                assert_eq!(bvh.any_hit(&r, tmin, tmax), *any, "{q:?} any: o={o} d={d}");
            }
            println!(
                "seed {seed} {q:?}: {} nodes, depth {}, {} refs, built in {:?}; {hits} of {} rays hit",
                bvh.node_count(),
                bvh.stats().max_depth,
                bvh.stats().references,
                bvh.stats().build_time,
                rays.len()
            );
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Watertightness on the bunny.

fn assets_dir() -> Option<PathBuf> {
    Some(common::assets())
}

/// The bunny as (positions, triangles), or `None` (after a loud message; a panic under
/// `CI=true`) when the file is missing.
fn load_bunny() -> Option<(Vec<Vec3>, Vec<[u32; 3]>)> {
    let path = assets_dir()?.join("obj/common-3d-test-models/stanford-bunny.obj");
    if !path.is_file() {
        let msg = format!(
            "\n!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!\n\
             !!! the Stanford bunny is missing at {}\n\
             !!! set HYTRACE_ASSETS to the shared assets folder; the bunny tests are SKIPPED\n\
             !!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!\n",
            path.display()
        );
        eprintln!("{msg}");
        if std::env::var("CI").is_ok_and(|v| v == "true") {
            panic!("CI=true and the bunny is missing at {}", path.display());
        }
        return None;
    }
    let opts = tobj::LoadOptions {
        single_index: true,
        triangulate: true,
        ..Default::default()
    };
    let (models, _) = tobj::load_obj(&path, &opts).expect("bunny loads");
    let mut pos = Vec::new();
    let mut tris = Vec::new();
    for m in models {
        let base = pos.len() as u32;
        pos.extend(
            m.mesh
                .positions
                .chunks_exact(3)
                .map(|p| Vec3::new(p[0], p[1], p[2])),
        );
        tris.extend(
            m.mesh
                .indices
                .chunks_exact(3)
                .map(|t| [base + t[0], base + t[1], base + t[2]]),
        );
    }
    Some((pos, tris))
}

/// Möller & Trumbore ("Fast, minimum storage ray-triangle intersection", JGT 1997) with strict
/// inequalities at the edges: the classic test, deliberately *not* watertight.
fn moller_trumbore_strict(o: Vec3, d: Vec3, a: Vec3, b: Vec3, c: Vec3) -> Option<f32> {
    let e1 = b - a;
    let e2 = c - a;
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - a;
    let u = s.dot(p) * inv;
    if !(u > 0.0 && u < 1.0) {
        return None;
    }
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    if !(v > 0.0 && u + v < 1.0) {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t >= 0.0).then_some(t)
}

struct Aimed {
    origin: Vec3,
    dir: Vec3,
    /// Distance to the aimed-at point.
    t_aim: f32,
    /// The triangles around the aimed-at edge or vertex.
    local: Vec<u32>,
    vertex: bool,
}

/// Rays aimed exactly (up to the rounding of the aim point and of the normalised direction) at
/// points of edges shared by exactly two consistently oriented triangles and at vertices whose
/// whole fan is such a closed disc, from origins outside the bounds, in directions that see every
/// triangle around the target from the same side with |cos| ≥ 0.1. Such a ray crosses the surface
/// at the target (the triangles around it project onto a neighbourhood of the target's
/// projection), so it must hit *something* at t ≤ t_aim + tolerance.
fn aimed_rays(pos: &[Vec3], tris: &[[u32; 3]], n_edge: usize, n_vertex: usize) -> Vec<Aimed> {
    // Undirected edge → (triangles, sum of directions: 0 when used once each way).
    let mut edges: HashMap<(u32, u32), (Vec<u32>, i32)> = HashMap::new();
    for (i, t) in tris.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let e = edges.entry((a.min(b), a.max(b))).or_default();
            e.0.push(i as u32);
            e.1 += if a < b { 1 } else { -1 };
        }
    }
    let good = |a: u32, b: u32| {
        edges
            .get(&(a.min(b), a.max(b)))
            .is_some_and(|(ts, dir)| ts.len() == 2 && *dir == 0)
    };
    let normal = |t: u32| {
        let [a, b, c] = tris[t as usize].map(|k| pos[k as usize]);
        (b - a).cross(c - a).normalize()
    };
    let mut good_edges: Vec<(u32, u32, [u32; 2])> = edges
        .iter()
        .filter(|(_, (ts, dir))| ts.len() == 2 && *dir == 0)
        .map(|(&(a, b), (ts, _))| (a, b, [ts[0], ts[1]]))
        .collect();
    good_edges.sort_unstable();
    let mut fans: HashMap<u32, Vec<u32>> = HashMap::new();
    for (i, t) in tris.iter().enumerate() {
        for &v in t {
            fans.entry(v).or_default().push(i as u32);
        }
    }
    let mut good_vertices: Vec<(u32, Vec<u32>)> = fans
        .into_iter()
        .filter(|(v, fan)| {
            fan.len() >= 3
                && fan.iter().all(|&t| {
                    let t = tris[t as usize];
                    t.iter().filter(|&&w| w != *v).all(|&w| good(*v, w))
                })
        })
        .collect();
    good_vertices.sort_unstable();
    let bounds = pos
        .iter()
        .fold(Aabb::EMPTY, |b, p| b.union(&Aabb::new(*p, *p)));
    let reach = 2.0 * bounds.diagonal();
    let mut rng = Rng::new(0xB0_77E5);
    let mut out = Vec::with_capacity(n_edge + n_vertex);
    // A direction w (from the target towards the origin) that sees all of `local` from one
    // side with |cos| >= 0.1.
    let pick = |rng: &mut Rng, local: &[u32]| -> Option<Vec3> {
        let normals: Vec<Vec3> = local.iter().map(|&t| normal(t)).collect();
        for _ in 0..64 {
            let w = rng.direction();
            let s: Vec<f32> = normals.iter().map(|n| n.dot(w)).collect();
            if s.iter().all(|&c| c >= 0.1) || s.iter().all(|&c| c <= -0.1) {
                return Some(w);
            }
        }
        None
    };
    while out.len() < n_edge {
        let (a, b, ts) = good_edges[rng.below(good_edges.len() as u64) as usize];
        let Some(w) = pick(&mut rng, &ts) else {
            continue;
        };
        let s = rng.range_f32(0.01, 0.99);
        let (pa, pb) = (pos[a as usize], pos[b as usize]);
        let target = pa + s * (pb - pa);
        let origin = target + reach * w;
        let d = target - origin;
        out.push(Aimed {
            origin,
            dir: d.normalize(),
            t_aim: d.length(),
            local: ts.to_vec(),
            vertex: false,
        });
    }
    while out.len() < n_edge + n_vertex {
        let (v, fan) = &good_vertices[rng.below(good_vertices.len() as u64) as usize];
        let Some(w) = pick(&mut rng, fan) else {
            continue;
        };
        let target = pos[*v as usize];
        let origin = target + reach * w;
        let d = target - origin;
        out.push(Aimed {
            origin,
            dir: d.normalize(),
            t_aim: d.length(),
            local: fan.clone(),
            vertex: true,
        });
    }
    out
}

#[test]
fn bunny_is_watertight_at_edges_and_vertices() {
    let Some((pos, tris)) = load_bunny() else {
        return;
    };
    assert!(tris.len() > 69_000, "{} triangles", tris.len());
    let bvh = MeshBvh::build(&pos, &tris, BuildQuality::Medium);
    let rays = aimed_rays(&pos, &tris, 80_000, 40_000);
    let tol = |a: &Aimed| a.t_aim * (1.0 + 1e-4);

    // Watertight test through the BVH: every ray hits something before it passes the target.
    let leaks: Vec<usize> = rays
        .par_iter()
        .enumerate()
        .filter(|(_, a)| !bvh.any_hit(&ray(a.origin, a.dir), 0.0, tol(a)))
        .map(|(i, _)| i)
        .collect();
    // And locally: one of the triangles around the target is hit.
    let local_leaks = rays
        .par_iter()
        .filter(|a| {
            let r = WatertightRay::new(a.origin, a.dir);
            !a.local.iter().any(|&t| {
                let [p, q, s] = tris[t as usize].map(|k| pos[k as usize]);
                triangle::intersect(&r, p, q, s, 0.0, tol(a)).is_some()
            })
        })
        .count();
    // The closest hit agrees with any_hit and lies at or before the target.
    let closest_bad = rays
        .par_iter()
        .filter(|a| {
            bvh.closest_hit(&ray(a.origin, a.dir), 0.0, f32::INFINITY)
                .is_none_or(|h| h.t > tol(a))
        })
        .count();

    // Control: Möller–Trumbore with strict edge tests on the same rays. First the triangles
    // around the target, then, for the rays that miss those, every triangle (anything hit
    // before the target saves the ray).
    let mt_local_miss: Vec<&Aimed> = rays
        .iter()
        .filter(|a| {
            !a.local.iter().any(|&t| {
                let [p, q, s] = tris[t as usize].map(|k| pos[k as usize]);
                moller_trumbore_strict(a.origin, a.dir, p, q, s).is_some_and(|t| t <= tol(a))
            })
        })
        .collect();
    // "Every triangle" through an AabbBvh over the triangles' boxes (grown by 1e-6, far more
    // than the rounding of a hit point): a triangle the ray hits has a box the ray crosses.
    let tri_boxes: Vec<Aabb> = tris
        .iter()
        .map(|t| {
            let [p, q, s] = t.map(|k| pos[k as usize]);
            Aabb::new(p.min(q).min(s), p.max(q).max(s))
        })
        .collect();
    let box_bvh = AabbBvh::build(&tri_boxes);
    let mt_leaks: Vec<&&Aimed> = mt_local_miss
        .par_iter()
        .filter(|a| {
            let mut hit = false;
            let mut tmax = tol(a);
            box_bvh.visit_within(&ray(a.origin, a.dir), 0.0, &mut tmax, 1e-6, |k, _, _, _| {
                let [p, q, s] = tris[k].map(|k| pos[k as usize]);
                hit = moller_trumbore_strict(a.origin, a.dir, p, q, s).is_some_and(|t| t <= tol(a));
                if hit {
                    ControlFlow::Break(())
                } else {
                    ControlFlow::Continue(())
                }
            });
            !hit
        })
        .collect();
    let mt_vertex_leaks = mt_leaks.iter().filter(|a| a.vertex).count();
    // The control itself is a correct test away from edges: rays at the centroids of the same
    // triangles, from the same origins, do not miss them.
    let mt_centroid_misses = rays
        .par_iter()
        .filter(|a| {
            let t = a.local[0];
            let [p, q, s] = tris[t as usize].map(|k| pos[k as usize]);
            let d = ((p + q + s) / 3.0 - a.origin).normalize();
            moller_trumbore_strict(a.origin, d, p, q, s).is_none()
        })
        .count();
    println!(
        "bunny: {} triangles, {} rays ({} at edges, {} at vertices); watertight leaks: {} (local {}), \
         closest-hit misses: {}; strict Möller–Trumbore leaks: {} ({} at edges, {} at vertices), \
         misses at centroids: {}",
        tris.len(),
        rays.len(),
        rays.iter().filter(|a| !a.vertex).count(),
        rays.iter().filter(|a| a.vertex).count(),
        leaks.len(),
        local_leaks,
        closest_bad,
        mt_leaks.len(),
        mt_leaks.len() - mt_vertex_leaks,
        mt_vertex_leaks,
        mt_centroid_misses,
    );
    assert!(rays.len() >= 100_000);
    assert!(
        leaks.is_empty(),
        "watertight BVH leaks on rays {:?}",
        &leaks[..leaks.len().min(10)]
    );
    assert_eq!(local_leaks, 0);
    assert_eq!(closest_bad, 0);
    assert_eq!(
        mt_centroid_misses, 0,
        "the control is a working test away from edges"
    );
    assert!(
        !mt_leaks.is_empty(),
        "the control test must leak, or the rays do not really graze edges"
    );
}

// ---------------------------------------------------------------------------------------------
// Instances.

/// A closed, bumpy UV sphere (no self-intersections, so every closest hit is unambiguous away
/// from edges).
fn bumpy_sphere(rings: usize, segments: usize) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let mut pos = vec![Vec3::Y, -Vec3::Y];
    for i in 1..rings {
        let th = std::f32::consts::PI * i as f32 / rings as f32;
        for j in 0..segments {
            let ph = std::f32::consts::TAU * j as f32 / segments as f32;
            let r = 1.0 + 0.15 * (3.0 * th).sin() * (5.0 * ph).cos();
            pos.push(r * Vec3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin()));
        }
    }
    let at = |i: usize, j: usize| (2 + (i - 1) * segments + j % segments) as u32;
    let mut tris = Vec::new();
    for j in 0..segments {
        tris.push([0, at(1, j + 1), at(1, j)]);
        tris.push([1, at(rings - 1, j), at(rings - 1, j + 1)]);
    }
    for i in 1..rings - 1 {
        for j in 0..segments {
            tris.push([at(i, j), at(i, j + 1), at(i + 1, j)]);
            tris.push([at(i + 1, j), at(i, j + 1), at(i + 1, j + 1)]);
        }
    }
    (pos, tris)
}

/// A tree of one instance is walked without its instance tree (the mesh's root test culls
/// as the instance's box would): the answers of brute force in object space, bit for bit,
/// for a transformed instance and an untransformed one, closest and any hit.
#[test]
fn one_instance_gives_the_brute_force_answers() {
    let (pos, tris) = bumpy_sphere(16, 24);
    let meshes = vec![MeshBvh::build(&pos, &tris, BuildQuality::Medium)];
    for transform in [
        Affine3A::IDENTITY,
        Affine3A::from_scale_rotation_translation(
            Vec3::new(1.0, 2.5, 0.6),
            Quat::from_axis_angle(Vec3::new(1.0, 2.0, 0.5).normalize(), 0.7),
            Vec3::new(-0.8, 0.2, 0.1),
        ),
    ] {
        let tlas = InstanceBvh::build(
            &meshes,
            &[Instance { mesh: 0, transform }],
            BuildQuality::Medium,
        );
        let inv = transform.inverse();
        let mut rng = Rng::new(7);
        let mut hits = 0;
        for i in 0..4000 {
            let o = if i % 2 == 0 {
                rng.direction() * 6.0
            } else {
                rng.vec3_in(-1.0, 1.0)
            };
            let r = Ray::new(o, (rng.vec3_in(-1.5, 1.5) - o).normalize());
            let tmax = if i % 3 == 0 { 5.0 } else { f32::INFINITY };
            let (oo, od) = (
                inv.transform_point3(r.origin),
                inv.transform_vector3(r.direction),
            );
            let brute = brute_closest(&pos, &tris, oo, od, 0.0, tmax);
            let got = tlas.closest_hit(&meshes, &r, 0.0, tmax);
            assert_eq!(
                got.map(|h| (h.t.to_bits(), h.instance, h.triangle)),
                brute.map(|h| (h.t.to_bits(), 0, h.triangle)),
                "ray {i}"
            );
            assert_eq!(
                tlas.any_hit(&meshes, &r, 0.0, tmax),
                brute.is_some(),
                "ray {i}"
            );
            hits += usize::from(brute.is_some());
        }
        assert!(hits > 1000, "the rays must hit: {hits}");
    }
}

#[test]
fn instances_match_flattened_geometry() {
    let (pos, tris) = bumpy_sphere(24, 40);
    let meshes = vec![MeshBvh::build(&pos, &tris, BuildQuality::Medium)];
    let instances = [
        Instance {
            mesh: 0,
            transform: Affine3A::from_scale_rotation_translation(
                Vec3::new(1.0, 2.5, 0.6),
                Quat::from_axis_angle(Vec3::new(1.0, 2.0, 0.5).normalize(), 0.7),
                Vec3::new(-0.8, 0.2, 0.1),
            ),
        },
        Instance {
            mesh: 0,
            transform: Affine3A::from_scale_rotation_translation(
                Vec3::new(0.4, 1.3, 2.0),
                Quat::from_rotation_z(-1.1) * Quat::from_rotation_x(0.4),
                Vec3::new(0.9, -0.3, 0.4),
            ),
        },
    ];
    let tlas = InstanceBvh::build(&meshes, &instances, BuildQuality::Medium);
    assert_eq!(tlas.stats().kept, 2);
    // Flattened: instance k's triangle i is triangle k·n + i of the world mesh.
    let n = tris.len() as u32;
    let mut wpos = Vec::new();
    let mut wtris = Vec::new();
    for (k, inst) in instances.iter().enumerate() {
        let base = wpos.len() as u32;
        wpos.extend(pos.iter().map(|p| inst.transform.transform_point3(*p)));
        wtris.extend(tris.iter().map(|t| t.map(|i| base + i)));
        assert_eq!(base, k as u32 * pos.len() as u32);
    }
    let flat = MeshBvh::build(&wpos, &wtris, BuildQuality::Medium);

    let mut rng = Rng::new(99);
    let (mut hits, mut same_tri, mut edge_cases) = (0, 0, 0);
    for i in 0..10_000 {
        let (o, d) = if i % 2 == 0 {
            let o = rng.direction() * 6.0;
            (o, (rng.vec3_in(-2.0, 2.0) - o).normalize())
        } else {
            (rng.vec3_in(-1.0, 1.0), rng.direction())
        };
        let r = Ray::new(o, d);
        let (o, d) = (r.origin, r.direction);
        let a = tlas.closest_hit(&meshes, &r, 0.0, f32::INFINITY);
        let b = flat.closest_hit(&r, 0.0, f32::INFINITY);
        assert_eq!(
            tlas.any_hit(&meshes, &r, 0.0, f32::INFINITY),
            a.is_some(),
            "any_hit agrees with closest_hit"
        );
        // The TLAS against brute force over the instances (object-space rays, same
        // arithmetic): exact.
        let mut brute: Option<(f32, u32, u32)> = None;
        for (k, inst) in instances.iter().enumerate() {
            let inv = inst.transform.inverse();
            let (oo, od) = (inv.transform_point3(o), inv.transform_vector3(d));
            if let Some(h) = brute_closest(&pos, &tris, oo, od, 0.0, f32::INFINITY)
                && brute.is_none_or(|b| h.t < b.0)
            {
                brute = Some((h.t, k as u32, h.triangle));
            }
        }
        assert_eq!(
            a.map(|h| (h.t, h.instance, h.triangle)),
            brute,
            "TLAS vs brute force"
        );
        // Against the flattened world mesh: the same surface up to rounding.
        match (a, b) {
            (Some(a), Some(b)) => {
                hits += 1;
                // Relative, with t floored at 0.1 (a tenth of the mesh): the rounding of the
                // transformed origin is an absolute error, which dominates for tiny t.
                assert!(
                    (a.t - b.t).abs() <= 1e-4 * a.t.max(b.t).max(0.1),
                    "t: {} vs {} (o={o} d={d})",
                    a.t,
                    b.t
                );
                if a.instance * n + a.triangle == b.triangle {
                    same_tri += 1;
                    assert!((a.u - b.u).abs() < 1e-3 && (a.v - b.v).abs() < 1e-3);
                } else {
                    // Only on an edge between two triangles can rounding pick the other one.
                    let near_edge = |u: f32, v: f32| u.min(v).min(1.0 - u - v) < 1e-3;
                    assert!(near_edge(a.u, a.v) && near_edge(b.u, b.v), "{a:?} {b:?}");
                    edge_cases += 1;
                }
            }
            (None, None) => {}
            (a, b) => {
                // Only a silhouette-grazing ray may be a hit in one and a miss in the other.
                let h = a.map(|h| (h.u, h.v)).or(b.map(|h| (h.u, h.v))).unwrap();
                assert!(h.0.min(h.1).min(1.0 - h.0 - h.1) < 1e-3, "{a:?} vs {b:?}");
                edge_cases += 1;
            }
        }
    }
    println!("instances: {hits} hits, {same_tri} on the same triangle, {edge_cases} edge cases");
    assert!(hits > 3000 && edge_cases < 20, "{hits} {edge_cases}");
}

// ---------------------------------------------------------------------------------------------
// tmin / tmax.

#[test]
fn tmin_and_short_rays() {
    // Two big parallel triangles, z = 0 and z = 1, and a tilted one further up.
    let pos = vec![
        Vec3::new(-5.0, -5.0, 0.0),
        Vec3::new(5.0, -5.0, 0.0),
        Vec3::new(0.0, 5.0, 0.0),
        Vec3::new(-5.0, -5.0, 1.0),
        Vec3::new(5.0, -5.0, 1.0),
        Vec3::new(0.0, 5.0, 1.0),
        Vec3::new(-5.0, -5.0, 2.0),
        Vec3::new(5.0, -5.0, 2.5),
        Vec3::new(0.0, 5.0, 3.0),
    ];
    let tris = vec![[0, 1, 2], [3, 4, 5], [6, 7, 8]];
    let bvh = MeshBvh::build(&pos, &tris, BuildQuality::Medium);
    let d = Vec3::new(0.3, 0.1, 1.0).normalize();

    // Origin exactly on triangle 0 (its plane is z = 0 exactly): t is exactly 0, reported
    // with tmin = 0 ...
    let on = Ray::new(Vec3::new(0.1, 0.2, 0.0), d);
    let h = bvh.closest_hit(&on, 0.0, f32::INFINITY).unwrap();
    assert_eq!((h.triangle, h.t), (0, 0.0));
    assert!(
        bvh.any_hit(&on, 0.0, 0.0),
        "a zero-length interval at the surface"
    );
    // ... and skipped with tmin = 1e-3: the next surface is triangle 1 at 1/cos θ.
    let h = bvh.closest_hit(&on, 1e-3, f32::INFINITY).unwrap();
    assert_eq!(h.triangle, 1);
    assert!((h.t - 1.0 / d.z).abs() < 1e-5, "{}", h.t);

    // Origin on the tilted triangle 2 (on it only up to rounding): with tmin = 0 the answer is
    // either that triangle at |t| ≈ 0 or (if its rounded t is negative) nothing further up —
    // exactly what brute force says; with tmin = 1e-3 it is skipped.
    let mut rng = Rng::new(5);
    let (mut self_hits, mut skipped) = (0, 0);
    for _ in 0..1000 {
        let (mut u, mut v) = (rng.next_f32(), rng.next_f32());
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        let o = (1.0 - u - v) * pos[6] + u * pos[7] + v * pos[8];
        let dir = rng.direction();
        let n = (pos[7] - pos[6]).cross(pos[8] - pos[6]).normalize();
        if n.dot(dir).abs() < 0.01 {
            continue; // grazing: the start surface's rounded t could exceed any small tmin
        }
        let r = Ray::new(o, dir);
        let got = bvh.closest_hit(&r, 0.0, f32::INFINITY);
        assert_eq!(
            got,
            brute_closest(&pos, &tris, o, r.direction, 0.0, f32::INFINITY)
        );
        match got {
            Some(h) if h.triangle == 2 => {
                // The origin is off the plane by the rounding of its coordinates (≤ 5).
                assert!(h.t.abs() < 4e-6 / n.dot(dir).abs(), "{}", h.t);
                self_hits += 1;
            }
            _ => skipped += 1,
        }
        let far = bvh.closest_hit(&r, 1e-3, f32::INFINITY);
        assert!(
            far.is_none_or(|h| h.triangle != 2),
            "tmin = 1e-3 skips the start surface"
        );
    }
    println!("origin on a tilted triangle, tmin = 0: {self_hits} report it, {skipped} do not");
    assert!(self_hits > 100, "{self_hits}");

    // A negative tmin is taken as 0: triangle 0, half a unit behind the origin, is not
    // reported, for the mesh tree and through an instance.
    let above = Ray::new(Vec3::new(0.1, 0.2, 0.5), Vec3::Z);
    assert_eq!(
        bvh.closest_hit(&above, -10.0, f32::INFINITY)
            .map(|h| h.triangle),
        Some(1)
    );
    assert!(!bvh.any_hit(&above, -10.0, 0.25));
    let meshes = [bvh.clone()];
    let tlas = InstanceBvh::build(
        &meshes,
        &[Instance::from((
            0,
            Affine3A::from_translation(Vec3::new(0.0, 0.0, 0.25)),
        ))],
        BuildQuality::Medium,
    );
    assert_eq!(
        tlas.closest_hit(&meshes, &above, -10.0, f32::INFINITY)
            .map(|h| h.triangle),
        Some(1)
    );
    assert!(!tlas.any_hit(&meshes, &above, -10.0, 0.5));

    // Short rays: a surface at t = 3e-5 is hit with tmax = 5e-5 (obvhs's node test would clamp
    // the entry distance to 1e-4 and cull it), not with tmax = 2e-5.
    let short = Ray::new(Vec3::new(0.1, 0.2, -3e-5), Vec3::Z);
    let h = bvh.closest_hit(&short, 0.0, 5e-5).unwrap();
    assert_eq!(h.triangle, 0);
    assert!((h.t - 3e-5).abs() < 1e-9, "{}", h.t);
    assert!(bvh.any_hit(&short, 0.0, 5e-5));
    assert!(bvh.closest_hit(&short, 0.0, 2e-5).is_none());
    assert!(!bvh.any_hit(&short, 0.0, 2e-5));
    // The same in a deeper tree (the surface is then behind several levels of boxes).
    let mut rng = Rng::new(8);
    let (mut p2, mut t2) = soup(&mut rng, 3000);
    let base = p2.len() as u32;
    p2.extend([
        Vec3::new(0.30, 0.30, 0.5),
        Vec3::new(0.31, 0.30, 0.5),
        Vec3::new(0.30, 0.31, 0.5),
    ]);
    t2.push([base, base + 1, base + 2]);
    let target = t2.len() as u32 - 1;
    let big = MeshBvh::build(&p2, &t2, BuildQuality::High);
    assert!(big.stats().max_depth >= 3);
    let short = Ray::new(Vec3::new(0.302, 0.303, 0.5 - 3e-5), Vec3::Z);
    assert_eq!(
        big.closest_hit(&short, 0.0, 5e-5).map(|h| h.triangle),
        Some(target)
    );
    // And obvhs's own traversal does lose it (which is why the traversal is ours).
    let otris: Vec<obvhs::triangle::Triangle> = t2
        .iter()
        .map(|t| obvhs::triangle::Triangle {
            v0: p2[t[0] as usize].into(),
            v1: p2[t[1] as usize].into(),
            v2: p2[t[2] as usize].into(),
        })
        .collect();
    let cw = obvhs::cwbvh::builder::build_cwbvh_from_tris(
        &otris,
        obvhs::BvhBuildParams::medium_build(),
        &mut std::time::Duration::default(),
    );
    let oray = obvhs::ray::Ray::new(short.origin.into(), short.direction.into(), 0.0, 5e-5);
    let mut ohit = obvhs::ray::RayHit::none();
    let found = cw.ray_traverse(oray, &mut ohit, |r, id| {
        otris[cw.primitive_indices[id] as usize].intersect(r)
    });
    assert!(
        !found,
        "obvhs 0.4's 1e-4 clamp is expected to cull this short ray"
    );
}

// ---------------------------------------------------------------------------------------------
// Boxes.

fn brute_boxes(
    boxes: &[Aabb],
    r: &Ray,
    tmin: f32,
    tmax: f32,
    margin: f32,
) -> Vec<(usize, f32, f32)> {
    let mut v: Vec<(usize, f32, f32)> = boxes
        .iter()
        .enumerate()
        .filter(|(_, b)| !b.is_empty())
        .filter_map(|(i, b)| {
            let b = if margin > 0.0 { b.expand(margin) } else { *b };
            ray_box_interval(&b, r, tmin, tmax).map(|(t0, t1)| (i, t0, t1))
        })
        .collect();
    v.sort_by_key(|e| e.0);
    v
}

/// A random ray for the box walks of `boxes`, the `i`-th kind of four, and its range.
fn box_walk_ray(rng: &mut Rng, boxes: &[Aabb], i: usize) -> (Ray, f32, f32) {
    let (o, d) = match i % 4 {
        0 => (rng.direction() * 20.0, rng.vec3_in(-10.0, 10.0)),
        1 => (rng.vec3_in(-10.0, 10.0), rng.direction()),
        2 => {
            // Axis-parallel from a box corner (exactly on two of its planes).
            let b = boxes[rng.below(boxes.len() as u64) as usize];
            let mut d = Vec3::ZERO;
            d[rng.below(3) as usize] = if rng.next_f32() < 0.5 { 1.0 } else { -1.0 };
            (b.min, d)
        }
        _ => (Vec3::new(0.5, 1.0, 0.5), rng.direction()),
    };
    let r = ray(o, d - if i.is_multiple_of(4) { o } else { Vec3::ZERO });
    let (tmin, tmax) = if i.is_multiple_of(3) {
        (0.5, 15.0)
    } else {
        (0.0, f32::INFINITY)
    };
    (r, tmin, tmax)
}

/// Checks one ray's walks of `bvh` (built over `boxes`) against a scan with
/// `ray_box_interval`: every crossed box once with exactly its interval, nearest entry first;
/// a closest-hit walk that lowers tmax gets the interval clipped to the lowered tmax and finds
/// the nearest entry; an any-hit walk stops at the first; grown boxes likewise. Returns the
/// boxes crossed and those the closest-hit walk visited.
fn check_box_walks(bvh: &AabbBvh, boxes: &[Aabb], r: &Ray, tmin: f32, tmax: f32) -> (usize, usize) {
    let expect = brute_boxes(boxes, r, tmin, tmax, 0.0);

    let mut got = Vec::new();
    let mut tm = tmax;
    bvh.visit(r, tmin, &mut tm, |k, t0, t1, _| {
        got.push((k, t0, t1));
        ControlFlow::Continue(())
    });
    let entries: Vec<f32> = got.iter().map(|e| e.1).collect();
    // the tree sorts a node's children by the entry into the child's box, which holds
    // several boxes in a big tree: only the scan of a few boxes orders them exactly
    if boxes.len() <= 8 {
        assert!(entries.is_sorted(), "nearest entry first: {entries:?}");
    }
    got.sort_by_key(|e| e.0);
    assert_eq!(got, expect, "o={} d={}", r.origin, r.direction);

    // Closest-hit style: pretend every box is hit at its entry; shrinking tmax prunes.
    let mut tm = tmax;
    let mut best: Option<(f32, usize)> = None;
    let mut visits = 0;
    bvh.visit(r, tmin, &mut tm, |k, t0, t1, tmax| {
        visits += 1;
        assert_eq!(
            ray_box_interval(&boxes[k], r, tmin, *tmax),
            Some((t0, t1)),
            "the interval within the lowered tmax"
        );
        if best.is_none_or(|b| (t0, k) < b) {
            best = Some((t0, k));
            *tmax = t0;
        }
        ControlFlow::Continue(())
    });
    let brute_best = expect
        .iter()
        .map(|e| (e.1, e.0))
        .min_by(|a, b| a.partial_cmp(b).unwrap());
    assert_eq!(best.map(|b| b.0), brute_best.map(|b| b.0));

    // Any-hit style: stop at the first.
    let mut any = 0;
    let mut tm = tmax;
    bvh.visit(r, tmin, &mut tm, |_, _, _, _| {
        any += 1;
        ControlFlow::Break(())
    });
    assert_eq!(any, usize::from(!expect.is_empty()));

    // Grown boxes (soft-shadow queries).
    for margin in [0.25, 0.0, -1.0] {
        let mut got = Vec::new();
        let mut tm = tmax;
        bvh.visit_within(r, tmin, &mut tm, margin, |k, t0, t1, _| {
            got.push((k, t0, t1));
            ControlFlow::Continue(())
        });
        got.sort_by_key(|e| e.0);
        assert_eq!(got, brute_boxes(boxes, r, tmin, tmax, margin));
    }
    (expect.len(), visits)
}

#[test]
fn aabb_bvh_visits_exactly_the_crossed_boxes() {
    let mut rng = Rng::new(1234);
    let mut boxes: Vec<Aabb> = (0..10_000)
        .map(|i| {
            let c = rng.vec3_in(-10.0, 10.0);
            if i % 50 == 0 {
                // Flat boxes (zero extent on an axis), like the bounds of a planar patch.
                let mut h = rng.vec3_in(0.0, 0.3);
                h[i % 3] = 0.0;
                Aabb::new(c - h, c + h)
            } else {
                let h = rng.vec3_in(0.01, 0.3);
                Aabb::new(c - h, c + h)
            }
        })
        .collect();
    // Box corners that coincide: several rays below start on box faces.
    boxes.push(Aabb::new(Vec3::ZERO, Vec3::ONE));
    boxes.push(Aabb::new(Vec3::ONE, Vec3::splat(2.0)));
    let bvh = AabbBvh::build(&boxes);
    assert_eq!(bvh.stats().kept, boxes.len());
    assert!(bvh.unbounded().is_empty());
    let mut total_visits = 0usize;
    let mut closest_visits = 0usize;
    for i in 0..3000 {
        let (r, tmin, tmax) = box_walk_ray(&mut rng, &boxes, i);
        let (crossed, visited) = check_box_walks(&bvh, &boxes, &r, tmin, tmax);
        total_visits += crossed;
        closest_visits += visited;
    }
    println!(
        "boxes: {} nodes; {total_visits} boxes crossed in all, {closest_visits} visited by the \
         shrinking walk",
        bvh.node_count()
    );
    assert!(
        closest_visits * 2 < total_visits,
        "front-to-back order prunes"
    );
}

/// A scene's handful of SDF objects is scanned rather than walked: the same boxes with the
/// same intervals, nearest entry first, for one to eight boxes (and nine, walked again),
/// among them flat, touching, nested and coinciding ones.
#[test]
fn a_few_boxes_are_scanned_with_the_walks_answers() {
    let mut rng = Rng::new(77);
    for set in 0..400 {
        let n = 1 + set % 9;
        let mut boxes: Vec<Aabb> = (0..n)
            .map(|k| {
                let c = rng.vec3_in(-3.0, 3.0);
                let mut h = rng.vec3_in(0.0, 2.0);
                if k % 3 == 1 {
                    h[k % 3] = 0.0;
                }
                Aabb::new(c - h, c + h)
            })
            .collect();
        if set % 4 == 0 && n > 1 {
            boxes[n - 1] = boxes[0];
        }
        if set % 5 == 0 && n > 2 {
            boxes[1] = Aabb::new(boxes[0].max, boxes[0].max + Vec3::ONE);
        }
        let bvh = AabbBvh::build(&boxes);
        for i in 0..200 {
            let (r, tmin, tmax) = box_walk_ray(&mut rng, &boxes, i);
            check_box_walks(&bvh, &boxes, &r, tmin, tmax);
        }
    }
}

/// Rays visited many at a time (culled in groups where a tree holds 9 to 64 boxes, walked one
/// by one elsewhere) meet exactly the boxes a scan finds, each with its interval, the
/// unbounded ones first and the others nearest entry first: for coherent groups (neighbouring
/// camera rays, parallel shadow rays from nearby points), incoherent ones, rays with a zero
/// direction component or starting on box planes, empty and NaN ranges, and grown boxes.
#[test]
fn rays_visited_together_meet_the_boxes_each_meets_alone() {
    let mut rng = Rng::new(4242);
    for set in 0..240 {
        let n = 1 + set % 70;
        let mut boxes: Vec<Aabb> = (0..n)
            .map(|k| {
                let c = rng.vec3_in(-3.0, 3.0);
                let mut h = rng.vec3_in(0.0, 1.0);
                if k % 5 == 1 {
                    h[k % 3] = 0.0;
                }
                Aabb::new(c - h, c + h)
            })
            .collect();
        if set % 3 == 0 {
            boxes.push(Aabb::new(
                Vec3::new(f32::NEG_INFINITY, -3.5, f32::NEG_INFINITY),
                Vec3::new(f32::INFINITY, -3.0, f32::INFINITY),
            ));
        }
        let bvh = AabbBvh::build(&boxes);
        let count = 1 + rng.below(40) as usize;
        let kind = set % 4;
        let base = rng.vec3_in(-6.0, 6.0);
        let towards = rng.direction();
        let mut rays = Vec::new();
        let (mut tmins, mut tmaxs, mut margins) = (Vec::new(), Vec::new(), Vec::new());
        for i in 0..count {
            let (o, d) = match kind {
                // a camera's neighbouring rays
                0 => (base, towards + 0.02 * rng.vec3_in(-1.0, 1.0)),
                // parallel rays from nearby points
                1 => (base + 0.3 * rng.vec3_in(-1.0, 1.0), towards),
                // incoherent
                2 => (rng.vec3_in(-6.0, 6.0), rng.direction()),
                // axis-parallel from box corners
                _ => {
                    let b = boxes[rng.below(n as u64) as usize];
                    let mut d = Vec3::ZERO;
                    d[rng.below(3) as usize] = if rng.next_f32() < 0.5 { 1.0 } else { -1.0 };
                    (b.min, d)
                }
            };
            rays.push(Ray {
                origin: o,
                direction: d,
            });
            let (tmin, tmax) = match i % 7 {
                0 => (0.5, 15.0),
                1 => (2.0, 1.0),
                2 => (f32::NAN, 4.0),
                _ => (0.0, if i % 2 == 0 { f32::INFINITY } else { 8.0 }),
            };
            tmins.push(tmin);
            tmaxs.push(tmax);
            margins.push(if set % 2 == 0 {
                0.0
            } else {
                0.25 * (i % 3) as f32
            });
        }
        let mut got: Vec<Vec<(usize, f32, f32)>> = vec![Vec::new(); count];
        let mut last = 0;
        bvh.visit_rays_within(
            &rays,
            &tmins,
            &tmaxs,
            |r| margins[r],
            |r, k, t0, t1| {
                assert!(r >= last, "ray after ray");
                last = r;
                got[r].push((k, t0, t1));
            },
        );
        for r in 0..count {
            let visited = &got[r];
            // the unbounded boxes first, then the others nearest entry first
            let unbounded = visited
                .iter()
                .take_while(|e| !boxes[e.0].is_finite())
                .count();
            assert!(visited[unbounded..].iter().all(|e| boxes[e.0].is_finite()));
            // (a big tree's walk orders its nodes, not each box)
            let entries: Vec<f32> = visited[unbounded..].iter().map(|e| e.1).collect();
            let finite = boxes.iter().filter(|b| b.is_finite()).count();
            if finite <= hytrace::accel::bvh::GROUPED_BOXES {
                assert!(entries.is_sorted(), "set {set} ray {r}: {entries:?}");
            }
            let mut sorted = visited.clone();
            sorted.sort_by_key(|e| e.0);
            let (tmin, tmax) = (tmins[r], tmaxs[r]);
            let expect = if tmin.is_nan() || tmax.is_nan() || tmin > tmax {
                Vec::new()
            } else {
                brute_boxes(&boxes, &rays[r], tmin, tmax, margins[r])
            };
            assert_eq!(
                sorted, expect,
                "set {set} ({n} boxes, kind {kind}), ray {r}"
            );
        }
    }
}

#[test]
fn aabb_bvh_keeps_unbounded_and_drops_empty_boxes() {
    let slab = Aabb::new(
        Vec3::new(f32::NEG_INFINITY, -1.0, f32::NEG_INFINITY),
        Vec3::new(f32::INFINITY, 0.0, f32::INFINITY),
    );
    let nan = Aabb::new(Vec3::new(f32::NAN, 0.0, 0.0), Vec3::ONE);
    let boxes = [
        Aabb::symmetric(Vec3::ONE),
        slab,
        Aabb::EMPTY,
        Aabb::new(Vec3::ONE, Vec3::ZERO),
        Aabb::INFINITE,
        nan,
        Aabb::new(Vec3::splat(5.0), Vec3::splat(6.0)),
    ];
    let bvh = AabbBvh::build(&boxes);
    assert_eq!(bvh.unbounded(), &[1, 4, 5]);
    assert_eq!(bvh.stats().dropped_degenerate, 2);
    assert_eq!(bvh.stats().kept, 2);
    let r = Ray::new(Vec3::new(0.0, 5.0, 0.0), -Vec3::Y);
    let mut seen = Vec::new();
    let mut tmax = 100.0;
    bvh.visit(&r, 0.0, &mut tmax, |k, t0, t1, _| {
        seen.push((k, t0, t1));
        ControlFlow::Continue(())
    });
    assert_eq!(
        seen,
        vec![
            (1, 5.0, 6.0),
            (4, 0.0, 100.0),
            (5, 0.0, 100.0),
            (0, 4.0, 6.0)
        ]
    );
    // A ray missing the slab still meets the infinite and the NaN boxes.
    let r = Ray::new(Vec3::new(0.0, 5.0, 0.0), Vec3::X);
    let mut seen = Vec::new();
    bvh.visit(&r, 0.0, &mut tmax, |k, _, _, _| {
        seen.push(k);
        ControlFlow::Continue(())
    });
    assert_eq!(seen, vec![4, 5]);
}

// ---------------------------------------------------------------------------------------------
// Bad input.

#[test]
fn degenerate_input_does_not_panic() {
    let r = Ray::new(Vec3::new(0.2, 0.2, 5.0), -Vec3::Z);
    for q in QUALITIES {
        // Empty mesh, empty positions.
        let e = MeshBvh::build(&[], &[], q);
        assert!(e.is_empty() && e.node_count() == 0 && e.bounds().is_empty());
        assert!(e.closest_hit(&r, 0.0, f32::INFINITY).is_none() && !e.any_hit(&r, 0.0, 1e9));
        // One triangle.
        let p = [Vec3::ZERO, Vec3::X, Vec3::Y];
        let one = MeshBvh::build(&p, &[[0, 1, 2]], q);
        let h = one.closest_hit(&r, 0.0, f32::INFINITY).unwrap();
        assert_eq!(h.triangle, 0);
        assert!((h.t - 5.0).abs() < 1e-5);
        assert_eq!(
            one.bounds(),
            Aabb::new(Vec3::ZERO, Vec3::new(1.0, 1.0, 0.0))
        );
        // All degenerate: collinear, repeated vertex, single point.
        let p = [
            Vec3::ZERO,
            Vec3::X,
            Vec3::new(0.5, 0.0, 0.0),
            Vec3::splat(0.2),
        ];
        let deg = MeshBvh::build(&p, &[[0, 1, 2], [0, 0, 1], [3, 3, 3], [1, 1, 1]], q);
        assert_eq!(deg.stats().dropped_degenerate, 4);
        assert!(deg.is_empty() && deg.closest_hit(&r, 0.0, 1e9).is_none());
        // NaN and infinite vertices, and an index out of range, next to a good triangle.
        let p = [
            Vec3::ZERO,
            Vec3::X,
            Vec3::Y,
            Vec3::new(f32::NAN, 0.0, 0.0),
            Vec3::new(0.0, f32::INFINITY, 0.0),
        ];
        let bad = MeshBvh::build(&p, &[[0, 1, 3], [0, 4, 2], [0, 1, 2], [0, 1, 99]], q);
        assert_eq!(bad.dropped_nonfinite(), 2);
        assert_eq!(bad.stats().dropped_invalid, 1);
        assert_eq!(bad.closest_hit(&r, 0.0, 1e9).unwrap().triangle, 2);
        // Many copies of one triangle (identical boxes and Morton codes): ties go to the
        // smallest index.
        let p = [Vec3::ZERO, Vec3::X, Vec3::Y];
        let copies = MeshBvh::build(&p, &vec![[0, 1, 2]; 5000], q);
        assert_eq!(copies.closest_hit(&r, 0.0, 1e9).unwrap().triangle, 0);
        // Nonsense rays.
        for bad_ray in [
            Ray {
                origin: Vec3::NAN,
                direction: Vec3::Z,
            },
            Ray {
                origin: Vec3::ZERO,
                direction: Vec3::ZERO,
            },
            Ray {
                origin: Vec3::ZERO,
                direction: Vec3::NAN,
            },
        ] {
            assert!(one.closest_hit(&bad_ray, 0.0, 1e9).is_none());
            assert!(!copies.any_hit(&bad_ray, 0.0, 1e9));
        }
        assert!(one.closest_hit(&r, 1.0, 0.5).is_none(), "tmin > tmax");
        assert!(one.closest_hit(&r, f32::NAN, 10.0).is_none());
    }
    // Instances: unknown mesh, empty mesh, singular and NaN transforms are skipped.
    let meshes = vec![
        MeshBvh::build(&[], &[], BuildQuality::Fast),
        MeshBvh::build(
            &[Vec3::ZERO, Vec3::X, Vec3::Y],
            &[[0, 1, 2]],
            BuildQuality::Fast,
        ),
    ];
    let insts: Vec<Instance> = vec![
        (0, Affine3A::IDENTITY).into(),
        (7, Affine3A::IDENTITY).into(),
        (1, Affine3A::from_scale(Vec3::new(1.0, 0.0, 1.0))).into(),
        (1, Affine3A::from_translation(Vec3::NAN)).into(),
        (1, Affine3A::IDENTITY).into(),
    ];
    let tlas = InstanceBvh::build(&meshes, &insts, BuildQuality::Fast);
    assert_eq!(tlas.stats().dropped_invalid, 4);
    let h = tlas.closest_hit(&meshes, &r, 0.0, f32::INFINITY).unwrap();
    assert_eq!((h.instance, h.triangle), (4, 0));
    assert!((h.t - 5.0).abs() < 1e-5);
    let none = InstanceBvh::build(&meshes, &[], BuildQuality::Fast);
    assert!(none.closest_hit(&meshes, &r, 0.0, 1e9).is_none());
    assert!(!none.any_hit(&meshes, &r, 0.0, 1e9));
    // Boxes: none, and many identical ones (including identical points).
    let empty = AabbBvh::build(&[]);
    let mut tmax = 1e9;
    empty.visit(&r, 0.0, &mut tmax, |_, _, _, _| panic!("nothing to visit"));
    let same = AabbBvh::build(&vec![Aabb::new(Vec3::splat(0.1), Vec3::splat(0.1)); 3000]);
    let mut n = 0;
    let r = ray(Vec3::new(0.1, 0.1, 5.0), -Vec3::Z);
    same.visit(&r, 0.0, &mut tmax, |_, _, _, _| {
        n += 1;
        ControlFlow::Continue(())
    });
    assert_eq!(n, 3000, "a ray through a point box meets every copy");
}

// ---------------------------------------------------------------------------------------------
// Packets: `InstanceBvh::closest_hits` against one `closest_hit` per ray, bit for bit.

/// Asserts that the batch queries answer each ray exactly as the single-ray queries do.
fn assert_batch_matches_single(
    what: &str,
    tlas: &InstanceBvh,
    meshes: &[MeshBvh],
    rays: &[Ray],
    tmin: f32,
    tmax: &[f32],
) -> usize {
    let mut batch = vec![None; rays.len()];
    tlas.closest_hits(meshes, rays, tmin, tmax, &mut batch);
    let mut hits = 0;
    for (i, ((r, &t), b)) in rays.iter().zip(tmax).zip(&batch).enumerate() {
        let single = tlas.closest_hit(meshes, r, tmin, t);
        let bits = |h: &Option<hytrace::accel::bvh::InstanceHit>| {
            h.map(|h| {
                (
                    h.t.to_bits(),
                    h.instance,
                    h.triangle,
                    h.u.to_bits(),
                    h.v.to_bits(),
                )
            })
        };
        assert_eq!(
            bits(b),
            bits(&single),
            "{what}: ray {i} ({r:?}, tmin {tmin}, tmax {t}): packet {b:?} vs single {single:?}"
        );
        hits += usize::from(single.is_some());
    }
    let mut blocked = vec![false; rays.len()];
    tlas.any_hits(meshes, rays, tmin, tmax, &mut blocked);
    for (i, ((r, &t), &b)) in rays.iter().zip(tmax).zip(&blocked).enumerate() {
        let single = tlas.any_hit(meshes, r, tmin, t);
        assert_eq!(
            b, single,
            "{what}: any hit, ray {i} ({r:?}, tmin {tmin}, tmax {t})"
        );
    }
    hits
}

/// Pinhole rays through a `w`×`h` image, 32-pixel rows of 32×32 tiles (the bench's and the
/// renderer's order), looking from `eye` at `target`.
fn pinhole_rays(eye: Vec3, target: Vec3, w: u32, h: u32, fov_scale: f32) -> Vec<Ray> {
    let f = (target - eye).normalize();
    let right = f.cross(Vec3::Y).normalize();
    let up = right.cross(f);
    let mut rays = Vec::new();
    for ty in (0..h).step_by(32) {
        for tx in (0..w).step_by(32) {
            for y in ty..(ty + 32).min(h) {
                for x in tx..(tx + 32).min(w) {
                    let u = ((x as f32 + 0.5) / w as f32 - 0.5) * fov_scale;
                    let v = ((y as f32 + 0.5) / h as f32 - 0.5) * fov_scale;
                    rays.push(Ray::new(eye, f + u * right - v * up));
                }
            }
        }
    }
    rays
}

/// The packet tests' scene: a bumpy sphere untransformed (world rays walk the mesh as they
/// are) and rotated and scaled (object-space packets, some of whose rays change octant), and a
/// grid of small ones (many instances per packet, which the packet must split between).
fn packet_scene(rng: &mut Rng) -> (Vec<MeshBvh>, InstanceBvh) {
    let (pos, tris) = bumpy_sphere(48, 80);
    let (pos2, tris2) = bumpy_sphere(6, 9);
    let meshes = vec![
        MeshBvh::build(&pos, &tris, BuildQuality::Medium),
        MeshBvh::build(&pos2, &tris2, BuildQuality::Medium),
    ];
    let mut instances = vec![
        Instance::from((0, Affine3A::IDENTITY)),
        Instance::from((
            0,
            Affine3A::from_scale_rotation_translation(
                Vec3::new(0.7, 1.4, 0.9),
                Quat::from_axis_angle(Vec3::new(1.0, 2.0, 0.5).normalize(), 0.7),
                Vec3::new(2.5, 0.2, -0.5),
            ),
        )),
    ];
    for i in 0..64 {
        let c = Vec3::new((i % 8) as f32 * 0.5 - 2.0, (i / 8) as f32 * 0.5 - 2.0, -3.0);
        let rot = Quat::from_rotation_y(rng.next_f32() * 6.0);
        instances.push(Instance::from((
            1,
            Affine3A::from_scale_rotation_translation(Vec3::splat(0.2), rot, c),
        )));
    }
    let tlas = InstanceBvh::build(&meshes, &instances, BuildQuality::Medium);
    (meshes, tlas)
}

#[test]
fn packets_give_the_single_ray_answers() {
    let mut rng = Rng::new(2024);
    let (meshes, tlas) = packet_scene(&mut rng);
    let mut total_hits = 0;
    for (k, eye) in [
        Vec3::new(0.3, 0.8, 6.0),
        Vec3::new(-5.0, 2.0, 4.0),
        // On an octant boundary of the image centre: packets straddling it fall back.
        Vec3::new(0.0, 0.0, 7.0),
    ]
    .into_iter()
    .enumerate()
    {
        let rays = pinhole_rays(eye, Vec3::new(0.2, -0.3, -1.0), 160, 96, 1.2);
        let inf = vec![f32::INFINITY; rays.len()];
        total_hits += assert_batch_matches_single("pinhole", &tlas, &meshes, &rays, 0.0, &inf);
        // Per-ray limits: short, NaN, below tmin, and a tmin that cuts into the scene.
        let odd: Vec<f32> = (0..rays.len())
            .map(|i| match (i + k) % 7 {
                0 => 5.5,
                1 => f32::NAN,
                2 => -1.0,
                3 => 6.3,
                _ => f32::INFINITY,
            })
            .collect();
        assert_batch_matches_single("pinhole, odd tmax", &tlas, &meshes, &rays, 0.0, &odd);
        assert_batch_matches_single("pinhole, tmin 6", &tlas, &meshes, &rays, 6.0, &inf);
        assert_batch_matches_single("pinhole, tmin −1", &tlas, &meshes, &rays, -1.0, &inf);
    }
    assert!(
        total_hits > 5000,
        "the views should see the spheres: {total_hits}"
    );

    // Shadow-like packets (spread origins, one target), origins on an axis-parallel line,
    // axis-parallel directions inside a packet, and plain random rays.
    let light = Vec3::new(1.0, 6.0, 2.0);
    let mut rays = Vec::new();
    for _ in 0..4000 {
        let o = rng.vec3_in(-3.0, 3.0);
        rays.push(Ray::new(o, light - o));
    }
    for i in 0..640 {
        let o = Vec3::new(-4.0 + 0.0125 * i as f32, 0.1, 5.0);
        let d = if i % 5 == 0 {
            -Vec3::Z
        } else {
            Vec3::new(0.01, 0.02, -1.0)
        };
        rays.push(Ray::new(o, d));
    }
    for _ in 0..4000 {
        rays.push(Ray::new(rng.vec3_in(-4.0, 4.0), rng.direction()));
    }
    // Non-finite rays inside otherwise coherent packets: such a packet is traced ray by ray.
    let camera = pinhole_rays(Vec3::new(0.3, 0.8, 6.0), Vec3::ZERO, 64, 2, 1.0);
    for (k, mut r) in camera.into_iter().enumerate() {
        match k % 37 {
            5 => r.origin.x = f32::NAN,
            11 => r.direction.y = f32::NAN,
            17 => r.origin.z = f32::INFINITY,
            _ => {}
        }
        rays.push(r);
    }
    let inf = vec![f32::INFINITY; rays.len()];
    assert_batch_matches_single("mixed", &tlas, &meshes, &rays, 0.0, &inf);
    // Lengths that are not a multiple of the packet.
    for n in [0, 1, 31, 33, 97] {
        assert_batch_matches_single("short batch", &tlas, &meshes, &rays[..n], 0.0, &inf[..n]);
    }
}

/// Rays from nearby origins in all directions (AO and diffuse rays of neighbouring pixels)
/// make no frustum; on CPUs with AVX-512 or AVX2 they are traced sixteen at a time in lane
/// walks. The
/// answers are the single-ray ones, bit for bit, including groups holding a ray parallel to an
/// axis, a ray from a non-finite origin, or per-ray limits that retire rays.
#[test]
fn lane_walks_give_the_single_ray_answers() {
    let mut rng = Rng::new(31);
    let (meshes, tlas) = packet_scene(&mut rng);
    let mut rays = Vec::new();
    for group in 0..400 {
        // Around a point near the spheres (inside one now and then), or in the grid of small
        // instances.
        let centre = if group % 3 == 0 {
            Vec3::new(rng.range_f32(-2.2, 1.6), rng.range_f32(-2.2, 1.6), -2.6)
        } else {
            rng.vec3_in(-2.0, 3.0)
        };
        for k in 0..16 {
            let o = centre + rng.vec3_in(-0.1, 0.1);
            let d = match (group % 17, k) {
                (3, 5) => Vec3::X,
                (4, 0) => Vec3::new(0.0, -1.0, 0.3),
                _ => rng.direction(),
            };
            let o = if (group % 19, k) == (6, 9) {
                Vec3::new(f32::NAN, o.y, o.z)
            } else {
                o
            };
            rays.push(Ray::new(o, d));
        }
    }
    let inf = vec![f32::INFINITY; rays.len()];
    let hits = assert_batch_matches_single("near origins", &tlas, &meshes, &rays, 0.0, &inf);
    assert!(
        hits > rays.len() / 8,
        "the rays should hit: {hits} of {}",
        rays.len()
    );
    let odd: Vec<f32> = (0..rays.len())
        .map(|i| match i % 9 {
            0 => 0.7,
            1 => f32::NAN,
            2 => -1.0,
            3 => 2.5,
            _ => f32::INFINITY,
        })
        .collect();
    assert_batch_matches_single("near origins, odd tmax", &tlas, &meshes, &rays, 0.0, &odd);
    assert_batch_matches_single("near origins, tmin 1", &tlas, &meshes, &rays, 1.0, &inf);
    for n in [1, 15, 17, 45] {
        assert_batch_matches_single(
            "near origins, short",
            &tlas,
            &meshes,
            &rays[..n],
            0.0,
            &inf[..n],
        );
    }
}

/// The mesh bench's models that are present (a missing one is said loudly, and fails under
/// `CI=true`).
fn bench_models() -> Vec<(&'static str, hytrace::scene::Scene)> {
    use hytrace::bench::mesh::MESH_SCENES;
    let assets = assets_dir().expect("an assets folder");
    let mut models = Vec::new();
    for (name, rel) in MESH_SCENES {
        let path = assets.join(rel);
        if !path.is_file() {
            eprintln!("\n!!! {name} is missing at {}: SKIPPED\n", path.display());
            assert!(
                !std::env::var("CI").is_ok_and(|v| v == "true"),
                "CI=true and {} is missing",
                path.display()
            );
            continue;
        }
        let scene = hytrace::scene::Scene::from_model(&path, None).expect("bench model loads");
        models.push((name, scene));
    }
    models
}

#[test]
fn packets_give_the_single_ray_answers_on_the_bench_models() {
    use hytrace::accel::MeshAccel;
    use hytrace::bench::rays;
    let mut interleaved = false;
    for (name, scene) in bench_models() {
        let accel = MeshAccel::new(&scene.meshes, BuildQuality::Medium);
        let camera = rays::framing_camera(&scene, 16.0 / 9.0);
        let primary = rays::primary_from(&camera, 384, 216);
        let (ao, shadow) = rays::secondary(&scene, &accel, &primary);
        // Incoherent rays go one by one, or two at a time on a scene of one large tree.
        let incoherent = rays::incoherent(&scene, 20_000);
        interleaved |= accel.tlas.walks_pairs(&accel.blas);
        for (kind, set) in [
            ("primary", &primary),
            ("ao", &ao),
            ("shadow", &shadow),
            ("incoherent", &incoherent),
        ] {
            let r: Vec<Ray> = set.iter().map(|q| q.ray).collect();
            let t: Vec<f32> = set.iter().map(|q| q.tmax).collect();
            let hits = assert_batch_matches_single(
                &format!("{name} {kind}"),
                &accel.tlas,
                &accel.blas,
                &r,
                0.0,
                &t,
            );
            println!(
                "{name} {kind}: {} rays, {hits} hits, packet = single",
                r.len()
            );
            assert!(kind != "primary" || hits > 1000, "{name}: {hits} hits");
        }
    }
    // MetalRoughSpheres (a million triangles, all merged into one tree) is walked in pairs.
    assert!(
        interleaved,
        "no bench model's single rays were walked two at a time"
    );
}

/// Rays traced one by one are walked two at a time through a scene's large main tree, and
/// the other instances after it: on MetalRoughSpheres with one of its meshes placed a second
/// time (so that mesh keeps a tree of its own under two instances, and the rest are merged
/// into a tree of tens of megabytes), the batch queries give the single-ray answers.
#[test]
fn pair_walks_give_the_single_ray_answers_beside_other_instances() {
    use hytrace::accel::MeshAccel;
    use hytrace::bench::rays;
    let Some((_, mut scene)) = bench_models()
        .into_iter()
        .find(|(name, _)| name.starts_with("MetalRoughSpheres"))
    else {
        return; // (bench_models fails under CI when a model is missing)
    };
    // The smallest mesh, placed again beside its first placement.
    let meshes = &mut scene.meshes;
    let k = (0..meshes.instances.len())
        .min_by_key(|&k| meshes.meshes[meshes.instances[k].mesh].triangles.len())
        .expect("instances");
    let mut again = meshes.instances[k].clone();
    again.transform =
        glam::Affine3A::from_translation(glam::Vec3::new(0.3, 0.2, 0.1)) * again.transform;
    meshes.instances.push(again);
    let accel = MeshAccel::new(&scene.meshes, BuildQuality::Medium);
    assert!(
        accel.tlas.merged().is_some(),
        "the meshes placed once are merged"
    );
    assert!(
        accel.tlas.walks_pairs(&accel.blas),
        "the merged tree is walked in pairs"
    );
    let camera = rays::framing_camera(&scene, 16.0 / 9.0);
    let primary = rays::primary_from(&camera, 192, 108);
    let (ao, shadow) = rays::secondary(&scene, &accel, &primary);
    // Incoherent rays from anywhere in the model's box, and as many aimed at points of the
    // second placement, so that both kinds of answer (merged tree, other instances) are
    // checked.
    let mut incoherent = rays::incoherent(&scene, 10_000);
    let placed = scene.meshes.instances.last().expect("the second placement");
    let points: Vec<Vec3> = scene.meshes.meshes[placed.mesh]
        .positions
        .iter()
        .map(|&p| placed.transform.transform_point3(p))
        .collect();
    let b = accel.tlas.bounds();
    let mut rng = hytrace::rng::Rng::new(3);
    for k in 0..10_000 {
        let target = points[k % points.len()];
        let o = rng.vec3_in(b.min.min_element(), b.max.max_element());
        incoherent.push(rays::QueryRay {
            ray: Ray::new(o, (target - o).normalize()),
            tmax: f32::INFINITY,
        });
    }
    // The two placements of the mesh placed twice: outside the merged tree.
    let twice = [k as u32, (scene.meshes.instances.len() - 1) as u32];
    let mut on_twice = 0;
    for (kind, set) in [
        ("ao", &ao),
        ("shadow", &shadow),
        ("incoherent", &incoherent),
    ] {
        let r: Vec<Ray> = set.iter().map(|q| q.ray).collect();
        let t: Vec<f32> = set.iter().map(|q| q.tmax).collect();
        let what = format!("second placement {kind}");
        assert_batch_matches_single(&what, &accel.tlas, &accel.blas, &r, 0.0, &t);
        for (ray, &tmax) in r.iter().zip(&t) {
            let hit = accel.tlas.closest_hit(&accel.blas, ray, 0.0, tmax);
            on_twice += usize::from(hit.is_some_and(|h| twice.contains(&h.instance)));
        }
    }
    assert!(
        on_twice > 0,
        "no ray's nearest hit was on the mesh placed twice"
    );
}

/// The meshes placed once are merged into one tree of world-space triangles
/// (`hytrace::accel::merge`); its hits are reported as the instances' own. Against the
/// two-level tree of every instance, on the bench models: the same instance and triangle for
/// every ray but those that graze an edge or a silhouette (the baked vertices are the
/// transformed ones rounded to `f32`), and the same t up to that rounding.
#[test]
fn merged_meshes_give_the_instances_answers_on_the_bench_models() {
    use hytrace::accel::MeshAccel;
    use hytrace::bench::rays;
    let mut merged_models = 0;
    let models = bench_models();
    let instanced = models.iter().any(|(_, s)| s.meshes.instances.len() > 1);
    for (name, scene) in models {
        let two_level = MeshAccel::with_merging(&scene.meshes, BuildQuality::Medium, false);
        let merged = MeshAccel::new(&scene.meshes, BuildQuality::Medium);
        assert!(two_level.tlas.merged().is_none());
        let Some((_, origin)) = merged.tlas.merged() else {
            // (a model of one mesh placed once has nothing to merge)
            assert!(scene.meshes.instances.len() < 2, "{name}: nothing merged");
            continue;
        };
        merged_models += 1;
        assert!(!origin.is_empty());
        let camera = rays::framing_camera(&scene, 16.0 / 9.0);
        let primary = rays::primary_from(&camera, 384, 216);
        let (ao, shadow) = rays::secondary(&scene, &two_level, &primary);
        let incoherent = rays::incoherent(&scene, 20_000);
        for (kind, set) in [
            ("primary", &primary),
            ("ao", &ao),
            ("shadow", &shadow),
            ("incoherent", &incoherent),
        ] {
            let r: Vec<Ray> = set.iter().map(|q| q.ray).collect();
            let t: Vec<f32> = set.iter().map(|q| q.tmax).collect();
            let (mut a, mut b) = (vec![None; r.len()], vec![None; r.len()]);
            two_level
                .tlas
                .closest_hits(&two_level.blas, &r, 0.0, &t, &mut a);
            merged.tlas.closest_hits(&merged.blas, &r, 0.0, &t, &mut b);
            // (`grazing`: rays whose answers differ, each on an edge or coincident faces)
            let (mut hits, mut grazing) = (0, 0);
            let near_edge = |u: f32, v: f32| u.min(v).min(1.0 - u - v) < 1e-3;
            for (i, (a, b)) in a.iter().zip(&b).enumerate() {
                match (a, b) {
                    (Some(a), Some(b)) if (a.instance, a.triangle) == (b.instance, b.triangle) => {
                        hits += 1;
                        let scale = r[i].origin.abs().max_element().max(a.t).max(1.0);
                        assert!(
                            (a.t - b.t).abs() <= 1e-4 * scale,
                            "{name} {kind} ray {i}: t {} against {}",
                            a.t,
                            b.t
                        );
                    }
                    (None, None) => {}
                    (a, b) => {
                        // Two parts' coincident faces (CAD models have them) meet the ray at
                        // one t: rounding may pick either.
                        let coincident = match (a, b) {
                            (Some(a), Some(b)) => {
                                let scale = r[i].origin.abs().max_element().max(a.t).max(1.0);
                                (a.t - b.t).abs() <= 1e-4 * scale
                            }
                            _ => false,
                        };
                        for h in [a, b].into_iter().flatten() {
                            assert!(
                                coincident || near_edge(h.u, h.v),
                                "{name} {kind} ray {i}: {a:?} against {b:?}"
                            );
                        }
                        grazing += 1;
                    }
                }
            }
            eprintln!("{name} {kind}: {hits} hits alike, {grazing} grazing");
            assert!(
                grazing * 1000 <= r.len(),
                "{name} {kind}: {grazing} of {} rays differ",
                r.len()
            );
            // Any hit: the same, but for grazing rays.
            let (mut x, mut y) = (vec![false; r.len()], vec![false; r.len()]);
            two_level
                .tlas
                .any_hits(&two_level.blas, &r, 0.0, &t, &mut x);
            merged.tlas.any_hits(&merged.blas, &r, 0.0, &t, &mut y);
            let differ = x.iter().zip(&y).filter(|(x, y)| x != y).count();
            assert!(
                differ * 1000 <= r.len(),
                "{name} {kind}: any hit differs on {differ}"
            );
        }
    }
    if instanced {
        assert!(merged_models > 0, "the instanced bench models merge");
    }
}
