//! Peer section: the same SDF expressions rendered by fidget and by hytrace, timed alternately and
//! checked against a brute-force ground truth.
//!
//! Every model is a list of finite SDF objects seen by an orthographic camera along −z that frames
//! their bounding cube. hytrace renders the objects as a scene (primary rays with normals, one
//! directional light, no shadows, every object in the default material); fidget renders the min
//! of the same objects' distance tapes, converted to its expression trees ([`fidget::to_tree`]),
//! with its voxel renderer (depth and normals) at depth resolution = image height, on a grid
//! placed so that its columns are our pixel centres. The ground truth ([`truth`]) samples each
//! pixel's ray densely in f64.

pub mod evaluators;
#[cfg(feature = "fidget")]
pub mod fidget;
pub mod truth;

use crate::scene::{Light, Scene, SdfObject, Shadow};
use crate::sdf::SdfNode;
use glam::Vec3;
use serde::Serialize;
use std::fmt::Write;
use std::path::Path;

/// The cube a model is viewed in: centre and half side.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct View {
    /// Centre.
    pub center: Vec3,
    /// Half the side.
    pub half: f32,
}

/// One model, ready to render by both.
#[derive(Debug, Clone)]
pub struct PeerModel {
    /// Name in the tables.
    pub name: String,
    /// The scene hytrace renders (the kept objects, the peer camera, light and settings).
    pub scene: Scene,
    /// `scene` without its objects: what the first frame starts from.
    pub empty: Scene,
    /// The kept objects' world-space trees (what the first frame lowers again).
    pub nodes: Vec<(String, SdfNode)>,
    /// The view cube.
    pub view: View,
    /// Image side in pixels (square images).
    pub size: u32,
    /// What of the source scene was left out, for the table ("" for nothing).
    pub left_out: String,
}

/// The generated models, as scene sources: fidget's gyroid sphere, a union of 400 spheres, a
/// smooth-union chain of 60 links, a twisted, bent composite, and unions of 10 and 1,000 boxes
/// tiling the same square (the same pixels: cost against the size of the tree).
pub fn generated() -> Vec<(String, String)> {
    vec![
        ("gyroid sphere".into(), gyroid_sphere()),
        ("400 spheres".into(), spheres(400)),
        ("smooth chain (60 links)".into(), smooth_chain(60)),
        ("twisted + bent".into(), twisted_bent()),
        (TILES_FEW.into(), tiles(5, 2)),
        (TILES_MANY.into(), tiles(50, 20)),
    ]
}

/// The model names of the two tilings, whose frame times the report compares.
pub const TILES_FEW: &str = "10 tiles";
/// See [`TILES_FEW`].
pub const TILES_MANY: &str = "1000 tiles";

/// `nx`·`ny` boxes tiling the square [−0.9, 0.9]² edge to edge, of depths varying from box to
/// box, one `Union`: seen along z they cover exactly the same pixels for any count.
fn tiles(nx: usize, ny: usize) -> String {
    let (wx, wy) = (1.8 / nx as f32, 1.8 / ny as f32);
    let mut shapes = Vec::with_capacity(nx * ny);
    for j in 0..ny {
        for i in 0..nx {
            // depths from a fixed hash of the cell, 0.05 to 0.15
            let h = ((i * 7919 + j * 104729) % 101) as f32 / 100.0;
            shapes.push(format!(
                "Transform(translate: ({:.5}, {:.5}, 0), shape: Box(half_extents: ({:.5}, {:.5}, {:.4})))",
                -0.9 + (i as f32 + 0.5) * wx,
                -0.9 + (j as f32 + 0.5) * wy,
                0.5 * wx,
                0.5 * wy,
                0.05 + 0.1 * h
            ));
        }
    }
    scene_source(&format!(
        "(name: \"tiles\", shape: Union([{}]))",
        shapes.join(", ")
    ))
}

fn scene_source(objects: &str) -> String {
    format!(
        "Scene(camera: Orthographic(position: (0, 0, 3), look_at: (0, 0, 0), height: 2), \
         objects: [{objects}])"
    )
}

/// fidget's gyroid sphere ([`crate::sdf::conformance::FIDGET_GYROID_SPHERE`]) as a scene.
fn gyroid_sphere() -> String {
    scene_source(&format!(
        "(name: \"gyroid sphere\", shape: {})",
        crate::sdf::conformance::FIDGET_GYROID_SPHERE
    ))
}

/// `n` spheres of radius 0.06 along a six-turn spiral (the shape of fidget's many-spheres
/// benchmark), one `Union`.
fn spheres(n: usize) -> String {
    let mut shapes = Vec::with_capacity(n);
    for i in 0..n {
        let s = i as f32 / (n.max(2) - 1) as f32;
        let a = s * 6.0 * std::f32::consts::TAU;
        let r = 0.85 * (0.3 + 0.7 * s);
        shapes.push(format!(
            "Transform(translate: ({:.4}, {:.4}, {:.4}), shape: Sphere(radius: 0.06))",
            r * a.cos(),
            -0.9 + 1.8 * s,
            r * a.sin()
        ));
    }
    scene_source(&format!(
        "(name: \"spheres\", shape: Union([{}]))",
        shapes.join(", ")
    ))
}

