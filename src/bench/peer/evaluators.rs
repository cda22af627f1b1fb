//! The "Tape evaluators" table: our tape interpreter (8-lane SIMD and scalar) against fidget's
//! VM and JIT float-slice evaluators, on the very tapes the tracer runs and at points where it
//! runs them, to decide by measurement whether native code (a JIT) would pay off on the CPU.
//!
//! Workload, per model: sphere tracing evaluates points on rays near the surface, that is in
//! the octree's crossed leaves ([`Verdict::Surface`]), with each leaf's specialised tape. The
//! proxy: [`GROUP`] uniform random points in each of up to `groups` crossed leaves drawn at
//! random from every object's octree (an object without an octree: its bounds, whole tape),
//! plus one group in 16 outside the octree's box (within a quarter of its side), evaluated
//! with the whole tape as the tracer does there. The same points are also evaluated with the
//! whole tape everywhere: what an evaluator that does not specialise pays.
//!
//! Every evaluator gets the same points, in the same order, and writes the distances to the
//! same buffer. fidget's tapes are converted from ours ([`super::fidget::tape_to_tree`]) and
//! built once per distinct tape, outside the timing; its float-slice evaluators run at batch
//! sizes 8 (our packet width) and 256. Single thread; the evaluators alternate, one pass over
//! the workload each, as the other tables alternate backends.

use crate::accel::field::ObjectField;
use crate::geom::Aabb;
use crate::rng::Rng;
use crate::sdf::simplify::Verdict;
use crate::sdf::tape::Tape;
use glam::Vec3;
use rustc_hash::FxHashMap as HashMap;
use serde::Serialize;
use std::fmt::Write;

/// Points per group: one leaf's points, a multiple of every batch size timed.
pub const GROUP: usize = 256;

/// Lanes of our packets (and of [`crate::sdf::simd::eval8`]).
pub const LANES: usize = 8;

/// Batch sizes of fidget's float-slice evaluators.
pub const FIDGET_BATCHES: [usize; 2] = [8, 256];

/// One leaf group outside the octree's box per this many inside.
pub const OUTSIDE_EVERY: usize = 16;

/// Crossed leaves sampled per model: with `--quick`, and otherwise.
pub const GROUPS_QUICK: usize = 16;
/// See [`GROUPS_QUICK`].
pub const GROUPS: usize = 256;

/// [`GROUP`] points in one region, with the tape valid there and the whole tape.
#[derive(Debug, Clone)]
pub struct Group {
    /// Index into [`Workload::tapes`] of the tape the tracer runs here.
    pub specialised: usize,
    /// Index into [`Workload::tapes`] of the object's whole tape.
    pub whole: usize,
    /// Coordinates, in packets of [`LANES`].
    pub x: Vec<[f32; LANES]>,
    /// See `x`.
    pub y: Vec<[f32; LANES]>,
    /// See `x`.
    pub z: Vec<[f32; LANES]>,
}

/// The points of one model and the tapes to evaluate them with.
#[derive(Debug, Clone)]
pub struct Workload<'a> {
    /// Distinct tapes used (leaf tapes and whole tapes).
    pub tapes: Vec<&'a Tape>,
    /// The groups, leaves first.
    pub groups: Vec<Group>,
    /// Groups in crossed leaves (or in the bounds of an object without an octree).
    pub leaf_groups: usize,
    /// Groups outside an octree's box.
    pub outside_groups: usize,
    /// Crossed leaves over the model's octrees, the pool the leaf groups were drawn from.
    pub crossed_leaves: usize,
}

fn random_in(rng: &mut Rng, lo: Vec3, hi: Vec3) -> Vec3 {
    Vec3::new(
        rng.range_f32(lo.x, hi.x),
        rng.range_f32(lo.y, hi.y),
        rng.range_f32(lo.z, hi.z),
    )
}

