//! `validate` and `compare` against Embree 4: the validation passes on every shipped scene and
//! on real models placed in scenes, the command line writes its table, JSON and mismatch image
//! and fails with a non-zero status, deliberately broken tracers are rejected, and `compare`
//! writes every file with a PSNR above a justified bound.
//!
//! Sizes are small (96×72 camera rays + 500 random rays) to keep the suite fast on two cores;
//! the tables are printed (run with `--nocapture`).
#![cfg(feature = "embree")]

mod common;

use glam::Vec3;
use hytrace::geom::Ray;
use hytrace::reference::embree::EmbreeScene;
use hytrace::reference::shading::EmbreeTracer;
use hytrace::reference::validate::{
    Kind, Options, Report, SdfCheck, validate, validate_with_embree,
};
use hytrace::render::{RenderOptions, cpu};
use hytrace::scene::material::MaterialParams;
use hytrace::scene::{Scene, Shadow};
use hytrace::sdf::tape::MaterialVec;
use hytrace::sdf::tape::Registers;
use hytrace::shade::ShadingTracer;
use hytrace::trace::query::{ObjectId, QueryHit, RayQuery};
use hytrace::trace::{Hit, SceneTracer, Surface, epsilon_at};
use std::path::{Path, PathBuf};
use std::process::Command;

