//! Mesh section: our two-level BVH traversal against Embree 4 on the same ray arrays, and
//! frame times of meshes from a thousand to a million triangles.

use super::rays::{self, Query, QueryRay, RaySet};
use super::{BenchOptions, QueryFn, Workers, alternate, geomean, median};
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
    /// The fastest Embree configuration's median Mrays/s.
    pub embree_mrays: Option<f64>,
    /// ours / the fastest Embree configuration.
    pub ratio: Option<f64>,
    /// Fraction of rays on which ours and the fastest Embree configuration agree on hit or
    /// miss.
    pub agreement: Option<f64>,
    /// Label of the fastest Embree configuration (see [`EmbreeConfig::label`]).
    pub fastest: Option<String>,
    /// Every timed run, seconds (ours).
    pub ours_seconds: Vec<f64>,
    /// Every timed run, seconds (the fastest Embree configuration).
    pub embree_seconds: Vec<f64>,
    /// Every Embree configuration, timed in the same rounds as ours.
    pub embree: Vec<EmbreeFigure>,
}

/// One way of querying Embree: scene mode and rays per call.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct EmbreeConfig {
    /// Scenes built with the ROBUST flag (watertight); otherwise Embree's default flags.
    pub robust: bool,
    /// Rays per query call: 1 (`rtcIntersect1`/`rtcOccluded1`), 8 or 16 (packets).
    pub packet: usize,
}

impl EmbreeConfig {
    /// "default/1", "robust/16", …: mode / rays per call.
    pub fn label(&self) -> String {
        format!(
            "{}/{}",
            if self.robust { "robust" } else { "default" },
            self.packet
        )
    }
}

/// One Embree configuration's figure on a ray set.
#[derive(Debug, Clone, Serialize)]
pub struct EmbreeFigure {
    /// What was timed.
    pub config: EmbreeConfig,
    /// `config.label()`.
    pub label: String,
    /// Median Mrays/s.
    pub mrays: f64,
    /// ours / this.
    pub ratio: f64,
    /// Fraction of rays on which this and ours agree on hit or miss.
    pub agreement: f64,
    /// For packets: fraction of rays whose answer (t of the closest hit, bit for bit, or the
    /// occlusion) equals the single-ray answer of the same mode. `None` for single rays.
    pub same_as_single: Option<f64>,
    /// Every timed run, seconds.
    pub seconds: Vec<f64>,
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
    /// Our BVH build (all meshes and the instance tree) at the bench's preset, ms, median
    /// of the builds timed; meshes in parallel on the rayon pool (all cores).
    pub ours_build_ms: f64,
    /// Our build at the `Medium` preset (the renderer's default), ms.
    pub ours_medium_build_ms: f64,
    /// Embree's scene build (quality HIGH, ROBUST, its own threads), ms.
    pub embree_build_ms: Option<f64>,
    /// Embree's scene build (quality HIGH, default flags), ms.
    pub embree_default_build_ms: Option<f64>,
    /// Embree's scene build (quality MEDIUM, Embree's default quality, default flags), ms.
    pub embree_medium_build_ms: Option<f64>,
}