impl<'a> Workload<'a> {
    /// The workload of `fields` (one per object, `bounds` theirs): up to `groups` crossed
    /// leaves, drawn without replacement (all of them when there are fewer), seeded by `seed`.
    pub fn new(fields: &'a [ObjectField], bounds: &[Aabb], groups: usize, seed: u64) -> Self {
        let mut rng = Rng::new(seed);
        // Candidate regions: (object, leaf tape or None for the whole tape, box).
        let mut pool: Vec<(usize, Option<u32>, Aabb)> = Vec::new();
        let mut crossed_leaves = 0;
        for (i, f) in fields.iter().enumerate() {
            match &f.octree {
                Some(tree) => {
                    for (leaf, b) in tree.leaf_boxes() {
                        if leaf.verdict == Verdict::Surface {
                            pool.push((i, Some(leaf.tape), b));
                            crossed_leaves += 1;
                        }
                    }
                }
                None => {
                    if let Some(&b) = bounds.get(i).filter(|b| b.is_finite() && !b.is_empty()) {
                        pool.push((i, None, b));
                    }
                }
            }
        }
        // A partial Fisher–Yates shuffle: the first `groups` entries are the sample.
        let take = groups.min(pool.len());
        for k in 0..take {
            let j = k + (rng.next_u64() % (pool.len() - k) as u64) as usize;
            pool.swap(k, j);
        }
        pool.truncate(take);
        let mut w = Workload {
            tapes: Vec::new(),
            groups: Vec::new(),
            leaf_groups: 0,
            outside_groups: 0,
            crossed_leaves,
        };
        let mut index: HashMap<(usize, Option<u32>), usize> = HashMap::default();
        let mut tape_index = |w: &mut Workload<'a>, object: usize, leaf: Option<u32>| {
            *index.entry((object, leaf)).or_insert_with(|| {
                let f = &fields[object];
                let tape = match (leaf, &f.octree) {
                    (Some(t), Some(tree)) => tree.tapes.get(t as usize).unwrap_or(&f.whole),
                    _ => &f.whole,
                };
                w.tapes.push(tape);
                w.tapes.len() - 1
            })
        };
        let mut per_object = vec![0usize; fields.len()];
        for &(object, leaf, b) in &pool {
            let specialised = tape_index(&mut w, object, leaf);
            let whole = tape_index(&mut w, object, None);
            w.groups.push(group(&mut rng, specialised, whole, |r| {
                random_in(r, b.min, b.max)
            }));
            per_object[object] += 1;
        }
        w.leaf_groups = w.groups.len();
        for (object, &n) in per_object.iter().enumerate() {
            let Some(tree) = &fields[object].octree else {
                continue;
            };
            let inner = tree.bounds();
            let outer = inner.expand(0.25 * (inner.max - inner.min).max_element());
            let whole = tape_index(&mut w, object, None);
            for _ in 0..n.div_ceil(OUTSIDE_EVERY) {
                w.groups.push(group(&mut rng, whole, whole, |r| {
                    // Rejection sampling of the shell (about 70% of the outer box); a point
                    // left inside after many tries only shifts the mix a little.
                    let mut p = random_in(r, outer.min, outer.max);
                    for _ in 0..64 {
                        if !(p.cmpge(inner.min).all() && p.cmple(inner.max).all()) {
                            break;
                        }
                        p = random_in(r, outer.min, outer.max);
                    }
                    p
                }));
                w.outside_groups += 1;
            }
        }
        w
    }

    /// Points in all.
    pub fn points(&self) -> usize {
        self.groups.len() * GROUP
    }

    /// Instructions evaluated over all points, with the specialised tapes or the whole ones.
    pub fn instructions(&self, specialised: bool) -> usize {
        self.groups
            .iter()
            .map(|g| self.tapes[g.tape(specialised)].len() * GROUP)
            .sum()
    }

    /// Mean tape length per point evaluation.
    pub fn mean_len(&self, specialised: bool) -> f64 {
        self.instructions(specialised) as f64 / self.points().max(1) as f64
    }
}

impl Group {
    /// The tape index for the specialised or the whole workload.
    pub fn tape(&self, specialised: bool) -> usize {
        if specialised {
            self.specialised
        } else {
            self.whole
        }
    }
}

fn group(
    rng: &mut Rng,
    specialised: usize,
    whole: usize,
    mut point: impl FnMut(&mut Rng) -> Vec3,
) -> Group {
    let mut g = Group {
        specialised,
        whole,
        x: vec![[0.0; LANES]; GROUP / LANES],
        y: vec![[0.0; LANES]; GROUP / LANES],
        z: vec![[0.0; LANES]; GROUP / LANES],
    };
    for i in 0..GROUP {
        let p = point(rng);
        let (c, l) = (i / LANES, i % LANES);
        g.x[c][l] = p.x;
        g.y[c][l] = p.y;
        g.z[c][l] = p.z;
    }
    g
}

