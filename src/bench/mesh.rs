//! Mesh section: our two-level BVH traversal against Embree 4 on the same ray arrays, and
//! frame times of meshes from a thousand to a million triangles.

use super::rays::{self, Query, QueryRay, RaySet};
use super::{BenchOptions, Workers, alternate, geomean, median};
use crate::accel::MeshAccel;
use crate::scene::generate::icosphere_scene;
use crate::scene::{Scene, SceneMeshes};
use anyhow::Context;
use arrayvec::ArrayVec;
use glam::{Mat3A, Vec3};
use serde::Serialize;
use std::fmt::Write;
use std::hint::black_box;
use std::path::Path;

/// The benchmark models, as (name, path under the assets folder).
pub const MESH_SCENES: [(&str, &str); 4] = [
    (
        "ReciprocatingSaw",
        "glTF/ReciprocatingSaw/glTF/ReciprocatingSaw.gltf",
    ),
    (
        "2CylinderEngine",
        "glTF/2CylinderEngine/glTF-Binary/2CylinderEngine.glb",
    ),
    (
        "MetalRoughSpheresNoTextures",
        "glTF/MetalRoughSpheresNoTextures/glTF/MetalRoughSpheresNoTextures.gltf",
    ),
    ("bunny", "obj/common-3d-test-models/stanford-bunny.obj"),
];

/// The ray sets of the mesh section, in the order they run.
pub const RAY_SETS: [&str; 4] = ["primary", "ao", "shadow", "incoherent"];

/// One figure: a ray set on a scene with a number of threads.
#[derive(Debug, Clone, Serialize)]
pub struct MeshRow {
    /// Scene name.
    pub scene: String,
    /// Ray set ("primary", "ao", "shadow", "incoherent").
    pub kind: String,
    /// Query traced.
    pub query: Query,
    /// Threads.
    pub threads: usize,
    /// Rays in the set.
    pub rays: usize,
    /// Fraction of the rays that hit (ours).
    pub hit_fraction: f64,
    /// Our median Mrays/s.
    pub ours_mrays: f64,
    /// Embree's median Mrays/s.
    pub embree_mrays: Option<f64>,
    /// ours / Embree.
    pub ratio: Option<f64>,
    /// Fraction of rays on which both agree on hit or miss.
    pub agreement: Option<f64>,
    /// Every timed run, seconds (ours).
    pub ours_seconds: Vec<f64>,
    /// Every timed run, seconds (Embree).
    pub embree_seconds: Vec<f64>,
}

/// Build of one scene.
#[derive(Debug, Clone, Serialize)]
pub struct MeshSceneInfo {
    /// Scene name.
    pub scene: String,
    /// Triangles over all instances.
    pub triangles: usize,
    /// Triangles stored once per mesh.
    pub unique_triangles: usize,
    /// Instances.
    pub instances: usize,
    /// Our BVH build (all meshes and the instance tree), ms, one thread.
    pub ours_build_ms: f64,
    /// Embree's scene build (quality HIGH, its own threads), ms.
    pub embree_build_ms: Option<f64>,
}

/// Geometric mean over scenes of one ray set and thread count.
#[derive(Debug, Clone, Serialize)]
pub struct MeshSummary {
    /// Ray set, or "closest hit" for primary, AO and incoherent together.
    pub kind: String,
    /// Threads.
    pub threads: usize,
    /// Geometric mean of ours / Embree.
    pub ratio: f64,
    /// Lowest agreement among the rows.
    pub min_agreement: f64,
}

/// The mesh section.
#[derive(Debug, Clone, Serialize)]
pub struct MeshReport {
    /// Image size of the primary rays.
    pub width: u32,
    /// See `width`.
    pub height: u32,
    /// Incoherent rays per scene.
    pub incoherent: usize,
    /// Our build quality.
    pub bvh: String,
    /// Builds.
    pub scenes: Vec<MeshSceneInfo>,
    /// Figures.
    pub rows: Vec<MeshRow>,
    /// Geometric means (only with Embree).
    pub summary: Vec<MeshSummary>,
}

