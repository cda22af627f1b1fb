//! SDF section: distance evaluations and speed of the sphere-tracing steppers on the scene
//! files, with their hit sets compared to plain sphere tracing; and frame times of many SDF
//! objects with and without the SDF BVH.

use super::rays::{self, QueryRay};
use super::{BenchOptions, Workers, alternate, median, per_ray};
use crate::accel::field::FieldCursor;
use crate::scene::{Scene, Stepper, TracerSettings};
use crate::sdf::tape::Registers;
use crate::trace::{AccelOptions, SceneTracer, epsilon_at, normal, trace};
use serde::Serialize;
use std::cell::RefCell;
use std::fmt::Write;
use std::ops::ControlFlow;
use std::path::Path;

/// The steppers compared, Hart's first (the reference).
pub fn steppers() -> Vec<Stepper> {
    vec![
        Stepper::Hart,
        Stepper::Relaxed(1.2),
        Stepper::Relaxed(1.6),
        Stepper::Adaptive,
        Stepper::Segment,
    ]
}

/// One stepper on one scene.
#[derive(Debug, Clone, Serialize)]
pub struct SdfRow {
    /// Scene name.
    pub scene: String,
    /// Stepper, as the scene file writes it.
    pub stepper: String,
    /// Primary rays (pixels).
    pub pixels: usize,
    /// Distance evaluations per pixel (all objects the ray visits).
    pub evals_per_pixel: f64,
    /// Of those, interval (segment) evaluations per pixel (each counted as one evaluation).
    pub interval_evals_per_pixel: f64,
    /// Evaluations relative to Hart's on the same scene.
    pub evals_vs_hart: f64,
    /// Median Mrays/s (all threads).
    pub mrays: f64,
    /// Median ms to trace all the scene's primary rays (one frame at its image size, all
    /// threads; closest hits without normals or shading).
    pub ms_per_frame: f64,
    /// Fraction of pixels where the hit (object, or miss) is the same as Hart's.
    pub same_hits: f64,
    /// Of the pixels both hit on the same object: fraction whose hit distances differ by at
    /// most the ε band, (ε(t₁) + ε(t₂)) / max(|n·d|, 0.01).
    pub within_band: f64,
}

/// The SDF section.
#[derive(Debug, Clone, Serialize)]
pub struct SdfReport {
    /// Threads used.
    pub threads: usize,
    /// Figures.
    pub rows: Vec<SdfRow>,
}

/// Many objects: one frame.
#[derive(Debug, Clone, Serialize)]
pub struct SdfScalingRow {
    /// SDF objects (plus the ground plane).
    pub objects: usize,
    /// With the SDF BVH (else the linear scan).
    pub bvh: bool,
    /// Primary rays per frame.
    pub pixels: usize,
    /// Median ms per frame.
    pub ms_per_frame: f64,
    /// Fraction of pixels hitting something.
    pub hit_fraction: f64,
}

/// What a primary ray found: `(t, id)` with id −1 for a miss, −2 for a mesh, else the object.
#[derive(Debug, Clone, Copy, Default)]
struct Found {
    t: f32,
    id: i64,
    steps: u32,
    intervals: u32,
}

/// The closest hit over the scene's meshes and SDF objects, as `SceneTracer::closest_hit`
/// finds it (meshes first, then every object whose bounds the ray crosses), without the
/// normal, and counting the evaluations of misses too.
fn primary_hit(
    tracer: &SceneTracer,
    s: &TracerSettings,
    ray: &QueryRay,
    regs: &mut Registers,
) -> Found {
    let mut limit = ray.tmax.min(s.max_distance);
    let mut found = Found {
        t: f32::INFINITY,
        id: -1,
        steps: 0,
        intervals: 0,
    };
    let meshes = tracer.mesh_accel();
    if !meshes.is_empty()
        && let Some(h) = meshes.tlas.closest_hit(&meshes.blas, &ray.ray, 0.0, limit)
    {
        limit = h.t;
        found.t = h.t;
        found.id = -2;
    }
    tracer
        .sdf_accel()
        .visit(&ray.ray, 0.0, &mut limit, |i, t0, t1, limit| {
            let r = trace(&mut tracer.cursor(i, regs), &ray.ray, t0, t1, s);
            found.steps += r.steps;
            found.intervals += r.intervals;
            if let Some(t) = r.t {
                found.t = t;
                found.id = i as i64;
                *limit = t;
            }
            ControlFlow::Continue(())
        });
    found
}