/// The worst |b − a| / (1 + |a|) over two equally long result lists (a: the reference); NaN on
/// one side only is infinitely wrong.
pub fn max_relative_difference(reference: &[f32], other: &[f32]) -> f64 {
    if reference.len() != other.len() {
        return f64::INFINITY;
    }
    reference
        .iter()
        .zip(other)
        .map(|(&a, &b)| {
            if a == b || (a.is_nan() && b.is_nan()) {
                0.0
            } else if a.is_nan() || b.is_nan() {
                f64::INFINITY
            } else {
                let (a, b) = (f64::from(a), f64::from(b));
                (a - b).abs() / (1.0 + a.abs())
            }
        })
        .fold(0.0, f64::max)
}

/// One evaluator on one workload (specialised tapes, or whole tapes on the same points).
#[derive(Debug, Clone, Serialize)]
pub struct EvalTiming {
    /// Median ns per point evaluation.
    pub ns_per_point: f64,
    /// Fastest pass, ns per point evaluation.
    pub best_ns_per_point: f64,
    /// Median ns per point and instruction (our instructions: the same count for every
    /// evaluator, so that the figures compare).
    pub ns_per_point_instruction: f64,
    /// The worst |value − ours| / (1 + |ours|) against our scalar interpreter on the same
    /// points and tapes.
    pub max_relative_difference: f64,
    /// Every timed pass over the workload, ms.
    pub runs_ms: Vec<f64>,
}

/// One evaluator's figures on a model.
#[derive(Debug, Clone, Serialize)]
pub struct EvalFigure {
    /// "hytrace eval8", "hytrace native", "hytrace scalar", "fidget VM" or "fidget JIT".
    pub evaluator: String,
    /// Points per call.
    pub batch: usize,
    /// With the tapes the tracer runs (leaf tapes; the whole tape outside the octree).
    pub specialised: EvalTiming,
    /// With the whole tape at every point.
    pub whole: EvalTiming,
}

/// The table's figures for one model.
#[derive(Debug, Clone, Serialize)]
pub struct EvalModel {
    /// Model.
    pub model: String,
    /// Point evaluations per pass.
    pub points: usize,
    /// Groups of [`GROUP`] points in crossed leaves.
    pub leaf_groups: usize,
    /// Groups outside an octree's box.
    pub outside_groups: usize,
    /// Crossed leaves the leaf groups were drawn from.
    pub crossed_leaves: usize,
    /// Distinct tapes evaluated (each converted and built once for fidget).
    pub tapes: usize,
    /// Mean instructions of our tape per point: specialised workload.
    pub mean_tape_specialised: f64,
    /// Mean instructions of our tape per point: whole tapes.
    pub mean_tape_whole: f64,
    /// Mean length of fidget's VM tape per point: specialised workload.
    pub fidget_mean_tape_specialised: f64,
    /// Mean length of fidget's VM tape per point: whole tapes.
    pub fidget_mean_tape_whole: f64,
    /// ms to convert and build fidget's VM tapes (all distinct tapes).
    pub fidget_vm_build_ms: f64,
    /// ms to convert and compile fidget's JIT tapes.
    pub fidget_jit_build_ms: f64,
    /// Per evaluator.
    pub figures: Vec<EvalFigure>,
}

/// The "Tape evaluators" table.
#[derive(Debug, Clone, Serialize, Default)]
pub struct EvalReport {
    /// How [`crate::sdf::simd::eval8`] runs on this CPU.
    pub simd: String,
    /// Crossed leaves sampled per model (at most).
    pub groups: usize,
    /// Per model.
    pub models: Vec<EvalModel>,
}