/// Mesh scaling: one size.
#[derive(Debug, Clone, Serialize)]
pub struct MeshScalingRow {
    /// Triangles.
    pub triangles: usize,
    /// Primary rays per frame.
    pub pixels: usize,
    /// Our median ms per frame (all threads).
    pub ours_ms: f64,
    /// Embree's.
    pub embree_ms: Option<f64>,
    /// Our build, ms.
    pub ours_build_ms: f64,
    /// Embree's build, ms.
    pub embree_build_ms: Option<f64>,
    /// Hit/miss agreement.
    pub agreement: Option<f64>,
}

/// World-space geometric normals the way both backends report them: per mesh the face normals,
/// per instance its normal matrix.
struct FaceNormals {
    faces: Vec<Vec<Vec3>>,
    instances: Vec<(usize, Mat3A)>,
}

impl FaceNormals {
    fn new(m: &SceneMeshes) -> Self {
        FaceNormals {
            faces: m
                .meshes
                .iter()
                .map(|mesh| {
                    mesh.triangles
                        .iter()
                        .map(|t| {
                            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
                            (b - a).cross(c - a)
                        })
                        .collect()
                })
                .collect(),
            instances: m
                .instances
                .iter()
                .map(|i| (i.mesh, i.normal_matrix))
                .collect(),
        }
    }

    #[inline]
    fn normal(&self, instance: u32, triangle: u32) -> Vec3 {
        let (mesh, nm) = self.instances[instance as usize];
        (nm * self.faces[mesh][triangle as usize]).normalize_or_zero()
    }
}

/// The Embree side, when built in: the scene and its build time in ms.
#[cfg(feature = "embree")]
type Referee = crate::reference::embree::EmbreeScene;
#[cfg(not(feature = "embree"))]
type Referee = ();

#[cfg(feature = "embree")]
fn build_referee(scene: &Scene) -> anyhow::Result<Option<(Referee, f64)>> {
    let start = std::time::Instant::now();
    let e = crate::reference::embree::EmbreeScene::build(scene)
        .map_err(|e| anyhow::anyhow!("Embree: {e}"))?;
    Ok(Some((e, start.elapsed().as_secs_f64() * 1e3)))
}
#[cfg(not(feature = "embree"))]
fn build_referee(_: &Scene) -> anyhow::Result<Option<(Referee, f64)>> {
    Ok(None)
}

/// Embree's answers as our figures store them: t of the closest hit (∞ for a miss), or 1/0 for
/// occlusion, one `rtcIntersect1` / `rtcOccluded1` per ray. Its closest-hit query also
/// computes the geometric normal, as ours does below.
#[cfg(feature = "embree")]
fn referee_query(e: &Referee, query: Query) -> impl Fn(&[QueryRay], &mut [f32]) + Sync + '_ {
    use crate::trace::query::RayQuery;
    move |rays: &[QueryRay], out: &mut [f32]| {
        for (q, out) in rays.iter().zip(out) {
            *out = match query {
                Query::Closest => e
                    .closest_hit(&q.ray, 0.0, q.tmax)
                    .map_or(f32::INFINITY, |h| h.t),
                Query::Occluded => f32::from(u8::from(e.occluded(&q.ray, 0.0, q.tmax))),
            }
        }
    }
}
#[cfg(not(feature = "embree"))]
fn referee_query(_: &Referee, _: Query) -> impl Fn(&[QueryRay], &mut [f32]) + Sync + '_ {
    |_: &[QueryRay], out: &mut [f32]| out.fill(f32::NAN)
}