fn stepper_name(s: Stepper) -> String {
    s.to_string()
}

thread_local! {
    static REGS: RefCell<Registers> = RefCell::new(Registers::new());
}

/// Traces all rays with stepper settings `s`; returns the answers and the seconds of every
/// timed run.
fn trace_all(
    workers: &Workers,
    tracer: &SceneTracer,
    s: &TracerSettings,
    rays: &[QueryRay],
    runs: usize,
) -> (Vec<Found>, Vec<f64>) {
    let f = |q: &QueryRay| REGS.with(|r| primary_hit(tracer, s, q, &mut r.borrow_mut()));
    let mut out = vec![Found::default(); rays.len()];
    workers.map(rays, &mut out, f);
    let times = (0..runs.max(1))
        .map(|_| workers.map(rays, &mut out, f))
        .collect();
    (out, times)
}

/// Runs the SDF section on the given scenes (all threads).
pub fn run(opts: &BenchOptions, scenes: &[(String, Scene)]) -> anyhow::Result<SdfReport> {
    let threads = opts.threads.iter().copied().max().unwrap_or(1);
    let workers = Workers::new(threads)?;
    let mut rows = Vec::new();
    for (name, scene) in scenes {
        eprintln!("bench: SDF scene {name}");
        let tracer = SceneTracer::new(scene);
        let (w, h) = if opts.quick {
            (48, 27)
        } else {
            (scene.image.width, scene.image.height)
        };
        let rays = rays::primary(scene, w, h);
        let mut settings: Vec<TracerSettings> = steppers()
            .into_iter()
            .map(|st| TracerSettings {
                stepper: st,
                ..scene.tracer
            })
            .collect();
        // Alternate the steppers run by run (the same fairness as ours/Embree).
        let mut results: Vec<(Vec<Found>, Vec<f64>)> =
            settings.iter().map(|_| (Vec::new(), Vec::new())).collect();
        for round in 0..opts.runs.max(1) {
            for (k, s) in settings.iter_mut().enumerate() {
                let (out, t) = trace_all(&workers, &tracer, s, &rays, 1);
                if round == 0 {
                    results[k].0 = out;
                }
                results[k].1.extend(t);
            }
        }
        let n = rays.len();
        let hart = &results[0].0;
        let hart_evals: u64 = hart.iter().map(|f| u64::from(f.steps)).sum();
        let mut regs = Registers::new();
        for (s, (found, times)) in settings.iter().zip(&results) {
            let evals: u64 = found.iter().map(|f| u64::from(f.steps)).sum();
            let interval_evals: u64 = found.iter().map(|f| u64::from(f.intervals)).sum();
            let same = found.iter().zip(hart).filter(|(a, b)| a.id == b.id).count();
            let (mut common, mut inside) = (0usize, 0usize);
            for ((a, b), q) in found.iter().zip(hart).zip(&rays) {
                if a.id != b.id || a.id < 0 {
                    continue;
                }
                common += 1;
                let tape = &scene.objects[b.id as usize].lowered.distance;
                let p = q.ray.at(b.t);
                let (nrm, _) = normal::estimate(
                    &mut FieldCursor::whole(tape, &mut regs),
                    p,
                    normal::step_for(&scene.tracer, b.t, p),
                    scene.tracer.normals,
                );
                let cos = nrm.dot(q.ray.direction).abs().max(0.01);
                let band = (epsilon_at(s, a.t) + epsilon_at(s, b.t)) / cos;
                if (a.t - b.t).abs() <= band {
                    inside += 1;
                }
            }
            rows.push(SdfRow {
                scene: name.clone(),
                stepper: stepper_name(s.stepper),
                pixels: n,
                evals_per_pixel: evals as f64 / n as f64,
                interval_evals_per_pixel: interval_evals as f64 / n as f64,
                evals_vs_hart: evals as f64 / hart_evals.max(1) as f64,
                mrays: n as f64 / median(times) / 1e6,
                ms_per_frame: median(times) * 1e3,
                same_hits: same as f64 / n as f64,
                within_band: if common == 0 {
                    1.0
                } else {
                    inside as f64 / common as f64
                },
            });
        }
    }
    Ok(SdfReport { threads, rows })
}