impl EvalReport {
    /// Appends the table.
    pub fn markdown(&self, s: &mut String) {
        if self.models.is_empty() {
            return;
        }
        let _ = writeln!(s, "### Tape evaluators\n");
        let _ = writeln!(
            s,
            "Our tape interpreter against fidget's float-slice evaluators, single thread, on the tapes the tracer runs: {GROUP} random points in each of up to {} crossed octree leaves per model (each with its leaf's specialised tape), plus one group in {OUTSIDE_EVERY} outside the octree with the whole tape (\"specialised\"), and the same points with the whole tape everywhere (\"whole\"). fidget evaluates our tapes converted to its trees, each built once outside the timing. hytrace eval8: 8-lane packets by the interpreter ({}); hytrace native: the same packets run by each tape's native AVX2 code (what the renderer runs where the CPU has AVX2); scalar: one point per call. Median ns per point evaluation; ns/(pt·instr) divides by our instruction count for every evaluator; \"max rel diff\": the worst |value − ours| / (1 + |ours|) against our scalar interpreter on the same points.\n",
            self.groups, self.simd
        );
        let _ = writeln!(
            s,
            "| model | evaluator | batch | specialised ns/pt | ns/(pt·instr) | max rel diff | whole ns/pt | ns/(pt·instr) | max rel diff | specialised ÷ hytrace eval8 | runs |"
        );
        let _ = writeln!(s, "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
        for m in &self.models {
            let base = m
                .figures
                .first()
                .map_or(f64::NAN, |f| f.specialised.ns_per_point);
            for f in &m.figures {
                let _ = writeln!(
                    s,
                    "| {} | {} | {} | {:.1} | {:.3} | {:.1e} | {:.1} | {:.3} | {:.1e} | {:.2} | {} |",
                    m.model,
                    f.evaluator,
                    f.batch,
                    f.specialised.ns_per_point,
                    f.specialised.ns_per_point_instruction,
                    f.specialised.max_relative_difference,
                    f.whole.ns_per_point,
                    f.whole.ns_per_point_instruction,
                    f.whole.max_relative_difference,
                    f.specialised.ns_per_point / base,
                    f.specialised.runs_ms.len(),
                );
            }
        }
        let _ = writeln!(
            s,
            "\nWorkloads: points per pass, groups of {GROUP} (in crossed leaves / outside the octree), the crossed leaves drawn from, distinct tapes, mean tape length per point (ours; fidget's VM tape of the converted tree) and fidget's build time over all distinct tapes.\n"
        );
        let _ = writeln!(
            s,
            "| model | points | groups in / out | crossed leaves | tapes | ours: specialised / whole | fidget VM: specialised / whole | fidget VM / JIT build ms |"
        );
        let _ = writeln!(s, "|---|---:|---|---:|---:|---|---|---|");
        for m in &self.models {
            let _ = writeln!(
                s,
                "| {} | {} | {} / {} | {} | {} | {:.1} / {:.1} | {:.1} / {:.1} | {:.1} / {:.1} |",
                m.model,
                m.points,
                m.leaf_groups,
                m.outside_groups,
                m.crossed_leaves,
                m.tapes,
                m.mean_tape_specialised,
                m.mean_tape_whole,
                m.fidget_mean_tape_specialised,
                m.fidget_mean_tape_whole,
                m.fidget_vm_build_ms,
                m.fidget_jit_build_ms,
            );
        }
        s.push('\n');
    }
}

#[cfg(feature = "fidget")]
pub use with_fidget::measure;

#[cfg(feature = "fidget")]
mod with_fidget {
    use super::*;
    use crate::bench::peer::fidget::tape_to_tree;
    use crate::sdf::simd::{PacketRegisters, SimdLevel, eval8, eval8_interpreted};
    use crate::sdf::tape::Registers;
    use anyhow::Context as _;
    use fidget::eval::{BulkEvaluator, Function, MathFunction};
    use fidget::shape::{Shape, ShapeBulkEval, ShapeTape};
    use std::time::Instant;

    /// A float-slice tape per distinct tape of the workload, and an evaluator to run them.
    struct Slices<F: Function> {
        tapes: Vec<ShapeTape<<F::FloatSliceEval as BulkEvaluator>::Tape>>,
        sizes: Vec<usize>,
        eval: ShapeBulkEval<F::FloatSliceEval>,
    }