/// Our answers: closest hits through [`crate::accel::bvh::InstanceBvh::closest_hits`], which
/// traces coherent neighbours as packets (and the rest one by one), with the geometric normal
/// of each hit; occlusion through `any_hits`, likewise.
fn ours_query<'a>(
    accel: &'a MeshAccel,
    normals: &'a FaceNormals,
    query: Query,
) -> impl Fn(&[QueryRay], &mut [f32]) + Sync + 'a {
    move |rays: &[QueryRay], out: &mut [f32]| {
        // The batch queries take the rays and their limits as two slices.
        let n = rays.len();
        let ray_buf: ArrayVec<crate::geom::Ray, { super::CHUNK }> =
            rays.iter().map(|q| q.ray).collect();
        let tmax_buf: ArrayVec<f32, { super::CHUNK }> = rays.iter().map(|q| q.tmax).collect();
        match query {
            Query::Closest => {
                let mut hits = [None; super::CHUNK];
                accel
                    .tlas
                    .closest_hits(&accel.blas, &ray_buf, 0.0, &tmax_buf, &mut hits[..n]);
                for (o, h) in out.iter_mut().zip(&hits[..n]) {
                    *o = match h {
                        Some(h) => {
                            black_box(normals.normal(h.instance, h.triangle));
                            h.t
                        }
                        None => f32::INFINITY,
                    };
                }
            }
            Query::Occluded => {
                let mut blocked = [false; super::CHUNK];
                accel
                    .tlas
                    .any_hits(&accel.blas, &ray_buf, 0.0, &tmax_buf, &mut blocked[..n]);
                for (o, &b) in out.iter_mut().zip(&blocked[..n]) {
                    *o = f32::from(u8::from(b));
                }
            }
        }
    }
}

fn is_hit(query: Query, v: f32) -> bool {
    match query {
        Query::Closest => v.is_finite(),
        Query::Occluded => v != 0.0,
    }
}

/// Fraction of rays on which the two answer lists agree on hit or miss.
fn agreement(query: Query, a: &[f32], b: &[f32]) -> f64 {
    let same = a
        .iter()
        .zip(b)
        .filter(|(x, y)| is_hit(query, **x) == is_hit(query, **y))
        .count();
    same as f64 / a.len().max(1) as f64
}

/// Loads a benchmark model as a scene (its default framing camera).
fn load(assets: &Path, rel: &str) -> anyhow::Result<Scene> {
    let path = assets.join(rel);
    if !path.exists() {
        anyhow::bail!(
            "{}: benchmark model not found in the shared assets folder {}",
            path.display(),
            assets.display()
        );
    }
    Scene::from_model(&path, None).with_context(|| format!("loading {}", path.display()))
}