fn options() -> Options {
    Options {
        width: 96,
        height: 72,
        random: 500,
        seed: 1,
    }
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The shared third-party models (`$HYTRACE_ASSETS`, default ../shared/assets). Missing: an
/// error under CI=true, a loud message otherwise.
fn assets(test: &str) -> Option<PathBuf> {
    common::assets_or_skip(test)
}

/// Validates and prints the table; the report.
fn run(name: &str, scene: &Scene) -> Report {
    let report = validate_with_embree(scene, &options()).unwrap_or_else(|e| panic!("{name}: {e}"));
    println!("{}", report.markdown());
    report
}

fn assert_passes(name: &str, scene: &Scene) -> Report {
    let report = run(name, scene);
    assert!(
        report.passed(),
        "{name}: validation against Embree failed:\n{}",
        report.failures.join("\n")
    );
    report
}

/// Loads a shipped scene; the scenes that name shared models need the assets.
fn shipped(name: &str) -> Option<Scene> {
    let path = root().join("assets/scenes").join(format!("{name}.ron"));
    let text = std::fs::read_to_string(&path).unwrap();
    if text.contains("$HYTRACE_ASSETS") && assets(name).is_none() {
        return None;
    }
    Some(Scene::load(&path).unwrap_or_else(|e| panic!("{e}")))
}

macro_rules! shipped_scene_tests {
    ($($name:ident),* $(,)?) => {
        $(
            #[test]
            fn $name() {
                if let Some(scene) = shipped(stringify!($name)) {
                    assert_passes(stringify!($name), &scene);
                }
            }
        )*
        const SHIPPED: &[&str] = &[$(stringify!($name)),*];
    };
}

mod shipped_scenes {
    use super::*;
    shipped_scene_tests!(
        antialiasing,
        csg,
        domain,
        glass,
        hybrid,
        implicit,
        pbr,
        primitives,
        shadows,
        showcase,
        smooth,
    );

    /// Every scene of assets/scenes/ has its test above.
    #[test]
    fn every_shipped_scene_is_validated() {
        let mut found: Vec<String> = std::fs::read_dir(root().join("assets/scenes"))
            .unwrap()
            .filter_map(|e| {
                let p = e.unwrap().path();
                (p.extension().is_some_and(|x| x == "ron"))
                    .then(|| p.file_stem().unwrap().to_string_lossy().into_owned())
            })
            .collect();
        found.sort();
        assert_eq!(found, SHIPPED, "add the new scene to shipped_scene_tests!");
    }
}

/// implicit.ron at its own image size: rays that skim its quartic torus before entering it
/// spend hundreds of Hart steps where f/λ falls to 10⁻⁴, and with a budget of 512 steps
/// fifteen of them missed the torus (the 96×72 image above has none of them); the scene now
/// asks for 1024.
#[test]
fn implicit_at_its_own_size() {
    let scene = shipped("implicit").unwrap();
    let options = Options {
        width: scene.image.width,
        height: scene.image.height,
        ..options()
    };
    let report = validate_with_embree(&scene, &options).unwrap_or_else(|e| panic!("implicit: {e}"));
    assert!(
        report.passed(),
        "implicit at {}×{}: validation against Embree failed:\n{}",
        options.width,
        options.height,
        report.failures.join("\n")
    );
}

/// Real models on their own, as `hytrace render MODEL` frames them: mesh thresholds only.
#[test]
fn real_models_pass() {
    let Some(dir) = assets("real_models_pass") else {
        return;
    };
    for (file, min_triangles) in [
        ("glTF/ReciprocatingSaw/glTF/ReciprocatingSaw.gltf", 100_000),
        (
            "glTF/2CylinderEngine/glTF-Binary/2CylinderEngine.glb",
            100_000,
        ),
        ("obj/common-3d-test-models/stanford-bunny.obj", 60_000),
        // textured glTF
        ("glTF/Duck/glTF-Binary/Duck.glb", 4_000),
    ] {
        let scene = Scene::from_model(&dir.join(file), None).unwrap_or_else(|e| panic!("{e}"));
        assert!(scene.meshes.triangle_count() >= min_triangles, "{file}");
        let r = assert_passes(file, &scene);
        assert!(
            r.kind(Kind::Mesh).rays > 300,
            "{file}: too few mesh rays to mean much"
        );
    }
}

/// The bunny (OBJ) and the textured duck (glTF) placed in a scene with analytic SDFs: a
/// ground plane, a torus, a glass and a mirror sphere; soft shadows and ambient occlusion.
const PLACED_MODELS: &str = r#"Scene(
    image: (width: 320, height: 240, samples: 1, background: (0.55, 0.65, 0.8)),
    camera: Perspective(position: (0, 2.6, 7.5), look_at: (0, 0.9, 0), fov: 40),
    lights: [
        Ambient(color: (0.6, 0.7, 0.9), intensity: 0.3),
        Directional(direction: (-0.35, -1.0, -0.45), intensity: 1.0),
        Point(position: (3, 4, 3), intensity: 12, shadow: SoftImproved(k: 12)),
    ],
    materials: {
        "ground": (color: (0.45, 0.45, 0.43)),
        "clay":   (color: (0.75, 0.62, 0.5), specular: (0.2, 0.2, 0.2), shininess: 20),
        "mirror": (color: (0.9, 0.9, 0.9), specular: (1, 1, 1), shininess: 300, reflectivity: 0.9),
        "glass":  (color: (0.95, 0.97, 1.0), specular: (1, 1, 1), shininess: 200, transparency: 0.9, ior: 1.5),
        "red":    (color: (0.8, 0.15, 0.1), specular: (0.4, 0.4, 0.4), shininess: 40),
    },
    objects: [
        (name: "ground", material: "ground", shape: Plane(normal: (0, 1, 0), offset: -0.4)),
        (name: "bunny", mesh: "$HYTRACE_ASSETS/obj/common-3d-test-models/stanford-bunny.obj",
            scale: 12, translate: (-1.4, -0.8, 0.2), material: "clay"),
        (name: "duck", mesh: "$HYTRACE_ASSETS/glTF/Duck/glTF-Binary/Duck.glb",
            scale: 0.8, translate: (1.5, -0.4, 0.6), rotate: (0, -35, 0)),
        (name: "torus", material: "red", translate: (-1.0, 2.1, 0.75), rotate: (20, 0, 10),
            shape: Torus(major: 0.45, minor: 0.12)),
        (name: "glass", material: "glass", translate: (0.2, 0.3, 1.6), shape: Sphere(radius: 0.5)),
        (name: "mirror", material: "mirror", translate: (0.6, 1.0, -2.2), shape: Sphere(radius: 1.0)),
    ],
    tracer: (epsilon: 1e-4, epsilon_per_unit: 1e-4, max_distance: 60),
    shading: (max_bounces: 4, ambient_occlusion: (strength: 1.0, steps: 5, step: 0.08)),
)"#;