/// `n` interlocked torus links around a circle, alternately in the circle's plane and across
/// it, blended by one `SmoothUnion` (a chain of n − 1 smooth minima).
fn smooth_chain(n: usize) -> String {
    let radius = 0.75f32;
    let mut links = Vec::with_capacity(n);
    for i in 0..n {
        let theta = i as f32 / n as f32 * std::f32::consts::TAU;
        let (s, c) = theta.sin_cos();
        // A torus lies in the xz-plane around y: turned about x it lies in the circle's plane;
        // turned about z by θ − 90° its axis is radial, so it stands across the circle.
        let rotate = if i % 2 == 0 {
            "(90, 0, 0)".to_string()
        } else {
            format!("(0, 0, {:.3})", theta.to_degrees() - 90.0)
        };
        links.push(format!(
            "Transform(translate: ({:.4}, {:.4}, 0), rotate: {rotate}, \
             shape: Torus(major: 0.055, minor: 0.014))",
            radius * c,
            radius * s
        ));
    }
    scene_source(&format!(
        "(name: \"chain\", shape: SmoothUnion(k: 0.01, shapes: [{}]))",
        links.join(", ")
    ))
}

/// A square tube with two rings, twisted about y and bent in the xy-plane.
fn twisted_bent() -> String {
    scene_source(
        "(name: \"twisted bent\", shape: Bend(rate: 0.5, shape: Twist(rate: 2.5, shape: Union([\
            Subtraction(base: RoundBox(half_extents: (0.28, 0.75, 0.28), radius: 0.04), \
                cut: Cylinder(half_height: 0.9, radius: 0.14)), \
            Transform(translate: (0, 0.4, 0), shape: Torus(major: 0.36, minor: 0.05)), \
            Transform(translate: (0, -0.4, 0), shape: Torus(major: 0.36, minor: 0.05))]))))",
    )
}

/// Lowers trees to objects the way the scene loader does, every material name resolved to the
/// default material (the peer renders geometry, not materials).
pub fn lower_objects(nodes: &[(String, SdfNode)]) -> anyhow::Result<Vec<SdfObject>> {
    let mut objects = Vec::new();
    for (name, node) in nodes {
        // split as a scene file's object is, the default material being opaque
        let parts = SdfObject::split(name, node.clone(), &|_| Some(0), 0, &|_| true)
            .map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
        objects.extend(parts);
    }
    Ok(objects)
}

/// An object more than this many times larger (largest side of its bounds) than all the others
/// together is a ground (a huge sphere or slab under the scene) and is left out: framing it
/// would shrink the rest to a few pixels.
pub const GROUND_RATIO: f32 = 10.0;

/// An SDF object of the scene file: its parts put back together.
struct FileObject {
    name: String,
    node: SdfNode,
    bounds: crate::geom::Aabb,
}

/// The scene's SDF objects as the file has them: an object split into parts is the union of
/// its parts again (the peer gets the model as written; [`lower_objects`] splits it as the
/// scene loader did).
fn file_objects(scene: &Scene) -> Vec<FileObject> {
    let mut out: Vec<FileObject> = Vec::new();
    for o in &scene.objects {
        match o.part {
            Some(p) if p.index > 0 => {
                let last = out.last_mut().expect("a later part follows the first");
                if let SdfNode::Union(members) = &mut last.node {
                    members.push(o.node.clone());
                }
                last.bounds = last.bounds.union(&o.bounds());
            }
            Some(_) => out.push(FileObject {
                name: o.name.clone(),
                node: SdfNode::Union(vec![o.node.clone()]),
                bounds: o.bounds(),
            }),
            None => out.push(FileObject {
                name: o.name.clone(),
                node: o.node.clone(),
                bounds: o.bounds(),
            }),
        }
    }
    out
}

/// The peer version of `scene` at `size`²: its finite SDF objects (infinite ones, such as
/// planes, a ground per [`GROUND_RATIO`] and meshes are left out and named in `left_out`), the
/// orthographic view of their bounding cube, one directional light, no shadows, no bounces, the
/// default material. `None` when no finite SDF object is left.
pub fn peer_model(name: &str, scene: &Scene, size: u32) -> anyhow::Result<Option<PeerModel>> {
    let mut left = Vec::new();
    let mut kept: Vec<FileObject> = Vec::new();
    for o in file_objects(scene) {
        if o.bounds.is_finite() && !o.bounds.is_empty() {
            kept.push(o);
        } else {
            left.push(format!("{} (infinite)", o.name));
        }
    }
    let side = |b: crate::geom::Aabb| (b.max - b.min).max_element();
    if kept.len() >= 2 {
        let largest = (0..kept.len())
            .max_by(|&a, &b| side(kept[a].bounds).total_cmp(&side(kept[b].bounds)))
            .unwrap_or(0);
        let rest = kept
            .iter()
            .enumerate()
            .filter(|&(i, _)| i != largest)
            .fold(crate::geom::Aabb::EMPTY, |acc, (_, o)| acc.union(&o.bounds));
        let ratio = side(kept[largest].bounds) / side(rest);
        if ratio > GROUND_RATIO {
            left.push(format!(
                "{} (ground, {ratio:.0}× the rest)",
                kept[largest].name
            ));
            kept.remove(largest);
        }
    }
    let bounds = kept
        .iter()
        .fold(crate::geom::Aabb::EMPTY, |acc, o| acc.union(&o.bounds));
    let nodes: Vec<(String, SdfNode)> = kept.into_iter().map(|o| (o.name, o.node)).collect();
    let meshes = scene.meshes.instances.len();
    if meshes > 0 {
        left.push(format!(
            "{meshes} mesh instance{}",
            if meshes == 1 { "" } else { "s" }
        ));
    }
    if nodes.is_empty() {
        return Ok(None);
    }
    let half = 0.5 * (bounds.max - bounds.min).max_element() * 1.02;
    let view = View {
        center: bounds.center(),
        half: half.max(1e-3),
    };
    let mut peer = scene.clone();
    peer.objects = Vec::new();
    peer.meshes = Default::default();
    peer.materials.truncate(1);
    peer.material_names.truncate(1);
    peer.image.width = size;
    peer.image.height = size;
    peer.image.samples = 1;
    peer.camera = crate::scene::camera::Camera::look_at(
        view.center + Vec3::Z * (2.0 * view.half),
        view.center,
        Vec3::Y,
        crate::scene::camera::Projection::Orthographic {
            height: 2.0 * view.half,
        },
    )
    .map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
    peer.lights = vec![Light::Directional {
        direction: Vec3::new(-0.3, -0.5, -1.0).normalize(),
        radiance: Vec3::splat(0.9),
        shadow: Shadow::None,
    }];
    peer.tracer.shadows = false;
    // The camera sits 2·half in front of the centre: rays must reach the back of the cube.
    peer.tracer.max_distance = peer.tracer.max_distance.max(4.0 * view.half);
    peer.shading.ambient_occlusion = None;
    peer.shading.max_bounces = 0;
    let empty = peer.clone();
    peer.objects = lower_objects(&nodes)?;
    Ok(Some(PeerModel {
        name: name.to_string(),
        scene: peer,
        empty,
        nodes,
        view,
        size,
        left_out: left.join(", "),
    }))
}