/// Geometric mean over scenes of one ray set and thread count.
#[derive(Debug, Clone, Serialize)]
pub struct MeshSummary {
    /// Ray set, or "closest hit" for primary, AO and incoherent together.
    pub kind: String,
    /// Threads.
    pub threads: usize,
    /// Geometric mean of ours / the fastest Embree configuration of this ray kind (the one
    /// with the lowest geometric mean in `per_config`).
    pub ratio: f64,
    /// That configuration's label.
    pub fastest: String,
    /// Geometric mean of ours / the fastest Embree configuration of each row (scene by
    /// scene; at most `ratio`).
    pub ratio_per_scene_best: f64,
    /// Per Embree configuration: (label, geometric mean of ours / it).
    pub per_config: Vec<(String, f64)>,
    /// Lowest hit/miss agreement of ours with a robust (watertight) configuration.
    pub min_agreement: f64,
    /// Lowest hit/miss agreement of ours with a default-mode configuration.
    pub min_agreement_default: f64,
    /// Lowest fraction of packet answers equal to the single-ray ones of the same mode.
    pub min_same_as_single: f64,
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
    /// Rays per Embree packet (8 or 16).
    pub embree_packet: Option<usize>,
    /// Whether the Embree library runs 8- and 16-ray packets natively
    /// (`RTC_DEVICE_PROPERTY_NATIVE_RAY8/16_SUPPORTED`).
    pub embree_native: Option<[bool; 2]>,
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

/// The Embree side, when built in: the mesh scenes in both modes (quality HIGH) and the
/// packet width.
#[cfg(feature = "embree")]
pub struct Referee {
    robust: crate::reference::embree::EmbreeScene,
    default: crate::reference::embree::EmbreeScene,
    width: crate::reference::embree::PacketWidth,
}
/// Without Embree built in, nothing: the mesh section reports our side alone.
#[cfg(not(feature = "embree"))]
pub struct Referee;

/// Builds one Embree scene; returns it and its build time in ms.
#[cfg(feature = "embree")]
fn build_embree(
    scene: &Scene,
    robust: bool,
    quality: crate::reference::embree::EmbreeQuality,
) -> anyhow::Result<(crate::reference::embree::EmbreeScene, f64)> {
    use crate::reference::embree::{EmbreeScene, ReferenceOptions};
    let options = ReferenceOptions {
        robust,
        quality,
        ..ReferenceOptions::default()
    };
    let start = std::time::Instant::now();
    let e = EmbreeScene::build_with(scene, &options).map_err(|e| anyhow::anyhow!("Embree: {e}"))?;
    Ok((e, start.elapsed().as_secs_f64() * 1e3))
}

/// Embree's build times of a scene, ms: HIGH robust, HIGH default flags, MEDIUM default flags.
type EmbreeBuilds = [f64; 3];

/// Builds the referee of `scene` `rounds` times after a warm-up round (taking turns with
/// `ours`, which is called once per round, told whether the round is timed, and keeps its own
/// times) and keeps the first scenes built; returns the referee (if Embree is built in) and
/// the median build times of the timed rounds. The warm-up round spares both builders the
/// costs of a first build in the process (thread pools starting, memory first touched),
/// which made single medians of three swing by a third.
#[cfg(feature = "embree")]
fn build_referee(
    scene: &Scene,
    packet: Option<usize>,
    rounds: usize,
    mut ours: impl FnMut(bool),
) -> anyhow::Result<(Option<Referee>, Option<EmbreeBuilds>)> {
    use crate::reference::embree::{EmbreeQuality, PacketWidth};
    let mut times: [Vec<f64>; 3] = Default::default();
    let mut kept = None;
    for round in 0..=rounds.max(1) {
        let timed = round > 0;
        ours(timed);
        let (robust, a) = build_embree(scene, true, EmbreeQuality::High)?;
        let (default, b) = build_embree(scene, false, EmbreeQuality::High)?;
        let (_, c) = build_embree(scene, false, EmbreeQuality::Medium)?;
        if timed {
            for (t, x) in times.iter_mut().zip([a, b, c]) {
                t.push(x);
            }
        }
        if kept.is_none() {
            kept = Some((robust, default));
        }
    }
    let (robust, default) = kept.expect("at least one round");
    let width = match packet {
        Some(16) => PacketWidth::Sixteen,
        Some(_) => PacketWidth::Eight,
        // The widest packet the library runs natively.
        None if robust.native_packets(PacketWidth::Sixteen) => PacketWidth::Sixteen,
        None => PacketWidth::Eight,
    };
    Ok((
        Some(Referee {
            robust,
            default,
            width,
        }),
        Some(times.map(|t| median(&t))),
    ))
}
#[cfg(not(feature = "embree"))]
fn build_referee(
    _: &Scene,
    _: Option<usize>,
    rounds: usize,
    mut ours: impl FnMut(bool),
) -> anyhow::Result<(Option<Referee>, Option<EmbreeBuilds>)> {
    for round in 0..=rounds.max(1) {
        ours(round > 0);
    }
    Ok((None, None))
}

#[cfg(feature = "embree")]
impl Referee {
    /// Rays per packet.
    fn packet(&self) -> usize {
        self.width.lanes()
    }

    /// Whether the library runs 8- and 16-ray packets natively.
    fn native(&self) -> [bool; 2] {
        use crate::reference::embree::PacketWidth;
        [PacketWidth::Eight, PacketWidth::Sixteen].map(|w| self.robust.native_packets(w))
    }