/// The placed-models scene, written into a temporary folder that lives as long as the
/// returned value (the file is read again by the command line).
fn placed_models(test: &str) -> Option<(Scene, PathBuf, tempfile::TempDir)> {
    assets(test)?;
    let dir = common::temp_dir(&format!("validate-{test}"));
    let path = dir.path().join("placed-models.ron");
    std::fs::write(&path, PLACED_MODELS).unwrap();
    Some((
        Scene::load(&path).unwrap_or_else(|e| panic!("{e}")),
        path,
        dir,
    ))
}

#[test]
fn real_models_placed_in_a_scene_pass() {
    let Some((scene, _, _dir)) = placed_models("placed_models") else {
        return;
    };
    let r = assert_passes("bunny and duck among analytic SDFs", &scene);
    assert!(r.kind(Kind::Mesh).rays > 300);
    assert!(r.kind(Kind::AnalyticSdf).rays > 1000);
    assert!(r.objects.iter().all(|o| o.check == SdfCheck::Analytic));
}

/// A scene of analytic primitives only (no shared assets needed), large in the frame.
const ANALYTIC: &str = r#"Scene(
    camera: Perspective(position: (1.5, 3, 7), look_at: (0, 0, 0), fov: 45),
    lights: [Point(position: (3, 6, 4), intensity: 20), Directional(direction: (-0.3, -1, -0.2), intensity: 1)],
    objects: [
        (shape: Torus(major: 1.2, minor: 0.35), rotate: (60, 20, 0)),
        (shape: Box(half_extents: (0.5, 0.5, 0.5)), rotate: (10, 20, 30), translate: (0, -1, 0.5)),
        (shape: Sphere(radius: 0.6), translate: (1.8, 0.2, -0.5)),
        (shape: Plane(normal: (0, 1, 0), offset: -1.6)),
    ],
    tracer: (epsilon: 1e-4, epsilon_per_unit: 1e-4, max_distance: 60),
)"#;

fn analytic_scene() -> Scene {
    Scene::from_source(ANALYTIC, Path::new("analytic.ron")).unwrap_or_else(|e| panic!("{e}"))
}

/// The command line: the table on stdout, the JSON and the mismatch image, status 0 on a
/// passing scene; status 1 and the failures on a scene with an object Embree skips.
#[test]
fn command_line_validate() {
    let dir_tmp = common::temp_dir("validate-cli");
    let dir = dir_tmp.path().to_path_buf();
    let good = dir.join("analytic.ron");
    std::fs::write(&good, ANALYTIC).unwrap();
    let json = dir.join("report.json");
    let png = dir.join("mismatch.png");
    let out = Command::new(env!("CARGO_BIN_EXE_hytrace"))
        .arg("validate")
        .arg(&good)
        .args(["--width", "96", "--height", "72", "--random", "500"])
        .arg("--json")
        .arg(&json)
        .arg("--mismatch")
        .arg(&png)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    println!("{stdout}");
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("| analytic SDF |"), "{stdout}");
    assert!(stdout.contains("PASSED"), "{stdout}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["width"], 96);
    assert_eq!(v["failures"].as_array().unwrap().len(), 0);
    let kinds = v["kinds"].as_array().unwrap();
    assert_eq!(kinds[0]["kind"], "analytic_sdf");
    assert!(kinds[0]["rays"].as_u64().unwrap() > 3000);
    let img = image::open(&png).unwrap();
    assert!(img.width() >= 96 && img.height() > 72);

    // One step cannot reach the spheres from the camera: every ray that Embree sees hit comes
    // back as a miss, far below the 99.9% agreement required.
    let bad = dir.join("coarse.ron");
    std::fs::write(
        &bad,
        "Scene(camera: Perspective(position: (0, 1, 5), look_at: (0, 0, 0)),
               objects: [(shape: Sphere(radius: 0.3)), (shape: Sphere(radius: 0.5), translate: (2, 0, 0))],
               tracer: (max_steps: 1))",
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_hytrace"))
        .arg("validate")
        .arg(&bad)
        .args(["--width", "32", "--height", "24", "--random", "50"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stdout}\n{stderr}");
    assert!(stdout.contains("FAILED"), "{stdout}");
    assert!(
        stdout.contains("analytic SDFs: hit/miss agreement"),
        "{stdout}"
    );
    assert!(stderr.contains("coarse.ron"), "{stderr}");

    // Bad flags are clear errors.
    for (args, expect) in [
        (vec!["--width", "0"], "at least 1"),
        (vec!["--json", "out.txt"], ".json"),
        (vec!["--mismatch", "/no/such/dir/m.png"], "not a directory"),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_hytrace"))
            .arg("validate")
            .arg(&good)
            .args(&args)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {stderr}");
        assert!(stderr.contains(expect), "{args:?}: {stderr}");
    }
}

/// How a broken tracer goes wrong.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Breakage {
    /// Every hit 20·ε(t) too far.
    ShiftT,
    /// Mesh hits within 2% (barycentric) of a triangle edge are dropped.
    DropEdgeHits,
    /// Sphere tracing with steps of 1.5× the distance (no safety): overshoots the surface.
    Overshoot,
}