/// Every model of the section: the generated ones, then the shipped scenes (`scenes`).
pub fn models(scenes: &[(String, Scene)], size: u32) -> anyhow::Result<Vec<PeerModel>> {
    let mut out = Vec::new();
    for (name, source) in generated() {
        let scene = Scene::from_source(&source, Path::new(&format!("<{name}>")))?;
        out.extend(peer_model(&name, &scene, size)?);
    }
    for (name, scene) in scenes {
        out.extend(peer_model(&format!("{name}.ron"), scene, size)?);
    }
    Ok(out)
}

/// A hit mask from per-pixel hits.
pub fn mask_of(hits: impl Iterator<Item = bool>) -> Vec<bool> {
    hits.collect()
}

/// The ground truth of a model on a strided subset of its pixels.
#[derive(Debug, Clone, Serialize)]
pub struct Truth {
    /// Every `stride`-th pixel of every `stride`-th row is sampled.
    pub stride: u32,
    /// Samples along each ray (over the view cube's depth).
    pub samples: usize,
    /// The pixels sampled (row-major indices) and whether each is a hit.
    #[serde(skip)]
    pub pixels: Vec<(usize, bool)>,
    /// Number of pixels sampled.
    pub count: usize,
    /// Of those, hits.
    pub hits: usize,
    /// Seconds it took (all cores).
    pub seconds: f64,
}

/// Operation evaluations (operations × samples) the ground truth of one model may cost: about
/// ten seconds of two cores. The stride is chosen from a sparse pilot run so that this holds,
/// which depends only on the model, not on the machine.
pub const TRUTH_BUDGET: f64 = 1.2e10;

/// Ground truth at `samples_per_pixel` samples per ray, strided to fit [`TRUTH_BUDGET`].
pub fn ground_truth(model: &PeerModel, workers: &super::Workers) -> Truth {
    let start = std::time::Instant::now();
    let objects: Vec<truth::TruthObject> = model
        .scene
        .objects
        .iter()
        .map(|o| {
            let b = o.bounds();
            let pad = 1e-5 * f64::from(model.view.half);
            truth::TruthObject {
                program: truth::F64Program::new(&o.lowered.program),
                min: (b.min.as_dvec3() - pad).to_array(),
                max: (b.max.as_dvec3() + pad).to_array(),
            }
        })
        .collect();
    let n = model.size as usize;
    let samples = 2 * n;
    let v = model.view;
    let (cx, cy, cz, h) = (
        f64::from(v.center.x),
        f64::from(v.center.y),
        f64::from(v.center.z),
        f64::from(v.half),
    );
    let s = 2.0 / n as f64;
    let ray = |i: usize, regs: &mut Vec<f64>| {
        let (px, py) = (i % n, i / n);
        let x = cx + h * (-1.0 + (px as f64 + 0.5) * s);
        let y = cy + h * (1.0 - (py as f64 + 0.5) * s);
        truth::ray_hits(&objects, x, y, cz + h, 2.0 * h, samples, regs)
    };
    let cost_per_ray: f64 = {
        // Pilot: a sparse grid, counting the evaluations along each ray.
        let step = (n / 16).max(1);
        let ops: Vec<f64> = objects.iter().map(|o| o.program.len() as f64).collect();
        let total: f64 = (0..n)
            .step_by(step)
            .flat_map(|py| (0..n).step_by(step).map(move |px| (px, py)))
            .map(|(px, py)| {
                // Upper bound: every object whose bounds the ray crosses, full depth in them.
                let x = cx + h * (-1.0 + (px as f64 + 0.5) * s);
                let y = cy + h * (1.0 - (py as f64 + 0.5) * s);
                objects
                    .iter()
                    .zip(&ops)
                    .filter(|(o, _)| {
                        x >= o.min[0] && x <= o.max[0] && y >= o.min[1] && y <= o.max[1]
                    })
                    .map(|(o, k)| k * samples as f64 * ((o.max[2] - o.min[2]) / (2.0 * h)).min(1.0))
                    .sum::<f64>()
            })
            .sum();
        let count = n.div_ceil(step).pow(2) as f64;
        total / count
    };
    let mut stride = 1usize;
    while cost_per_ray * (n.div_ceil(stride).pow(2) as f64) > TRUTH_BUDGET && stride < n {
        stride += 1;
    }
    let idx: Vec<usize> = (0..n)
        .step_by(stride)
        .flat_map(|py| (0..n).step_by(stride).map(move |px| py * n + px))
        .collect();
    let mut hits = vec![false; idx.len()];
    thread_local! {
        static REGS: std::cell::RefCell<Vec<f64>> = const { std::cell::RefCell::new(Vec::new()) };
    }
    workers.map(&idx, &mut hits, |&i| {
        REGS.with(|r| ray(i, &mut r.borrow_mut()))
    });
    let pixels: Vec<(usize, bool)> = idx.into_iter().zip(hits).collect();
    Truth {
        stride: stride as u32,
        samples,
        count: pixels.len(),
        hits: pixels.iter().filter(|p| p.1).count(),
        pixels,
        seconds: start.elapsed().as_secs_f64(),
    }
}