    impl<F: Function + MathFunction + Clone> Slices<F> {
        fn new(tapes: &[&Tape]) -> anyhow::Result<(Self, f64)> {
            let start = Instant::now();
            let mut out = Slices {
                tapes: Vec::with_capacity(tapes.len()),
                sizes: Vec::with_capacity(tapes.len()),
                eval: Shape::<F>::new_float_slice_eval(),
            };
            for (i, t) in tapes.iter().enumerate() {
                let tree = tape_to_tree(t).with_context(|| format!("tape {i}"))?;
                let mut ctx = fidget::context::Context::new();
                let node = ctx.import(&tree);
                let shape = Shape::<F>::new(&ctx, node)
                    .map_err(|e| anyhow::anyhow!("tape {i}: fidget cannot build it: {e}"))?;
                out.sizes.push(shape.size());
                out.tapes.push(shape.float_slice_tape(Default::default()));
            }
            Ok((out, start.elapsed().as_secs_f64()))
        }

        /// One pass over the workload in batches of `batch`.
        fn run(
            &mut self,
            w: &Workload,
            specialised: bool,
            batch: usize,
            out: &mut [f32],
        ) -> anyhow::Result<()> {
            for (g, res) in w.groups.iter().zip(out.chunks_exact_mut(GROUP)) {
                let tape = &self.tapes[g.tape(specialised)];
                let (x, y, z) = (g.x.as_flattened(), g.y.as_flattened(), g.z.as_flattened());
                for (c, r) in res.chunks_exact_mut(batch).enumerate() {
                    let span = c * batch..(c + 1) * batch;
                    let v = self
                        .eval
                        .eval(tape, &x[span.clone()], &y[span.clone()], &z[span])
                        .map_err(|e| anyhow::anyhow!("fidget float-slice evaluation: {e}"))?;
                    r.copy_from_slice(v);
                }
            }
            Ok(())
        }
    }

    /// The evaluators of the table, in its order.
    #[derive(Debug, Clone, Copy)]
    enum Kind {
        Eval8,
        Native,
        Scalar,
        Vm(usize),
        Jit(usize),
    }

    impl Kind {
        fn all() -> Vec<Kind> {
            let mut v = vec![Kind::Eval8, Kind::Scalar];
            if crate::sdf::jit::available() {
                v.push(Kind::Native);
            }
            v.extend(FIDGET_BATCHES.iter().map(|&b| Kind::Vm(b)));
            v.extend(FIDGET_BATCHES.iter().map(|&b| Kind::Jit(b)));
            v
        }

        fn name(self) -> &'static str {
            match self {
                Kind::Eval8 => "hytrace eval8",
                Kind::Native => "hytrace native",
                Kind::Scalar => "hytrace scalar",
                Kind::Vm(_) => "fidget VM",
                Kind::Jit(_) => "fidget JIT",
            }
        }

        fn batch(self) -> usize {
            match self {
                Kind::Eval8 | Kind::Native => LANES,
                Kind::Scalar => 1,
                Kind::Vm(b) | Kind::Jit(b) => b,
            }
        }
    }