/// Frame times (primary rays with normals, `SceneTracer::closest_hit`) of
/// `many_objects(n)` scenes, with and without the SDF BVH.
pub fn scaling(opts: &BenchOptions) -> anyhow::Result<Vec<SdfScalingRow>> {
    let counts: &[usize] = if opts.quick {
        &[10, 100]
    } else {
        &[10, 100, 1_000, 10_000]
    };
    let (w, h) = if opts.quick { (32, 18) } else { (480, 270) };
    let workers = Workers::new(opts.threads.iter().copied().max().unwrap_or(1))?;
    let mut out = Vec::new();
    for &n in counts {
        eprintln!("bench: SDF scaling, {n} objects");
        let scene = Scene::from_source(
            &crate::scene::generate::many_objects(n),
            Path::new("<many_objects>"),
        )?;
        let rays = rays::primary(&scene, w, h);
        let with = SceneTracer::with_options(
            &scene,
            AccelOptions {
                sdf_bvh: true,
                ..Default::default()
            },
        );
        let without = SceneTracer::with_options(
            &scene,
            AccelOptions {
                sdf_bvh: false,
                ..Default::default()
            },
        );
        let f_with = per_ray(|q: &QueryRay| {
            with.closest_hit(&q.ray, 0.0, q.tmax)
                .map_or(f32::INFINITY, |h| h.t)
        });
        let f_without = per_ray(|q: &QueryRay| {
            without
                .closest_hit(&q.ray, 0.0, q.tmax)
                .map_or(f32::INFINITY, |h| h.t)
        });
        let (mut a, mut b) = (Vec::new(), Vec::new());
        let t = alternate(
            &workers,
            &rays,
            opts.runs,
            opts.min_seconds,
            &mut [(&f_with, &mut a), (&f_without, &mut b)],
        );
        let hits = a.iter().filter(|t| t.is_finite()).count() as f64 / rays.len() as f64;
        for (bvh, times) in [(true, &t[0]), (false, &t[1])] {
            out.push(SdfScalingRow {
                objects: n,
                bvh,
                pixels: rays.len(),
                ms_per_frame: median(times) * 1e3,
                hit_fraction: hits,
            });
        }
    }
    Ok(out)
}

impl SdfReport {
    /// Appends the section's table.
    pub fn markdown(&self, s: &mut String) {
        let _ = writeln!(s, "## SDF steppers\n");
        let _ = writeln!(
            s,
            "Primary rays at each scene's image size, {} threads (ms/frame: all of them, closest hits only); evaluations counted over every object a ray visits (an interval evaluation counts as one); hits compared with Hart's.\n",
            self.threads
        );
        let _ = writeln!(
            s,
            "| scene | stepper | pixels | evals/pixel | of which interval | vs Hart | Mrays/s | ms/frame | same hit as Hart | Δt within ε band |"
        );
        let _ = writeln!(s, "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|");
        for r in &self.rows {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {:.2} | {:.2} | {:.3} | {:.3} | {:.1} | {:.4}% | {:.4}% |",
                r.scene,
                r.stepper,
                r.pixels,
                r.evals_per_pixel,
                r.interval_evals_per_pixel,
                r.evals_vs_hart,
                r.mrays,
                r.ms_per_frame,
                100.0 * r.same_hits,
                100.0 * r.within_band
            );
        }
        s.push('\n');
    }
}
