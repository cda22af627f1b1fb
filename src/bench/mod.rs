//! Benchmarks (`hytrace bench`): our mesh traversal against Embree on identical rays, the SDF
//! steppers against plain sphere tracing, how frame times scale with scene size, and our SDF
//! renderer against fidget's (`peer`).
//!
//! Method, shared by every section: inputs (rays, scenes) are built once before any timing;
//! each measurement runs once untimed (warm-up), then at least `runs` times and until every
//! backend has been timed for `min_seconds` in all (short ray sets, such as the shadow rays of
//! a small model, take a few milliseconds a run, and three of those are at the mercy of one
//! scheduler hiccup), the backends alternating (ours, Embree, ours, Embree, …) so that a slow
//! spell of a shared machine hits both; the figure reported is the median. Results are checked beside the speed (hit/miss agreement
//! with Embree, hit sets of the steppers against Hart's), since a fast wrong answer is no
//! answer. Nothing here asserts a speed.

pub mod mesh;
pub mod peer;
pub mod rays;
pub mod sdf;

use rayon::prelude::*;
use serde::Serialize;
use std::fmt::Write;
use std::path::PathBuf;
use std::time::Instant;

use rays::QueryRay;

/// What to run and how long.
#[derive(Debug, Clone)]
pub struct BenchOptions {
    /// Tiny sizes and one timed run: checks that everything runs (CI smoke test).
    pub quick: bool,
    /// Timed runs per measurement (after one warm-up), at least.
    pub runs: usize,
    /// More rounds are timed until each backend's timed runs add up to this many seconds (at
    /// most [`MAX_ROUNDS`] rounds).
    pub min_seconds: f64,
    /// Thread counts to measure with (each a rayon pool of that size).
    pub threads: Vec<usize>,
    /// Folder of the shared assets (the mesh scenes).
    pub assets: PathBuf,
    /// Mesh scenes to run, by name (all when empty).
    pub mesh_scenes: Vec<String>,
    /// Ray sets of the mesh section to run, by name (all when empty).
    pub ray_sets: Vec<String>,
    /// Primary-ray image size of the mesh section.
    pub width: u32,
    /// See `width`.
    pub height: u32,
    /// Number of incoherent rays per mesh scene.
    pub incoherent: usize,
    /// Build quality of our mesh BVHs.
    pub bvh: crate::accel::bvh::BuildQuality,
    /// Sections to run.
    pub sections: Sections,
    /// Image side (pixels, square) of the peer section.
    pub peer_size: u32,
    /// Seconds after which the peer section cancels a fidget frame.
    pub peer_frame_limit: f64,
    /// Rays per Embree packet query (8 or 16); `None`: the widest the library runs natively.
    pub embree_packet: Option<usize>,
}

/// Which sections run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Sections {
    /// Meshes against Embree.
    pub mesh: bool,
    /// SDF steppers.
    pub sdf: bool,
    /// Scaling with scene size.
    pub scaling: bool,
    /// SDF renderer against fidget.
    pub peer: bool,
    /// The peer section's "Tape evaluators" table: our tape interpreter against fidget's VM
    /// and JIT on the tracer's tapes (also part of `peer`).
    pub evaluators: bool,
}

/// The machine and build the figures come from.
#[derive(Debug, Clone, Serialize)]
pub struct Machine {
    /// `model name` of /proc/cpuinfo.
    pub cpu: String,
    /// Logical cores available to this process.
    pub cores: usize,
    /// Whether the CPU has AVX2 (runtime detection).
    pub avx2_available: bool,
    /// The node test our traversal uses on this CPU.
    pub node_test: String,
    /// `git rev-parse HEAD` (with `-dirty` when the tree has changes), or "unknown".
    pub commit: String,
    /// Whether this binary was built with the `embree` feature.
    pub embree: bool,
    /// UTC time of the run (seconds since the Unix epoch).
    pub unix_time: u64,
    /// Load average (1 min) when the run started: others' work on a shared machine.
    pub load_average: Option<f64>,
}