struct Broken<'a> {
    tracer: SceneTracer<'a>,
    how: Breakage,
}

impl Broken<'_> {
    fn field(&self, p: Vec3, regs: &mut Registers) -> f32 {
        self.tracer
            .scene()
            .objects
            .iter()
            .map(|o| o.lowered.distance.eval_in(p, regs))
            .fold(f32::INFINITY, f32::min)
    }

    /// An over-relaxed sphere tracer without the fallback that makes over-relaxation safe
    /// (Keinert et al. 2014 step back when consecutive spheres do not overlap; this one does
    /// not): t += 1.5·f.
    fn overshooting_march(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<QueryHit> {
        let s = &self.tracer.scene().tracer;
        let mut regs = Registers::new();
        let mut t = tmin;
        for _ in 0..s.max_steps {
            if t > tmax.min(s.max_distance) {
                return None;
            }
            let p = ray.at(t);
            let d = self.field(p, &mut regs);
            if d < epsilon_at(s, t) {
                let h = 1e-3;
                let g = Vec3::new(
                    self.field(p + Vec3::X * h, &mut regs) - self.field(p - Vec3::X * h, &mut regs),
                    self.field(p + Vec3::Y * h, &mut regs) - self.field(p - Vec3::Y * h, &mut regs),
                    self.field(p + Vec3::Z * h, &mut regs) - self.field(p - Vec3::Z * h, &mut regs),
                );
                let object = self
                    .tracer
                    .scene()
                    .objects
                    .iter()
                    .enumerate()
                    .map(|(i, o)| (i, o.lowered.distance.eval_in(p, &mut regs)))
                    .min_by(|a, b| a.1.total_cmp(&b.1))
                    .unwrap()
                    .0;
                return Some(QueryHit {
                    t,
                    normal: g.normalize_or_zero(),
                    object: ObjectId::Sdf(object),
                });
            }
            t += 1.5 * d;
        }
        None
    }
}

impl RayQuery for Broken<'_> {
    fn closest_hit(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<QueryHit> {
        match self.how {
            Breakage::ShiftT => {
                let mut h = RayQuery::closest_hit(&self.tracer, ray, tmin, tmax)?;
                h.t += 20.0 * epsilon_at(&self.tracer.scene().tracer, h.t);
                Some(h)
            }
            Breakage::DropEdgeHits => {
                let hit = self.tracer.closest_hit(ray, tmin, tmax)?;
                if let Surface::Mesh { u, v, .. } = hit.surface
                    && u.min(v).min(1.0 - u - v) < 0.02
                {
                    return None;
                }
                RayQuery::closest_hit(&self.tracer, ray, tmin, tmax)
            }
            Breakage::Overshoot => self.overshooting_march(ray, tmin, tmax),
        }
    }

    fn occluded(&self, ray: &Ray, tmin: f32, tmax: f32) -> bool {
        match self.how {
            Breakage::Overshoot => self.overshooting_march(ray, tmin, tmax).is_some(),
            Breakage::DropEdgeHits => self.closest_hit(ray, tmin, tmax).is_some(),
            Breakage::ShiftT => RayQuery::occluded(&self.tracer, ray, tmin, tmax),
        }
    }
}

fn checks(embree: &EmbreeScene) -> Vec<SdfCheck> {
    embree.checks.clone()
}