impl Truth {
    /// Fraction of the sampled pixels where `mask` says what the ground truth says.
    pub fn agreement(&self, mask: &[bool]) -> f64 {
        if self.pixels.is_empty() {
            return f64::NAN;
        }
        let same = self
            .pixels
            .iter()
            .filter(|&&(i, hit)| mask.get(i).copied().unwrap_or(false) == hit)
            .count();
        same as f64 / self.pixels.len() as f64
    }
}

/// Fraction of pixels where two masks agree.
pub fn same_fraction(a: &[bool], b: &[bool]) -> f64 {
    if a.is_empty() || a.len() != b.len() {
        return f64::NAN;
    }
    a.iter().zip(b).filter(|(x, y)| x == y).count() as f64 / a.len() as f64
}

/// One backend's frames in one measurement: median ms, or None when its first frame took longer
/// than the frame limit (then it was cancelled and not timed further).
#[derive(Debug, Clone, Serialize)]
pub struct Frames {
    /// Median ms per frame.
    pub median_ms: Option<f64>,
    /// Every timed frame, ms.
    pub runs_ms: Vec<f64>,
}

impl Frames {
    #[cfg(feature = "fidget")]
    fn new(times: Option<&[f64]>) -> Frames {
        match times {
            Some(t) => Frames {
                median_ms: Some(super::median(t) * 1e3),
                runs_ms: t.iter().map(|s| s * 1e3).collect(),
            },
            None => Frames {
                median_ms: None,
                runs_ms: Vec::new(),
            },
        }
    }
}

/// One model at one thread count.
#[derive(Debug, Clone, Serialize)]
pub struct PeerRow {
    /// Model.
    pub model: String,
    /// Threads.
    pub threads: usize,
    /// fidget, bytecode VM (shape built before).
    pub fidget_vm: Frames,
    /// fidget, JIT (shape compiled before).
    pub fidget_jit: Frames,
    /// hytrace first frame: lowering, `SceneTracer` (octree), render.
    pub hytrace_first: Frames,
    /// hytrace steady-state frame (tracer reused).
    pub hytrace_steady: Frames,
    /// hytrace steady ÷ fidget's faster CPU evaluator's frame; when both fidget evaluators hit
    /// the frame limit, hytrace ÷ the limit (an upper bound, see `ratio_is_bound`).
    pub steady_ratio: f64,
    /// hytrace first frame ÷ (fidget's faster evaluator's build + frame).
    pub first_ratio: f64,
    /// Whether the ratios are upper bounds (fidget over the limit).
    pub ratio_is_bound: bool,
}

/// One model: what it is and how right each renderer is.
#[derive(Debug, Clone, Serialize)]
pub struct PeerModelReport {
    /// Model.
    pub model: String,
    /// Image side in pixels.
    pub size: u32,
    /// SDF objects rendered.
    pub objects: usize,
    /// Live distance operations summed over the objects (our SSA).
    pub ops: usize,
    /// What was left out of the source scene.
    pub left_out: String,
    /// The view cube.
    pub view: View,
    /// fidget: ms to convert the tapes and build the VM shape.
    pub fidget_vm_build_ms: f64,
    /// fidget: ms to convert the tapes and compile the JIT shape.
    pub fidget_jit_build_ms: f64,
    /// The ground truth used.
    pub truth: Truth,
    /// Hit-mask agreement with the ground truth: fidget VM (None: no frame within the limit).
    pub fidget_vm_agreement: Option<f64>,
    /// fidget JIT.
    pub fidget_jit_agreement: Option<f64>,
    /// hytrace.
    pub hytrace_agreement: f64,
    /// hytrace's mask against fidget's (VM, else JIT) on every pixel.
    pub hytrace_vs_fidget: Option<f64>,
    /// Fraction of pixels hytrace hits.
    pub hit_fraction: f64,
}

/// The GPU comparison (gyroid sphere).
#[derive(Debug, Clone, Serialize)]
pub struct PeerGpu {
    /// Model.
    pub model: String,
    /// Image side.
    pub size: u32,
    /// The adapter (lavapipe on this machine).
    pub adapter: String,
    /// hytrace `--backend gpu`: one first frame (kernel compile, upload, render), ms.
    pub hytrace_first_ms: Option<f64>,
    /// hytrace GPU steady frames (kernel reused; the scene is uploaded per frame, as the
    /// renderer does).
    pub hytrace_steady: Frames,
    /// fidget wgpu voxel renderer: one first frame (pipelines, shape upload, render), ms.
    pub fidget_first_ms: Option<f64>,
    /// fidget wgpu steady frames.
    pub fidget_steady: Frames,
    /// hytrace GPU's hit-mask agreement with the ground truth.
    pub hytrace_agreement: Option<f64>,
    /// fidget wgpu's.
    pub fidget_agreement: Option<f64>,
    /// Why a part did not run, if one did not.
    pub note: String,
}