    /// Every configuration with its answers as our figures store them: t of the closest hit
    /// (∞ for a miss), or 1/0 for occlusion. Both query styles compute the geometric normal
    /// of a closest hit, as ours does below. Single rays: `rtcIntersect1` / `rtcOccluded1`;
    /// packets: each chunk cut into packets of `width` rays in order (`rtcIntersect8/16`,
    /// `rtcOccluded8/16`), the last one masked.
    fn backends(
        &self,
        query: Query,
        only_robust_single: bool,
    ) -> Vec<(EmbreeConfig, Box<QueryFn<'_>>)> {
        use crate::trace::query::RayQuery;
        let mut out: Vec<(EmbreeConfig, Box<QueryFn<'_>>)> = Vec::new();
        for robust in [false, true] {
            if only_robust_single && !robust {
                continue;
            }
            let e = if robust { &self.robust } else { &self.default };
            let single = move |rays: &[QueryRay], out: &mut [f32]| {
                for (q, out) in rays.iter().zip(out) {
                    *out = match query {
                        Query::Closest => e
                            .closest_hit(&q.ray, 0.0, q.tmax)
                            .map_or(f32::INFINITY, |h| h.t),
                        Query::Occluded => f32::from(u8::from(e.occluded(&q.ray, 0.0, q.tmax))),
                    }
                }
            };
            out.push((EmbreeConfig { robust, packet: 1 }, Box::new(single)));
            if only_robust_single {
                continue;
            }
            let width = self.width;
            let packets = move |rays: &[QueryRay], out: &mut [f32]| {
                let n = rays.len();
                let ray_buf: ArrayVec<crate::geom::Ray, { super::CHUNK }> =
                    rays.iter().map(|q| q.ray).collect();
                let tmax_buf: ArrayVec<f32, { super::CHUNK }> =
                    rays.iter().map(|q| q.tmax).collect();
                match query {
                    Query::Closest => {
                        let mut hits = [None; super::CHUNK];
                        e.closest_hits(width, &ray_buf, 0.0, &tmax_buf, &mut hits[..n]);
                        for (o, h) in out.iter_mut().zip(&hits[..n]) {
                            *o = h.map_or(f32::INFINITY, |h| h.t);
                        }
                    }
                    Query::Occluded => {
                        let mut blocked = [false; super::CHUNK];
                        e.occluded_many(width, &ray_buf, 0.0, &tmax_buf, &mut blocked[..n]);
                        for (o, &b) in out.iter_mut().zip(&blocked[..n]) {
                            *o = f32::from(u8::from(b));
                        }
                    }
                }
            };
            out.push((
                EmbreeConfig {
                    robust,
                    packet: width.lanes(),
                },
                Box::new(packets),
            ));
        }
        out
    }
}
#[cfg(not(feature = "embree"))]
impl Referee {
    fn packet(&self) -> usize {
        0
    }
    fn native(&self) -> [bool; 2] {
        [false; 2]
    }
    fn backends(&self, _: Query, _: bool) -> Vec<(EmbreeConfig, Box<QueryFn<'_>>)> {
        Vec::new()
    }
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
    let (mut embree_packet, mut embree_native) = (None, None);
    for (name, rel) in chosen {
        eprintln!("bench: mesh scene {name}");
        let scene = load(&opts.assets, rel)?;
        // Builds are timed in turns (ours at the bench's preset, ours at Medium, then
        // Embree's), after a warm-up round, three rounds unless quick; the median is reported.
        let rounds = if opts.quick { 1 } else { 3 };
        let (mut ours_ms, mut medium_ms) = (Vec::new(), Vec::new());
        let mut accel = None;
        let (referee, embree_ms) = build_referee(&scene, opts.embree_packet, rounds, |timed| {
            let a = MeshAccel::new(&scene.meshes, opts.bvh);
            let m = MeshAccel::new(&scene.meshes, crate::accel::bvh::BuildQuality::Medium);
            if timed {
                ours_ms.push(a.build_time.as_secs_f64() * 1e3);
                medium_ms.push(m.build_time.as_secs_f64() * 1e3);
            }
            accel.get_or_insert(a);
        })?;
        let accel = accel.expect("built at least once");
        if let Some(r) = &referee {
            embree_packet = Some(r.packet());
            embree_native = Some(r.native());
        }
        scenes.push(MeshSceneInfo {
            scene: name.into(),
            triangles: scene.meshes.triangle_count(),
            unique_triangles: scene.meshes.unique_triangle_count(),
            instances: scene.meshes.instances.len(),
            ours_build_ms: median(&ours_ms),
            ours_medium_build_ms: median(&medium_ms),
            embree_build_ms: embree_ms.map(|t| t[0]),
            embree_default_build_ms: embree_ms.map(|t| t[1]),
            embree_medium_build_ms: embree_ms.map(|t| t[2]),
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
                rows.push(time_set(
                    opts,
                    w,
                    name,
                    set,
                    &accel,
                    &normals,
                    referee.as_ref(),
                ));
            }
        }
    }
    let summary = summarize(&rows, &opts.threads);
    Ok(MeshReport {
        width: opts.width,
        height: opts.height,
        incoherent: opts.incoherent,
        bvh: format!(
            "{:?} ({})",
            opts.bvh,
            if opts.bvh.binned() {
                "binned SAH splits on the rayon pool, collapsed to eight children per node by the SAH"
            } else {
                "obvhs's PLOC with reinsertion"
            }
        ),
        embree_packet,
        embree_native,
        scenes,
        rows,
        summary,
    })
}

/// Times one ray set with one pool: ours and every Embree configuration in alternating
/// rounds.
fn time_set(
    opts: &BenchOptions,
    w: &Workers,
    scene: &str,
    set: &RaySet,
    accel: &MeshAccel,
    normals: &FaceNormals,
    referee: Option<&Referee>,
) -> MeshRow {
    let ours = ours_query(accel, normals, set.query);
    let embree = referee.map_or_else(Vec::new, |r| r.backends(set.query, false));
    let mut outs: Vec<Vec<f32>> = vec![Vec::new(); 1 + embree.len()];
    let mut backends: Vec<(&QueryFn, &mut Vec<f32>)> = std::iter::once(&ours as &QueryFn)
        .chain(embree.iter().map(|(_, f)| &**f))
        .zip(outs.iter_mut())
        .collect();
    let times = alternate(w, &set.rays, opts.runs, opts.min_seconds, &mut backends);
    let n = set.rays.len() as f64;
    let mrays = |t: &[f64]| n / median(t) / 1e6;
    let ours_mrays = mrays(&times[0]);
    let figures: Vec<EmbreeFigure> = embree
        .iter()
        .enumerate()
        .map(|(k, (config, _))| {
            let single = embree
                .iter()
                .position(|(c, _)| c.robust == config.robust && c.packet == 1)
                .filter(|_| config.packet > 1);
            let m = mrays(&times[k + 1]);
            EmbreeFigure {
                config: *config,
                label: config.label(),
                mrays: m,
                ratio: ours_mrays / m,
                agreement: agreement(set.query, &outs[0], &outs[k + 1]),
                same_as_single: single.map(|j| identical(&outs[k + 1], &outs[j + 1])),
                seconds: times[k + 1].clone(),
            }
        })
        .collect();
    let best = figures
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.mrays.total_cmp(&b.1.mrays))
        .map(|(k, _)| k);
    MeshRow {
        scene: scene.into(),
        kind: set.kind.into(),
        query: set.query,
        threads: w.threads,
        rays: set.rays.len(),
        hit_fraction: outs[0].iter().filter(|&&v| is_hit(set.query, v)).count() as f64 / n,
        ours_mrays,
        embree_mrays: best.map(|k| figures[k].mrays),
        ratio: best.map(|k| figures[k].ratio),
        agreement: best.map(|k| figures[k].agreement),
        fastest: best.map(|k| figures[k].label.clone()),
        ours_seconds: times[0].clone(),
        embree_seconds: best.map_or_else(Vec::new, |k| figures[k].seconds.clone()),
        embree: figures,
    }
}

/// Fraction of rays with the very same answer (bit for bit).
fn identical(a: &[f32], b: &[f32]) -> f64 {
    let same = a
        .iter()
        .zip(b)
        .filter(|(x, y)| x.to_bits() == y.to_bits())
        .count();
    same as f64 / a.len().max(1) as f64
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
            let best: Vec<f64> = sel.iter().filter_map(|r| r.ratio).collect();
            if best.is_empty() || best.len() != sel.len() {
                continue;
            }
            // Configurations in the order the rows list them.
            let per_config: Vec<(String, f64)> = sel[0]
                .embree
                .iter()
                .map(|f| {
                    let ratios: Vec<f64> = sel
                        .iter()
                        .filter_map(|r| r.embree.iter().find(|g| g.label == f.label))
                        .map(|g| g.ratio)
                        .collect();
                    (f.label.clone(), geomean(&ratios))
                })
                .collect();
            let (fastest, ratio) = per_config
                .iter()
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .cloned()
                .expect("rows with a ratio have configurations");
            let figures = || sel.iter().flat_map(|r| &r.embree);
            let lowest = |robust: bool| {
                figures()
                    .filter(|f| f.config.robust == robust)
                    .map(|f| f.agreement)
                    .fold(1.0, f64::min)
            };
            out.push(MeshSummary {
                kind: label.into(),
                threads: t,
                ratio,
                fastest,
                ratio_per_scene_best: geomean(&best),
                per_config,
                min_agreement: lowest(true),
                min_agreement_default: lowest(false),
                min_same_as_single: figures()
                    .filter_map(|f| f.same_as_single)
                    .fold(1.0, f64::min),
            });
        }
    }
    out
}