/// The referee has teeth: a tracer off by 20·ε(t) and an overshooting sphere tracer fail on
/// analytic SDFs, a triangle test that drops edge hits fails on a real mesh; the real tracer
/// passes the same comparisons.
#[test]
fn broken_tracers_fail() {
    let scene = analytic_scene();
    let embree = EmbreeScene::build(&scene).unwrap();
    let checks = checks(&embree);
    let real = SceneTracer::new(&scene);
    let r = validate(&scene, &real, &embree, &checks, &options()).unwrap();
    assert!(r.passed(), "{}", r.markdown());
    for how in [Breakage::ShiftT, Breakage::Overshoot] {
        let broken = Broken {
            tracer: SceneTracer::new(&scene),
            how,
        };
        let r = validate(&scene, &broken, &embree, &checks, &options()).unwrap();
        println!("{how:?}:\n{}", r.markdown());
        assert!(!r.passed(), "{how:?} passed");
        let a = r.kind(Kind::AnalyticSdf);
        assert!(a.dt_over_tolerance > 50, "{how:?}: {a:?}");
        assert!(
            r.failures.iter().any(|f| f.contains("|Δt| over")),
            "{how:?}: {:?}",
            r.failures
        );
    }

    let Some(dir) = assets("broken_tracers_fail (mesh part)") else {
        return;
    };
    let scene = Scene::from_model(
        &dir.join("obj/common-3d-test-models/stanford-bunny.obj"),
        None,
    )
    .unwrap();
    let embree = EmbreeScene::build(&scene).unwrap();
    let checks = self::checks(&embree);
    let broken = Broken {
        tracer: SceneTracer::new(&scene),
        how: Breakage::DropEdgeHits,
    };
    let r = validate(&scene, &broken, &embree, &checks, &options()).unwrap();
    println!("DropEdgeHits:\n{}", r.markdown());
    assert!(!r.passed());
    assert!(
        r.failures
            .iter()
            .any(|f| f.starts_with("meshes: hit/miss agreement")),
        "{:?}",
        r.failures
    );
}

/// Our tracer answering every query alone: the batched queries fall back to
/// `ShadingTracer`'s one-at-a-time defaults.
struct OneAtATime<'a>(&'a SceneTracer<'a>);

impl ShadingTracer for OneAtATime<'_> {
    fn scene(&self) -> &Scene {
        self.0.scene()
    }
    fn closest_hit(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<Hit> {
        self.0.closest_hit(ray, tmin, tmax)
    }
    fn exit(&self, surface: Surface, ray: &Ray, tmax: f32) -> Option<(f32, Vec3)> {
        self.0.exit(surface, ray, tmax)
    }
    fn visibility(&self, ray: &Ray, tmin: f32, tmax: f32, shadow: Shadow) -> f32 {
        self.0.visibility(ray, tmin, tmax, shadow)
    }
    fn distance(&self, p: Vec3, reach: f32) -> f32 {
        self.0.distance(p, reach)
    }
    fn material_at(&self, hit: &Hit, p: Vec3, materials: &[MaterialVec]) -> MaterialParams {
        self.0.material_at(hit, p, materials)
    }
}

/// `compare` renders Embree's hits through `render_through`, the CPU renderer's own loop over
/// any `ShadingTracer`; a tracer that answers one query at a time (as the Embree tracer does)
/// gets the image our bundled tracer renders, bit for bit, so the embree image differs only
/// by the hits.
#[test]
fn one_query_at_a_time_renders_the_cpu_renderer_s_image() {
    let showcase =
        Scene::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/scenes/showcase.ron"))
            .unwrap_or_else(|e| panic!("{e}"));
    for scene in [analytic_scene(), showcase] {
        let tracer = SceneTracer::new(&scene);
        let opts = RenderOptions {
            width: 64,
            height: 48,
            samples: 2,
            threads: None,
            progress: false,
        };
        let alone = cpu::render_through(&OneAtATime(&tracer), &opts).unwrap();
        let bundled = cpu::render(&scene, &opts).unwrap();
        assert!(alone == bundled, "{}", scene.source_name);
    }
}