/// The peer section.
#[derive(Debug, Clone, Serialize)]
pub struct PeerReport {
    /// Why the section did not run (built without the `fidget` feature), if it did not.
    pub skipped: Option<String>,
    /// fidget's version.
    pub fidget_version: String,
    /// A fidget frame still running after this many seconds is cancelled and reported as over
    /// the limit.
    pub frame_limit_s: f64,
    /// Per model.
    pub models: Vec<PeerModelReport>,
    /// Per model and thread count.
    pub rows: Vec<PeerRow>,
    /// The GPU comparison.
    pub gpu: Option<PeerGpu>,
    /// The "Tape evaluators" table (None when not run).
    pub evaluators: Option<evaluators::EvalReport>,
}

/// Version of the fidget crates compared with.
pub const FIDGET_VERSION: &str = "0.5.1";

/// Timed rounds of one measurement stop, once every backend has one timed frame, when they
/// have taken this many seconds in all (a slow model gets fewer than `--runs` frames).
pub const ROUND_SECONDS: f64 = 60.0;

/// Largest image side of the GPU row: lavapipe takes seconds per frame.
pub const GPU_SIZE: u32 = 256;

/// Runs the section (or reports that it needs the `fidget` feature).
pub fn run(opts: &super::BenchOptions, scenes: &[(String, Scene)]) -> anyhow::Result<PeerReport> {
    #[cfg(feature = "fidget")]
    {
        run_with_fidget(opts, scenes)
    }
    #[cfg(not(feature = "fidget"))]
    {
        let _ = scenes;
        eprintln!("bench: SDF peer section skipped: build with `--features fidget`");
        Ok(PeerReport {
            skipped: Some(
                "needs the `fidget` feature (`cargo run --features fidget -- bench`, which \
                 scripts/bench.sh does)"
                    .into(),
            ),
            fidget_version: FIDGET_VERSION.into(),
            frame_limit_s: opts.peer_frame_limit,
            models: Vec::new(),
            rows: Vec::new(),
            gpu: None,
            evaluators: None,
        })
    }
}

/// A frame: seconds and hit mask, or None when it was cancelled at the frame limit.
#[cfg(feature = "fidget")]
type Frame = anyhow::Result<Option<(f64, Vec<bool>)>>;

/// What [`alternate_frames`] measured, per backend: the timed seconds and the warm-up's hit
/// mask, both None for a backend over the frame limit.
#[cfg(feature = "fidget")]
type Timed<const N: usize> = ([Option<Vec<f64>>; N], [Option<Vec<bool>>; N]);