    /// Measures `fields` (a model's, `bounds` its objects'): every evaluator on both workloads,
    /// alternating, until each has `opts.runs` passes and `opts.min_seconds` in all (at most
    /// [`crate::bench::MAX_ROUNDS`] rounds, no new round after
    /// [`super::super::ROUND_SECONDS`]).
    pub fn measure(
        opts: &crate::bench::BenchOptions,
        name: &str,
        fields: &[ObjectField],
        bounds: &[Aabb],
    ) -> anyhow::Result<EvalModel> {
        let groups = if opts.quick { GROUPS_QUICK } else { GROUPS };
        let w = Workload::new(fields, bounds, groups, 0x7a9e);
        if w.groups.is_empty() {
            anyhow::bail!("{name}: no crossed leaf and no finite bounds to evaluate in");
        }
        let (mut vm, vm_build) = Slices::<fidget::vm::VmFunction>::new(&w.tapes)
            .with_context(|| format!("{name}: fidget VM tapes"))?;
        let (mut jit, jit_build) = Slices::<fidget::jit::JitFunction>::new(&w.tapes)
            .with_context(|| format!("{name}: fidget JIT tapes"))?;
        let level = SimdLevel::detect();
        let mut packet = PacketRegisters::new();
        let mut regs = Registers::new();
        let n = w.points();
        let mut pass = |kind: Kind, specialised: bool, out: &mut [f32]| -> anyhow::Result<f64> {
            let start = Instant::now();
            match kind {
                Kind::Eval8 | Kind::Native => {
                    let eval = if matches!(kind, Kind::Native) {
                        eval8
                    } else {
                        eval8_interpreted
                    };
                    for (g, res) in w.groups.iter().zip(out.chunks_exact_mut(GROUP)) {
                        let tape = w.tapes[g.tape(specialised)];
                        for (c, r) in res.chunks_exact_mut(LANES).enumerate() {
                            let v = eval(level, tape, &g.x[c], &g.y[c], &g.z[c], &mut packet);
                            r.copy_from_slice(&v);
                        }
                    }
                }
                Kind::Scalar => {
                    for (g, res) in w.groups.iter().zip(out.chunks_exact_mut(GROUP)) {
                        let tape = w.tapes[g.tape(specialised)];
                        for (i, r) in res.iter_mut().enumerate() {
                            let (c, l) = (i / LANES, i % LANES);
                            let p = Vec3::new(g.x[c][l], g.y[c][l], g.z[c][l]);
                            *r = tape.eval_in(p, &mut regs);
                        }
                    }
                }
                Kind::Vm(b) => vm.run(&w, specialised, b, out)?,
                Kind::Jit(b) => jit.run(&w, specialised, b, out)?,
            }
            Ok(start.elapsed().as_secs_f64())
        };
        let kinds = Kind::all();
        // (kind, specialised) slots: outputs of the warm-up pass, then timed seconds.
        let slots: Vec<(Kind, bool)> = kinds
            .iter()
            .flat_map(|&k| [(k, true), (k, false)])
            .collect();
        let mut outputs = vec![vec![0.0f32; n]; slots.len()];
        for (&(k, s), out) in slots.iter().zip(&mut outputs) {
            pass(k, s, out)?;
        }
        let mut scratch = vec![0.0f32; n];
        let mut times: Vec<Vec<f64>> = vec![Vec::new(); slots.len()];
        let enough = |times: &[Vec<f64>]| {
            times
                .iter()
                .all(|t| t.len() >= opts.runs.max(1) && t.iter().sum::<f64>() >= opts.min_seconds)
        };
        let start = Instant::now();
        let mut rounds = 0;
        while !enough(&times)
            && rounds < crate::bench::MAX_ROUNDS
            && (rounds == 0 || start.elapsed().as_secs_f64() < super::super::ROUND_SECONDS)
        {
            for (&(k, s), t) in slots.iter().zip(&mut times) {
                t.push(pass(k, s, &mut scratch)?);
            }
            rounds += 1;
        }
        // Our scalar interpreter is the reference (slots 2 and 3: specialised, whole).
        let timing = |slot: usize, specialised: bool| {
            let t = &times[slot];
            let reference = &outputs[if specialised { 2 } else { 3 }];
            let median = crate::bench::median(t);
            let best = t.iter().copied().fold(f64::INFINITY, f64::min);
            EvalTiming {
                ns_per_point: median * 1e9 / n as f64,
                best_ns_per_point: best * 1e9 / n as f64,
                ns_per_point_instruction: median * 1e9 / w.instructions(specialised).max(1) as f64,
                max_relative_difference: max_relative_difference(reference, &outputs[slot]),
                runs_ms: t.iter().map(|s| s * 1e3).collect(),
            }
        };
        let figures = kinds
            .iter()
            .enumerate()
            .map(|(i, &k)| EvalFigure {
                evaluator: k.name().into(),
                batch: k.batch(),
                specialised: timing(2 * i, true),
                whole: timing(2 * i + 1, false),
            })
            .collect();
        let fidget_mean = |specialised: bool| {
            w.groups
                .iter()
                .map(|g| vm.sizes[g.tape(specialised)] as f64)
                .sum::<f64>()
                / w.groups.len() as f64
        };
        Ok(EvalModel {
            model: name.into(),
            points: n,
            leaf_groups: w.leaf_groups,
            outside_groups: w.outside_groups,
            crossed_leaves: w.crossed_leaves,
            tapes: w.tapes.len(),
            mean_tape_specialised: w.mean_len(true),
            mean_tape_whole: w.mean_len(false),
            fidget_mean_tape_specialised: fidget_mean(true),
            fidget_mean_tape_whole: fidget_mean(false),
            fidget_vm_build_ms: vm_build * 1e3,
            fidget_jit_build_ms: jit_build * 1e3,
            figures,
        })
    }
}