/// `compare` writes every file; PSNR(cpu, embree) ≥ 30 dB and PSNR(cpu, gpu) ≥ 40 dB on the
/// placed-models scene.
///
/// Why 30 dB: the two images differ where the hits differ — at most 0.1 % of rays by the
/// validation thresholds, which may be off by the full range (squared error ≤ 1) — and
/// elsewhere by the normal estimate and the ε-offset of hit points, which is at most one or
/// two 8-bit levels (squared error ≈ (2/255)²). MSE ≤ 0.001 + 6e-5, so PSNR ≥ 29.7 dB.
#[test]
fn compare_writes_images_and_metrics() {
    let Some((scene, path, _dir)) = placed_models("compare") else {
        return;
    };
    let out_tmp = common::temp_dir("validate-compare-out");
    let out = out_tmp.path().to_path_buf();
    let run = Command::new(env!("CARGO_BIN_EXE_hytrace"))
        .arg("compare")
        .arg(&path)
        .arg("-o")
        .arg(&out)
        .args([
            "--width", "160", "--height", "120", "--spp", "1", "--gpu", "always",
        ])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    println!("{stdout}");
    assert!(
        run.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    for f in [
        "cpu.png",
        "embree.png",
        "gpu.png",
        "sheet.png",
        "diff-cpu-embree.png",
        "diff-cpu-gpu.png",
        "flip-cpu-embree.png",
        "flip-cpu-gpu.png",
        "index.html",
        "metrics.txt",
        "metrics.json",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let cpu_png = image::open(out.join("cpu.png")).unwrap();
    assert_eq!((cpu_png.width(), cpu_png.height()), (160, 120));
    let sheet = image::open(out.join("sheet.png")).unwrap();
    assert!(sheet.width() > 3 * 160);
    // CPU and GPU: the same scene description, the same arithmetic: ≥ 40 dB (issue #6), or
    // identical images (no PSNR).
    let g = &serde_json::from_str::<serde_json::Value>(
        &std::fs::read_to_string(out.join("metrics.json")).unwrap(),
    )
    .unwrap()["comparisons"][1];
    assert_eq!(g["other"], "gpu");
    if let Some(psnr) = g["psnr_db"].as_f64() {
        assert!(psnr >= 40.0, "CPU vs GPU PSNR {psnr} dB < 40 dB");
    }
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    let m = &v["comparisons"][0];
    assert_eq!(m["reference"], "cpu");
    assert_eq!(m["other"], "embree");
    let psnr = m["psnr_db"].as_f64().expect("images differ a little");
    assert!(psnr >= 30.0, "PSNR {psnr} dB < 30 dB");
    let ssim = m["ssim"].as_f64().unwrap();
    assert!(ssim > 0.95 && ssim <= 1.0, "SSIM {ssim}");
    // FLIP agrees: pictures this close are far from FLIP's visible-everywhere end (1).
    let flip = m["flip_mean"].as_f64().unwrap();
    assert!(flip > 0.0 && flip < 0.05, "FLIP {flip}");
    let flip_gpu = g["flip_mean"].as_f64().unwrap();
    assert!(
        (0.0..0.02).contains(&flip_gpu),
        "CPU vs GPU FLIP {flip_gpu}"
    );
    let flip_png = image::open(out.join("flip-cpu-embree.png")).unwrap();
    assert_eq!((flip_png.width(), flip_png.height()), (160, 120));
    let page = std::fs::read_to_string(out.join("index.html")).unwrap();
    for b in ["cpu", "embree", "gpu", "flip-cpu-gpu"] {
        assert!(
            page.contains(&format!("\"name\":\"{b}\"")),
            "{b} is not on the page"
        );
    }
    assert!(stdout.contains("penumbrae and ambient occlusion from our SDF"));
    let text = std::fs::read_to_string(out.join("metrics.txt")).unwrap();
    assert!(text.contains("PSNR"), "{text}");

    // Every mesh hit Embree reports has its triangle on our side.
    let embree = EmbreeScene::build(&scene).unwrap();
    let ours = SceneTracer::new(&scene);
    let tracer = EmbreeTracer::new(&embree, &ours);
    cpu::render_through(&tracer, &RenderOptions::single_sample(160, 120)).unwrap();
    let (fallbacks, mesh_hits) = tracer.fallbacks();
    assert!(mesh_hits > 500, "{mesh_hits} mesh hits");
    assert_eq!(fallbacks, 0);
}