#[cfg(feature = "fidget")]
fn run_with_fidget(
    opts: &super::BenchOptions,
    scenes: &[(String, Scene)],
) -> anyhow::Result<PeerReport> {
    use self::fidget::{Evaluator, Prepared};
    let size = opts.peer_size;
    let limit = opts.peer_frame_limit;
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let all_cores = super::Workers::new(cores)?;
    let mut report = PeerReport {
        skipped: None,
        fidget_version: FIDGET_VERSION.into(),
        frame_limit_s: limit,
        models: Vec::new(),
        rows: Vec::new(),
        gpu: None,
        evaluators: None,
    };
    let models = models(scenes, size)?;
    if opts.sections.evaluators {
        report.evaluators = Some(evaluator_table(opts, &models)?);
    }
    if !opts.sections.peer {
        return Ok(report);
    }
    for model in &models {
        eprintln!("bench: SDF peer, {}", model.name);
        let prepared = Prepared::new(model);
        let truth = ground_truth(model, &all_cores);
        let tracer = crate::trace::SceneTracer::new(&model.scene);
        let render_opts = crate::render::RenderOptions::single_sample(size, size);
        // Masks of fidget VM, fidget JIT and hytrace, from whichever thread count gave one.
        let mut masks: [Option<Vec<bool>>; 3] = Default::default();
        for &threads in &opts.threads {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .map_err(|e| anyhow::anyhow!("cannot start {threads} threads: {e}"))?;
            let fidget_pool = self::fidget::pool(threads)?;
            let hytrace_frame = |tracer: &crate::trace::SceneTracer| -> anyhow::Result<Vec<bool>> {
                let fb = pool.install(|| crate::render::cpu::render_with(tracer, &render_opts))?;
                Ok(mask_of(fb.depth.iter().map(|d| d.is_finite())))
            };
            // On the bench's pool: building the tracer is parallel too.
            let first = || -> Frame {
                pool.install(|| {
                    let start = std::time::Instant::now();
                    let mut scene = model.empty.clone();
                    scene.objects = lower_objects(&model.nodes)?;
                    let tracer = crate::trace::SceneTracer::new(&scene);
                    let mask = hytrace_frame(&tracer)?;
                    Ok(Some((start.elapsed().as_secs_f64(), mask)))
                })
            };
            let steady = || -> Frame {
                let start = std::time::Instant::now();
                let mask = hytrace_frame(&tracer)?;
                Ok(Some((start.elapsed().as_secs_f64(), mask)))
            };
            let vm = || prepared.render(Evaluator::Vm, fidget_pool.as_ref(), limit);
            let jit = || prepared.render(Evaluator::Jit, fidget_pool.as_ref(), limit);
            let backends: [&dyn Fn() -> Frame; 4] = [&vm, &jit, &first, &steady];
            let (times, outs) = alternate_frames(opts, &backends)?;
            let [m_vm, m_jit, _, m_ours] = outs;
            for (slot, m) in masks.iter_mut().zip([m_vm, m_jit, m_ours]) {
                if slot.is_none() {
                    *slot = m;
                }
            }
            let frames = times.map(|t| Frames::new(t.as_deref()));
            let ours = |k: usize| frames[k].median_ms.unwrap_or(f64::NAN);
            // fidget's faster evaluator, or the limit when neither finished.
            let best = [(0, prepared.vm_build), (1, prepared.jit_build)]
                .into_iter()
                .filter_map(|(k, build)| frames[k].median_ms.map(|ms| (ms, build * 1e3)))
                .min_by(|a, b| a.0.total_cmp(&b.0));
            let ratio_is_bound = best.is_none();
            let (best_ms, best_build) = best.unwrap_or((limit * 1e3, 0.0));
            report.rows.push(PeerRow {
                model: model.name.clone(),
                threads,
                steady_ratio: ours(3) / best_ms,
                first_ratio: ours(2) / (best_build + best_ms),
                ratio_is_bound,
                fidget_vm: frames[0].clone(),
                fidget_jit: frames[1].clone(),
                hytrace_first: frames[2].clone(),
                hytrace_steady: frames[3].clone(),
            });
        }
        let [m_vm, m_jit, m_ours] = masks;
        let m_ours = m_ours.unwrap_or_default();
        let fidget_mask = m_vm.as_ref().or(m_jit.as_ref());
        report.models.push(PeerModelReport {
            model: model.name.clone(),
            size,
            objects: model.scene.objects.len(),
            ops: model
                .scene
                .objects
                .iter()
                .map(|o| o.lowered.program.distance_only().live_len())
                .sum(),
            left_out: model.left_out.clone(),
            view: model.view,
            fidget_vm_build_ms: prepared.vm_build * 1e3,
            fidget_jit_build_ms: prepared.jit_build * 1e3,
            fidget_vm_agreement: m_vm.as_ref().map(|m| truth.agreement(m)),
            fidget_jit_agreement: m_jit.as_ref().map(|m| truth.agreement(m)),
            hytrace_agreement: truth.agreement(&m_ours),
            hytrace_vs_fidget: fidget_mask.map(|m| same_fraction(&m_ours, m)),
            hit_fraction: m_ours.iter().filter(|&&h| h).count() as f64 / m_ours.len().max(1) as f64,
            truth,
        });
        if report.gpu.is_none() && model.name == "gyroid sphere" {
            report.gpu = Some(gpu_row(opts, model, &all_cores));
        }
    }
    Ok(report)
}

/// The "Tape evaluators" table over `models` ([`evaluators`]).
#[cfg(feature = "fidget")]
fn evaluator_table(
    opts: &super::BenchOptions,
    models: &[PeerModel],
) -> anyhow::Result<evaluators::EvalReport> {
    let mut table = evaluators::EvalReport {
        simd: format!("{:?}", crate::sdf::simd::SimdLevel::detect()),
        groups: if opts.quick {
            evaluators::GROUPS_QUICK
        } else {
            evaluators::GROUPS
        },
        models: Vec::new(),
    };
    for model in models {
        eprintln!("bench: SDF peer, tape evaluators, {}", model.name);
        let fields = crate::trace::build_fields(&model.scene, true, true);
        let bounds: Vec<crate::geom::Aabb> =
            model.scene.objects.iter().map(|o| o.bounds()).collect();
        table
            .models
            .push(evaluators::measure(opts, &model.name, &fields, &bounds)?);
    }
    Ok(table)
}

/// Times `backends` alternately, as [`super::alternate`] does for ray sets: one untimed warm-up
/// each (whose masks are returned; a backend whose warm-up hits the frame limit is not timed:
/// None), then rounds of one frame each until every backend has at least `runs` frames and
/// `min_seconds` in all, at most [`super::MAX_ROUNDS`] rounds, and no new round once the timed
/// rounds have taken [`ROUND_SECONDS`].
#[cfg(feature = "fidget")]
fn alternate_frames<const N: usize>(
    opts: &super::BenchOptions,
    backends: &[&dyn Fn() -> Frame; N],
) -> anyhow::Result<Timed<N>> {
    let mut masks: [Option<Vec<bool>>; N] = std::array::from_fn(|_| None);
    let mut times: [Option<Vec<f64>>; N] = std::array::from_fn(|_| None);
    for ((b, m), t) in backends.iter().zip(&mut masks).zip(&mut times) {
        if let Some((_, mask)) = b()? {
            *m = Some(mask);
            *t = Some(Vec::new());
        }
    }
    let enough = |times: &[Option<Vec<f64>>; N]| {
        times
            .iter()
            .flatten()
            .all(|t| t.len() >= opts.runs.max(1) && t.iter().sum::<f64>() >= opts.min_seconds)
    };
    let start = std::time::Instant::now();
    let mut rounds = 0;
    while !enough(&times)
        && rounds < super::MAX_ROUNDS
        && (rounds == 0 || start.elapsed().as_secs_f64() < ROUND_SECONDS)
    {
        for (b, t) in backends.iter().zip(&mut times) {
            if let Some(t) = t {
                match b()? {
                    Some((s, _)) => t.push(s),
                    // Over the limit now though not in the warm-up (a loaded machine): count
                    // it at the limit rather than drop it.
                    None => t.push(opts.peer_frame_limit),
                }
            }
        }
        rounds += 1;
    }
    Ok((times, masks))
}