/// A fraction as a percentage; one that falls short of 1 by less than the fourth decimal
/// shows more decimals, so that a disagreement is never printed as 100%.
fn percent(a: f64) -> String {
    let s = format!("{:.4}%", 100.0 * a);
    if a < 1.0 && s == "100.0000%" {
        format!("{:.7}%", 100.0 * a)
    } else {
        s
    }
}

impl MeshReport {
    /// Appends the section's tables.
    pub fn markdown(&self, s: &mut String) {
        let _ = writeln!(s, "## Meshes: ours against Embree 4\n");
        let packet = self
            .embree_packet
            .map_or_else(|| "—".to_string(), |p| p.to_string());
        let native = self.embree_native.map_or_else(
            || "—".to_string(),
            |[a, b]| format!("8 rays {}, 16 rays {}", yes(a), yes(b)),
        );
        let _ = writeln!(
            s,
            "Primary rays {}×{} from a camera framing the model's bounds; AO rays (cosine-distributed, closest hit within the model's radius) and shadow rays (to a point light above) from every primary hit; {} incoherent rays (uniform origins in the bounds, uniform directions); our BVH: the {} preset, watertight traversal and triangle test; build times are medians of three rounds of both builders in turns (one with --quick), after a warm-up round. Embree: build quality HIGH, in two modes, *default* (Embree's default scene flags: fastest, not watertight; HIGH adds spatial splits) and *robust* (`RTC_SCENE_FLAG_ROBUST`: watertight; Embree then builds its plain binned-SAH tree whatever the quality), each queried one ray at a time (`rtcIntersect1`/`rtcOccluded1`, \"/1\") and in packets of {packet} rays cut in order from the same 64-ray chunks ours gets, with valid masks (`rtcIntersect{packet}`/`rtcOccluded{packet}`, \"/{packet}\"; native packets in this library: {native}). Embree 4 has no stream queries (`rtcIntersect1M` was removed in 4.0).\n",
            self.width, self.height, self.incoherent, self.bvh
        );
        let _ = writeln!(
            s,
            "| scene | triangles (unique) | instances | ours build ms | ours Medium build ms | Embree HIGH robust ms | Embree HIGH default ms | Embree MEDIUM default ms | ours / Embree HIGH (faster mode) | ours Medium / Embree MEDIUM |"
        );
        let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
        for sc in &self.scenes {
            let _ = writeln!(
                s,
                "| {} | {} ({}) | {} | {:.0} | {:.0} | {} | {} | {} | {} | {} |",
                sc.scene,
                sc.triangles,
                sc.unique_triangles,
                sc.instances,
                sc.ours_build_ms,
                sc.ours_medium_build_ms,
                super::fmt_opt(sc.embree_build_ms, 0),
                super::fmt_opt(sc.embree_default_build_ms, 0),
                super::fmt_opt(sc.embree_medium_build_ms, 0),
                super::fmt_opt(
                    sc.embree_build_ms
                        .zip(sc.embree_default_build_ms)
                        .map(|(a, b)| sc.ours_build_ms / a.min(b)),
                    2
                ),
                super::fmt_opt(
                    sc.embree_medium_build_ms
                        .map(|e| sc.ours_medium_build_ms / e),
                    2
                ),
            );
        }
        let _ = writeln!(
            s,
            "\nAgainst the fastest Embree configuration of each row (named):\n"
        );
        let _ = writeln!(
            s,
            "| scene | rays | threads | count | hit % | ours Mrays/s | Embree Mrays/s | ours/Embree | hit/miss agreement |"
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
                match (&r.embree_mrays, &r.fastest) {
                    (Some(m), Some(f)) => format!("{m:.2} ({f})"),
                    _ => "—".into(),
                },
                super::fmt_opt(r.ratio, 2),
                r.agreement.map_or_else(|| "—".into(), percent),
            );
        }
        if self.rows.iter().any(|r| !r.embree.is_empty()) {
            let _ = writeln!(
                s,
                "\nEvery Embree configuration (timed in the same alternating rounds as ours; \"= single\": packet answers bit for bit equal to the same mode's single-ray answers):\n"
            );
            let _ = writeln!(
                s,
                "| Embree | scene | rays | threads | Mrays/s | ours Mrays/s | ours/Embree | agreement with ours | = single |"
            );
            let _ = writeln!(s, "|---|---|---|---:|---:|---:|---:|---:|---:|");
            for r in &self.rows {
                for f in &r.embree {
                    let _ = writeln!(
                        s,
                        "| {} | {} | {} | {} | {:.2} | {:.2} | {:.2} | {} | {} |",
                        f.label,
                        r.scene,
                        r.kind,
                        r.threads,
                        f.mrays,
                        r.ours_mrays,
                        f.ratio,
                        percent(f.agreement),
                        f.same_as_single.map_or_else(|| "—".into(), percent),
                    );
                }
            }
        }
        if !self.summary.is_empty() {
            let labels: Vec<&str> = self.summary[0]
                .per_config
                .iter()
                .map(|(l, _)| l.as_str())
                .collect();
            let _ = writeln!(
                s,
                "\nGeometric mean over scenes of ours/Embree, per Embree configuration, and against the fastest configuration of the ray kind (the lowest of those) and the fastest of each scene. Ours stays watertight in every column; the agreement columns are hit/miss agreement of ours with Embree's robust (watertight) and default modes:\n"
            );
            let mut head = String::from("| rays | threads |");
            let mut rule = String::from("|---|---:|");
            for l in &labels {
                let _ = write!(head, " ours/{l} |");
                rule.push_str("---:|");
            }
            let _ = writeln!(
                s,
                "{head} ours/fastest (which) | ours/fastest per scene | agreement robust | agreement default | packets = single |"
            );
            let _ = writeln!(s, "{rule}---:|---:|---:|---:|---:|");
            for g in &self.summary {
                let mut line = format!("| {} | {} |", g.kind, g.threads);
                for (_, r) in &g.per_config {
                    let _ = write!(line, " {r:.3} |");
                }
                let _ = writeln!(
                    s,
                    "{line} {:.3} ({}) | {:.3} | {} | {} | {} |",
                    g.ratio,
                    g.fastest,
                    g.ratio_per_scene_best,
                    percent(g.min_agreement),
                    percent(g.min_agreement_default),
                    percent(g.min_same_as_single),
                );
            }
        }
        s.push('\n');
    }
}