impl Machine {
    /// Looks at this machine.
    pub fn detect() -> Machine {
        let cpu = std::fs::read_to_string("/proc/cpuinfo")
            .ok()
            .and_then(|s| {
                s.lines()
                    .find(|l| l.starts_with("model name"))
                    .and_then(|l| l.split(':').nth(1))
                    .map(|m| m.trim().to_string())
            })
            .unwrap_or_else(|| "unknown".into());
        let git = |args: &[&str]| {
            std::process::Command::new("git")
                .args(args)
                .output()
                .ok()
                .filter(|o| o.status.success())
                .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        };
        let commit = match git(&["rev-parse", "HEAD"]) {
            Some(c) => {
                let dirty = git(&["status", "--porcelain", "--untracked-files=no"])
                    .is_some_and(|s| !s.is_empty());
                if dirty { format!("{c}-dirty") } else { c }
            }
            None => "unknown".into(),
        };
        Machine {
            cpu,
            cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
            avx2_available: avx2_available(),
            node_test: crate::accel::bvh::node_test_name().into(),
            commit,
            embree: cfg!(feature = "embree"),
            unix_time: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs()),
            load_average: std::fs::read_to_string("/proc/loadavg")
                .ok()
                .and_then(|s| s.split_whitespace().next().and_then(|x| x.parse().ok())),
        }
    }
}

fn avx2_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Everything one run measured (what `--json` writes).
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// Where and what.
    pub machine: Machine,
    /// Whether this was a `--quick` smoke run (sizes too small to mean anything).
    pub quick: bool,
    /// Timed runs per figure, at least.
    pub runs: usize,
    /// Seconds each backend is timed per figure, at least (see [`BenchOptions::min_seconds`]).
    pub min_seconds: f64,
    /// Mesh section.
    pub mesh: Option<mesh::MeshReport>,
    /// SDF section.
    pub sdf: Option<sdf::SdfReport>,
    /// Scaling section.
    pub scaling: Option<Scaling>,
    /// Peer section (fidget).
    pub peer: Option<peer::PeerReport>,
}

/// Frame times against scene size.
#[derive(Debug, Clone, Serialize)]
pub struct Scaling {
    /// Many SDF objects, with and without the SDF BVH.
    pub sdf: Vec<sdf::SdfScalingRow>,
    /// Time with 10,000 objects over time with 10 (with the BVH), when both ran.
    pub sdf_ratio: Option<f64>,
    /// Meshes of growing size, ours and Embree.
    pub mesh: Vec<mesh::MeshScalingRow>,
}

/// Runs the sections asked for. `sdf_scenes` are (name, file) pairs for the SDF and peer
/// sections.
pub fn run(
    opts: &BenchOptions,
    sdf_scenes: &[(String, crate::scene::Scene)],
) -> anyhow::Result<Report> {
    let machine = Machine::detect();
    let mesh = if opts.sections.mesh {
        Some(mesh::run(opts)?)
    } else {
        None
    };
    let sdf = if opts.sections.sdf {
        Some(sdf::run(opts, sdf_scenes)?)
    } else {
        None
    };
    let scaling = if opts.sections.scaling {
        let sdf = sdf::scaling(opts)?;
        let at = |n: usize| {
            sdf.iter()
                .find(|r| r.objects == n && r.bvh)
                .map(|r| r.ms_per_frame)
        };
        let sdf_ratio = at(10_000).zip(at(10)).map(|(a, b)| a / b);
        Some(Scaling {
            sdf,
            sdf_ratio,
            mesh: mesh::scaling(opts)?,
        })
    } else {
        None
    };
    let peer = if opts.sections.peer || opts.sections.evaluators {
        Some(peer::run(opts, sdf_scenes)?)
    } else {
        None
    };
    Ok(Report {
        machine,
        quick: opts.quick,
        runs: opts.runs,
        min_seconds: opts.min_seconds,
        mesh,
        sdf,
        scaling,
        peer,
    })
}