/// The GPU row: hytrace's wgpu renderer against fidget's on the same device, at most
/// [`GPU_SIZE`]² (with its own ground truth at that size).
#[cfg(feature = "fidget")]
fn gpu_row(opts: &super::BenchOptions, model: &PeerModel, workers: &super::Workers) -> PeerGpu {
    let size = model.size.min(GPU_SIZE);
    let mut model = model.clone();
    model.size = size;
    model.scene.image.width = size;
    model.scene.image.height = size;
    let model = &model;
    let mut row = PeerGpu {
        model: model.name.clone(),
        size,
        adapter: String::new(),
        hytrace_first_ms: None,
        hytrace_steady: Frames::new(None),
        fidget_first_ms: None,
        fidget_steady: Frames::new(None),
        hytrace_agreement: None,
        fidget_agreement: None,
        note: String::new(),
    };
    eprintln!("bench: SDF peer, GPU ({}, {size}²)", model.name);
    let ctx = match crate::gpu::context::GpuContext::new() {
        Ok(c) => c,
        Err(e) => {
            row.note = format!("no GPU adapter: {e}");
            return row;
        }
    };
    row.adapter = format!(
        "{} ({:?})",
        ctx.adapter_name(),
        ctx.adapter_info().device_type
    );
    let truth = ground_truth(model, workers);
    let render_opts = crate::render::RenderOptions::single_sample(size, size);
    let hytrace = |renderer: &crate::gpu::render::GpuRenderer| -> Frame {
        let start = std::time::Instant::now();
        let fb = renderer.render(&ctx, &model.scene, &render_opts)?;
        Ok(Some((
            start.elapsed().as_secs_f64(),
            mask_of(fb.depth.iter().map(|d| d.is_finite())),
        )))
    };
    let start = std::time::Instant::now();
    let renderer = crate::gpu::render::GpuRenderer::new(&ctx);
    match hytrace(&renderer) {
        Ok(Some((_, mask))) => {
            row.hytrace_first_ms = Some(start.elapsed().as_secs_f64() * 1e3);
            row.hytrace_agreement = Some(truth.agreement(&mask));
        }
        Ok(None) => {}
        Err(e) => {
            row.note = format!("hytrace GPU: {e}");
            return row;
        }
    }
    let start = std::time::Instant::now();
    let peer = self::fidget::GpuPeer::new(&ctx, model).and_then(|mut p| {
        let (_, mask) = p.render()?;
        Ok((p, mask))
    });
    let first = start.elapsed().as_secs_f64() * 1e3;
    let ours = || hytrace(&renderer);
    match peer {
        Ok((peer, mask)) => {
            row.fidget_first_ms = Some(first);
            row.fidget_agreement = Some(truth.agreement(&mask));
            let peer = std::cell::RefCell::new(peer);
            let theirs = || -> Frame { Ok(Some(peer.borrow_mut().render()?)) };
            let backends: [&dyn Fn() -> Frame; 2] = [&theirs, &ours];
            match alternate_frames(opts, &backends) {
                Ok((t, _)) => {
                    row.fidget_steady = Frames::new(t[0].as_deref());
                    row.hytrace_steady = Frames::new(t[1].as_deref());
                }
                Err(e) => row.note = format!("GPU run failed: {e}"),
            }
        }
        Err(e) => {
            row.note = format!("fidget's wgpu renderer failed: {e}");
            let backends: [&dyn Fn() -> Frame; 1] = [&ours];
            if let Ok((t, _)) = alternate_frames(opts, &backends) {
                row.hytrace_steady = Frames::new(t[0].as_deref());
            }
        }
    }
    row
}

/// `text`, or a dash for nothing.
fn or_dash(text: &str) -> &str {
    if text.is_empty() { "—" } else { text }
}

fn pct(x: Option<f64>) -> String {
    match x {
        Some(x) if x.is_finite() => format!("{:.3}%", 100.0 * x),
        _ => "—".into(),
    }
}

impl PeerReport {
    /// hytrace's frames of the 1,000-box tiling over the 10-box one, per thread count: what
    /// the size of the tree costs over the same pixels.
    fn tiles_markdown(&self, s: &mut String) {
        for r in self.rows.iter().filter(|r| r.model == TILES_MANY) {
            let Some(few) = self
                .rows
                .iter()
                .find(|f| f.model == TILES_FEW && f.threads == r.threads)
            else {
                continue;
            };
            let ratio = |a: &Frames, b: &Frames| match (a.median_ms, b.median_ms) {
                (Some(a), Some(b)) if b > 0.0 => format!("{:.2}×", a / b),
                _ => "—".into(),
            };
            let _ = writeln!(
                s,
                "\nhytrace, {TILES_MANY} over {TILES_FEW} (the same pixels), {} threads: steady frame {}, first frame {}; fidget VM {}, JIT {}.",
                r.threads,
                ratio(&r.hytrace_steady, &few.hytrace_steady),
                ratio(&r.hytrace_first, &few.hytrace_first),
                ratio(&r.fidget_vm, &few.fidget_vm),
                ratio(&r.fidget_jit, &few.fidget_jit),
            );
        }
    }