/// Runs the mesh section.
pub fn run(opts: &BenchOptions) -> anyhow::Result<MeshReport> {
    let chosen: Vec<(&str, &str)> = if opts.mesh_scenes.is_empty() {
        MESH_SCENES.to_vec()
    } else {
        let mut v = Vec::new();
        for name in &opts.mesh_scenes {
            let Some(s) = MESH_SCENES
                .iter()
                .find(|(n, _)| n.eq_ignore_ascii_case(name))
            else {
                anyhow::bail!(
                    "unknown mesh scene {name:?} (known: {})",
                    MESH_SCENES.map(|(n, _)| n).join(", ")
                );
            };
            v.push(*s);
        }
        v
    };
    let workers: Vec<Workers> = opts
        .threads
        .iter()
        .map(|&t| Workers::new(t))
        .collect::<anyhow::Result<_>>()?;
    let mut scenes = Vec::new();
    let mut rows = Vec::new();
    for (name, rel) in chosen {
        eprintln!("bench: mesh scene {name}");
        let scene = load(&opts.assets, rel)?;
        let accel = MeshAccel::new(&scene.meshes, opts.bvh);
        let referee = build_referee(&scene)?;
        scenes.push(MeshSceneInfo {
            scene: name.into(),
            triangles: scene.meshes.triangle_count(),
            unique_triangles: scene.meshes.unique_triangle_count(),
            instances: scene.meshes.instances.len(),
            ours_build_ms: accel.build_time.as_secs_f64() * 1e3,
            embree_build_ms: referee.as_ref().map(|r| r.1),
        });
        let normals = FaceNormals::new(&scene.meshes);
        let camera = rays::framing_camera(&scene, opts.width as f32 / opts.height as f32);
        let primary = rays::primary_from(&camera, opts.width, opts.height);
        let (ao, shadow) = rays::secondary(&scene, &accel, &primary);
        let sets = [
            RaySet {
                kind: "primary",
                query: Query::Closest,
                rays: primary,
            },
            RaySet {
                kind: "ao",
                query: Query::Closest,
                rays: ao,
            },
            RaySet {
                kind: "shadow",
                query: Query::Occluded,
                rays: shadow,
            },
            RaySet {
                kind: "incoherent",
                query: Query::Closest,
                rays: rays::incoherent(&scene, opts.incoherent),
            },
        ];
        for set in &sets {
            let chosen = opts.ray_sets.is_empty() || opts.ray_sets.iter().any(|k| k == set.kind);
            if set.rays.is_empty() || !chosen {
                continue;
            }
            for w in &workers {
                let ours = ours_query(&accel, &normals, set.query);
                let (mut out_ours, mut out_emb) = (Vec::new(), Vec::new());
                let (ours_s, emb_s) = match &referee {
                    Some((e, _)) => {
                        let emb = referee_query(e, set.query);
                        let t = alternate(
                            w,
                            &set.rays,
                            opts.runs,
                            opts.min_seconds,
                            &mut [(&ours, &mut out_ours), (&emb, &mut out_emb)],
                        );
                        (t[0].clone(), t[1].clone())
                    }
                    None => {
                        let t = alternate(
                            w,
                            &set.rays,
                            opts.runs,
                            opts.min_seconds,
                            &mut [(&ours, &mut out_ours)],
                        );
                        (t[0].clone(), Vec::new())
                    }
                };
                let n = set.rays.len() as f64;
                let ours_mrays = n / median(&ours_s) / 1e6;
                let embree_mrays = (!emb_s.is_empty()).then(|| n / median(&emb_s) / 1e6);
                rows.push(MeshRow {
                    scene: name.into(),
                    kind: set.kind.into(),
                    query: set.query,
                    threads: w.threads,
                    rays: set.rays.len(),
                    hit_fraction: out_ours.iter().filter(|&&v| is_hit(set.query, v)).count() as f64
                        / n,
                    ours_mrays,
                    embree_mrays,
                    ratio: embree_mrays.map(|e| ours_mrays / e),
                    agreement: (!emb_s.is_empty())
                        .then(|| agreement(set.query, &out_ours, &out_emb)),
                    ours_seconds: ours_s,
                    embree_seconds: emb_s,
                });
            }
        }
    }
    let summary = summarize(&rows, &opts.threads);
    Ok(MeshReport {
        width: opts.width,
        height: opts.height,
        incoherent: opts.incoherent,
        bvh: format!("{:?}", opts.bvh),
        scenes,
        rows,
        summary,
    })
}

fn summarize(rows: &[MeshRow], threads: &[usize]) -> Vec<MeshSummary> {
    let mut out = Vec::new();
    let groups: [(&str, &[&str]); 5] = [
        (
            "closest hit (primary, ao, incoherent)",
            &["primary", "ao", "incoherent"],
        ),
        ("primary", &["primary"]),
        ("ao", &["ao"]),
        ("shadow", &["shadow"]),
        ("incoherent", &["incoherent"]),
    ];
    for &t in threads {
        for (label, kinds) in groups {
            let sel: Vec<&MeshRow> = rows
                .iter()
                .filter(|r| r.threads == t && kinds.contains(&r.kind.as_str()))
                .collect();
            let ratios: Vec<f64> = sel.iter().filter_map(|r| r.ratio).collect();
            if ratios.is_empty() || ratios.len() != sel.len() {
                continue;
            }
            out.push(MeshSummary {
                kind: label.into(),
                threads: t,
                ratio: geomean(&ratios),
                min_agreement: sel.iter().filter_map(|r| r.agreement).fold(1.0, f64::min),
            });
        }
    }
    out
}