/// A pool of `threads` workers, or none for one thread (a plain loop on the caller's thread).
pub struct Workers {
    pool: Option<rayon::ThreadPool>,
    /// Number of threads.
    pub threads: usize,
}

impl Workers {
    /// Workers for `threads` threads (≥ 1).
    pub fn new(threads: usize) -> anyhow::Result<Workers> {
        let threads = threads.max(1);
        let pool = if threads > 1 {
            Some(
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .map_err(|e| anyhow::anyhow!("cannot start {threads} threads: {e}"))?,
            )
        } else {
            None
        };
        Ok(Workers { pool, threads })
    }

    /// Applies `f` to every item, writing `out[i] = f(&items[i])`; returns the wall time in
    /// seconds. See [`Self::map_chunks`].
    pub fn map<T: Sync, R: Send, F: Fn(&T) -> R + Sync>(
        &self,
        items: &[T],
        out: &mut [R],
        f: F,
    ) -> f64 {
        self.map_chunks(items, out, |items, out| {
            for (o, i) in out.iter_mut().zip(items) {
                *o = f(i);
            }
        })
    }

    /// Applies `f` to chunks of [`CHUNK`] consecutive items and the matching chunks of `out`;
    /// returns the wall time in seconds. Chunks keep neighbouring (coherent) rays together on
    /// one thread, and let a backend trace them together.
    pub fn map_chunks<T: Sync, R: Send, F: Fn(&[T], &mut [R]) + Sync>(
        &self,
        items: &[T],
        out: &mut [R],
        f: F,
    ) -> f64 {
        assert_eq!(items.len(), out.len());
        let start = Instant::now();
        match &self.pool {
            None => {
                for (o, i) in out.chunks_mut(CHUNK).zip(items.chunks(CHUNK)) {
                    f(i, o);
                }
            }
            Some(pool) => pool.install(|| {
                out.par_chunks_mut(CHUNK)
                    .zip(items.par_chunks(CHUNK))
                    .for_each(|(o, i)| f(i, o))
            }),
        }
        start.elapsed().as_secs_f64()
    }
}

/// Rays handed out together by [`Workers::map_chunks`].
pub const CHUNK: usize = 64;

/// The median of a non-empty list.
pub fn median(v: &[f64]) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// The geometric mean of positive numbers (NaN for none).
pub fn geomean(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    (v.iter().map(|x| x.ln()).sum::<f64>() / v.len() as f64).exp()
}

/// A backend's answers to a chunk of rays (per ray: t of the closest hit, ∞ for a miss; or 1/0
/// for occlusion).
pub(crate) type QueryFn<'a> = dyn Fn(&[QueryRay], &mut [f32]) + Sync + 'a;

/// A backend that answers one ray at a time, as a [`QueryFn`].
pub(crate) fn per_ray<'a>(
    f: impl Fn(&QueryRay) -> f32 + Sync + 'a,
) -> impl Fn(&[QueryRay], &mut [f32]) + Sync + 'a {
    move |rays: &[QueryRay], out: &mut [f32]| {
        for (q, o) in rays.iter().zip(out) {
            *o = f(q);
        }
    }
}

/// Most rounds [`alternate`] times, however short a run.
pub const MAX_ROUNDS: usize = 200;