fn yes(b: bool) -> &'static str {
    if b { "yes" } else { "no" }
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
        let mut accel = None;
        // (The timed round's tree is the one kept, and its time the one reported.)
        let (referee, embree_ms) = build_referee(&scene, opts.embree_packet, 1, |_| {
            accel = Some(MeshAccel::new(&scene.meshes, opts.bvh));
        })?;
        let accel = accel.expect("built once");
        let normals = FaceNormals::new(&scene.meshes);
        let rays = rays::primary(&scene, w, h);
        let ours = ours_query(&accel, &normals, Query::Closest);
        // The referee's configuration only: robust, one ray at a time.
        let embree = referee
            .as_ref()
            .map_or_else(Vec::new, |r| r.backends(Query::Closest, true));
        let mut outs: Vec<Vec<f32>> = vec![Vec::new(); 1 + embree.len()];
        let mut backends: Vec<(&QueryFn, &mut Vec<f32>)> = std::iter::once(&ours as &QueryFn)
            .chain(embree.iter().map(|(_, f)| &**f))
            .zip(outs.iter_mut())
            .collect();
        let t = alternate(&workers, &rays, opts.runs, opts.min_seconds, &mut backends);
        let ours_s = t[0].clone();
        let emb_s = t.get(1).cloned();
        let (out_ours, out_emb) = (&outs[0], outs.get(1));
        out.push(MeshScalingRow {
            triangles: scene.meshes.triangle_count(),
            pixels: rays.len(),
            ours_ms: median(&ours_s) * 1e3,
            embree_ms: emb_s.as_ref().map(|e| median(e) * 1e3),
            ours_build_ms: accel.build_time.as_secs_f64() * 1e3,
            embree_build_ms: embree_ms.map(|t| t[0]),
            agreement: out_emb.map(|e| agreement(Query::Closest, out_ours, e)),
        });
    }
    Ok(out)
}