impl MeshReport {
    /// Appends the section's tables.
    pub fn markdown(&self, s: &mut String) {
        let _ = writeln!(s, "## Meshes: ours against Embree 4\n");
        let _ = writeln!(
            s,
            "Primary rays {}×{} from a camera framing the model's bounds; AO rays (cosine-distributed, closest hit within the model's radius) and shadow rays (to a point light above) from every primary hit; {} incoherent rays (uniform origins in the bounds, uniform directions); our BVH: obvhs {} preset; Embree: build quality HIGH, `rtcIntersect1`/`rtcOccluded1`.\n",
            self.width, self.height, self.incoherent, self.bvh
        );
        let _ = writeln!(
            s,
            "| scene | triangles (unique) | instances | ours build ms | Embree build ms |"
        );
        let _ = writeln!(s, "|---|---:|---:|---:|---:|");
        for sc in &self.scenes {
            let _ = writeln!(
                s,
                "| {} | {} ({}) | {} | {:.0} | {} |",
                sc.scene,
                sc.triangles,
                sc.unique_triangles,
                sc.instances,
                sc.ours_build_ms,
                super::fmt_opt(sc.embree_build_ms, 0)
            );
        }
        let _ = writeln!(
            s,
            "\n| scene | rays | threads | count | hit % | ours Mrays/s | Embree Mrays/s | ours/Embree | hit/miss agreement |"
        );
        let _ = writeln!(s, "|---|---|---:|---:|---:|---:|---:|---:|---:|");
        for r in &self.rows {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {:.1} | {:.2} | {} | {} | {} |",
                r.scene,
                r.kind,
                r.threads,
                r.rays,
                100.0 * r.hit_fraction,
                r.ours_mrays,
                super::fmt_opt(r.embree_mrays, 2),
                super::fmt_opt(r.ratio, 2),
                r.agreement
                    .map_or_else(|| "—".into(), |a| format!("{:.4}%", 100.0 * a)),
            );
        }
        if !self.summary.is_empty() {
            let _ = writeln!(s, "\nGeometric mean over scenes of ours/Embree:\n");
            let _ = writeln!(s, "| rays | threads | ours/Embree | lowest agreement |");
            let _ = writeln!(s, "|---|---:|---:|---:|");
            for g in &self.summary {
                let _ = writeln!(
                    s,
                    "| {} | {} | {:.3} | {:.4}% |",
                    g.kind,
                    g.threads,
                    g.ratio,
                    100.0 * g.min_agreement
                );
            }
        }
        s.push('\n');
    }
}

/// Frame times of primary rays on icospheres of growing size, ours and Embree, all threads.
pub fn scaling(opts: &BenchOptions) -> anyhow::Result<Vec<MeshScalingRow>> {
    let levels: &[u32] = if opts.quick {
        &[2, 3]
    } else {
        &[3, 5, 6, 7, 8]
    };
    let (w, h) = if opts.quick { (32, 18) } else { (960, 540) };
    let workers = Workers::new(opts.threads.iter().copied().max().unwrap_or(1))?;
    let mut out = Vec::new();
    for &level in levels {
        let scene = icosphere_scene(level)?;
        eprintln!(
            "bench: mesh scaling, {} triangles",
            scene.meshes.triangle_count()
        );
        let accel = MeshAccel::new(&scene.meshes, opts.bvh);
        let referee = build_referee(&scene)?;
        let normals = FaceNormals::new(&scene.meshes);
        let rays = rays::primary(&scene, w, h);
        let ours = ours_query(&accel, &normals, Query::Closest);
        let (mut out_ours, mut out_emb) = (Vec::new(), Vec::new());
        let (ours_s, emb_s) = match &referee {
            Some((e, _)) => {
                let emb = referee_query(e, Query::Closest);
                let t = alternate(
                    &workers,
                    &rays,
                    opts.runs,
                    opts.min_seconds,
                    &mut [(&ours, &mut out_ours), (&emb, &mut out_emb)],
                );
                (t[0].clone(), Some(t[1].clone()))
            }
            None => {
                let t = alternate(
                    &workers,
                    &rays,
                    opts.runs,
                    opts.min_seconds,
                    &mut [(&ours, &mut out_ours)],
                );
                (t[0].clone(), None)
            }
        };
        out.push(MeshScalingRow {
            triangles: scene.meshes.triangle_count(),
            pixels: rays.len(),
            ours_ms: median(&ours_s) * 1e3,
            embree_ms: emb_s.as_ref().map(|e| median(e) * 1e3),
            ours_build_ms: accel.build_time.as_secs_f64() * 1e3,
            embree_build_ms: referee.as_ref().map(|r| r.1),
            agreement: emb_s
                .as_ref()
                .map(|_| agreement(Query::Closest, &out_ours, &out_emb)),
        });
    }
    Ok(out)
}