/// Times `backends` (each writes its answers into its own buffer) alternately: one untimed
/// warm-up each, then rounds of one run each, at least `runs` of them and more until every
/// backend has been timed for `min_seconds` in all (at most [`MAX_ROUNDS`]). Returns the
/// seconds of every timed run, per backend.
pub(crate) fn alternate(
    workers: &Workers,
    rays: &[QueryRay],
    runs: usize,
    min_seconds: f64,
    backends: &mut [(&QueryFn, &mut Vec<f32>)],
) -> Vec<Vec<f64>> {
    for (f, out) in backends.iter_mut() {
        out.resize(rays.len(), 0.0);
        workers.map_chunks(rays, out, *f);
    }
    let mut times: Vec<Vec<f64>> = vec![Vec::with_capacity(runs); backends.len()];
    let timed_enough = |times: &[Vec<f64>]| {
        times
            .iter()
            .all(|t| t.len() >= runs.max(1) && t.iter().sum::<f64>() >= min_seconds)
    };
    while !timed_enough(&times) && times[0].len() < MAX_ROUNDS {
        for (k, (f, out)) in backends.iter_mut().enumerate() {
            times[k].push(workers.map_chunks(rays, out, *f));
        }
    }
    times
}

fn fmt_opt(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "—".into(), |x| format!("{x:.digits$}"))
}

impl Report {
    /// The report as Markdown tables.
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        let m = &self.machine;
        let _ = writeln!(
            s,
            "# hytrace bench{}\n",
            if self.quick { " (quick)" } else { "" }
        );
        let _ = writeln!(
            s,
            "- machine: {} — {} logical cores, AVX2 {}, node test: {}",
            m.cpu,
            m.cores,
            if m.avx2_available { "yes" } else { "no" },
            m.node_test
        );
        let _ = writeln!(s, "- commit: {}", m.commit);
        let _ = writeln!(
            s,
            "- Embree: {}; load average at start: {}; timed runs per figure: at least {}, and at least {} s per backend (median, after a warm-up)\n",
            if m.embree {
                "Embree 4 (`embree` feature)"
            } else {
                "not built in (build with `--features embree`)"
            },
            fmt_opt(m.load_average, 2),
            self.runs,
            self.min_seconds
        );
        if let Some(mesh) = &self.mesh {
            mesh.markdown(&mut s);
        }
        if let Some(sdf) = &self.sdf {
            sdf.markdown(&mut s);
        }
        if let Some(sc) = &self.scaling {
            let _ = writeln!(s, "## Scaling\n");
            let _ = writeln!(
                s,
                "SDF objects (`scene::generate::many_objects`), primary rays with normals, all threads:\n"
            );
            let _ = writeln!(s, "| objects | SDF BVH | pixels | ms/frame |");
            let _ = writeln!(s, "|---:|:---:|---:|---:|");
            for r in &sc.sdf {
                let _ = writeln!(
                    s,
                    "| {} | {} | {} | {:.2} |",
                    r.objects,
                    if r.bvh { "yes" } else { "no" },
                    r.pixels,
                    r.ms_per_frame
                );
            }
            let _ = writeln!(
                s,
                "\n10,000 objects / 10 objects (with the BVH): {}\n",
                fmt_opt(sc.sdf_ratio, 2)
            );
            let _ = writeln!(
                s,
                "Meshes (subdivided icospheres), primary rays, all threads:\n"
            );
            let _ = writeln!(
                s,
                "| triangles | pixels | ours ms/frame | Embree ms/frame | ours/Embree speed | ours build ms | Embree build ms | agreement |"
            );
            let _ = writeln!(s, "|---:|---:|---:|---:|---:|---:|---:|---:|");
            for r in &sc.mesh {
                let _ = writeln!(
                    s,
                    "| {} | {} | {:.2} | {} | {} | {:.1} | {} | {} |",
                    r.triangles,
                    r.pixels,
                    r.ours_ms,
                    fmt_opt(r.embree_ms, 2),
                    fmt_opt(r.embree_ms.map(|e| e / r.ours_ms), 2),
                    r.ours_build_ms,
                    fmt_opt(r.embree_build_ms, 1),
                    r.agreement
                        .map_or_else(|| "—".into(), |a| format!("{:.4}%", 100.0 * a)),
                );
            }
            s.push('\n');
        }
        if let Some(peer) = &self.peer {
            peer.markdown(&mut s);
        }
        s
    }
}