    /// Appends the section's tables.
    pub fn markdown(&self, s: &mut String) {
        let _ = writeln!(s, "## SDF peer: fidget {}\n", self.fidget_version);
        if let Some(why) = &self.skipped {
            let _ = writeln!(s, "Skipped: {why}.\n");
            return;
        }
        if self.models.is_empty() {
            // Only the evaluator table ran (`--only evaluators`).
            if let Some(e) = &self.evaluators {
                e.markdown(s);
            }
            return;
        }
        let size = self.models.first().map_or(0, |m| m.size);
        let limit = self.frame_limit_s;
        let _ = writeln!(
            s,
            "The same distance tapes rendered by fidget's voxel renderer (depth and normals, {size}³ voxels) and by hytrace's CPU renderer (primary rays with normals, one directional light, no shadows), {size}×{size} orthographic views of each model's bounding cube; fidget renders our tapes converted to its trees. hytrace's first frame lowers the objects, builds the `SceneTracer` (octree of specialised tapes) and renders; the steady frame reuses the tracer. fidget's frames use a shape built before (its build time is in the second table). Median ms per frame (runs: timed frames each); a fidget frame still running after {limit} s is cancelled (\"> {limit} s\") and not timed again. Ratios: hytrace ÷ fidget's faster CPU evaluator (below 1: hytrace is faster; \"<\" when both hit the limit); the first-frame ratio adds fidget's build to its frame.\n"
        );
        let _ = writeln!(
            s,
            "| model | threads | fidget VM ms | fidget JIT ms | hytrace first ms | hytrace steady ms | steady ÷ fidget | first ÷ fidget (build + frame) | runs |"
        );
        let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---:|---:|---:|");
        let ms = |f: &Frames| {
            f.median_ms
                .map_or_else(|| format!("> {limit} s"), |x| format!("{x:.1}"))
        };
        for r in &self.rows {
            let bound = if r.ratio_is_bound { "< " } else { "" };
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {} | {bound}{:.2} | {bound}{:.2} | {} |",
                r.model,
                r.threads,
                ms(&r.fidget_vm),
                ms(&r.fidget_jit),
                ms(&r.hytrace_first),
                ms(&r.hytrace_steady),
                r.steady_ratio,
                r.first_ratio,
                r.hytrace_steady.runs_ms.len()
            );
        }
        self.tiles_markdown(s);
        let _ = writeln!(
            s,
            "\nHit-mask agreement with the ground truth: each ray sampled at the given number of evenly spaced points through the view cube in f64 (a hit: any negative sample), on every k-th pixel of every k-th row (k chosen per model so that the ground truth costs at most {:.1e} operation evaluations). \"hytrace = fidget\": the two masks on every pixel.\n",
            TRUTH_BUDGET
        );
        let _ = writeln!(
            s,
            "| model | objects | tape ops | left out | fidget VM / JIT build ms | truth: k, pixels, samples/ray | hits | fidget VM | fidget JIT | hytrace | hytrace = fidget |"
        );
        let _ = writeln!(s, "|---|---:|---:|---|---:|---|---:|---:|---:|---:|---:|");
        for m in &self.models {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {:.1} / {:.1} | {}, {}, {} | {:.1}% | {} | {} | {} | {} |",
                m.model,
                m.objects,
                m.ops,
                or_dash(&m.left_out),
                m.fidget_vm_build_ms,
                m.fidget_jit_build_ms,
                m.truth.stride,
                m.truth.count,
                m.truth.samples,
                100.0 * m.truth.hits as f64 / m.truth.count.max(1) as f64,
                pct(m.fidget_vm_agreement),
                pct(m.fidget_jit_agreement),
                pct(Some(m.hytrace_agreement)),
                pct(m.hytrace_vs_fidget),
            );
        }
        if let Some(g) = &self.gpu {
            let _ = writeln!(
                s,
                "\nGPU, {} at {}×{}: hytrace `--backend gpu` against fidget's wgpu voxel renderer on the same wgpu device ({}). On this machine that device is Mesa's lavapipe, a Vulkan driver that runs the shaders on the CPU (its own threads on the same cores): these figures compare two compute pipelines on a software rasteriser, not GPU performance. First frame: hytrace compiles its kernel, fidget builds its pipelines; steady frames reuse them.\n",
                g.model,
                g.size,
                g.size,
                or_dash(&g.adapter)
            );
            let _ = writeln!(
                s,
                "| renderer | first frame ms | steady ms | runs | agreement |"
            );
            let _ = writeln!(s, "|---|---:|---:|---:|---:|");
            let opt = |v: Option<f64>| v.map_or_else(|| "—".into(), |x| format!("{x:.1}"));
            for (name, first, steady, agreement) in [
                (
                    "hytrace GPU",
                    g.hytrace_first_ms,
                    &g.hytrace_steady,
                    g.hytrace_agreement,
                ),
                (
                    "fidget wgpu",
                    g.fidget_first_ms,
                    &g.fidget_steady,
                    g.fidget_agreement,
                ),
            ] {
                let _ = writeln!(
                    s,
                    "| {name} | {} | {} | {} | {} |",
                    opt(first),
                    opt(steady.median_ms),
                    steady.runs_ms.len(),
                    pct(agreement)
                );
            }
            if let (Some(ours), Some(theirs)) =
                (g.hytrace_steady.median_ms, g.fidget_steady.median_ms)
            {
                let _ = writeln!(
                    s,
                    "\nhytrace GPU steady ÷ fidget wgpu steady: {:.2}",
                    ours / theirs
                );
            }
            if !g.note.is_empty() {
                let _ = writeln!(s, "\nNote: {}", g.note);
            }
        }
        s.push('\n');
        if let Some(e) = &self.evaluators {
            e.markdown(s);
        }
    }
}
