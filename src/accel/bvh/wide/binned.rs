//! A top-down binned-SAH builder of 8-wide trees, parallel on the rayon pool, giving the same
//! tree whatever the number of threads.
//!
//! **Why not obvhs here.** obvhs builds a binary tree (PLOC), optimises it and collapses it to
//! eight children per node, one pass after another; its collapse alone, sequential, is a third
//! of its build, and its parallel PLOC cuts the work into chunks by thread count, so the tree
//! (and the order in which equally near triangles are met) would change with the machine.
//! This builder makes the 8-wide nodes top-down: a run of primitives is split in two by the
//! surface area heuristic over binned centroids (Wald, "On fast Construction of SAH-based
//! Bounding Volume Hierarchies", IEEE RT 2007), each half again down to runs of at most
//! [`MAX_LEAF`], and the binary tree of these splits is collapsed to eight children per node
//! by the SAH as its splits return (see [`Bin`]). Subtrees of more than [`PARALLEL_MIN`]
//! primitives are built in parallel; each split depends only on its own primitives, so the
//! tree is the same on one thread or many.
//!
//! The child boxes are the exact `f32` unions of the primitive boxes below them, as in
//! [`super::build`]'s decoding of obvhs's trees, so the node test's conservativeness argument
//! holds unchanged.

use glam::{Vec3, Vec3A};
use obvhs::aabb::Aabb as OAabb;
use rayon::prelude::*;

use super::{LEAF_BIT, WideBvh, WideNode};

/// Most primitives in a leaf child: four, the most the two count bits of a leaf's meta encode
/// (eight such leaves fill the four blocks of eight triangles that `super::super::leaf`
/// allows a node). Measured on the bench's models, leaves of three gave 35–45 % more nodes
/// and traced as fast to 6 % slower.
pub(crate) const MAX_LEAF: usize = 4;
/// Bins per axis of the SAH sweep.
const BINS: usize = 16;
/// Runs of at most this many primitives are split by a full SAH sweep over their centroids
/// sorted along the longest axis: exact where binning approximates, and cheaper than binning's
/// fixed cost (clearing and sweeping 3 × 16 bins) on so few. (Sweeping all three axes traced
/// the bench's models 0–3 % faster for a sixth more build time.)
const SWEEP_MAX: usize = 24;
/// Subtrees of more primitives than this are built on the rayon pool.
const PARALLEL_MIN: usize = 2048;

/// A primitive's box and its index, 28 bytes: what the partitions move.
#[derive(Clone, Copy, Debug)]
struct PrimRef {
    lo: Vec3,
    id: u32,
    hi: Vec3,
}

impl PrimRef {
    #[inline(always)]
    fn lo(&self) -> Vec3A {
        Vec3A::from(self.lo)
    }
    #[inline(always)]
    fn hi(&self) -> Vec3A {
        Vec3A::from(self.hi)
    }
    /// Twice the centroid (the halving would only scale the bins).
    #[inline(always)]
    fn centroid2(&self) -> Vec3A {
        self.lo() + self.hi()
    }
}

/// A box as min and max (empty: min = +∞, max = −∞).
#[derive(Clone, Copy, Debug)]
struct Bounds {
    lo: Vec3A,
    hi: Vec3A,
}

impl Bounds {
    const EMPTY: Bounds = Bounds {
        lo: Vec3A::INFINITY,
        hi: Vec3A::NEG_INFINITY,
    };
    #[inline(always)]
    fn grow(&mut self, lo: Vec3A, hi: Vec3A) {
        self.lo = self.lo.min(lo);
        self.hi = self.hi.max(hi);
    }
    #[inline(always)]
    fn union(self, o: Bounds) -> Bounds {
        Bounds {
            lo: self.lo.min(o.lo),
            hi: self.hi.max(o.hi),
        }
    }
    /// Half the surface area (0 for an empty box).
    #[inline(always)]
    fn half_area(&self) -> f32 {
        let d = (self.hi - self.lo).max(Vec3A::ZERO);
        d.x * d.y + d.y * d.z + d.z * d.x
    }
}

/// A run of primitives: its box and the box of its (doubled) centroids.
#[derive(Clone, Copy, Debug)]
struct Run {
    bounds: Bounds,
    centroids: Bounds,
}

impl Run {
    const EMPTY: Run = Run {
        bounds: Bounds::EMPTY,
        centroids: Bounds::EMPTY,
    };
    #[inline(always)]
    fn add(&mut self, r: &PrimRef) {
        let (lo, hi) = (r.lo(), r.hi());
        self.bounds.grow(lo, hi);
        let c = lo + hi;
        self.centroids.grow(c, c);
    }
    fn of(refs: &[PrimRef]) -> Run {
        let mut run = Run::EMPTY;
        for r in refs {
            run.add(r);
        }
        run
    }
    /// [`Run::of`], in parallel parts for a large run (unions are exact: the same run).
    fn of_parallel(refs: &[PrimRef]) -> Run {
        if refs.len() <= PARALLEL_RUN {
            return Run::of(refs);
        }
        refs.par_chunks(PARALLEL_RUN / 2).map(Run::of).reduce(
            || Run::EMPTY,
            |a, b| Run {
                bounds: a.bounds.union(b.bounds),
                centroids: a.centroids.union(b.centroids),
            },
        )
    }
}

/// Splits `refs` in two by the binned SAH (or, when every centroid is the same point, in the
/// middle), reordering it so that the first part comes first. Returns the size of the first
/// part (between 1 and `refs.len() − 1`) and the two runs.
fn split(refs: &mut [PrimRef], run: &Run) -> (usize, Run, Run) {
    debug_assert!(refs.len() >= 2);
    if refs.len() <= SWEEP_MAX {
        return split_sorted(refs, run);
    }
    split_binned(refs, run)
}

/// The bin on each axis of a (doubled) centroid `c`: `(c − origin)·scale`, clamped to
/// `0..=BINS − 1` and truncated, three axes at once. What both the binning and the partition
/// of [`split_binned`] classify by, so that they agree. (The three saturating `f32 → usize`
/// casts this replaces were a third of the binning loop's instructions.)
#[inline(always)]
fn bins_of(c: Vec3A, origin: Vec3A, scale: Vec3A) -> [usize; 3] {
    // In range; a NaN (which finite boxes cannot give) becomes bin 0, as `max` returns its
    // second operand when the first is NaN.
    let b = ((c - origin) * scale)
        .max(Vec3A::ZERO)
        .min(Vec3A::splat((BINS - 1) as f32));
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{__m128, _mm_cvttps_epi32, _mm_storeu_si128};
        let mut out = [0i32; 4];
        // SAFETY: SSE2 is part of x86_64; a 16-byte store into a 16-byte array.
        unsafe { _mm_storeu_si128(out.as_mut_ptr().cast(), _mm_cvttps_epi32(__m128::from(b))) };
        [out[0] as usize, out[1] as usize, out[2] as usize]
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        [b.x as usize, b.y as usize, b.z as usize]
    }
}

/// [`split`] by binning: 16 bins per axis over the run's centroid box.
fn split_binned(refs: &mut [PrimRef], run: &Run) -> (usize, Run, Run) {
    let extent = run.centroids.hi - run.centroids.lo;
    // An axis of zero extent, or one so thin that the scale overflows, is not binned (its
    // scale is 0, which puts every centroid in bin 0).
    let scale = Vec3A::splat(BINS as f32 * (1.0 - 1e-5)) / extent;
    let scale = Vec3A::select(
        extent.cmpgt(Vec3A::ZERO) & scale.is_finite_mask(),
        scale,
        Vec3A::ZERO,
    );
    let origin = run.centroids.lo;
    let bin_run = |refs: &[PrimRef]| {
        // Two sets of bins, for the even and the odd references, joined at the end (unions
        // and sums are exact: the same bins). Neighbouring references mostly fall in the same
        // bin, and with one set each update waited for the previous one's store.
        let mut bins = [[[Bounds::EMPTY; BINS]; 3]; 2];
        let mut counts = [[[0u32; BINS]; 3]; 2];
        let mut add = |set: usize, r: &PrimRef| {
            let b = bins_of(r.centroid2(), origin, scale);
            let (lo, hi) = (r.lo(), r.hi());
            for axis in 0..3 {
                bins[set][axis][b[axis]].grow(lo, hi);
                counts[set][axis][b[axis]] += 1;
            }
        };
        let mut pairs = refs.chunks_exact(2);
        for pair in &mut pairs {
            add(0, &pair[0]);
            add(1, &pair[1]);
        }
        if let [last] = pairs.remainder() {
            add(0, last);
        }
        let [mut joined, odd] = bins;
        let [mut total, odd_counts] = counts;
        for axis in 0..3 {
            for k in 0..BINS {
                joined[axis][k] = joined[axis][k].union(odd[axis][k]);
                total[axis][k] += odd_counts[axis][k];
            }
        }
        (joined, total)
    };
    // A large run (the top of a large mesh, where one split waits for nothing else) is binned
    // in parallel parts; unions of boxes and sums of counts are exact, so the bins are the same.
    let (bins, counts) = if refs.len() > PARALLEL_RUN {
        refs.par_chunks(PARALLEL_RUN / 2).map(bin_run).reduce(
            || ([[Bounds::EMPTY; BINS]; 3], [[0u32; BINS]; 3]),
            |(mut b, mut c), (b2, c2)| {
                for axis in 0..3 {
                    for k in 0..BINS {
                        b[axis][k] = b[axis][k].union(b2[axis][k]);
                        c[axis][k] += c2[axis][k];
                    }
                }
                (b, c)
            },
        )
    } else {
        bin_run(refs)
    };
    // Sweep: cost of splitting after bin k = area(left)·|left| + area(right)·|right|.
    let mut best: Option<(f32, usize, usize)> = None;
    for axis in 0..3 {
        if scale[axis] == 0.0 {
            continue;
        }
        let mut right_area = [0.0f32; BINS];
        let mut right_count = [0u32; BINS];
        let mut acc = Bounds::EMPTY;
        let mut n = 0;
        for k in (1..BINS).rev() {
            acc = acc.union(bins[axis][k]);
            n += counts[axis][k];
            right_area[k] = acc.half_area();
            right_count[k] = n;
        }
        let mut acc = Bounds::EMPTY;
        let mut n = 0;
        for k in 0..BINS - 1 {
            acc = acc.union(bins[axis][k]);
            n += counts[axis][k];
            let (nl, nr) = (n, right_count[k + 1]);
            if nl == 0 || nr == 0 {
                continue;
            }
            let cost = acc.half_area() * nl as f32 + right_area[k + 1] * nr as f32;
            if best.is_none_or(|(c, _, _)| cost < c) {
                best = Some((cost, axis, k));
            }
        }
    }
    let Some((_, axis, k)) = best else {
        return split_middle(refs);
    };
    // Partition, bins ≤ k first. Which side a primitive goes to cannot be predicted, so the
    // partition is written without branches: each one is copied to the next free slot of its
    // side in a scratch array, from the left or from the right (the slot is selected, the
    // cursors move by its side's flag), and at the end the cursors meet.
    // Past bin k: the binning's classification, by the same function on the same values.
    let goes_right = |p: &PrimRef| bins_of(p.centroid2(), origin, scale)[axis] > k;
    let n = refs.len();
    let partition = |scratch: &mut Vec<PrimRef>| {
        // Written without filling it first (a pass of its own): every slot is written below.
        scratch.clear();
        scratch.reserve(n);
        let buf = &mut scratch.spare_capacity_mut()[..n];
        let (mut l, mut r) = (0, n);
        for p in refs.iter() {
            let right = goes_right(p);
            // One write, to the slot of its side (a select, not a branch).
            let slot = if right { r - 1 } else { l };
            buf[slot].write(*p);
            l += usize::from(!right);
            r -= usize::from(right);
        }
        // Each slot below the final `l` was written while `l` pointed at it, each from the
        // final `r` up while `r − 1` did; they meet.
        assert_eq!(l, r);
        // The copy back measures the two sides' runs on the way, one side after the other (a
        // pass of `cut` saved; measured during the partition, in turns that nothing predicts,
        // each run waited on its own last update).
        let (left_dst, right_dst) = refs.split_at_mut(l);
        let (left_src, right_src) = buf.split_at(l);
        let copy = |dst: &mut [PrimRef], src: &[std::mem::MaybeUninit<PrimRef>]| {
            let mut run = Run::EMPTY;
            for (d, s) in dst.iter_mut().zip(src) {
                // SAFETY: every slot of `buf` was written (above).
                let p = unsafe { s.assume_init() };
                run.add(&p);
                *d = p;
            }
            run
        };
        (l, copy(left_dst, left_src), copy(right_dst, right_src))
    };
    // The partition classifies as the binning did (the same function on the same values), so
    // both sides hold what the sweep counted; should they not, a cut in the middle keeps the
    // build finite.
    let one_sided = |mid: usize| mid == 0 || mid == n;
    // The largest runs (near the top of a large mesh, a few per build) are partitioned in
    // parallel, through an array of their own freed at once, so that no thread keeps one as
    // large as the largest mesh it has built.
    if n > PARALLEL_RUN {
        let mid = partition_parallel(refs, goes_right);
        return if one_sided(mid) {
            split_middle(refs)
        } else {
            cut(refs, mid)
        };
    }
    let (mid, left, right) = SCRATCH.with_borrow_mut(partition);
    if one_sided(mid) {
        return split_middle(refs);
    }
    (mid, left, right)
}

/// Runs of more primitives than this are binned, partitioned and measured in parallel parts
/// of half as many; the kept scratch array serves the others (0.9 MB of references at most).
const PARALLEL_RUN: usize = 1 << 15;

/// The partition of [`split_binned`] in parallel parts: each part's primitives that are not
/// `right` go, in order, after those of the parts before it from the left end, and the others,
/// in order, before those of the parts before it from the right end — exactly where the
/// one-pass partition puts them (its right side comes out reversed), so the tree does not
/// depend on the run's size or the thread count. Returns the size of the left side.
fn partition_parallel(refs: &mut [PrimRef], right: impl Fn(&PrimRef) -> bool + Sync) -> usize {
    let part = PARALLEL_RUN / 2;
    let lefts: Vec<usize> = refs
        .par_chunks(part)
        .map(|c| c.iter().filter(|p| !right(p)).count())
        .collect();
    let n = refs.len();
    let n_left: usize = lefts.iter().sum();
    let mut scratch = vec![refs[0]; n];
    {
        // Each part's two segments of the scratch array: its lefts in the left side, its
        // rights (from the top down, part 0 highest) in the right side.
        let (mut left_side, right_side) = scratch.split_at_mut(n_left);
        let mut right_side = right_side;
        let mut segments = Vec::with_capacity(lefts.len());
        for (chunk, &l) in refs.chunks(part).zip(&lefts) {
            let r = chunk.len() - l;
            let (ls, rest) = left_side.split_at_mut(l);
            left_side = rest;
            let (rest, rs) = right_side.split_at_mut(right_side.len() - r);
            right_side = rest;
            segments.push((ls, rs));
        }
        refs.par_chunks(part)
            .zip(segments)
            .for_each(|(chunk, (ls, rs))| {
                let (mut l, mut r) = (0, rs.len());
                for p in chunk {
                    if right(p) {
                        r -= 1;
                        rs[r] = *p;
                    } else {
                        ls[l] = *p;
                        l += 1;
                    }
                }
            });
    }
    refs.par_chunks_mut(part)
        .zip(scratch.par_chunks(part))
        .for_each(|(d, s)| d.copy_from_slice(s));
    n_left
}

thread_local! {
    /// The partition's scratch array, one per thread of the pool, kept between builds.
    static SCRATCH: std::cell::RefCell<Vec<PrimRef>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// A split of `refs` after its first `mid`, with the two sides' runs. Each side's run is a
/// pass of its own: gathered during the partition, the two runs were updated in turns that
/// nothing predicts, each waiting on its own last update.
fn cut(refs: &[PrimRef], mid: usize) -> (usize, Run, Run) {
    let (a, b) = refs.split_at(mid);
    (mid, Run::of_parallel(a), Run::of_parallel(b))
}

/// The split when every centroid is the same point: any is as good, and halves keep the tree
/// shallow.
fn split_middle(refs: &[PrimRef]) -> (usize, Run, Run) {
    cut(refs, refs.len() / 2)
}

/// [`split`] for short runs: sorted along the longest axis of the centroids, cut where the
/// SAH cost is least; in the middle when every centroid is the same point.
fn split_sorted(refs: &mut [PrimRef], run: &Run) -> (usize, Run, Run) {
    let n = refs.len();
    let extent = run.centroids.hi - run.centroids.lo;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    // (A NaN extent, from centroids that overflowed, is no axis to sort along either.)
    if extent[axis].is_nan() || extent[axis] <= 0.0 {
        return split_middle(refs);
    }
    // Sorted by keys made once, the centroid's coordinate in `total_cmp`'s order above the
    // reference's position (ties keep their order), then moved into place: a comparison sort
    // of the references themselves recomputed two centroids per comparison and moved 28-byte
    // records.
    debug_assert!(n <= SWEEP_MAX, "only short runs are sorted");
    let mut keys = [0u64; SWEEP_MAX];
    for (i, (key, r)) in keys.iter_mut().zip(refs.iter()).enumerate() {
        *key = u64::from(total_order_bits(r.centroid2()[axis])) << 32 | i as u64;
    }
    let keys = &mut keys[..n];
    keys.sort_unstable();
    let mut sorted = [refs[0]; SWEEP_MAX];
    for (s, key) in sorted.iter_mut().zip(keys.iter()) {
        *s = refs[(key & u64::from(u32::MAX)) as usize];
    }
    refs.copy_from_slice(&sorted[..n]);
    let mut right_area = [0.0f32; SWEEP_MAX];
    let mut acc = Bounds::EMPTY;
    for k in (1..n).rev() {
        acc.grow(refs[k].lo(), refs[k].hi());
        right_area[k] = acc.half_area();
    }
    let mut acc = Bounds::EMPTY;
    let mut best = (f32::INFINITY, n / 2);
    for k in 1..n {
        acc.grow(refs[k - 1].lo(), refs[k - 1].hi());
        let cost = acc.half_area() * k as f32 + right_area[k] * (n - k) as f32;
        if cost < best.0 {
            best = (cost, k);
        }
    }
    cut(refs, best.1)
}

/// The bits of `x` as an unsigned number in the order of [`f32::total_cmp`].
#[inline(always)]
fn total_order_bits(x: f32) -> u32 {
    let b = x.to_bits();
    if b >> 31 == 1 { !b } else { b | 1 << 31 }
}

/// A built subtree before it is laid out.
enum Built {
    /// `count` primitives from `first` (an index into the whole reference array).
    Leaf { first: u32, count: u32 },
    /// Up to eight children with their boxes.
    Node(Vec<(Bounds, Built)>),
}

/// A node of the binary tree of binned splits, and how the collapse represents it.
///
/// **The collapse to eight children** (Ylitie, Karras & Laine, "Efficient Incoherent Ray
/// Traversal on GPUs Through Compressed Wide BVHs", HPG 2017, section 3.1). Splitting a
/// node's run until it has eight children, always the child of largest surface next, makes
/// the eight but does not weigh them: a small child split into two leaves, or a large one
/// left whole, can both be cheaper. So the splits are made as a binary tree, and from its
/// leaves up every node learns the least SAH cost of its subtree as a forest of at most
/// i = 1..8 roots: as one leaf (`area·count·C_PRIM`, only for at most [`MAX_LEAF`]
/// primitives), as one wide node (`area·C_NODE` plus its best eight roots), or, for i > 1,
/// k roots from the left child and i − k from the right. A wide node's children are its
/// best eight roots. (obvhs's `bvh2_to_cwbvh` implements the same paper over its PLOC
/// trees; here the programme runs as the splits return, on the rayon pool with them.)
/// Measured against the largest-surface rule on the bench's rays (one thread, best of 0.3 s
/// windows, in turns): 2–7 % faster on the CAD models, 4–12 % on MetalRoughSpheres, within
/// 2 % on the bunny, for 3–9 % more build time on three of the four and none on the largest
/// (BENCHMARKS.md, "A node's eight children chosen by the SAH").
struct Bin {
    bounds: Bounds,
    /// The first primitive (an index into the whole reference array) and how many.
    first: u32,
    count: u32,
    /// The two halves of a split; none for a run of at most [`MAX_LEAF`], which stays whole
    /// (splitting those down to one primitive, as obvhs does, traced no faster here and cost
    /// a third more build).
    children: Option<Box<[Bin; 2]>>,
    /// `how[i - 1]`: how the subtree is best represented as at most `i` roots: [`AS_LEAF`] or
    /// [`AS_NODE`] (i = 1), [`AS_FEWER`] (as at most i − 1), or a number k in 1..i: k roots
    /// from the left half and i − k from the right.
    how: [u8; 8],
    /// As a wide node, how many of its eight roots come from the left half.
    node_split: u8,
}

const AS_LEAF: u8 = u8::MAX;
const AS_NODE: u8 = u8::MAX - 1;
const AS_FEWER: u8 = u8::MAX - 2;

/// The SAH costs of a node visit and of a primitive test, relative: Ylitie et al.'s values.
/// (Primitive costs of 0.15 and 0.6 traced the bench's models no differently, within 3 %.)
const C_NODE: f32 = 1.0;
const C_PRIM: f32 = 0.3;

/// Builds the binary tree over `refs` (which start at `first` in the whole array), with each
/// node's costs; returns the root and its costs as at most 1..=8 roots.
fn build_bin(refs: &mut [PrimRef], first: usize, run: Run) -> (Bin, [f32; 8]) {
    let area = run.bounds.half_area();
    let n = refs.len();
    if n <= MAX_LEAF {
        let leaf = area * n as f32 * C_PRIM;
        let mut how = [AS_FEWER; 8];
        how[0] = AS_LEAF;
        let bin = Bin {
            bounds: run.bounds,
            first: first as u32,
            count: n as u32,
            children: None,
            how,
            node_split: 0,
        };
        return (bin, [leaf; 8]);
    }
    let (mid, left, right) = split(refs, &run);
    let (a, b) = refs.split_at_mut(mid);
    let halves = |a: &mut [PrimRef], b: &mut [PrimRef]| {
        if n > PARALLEL_MIN {
            rayon::join(
                || build_bin(a, first, left),
                || build_bin(b, first + mid, right),
            )
        } else {
            (build_bin(a, first, left), build_bin(b, first + mid, right))
        }
    };
    let ((left_bin, left_cost), (right_bin, right_cost)) = halves(a, b);
    // split_cost[j]: the least cost of j roots with at least one from each half.
    let mut split_cost = [f32::INFINITY; 9];
    let mut split_at = [0u8; 9];
    for j in 2..=8 {
        for k in 1..j {
            let c = left_cost[k - 1] + right_cost[j - k - 1];
            if c < split_cost[j] {
                split_cost[j] = c;
                split_at[j] = k as u8;
            }
        }
    }
    // As one root, a run of more than `MAX_LEAF` is a wide node.
    let mut cost = [split_cost[8] + area * C_NODE; 8];
    let mut how = [AS_NODE; 8];
    for i in 2..=8 {
        (cost[i - 1], how[i - 1]) = if cost[i - 2] <= split_cost[i] {
            (cost[i - 2], AS_FEWER)
        } else {
            (split_cost[i], split_at[i])
        };
    }
    let bin = Bin {
        bounds: run.bounds,
        first: first as u32,
        count: n as u32,
        children: Some(Box::new([left_bin, right_bin])),
        how,
        node_split: split_at[8],
    };
    (bin, cost)
}

/// The subtree the collapse makes of `bin` as one root: a leaf or a wide node of its best
/// eight roots, built on the rayon pool for large subtrees.
fn collapse(bin: &Bin) -> Built {
    let Some(halves) = bin.children.as_ref().filter(|_| bin.how[0] == AS_NODE) else {
        return Built::Leaf {
            first: bin.first,
            count: bin.count,
        };
    };
    let mut roots = Vec::with_capacity(8);
    let k = bin.node_split as usize;
    roots_of(&halves[0], k, &mut roots);
    roots_of(&halves[1], 8 - k, &mut roots);
    // `collect` keeps the children's order whichever thread built each.
    let child = |b: &&Bin| (b.bounds, collapse(b));
    let children = if bin.count as usize > PARALLEL_MIN {
        roots.par_iter().map(child).collect()
    } else {
        roots.iter().map(child).collect()
    };
    Built::Node(children)
}

/// Appends the best (at most) `i` roots of `bin`'s subtree, in primitive order.
fn roots_of<'a>(bin: &'a Bin, i: usize, out: &mut Vec<&'a Bin>) {
    match (bin.how[i - 1], bin.children.as_ref()) {
        (AS_LEAF | AS_NODE, _) => out.push(bin),
        (AS_FEWER, _) => roots_of(bin, i - 1, out),
        (k, Some(halves)) => {
            roots_of(&halves[0], k as usize, out);
            roots_of(&halves[1], i - k as usize, out);
        }
        (_, None) => unreachable!("only a split is represented by its halves"),
    }
}

/// Builds over `boxes`, which must be finite with min ≤ max (the callers filter).
pub(crate) fn build(boxes: &[OAabb]) -> WideBvh {
    if let Some(empty) = super::empty_tree_of(boxes) {
        return empty;
    }
    let mut refs = prim_refs(boxes);
    let run = Run::of_parallel(&refs);
    let (root, _) = build_bin(&mut refs, 0, run);
    let built = collapse(&root);
    // The binary tree is no longer needed: freed before the nodes are laid out.
    drop(root);
    let root = match built {
        // A root that is one leaf is a node with one leaf child.
        leaf @ Built::Leaf { .. } => vec![(run.bounds, leaf)],
        Built::Node(children) => children,
    };
    // Lay the nodes out depth first: a parent before its children.
    let mut nodes = Vec::new();
    let mut max_depth = 0;
    lay_out(&root, 1, &mut nodes, &mut max_depth);
    WideBvh {
        nodes,
        order: refs.iter().map(|r| r.id).collect(),
        max_depth,
        bounds: (run.bounds.lo.into(), run.bounds.hi.into()),
    }
}

/// The references of `boxes`, each with its index.
fn prim_refs(boxes: &[OAabb]) -> Vec<PrimRef> {
    boxes
        .par_iter()
        .enumerate()
        .map(|(i, b)| PrimRef {
            lo: b.min.into(),
            id: i as u32,
            hi: b.max.into(),
        })
        .collect()
}

/// Appends the node of `children` and its subtrees; returns its index.
fn lay_out(
    children: &[(Bounds, Built)],
    depth: u32,
    nodes: &mut Vec<WideNode>,
    max_depth: &mut u32,
) -> u32 {
    *max_depth = (*max_depth).max(depth);
    let index = nodes.len();
    nodes.push(WideNode::EMPTY);
    for (slot, (b, child)) in children.iter().enumerate() {
        let meta = match child {
            Built::Leaf { first, count } => LEAF_BIT | (count - 1) << 29 | first,
            Built::Node(grand) => lay_out(grand, depth + 1, nodes, max_depth),
        };
        let node = &mut nodes[index];
        for axis in 0..3 {
            node.bounds[2 * axis][slot] = b.lo[axis];
            node.bounds[2 * axis + 1][slot] = b.hi[axis];
        }
        node.meta[slot] = meta;
    }
    index as u32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use glam::Vec3A;

    fn boxes_of(points: &[(Vec3, Vec3)]) -> Vec<OAabb> {
        points
            .iter()
            .map(|&(lo, hi)| OAabb::new(lo.into(), hi.into()))
            .collect()
    }

    fn random_boxes(n: usize, seed: u64) -> Vec<OAabb> {
        let mut rng = Rng::new(seed);
        let v: Vec<(Vec3, Vec3)> = (0..n)
            .map(|_| {
                let lo = rng.vec3_in(-10.0, 10.0);
                (lo, lo + rng.vec3_in(0.0, 0.5))
            })
            .collect();
        boxes_of(&v)
    }

    /// Every primitive sits in exactly one leaf of at most `MAX_LEAF`; every child box is the
    /// exact union of what lies below it; children come after their parents; the depth is
    /// what the tree has.
    fn check(boxes: &[OAabb], t: &WideBvh) {
        let mut seen = vec![0u32; boxes.len()];
        for &p in &t.order {
            seen[p as usize] += 1;
        }
        assert!(seen.iter().all(|&c| c == 1), "each primitive once");
        // (lo, hi, depth) of node i's subtree, bottom up.
        fn walk(t: &WideBvh, boxes: &[OAabb], i: usize, depth: u32, max: &mut u32) -> (Vec3, Vec3) {
            *max = (*max).max(depth);
            let node = &t.nodes[i];
            let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
            for slot in 0..8 {
                if node.bounds[0][slot] > node.bounds[1][slot] {
                    continue;
                }
                let meta = node.meta[slot];
                let (clo, chi) = if meta & LEAF_BIT != 0 {
                    let (first, count) = (
                        super::super::leaf_first(meta),
                        super::super::leaf_count(meta),
                    );
                    assert!((1..=MAX_LEAF as u32).contains(&count));
                    let (mut a, mut b) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
                    for &p in &t.order[first as usize..(first + count) as usize] {
                        a = a.min(boxes[p as usize].min.into());
                        b = b.max(boxes[p as usize].max.into());
                    }
                    (a, b)
                } else {
                    assert!(meta as usize > i, "children after their parent");
                    walk(t, boxes, meta as usize, depth + 1, max)
                };
                for axis in 0..3 {
                    assert_eq!(node.bounds[2 * axis][slot], clo[axis]);
                    assert_eq!(node.bounds[2 * axis + 1][slot], chi[axis]);
                }
                lo = lo.min(clo);
                hi = hi.max(chi);
            }
            (lo, hi)
        }
        let mut max = 0;
        let (lo, hi) = walk(t, boxes, 0, 1, &mut max);
        assert_eq!((lo, hi), t.bounds);
        assert_eq!(max, t.max_depth);
    }

    /// Every way of representing `bin` as one root, tried: a leaf, or a wide node over any cut
    /// of at most eight roots below it, each root again at its best. The least SAH cost.
    fn best_by_trying_every_cut(bin: &Bin) -> f32 {
        /// Every set of at most eight roots that covers `bin`'s subtree once.
        fn cuts(bin: &Bin) -> Vec<Vec<&Bin>> {
            let mut all = vec![vec![bin]];
            if let Some(halves) = &bin.children {
                for a in cuts(&halves[0]) {
                    for b in cuts(&halves[1]) {
                        if a.len() + b.len() <= 8 {
                            all.push([a.clone(), b].concat());
                        }
                    }
                }
            }
            all
        }
        let area = bin.bounds.half_area();
        let leaf = if bin.count as usize <= MAX_LEAF {
            area * bin.count as f32 * C_PRIM
        } else {
            f32::INFINITY
        };
        let Some(halves) = &bin.children else {
            return leaf;
        };
        let mut below = f32::INFINITY;
        for a in cuts(&halves[0]) {
            for b in cuts(&halves[1]) {
                if a.len() + b.len() <= 8 {
                    let c: f32 = a
                        .iter()
                        .chain(&b)
                        .map(|r| best_by_trying_every_cut(r))
                        .sum();
                    below = below.min(c);
                }
            }
        }
        leaf.min(below + area * C_NODE)
    }

    /// The SAH cost of a built tree: `C_NODE` times each node's area, `C_PRIM` times each
    /// leaf's area and count.
    fn cost_of(t: &WideBvh) -> f32 {
        let area = |lo: Vec3, hi: Vec3| {
            let d = hi - lo;
            d.x * d.y + d.y * d.z + d.z * d.x
        };
        let mut cost = 0.0;
        for node in &t.nodes {
            let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
            for slot in 0..8 {
                if node.bounds[0][slot] > node.bounds[1][slot] {
                    continue;
                }
                let b = |k: usize| {
                    Vec3::new(
                        node.bounds[k][slot],
                        node.bounds[k + 2][slot],
                        node.bounds[k + 4][slot],
                    )
                };
                let (clo, chi) = (b(0), b(1));
                lo = lo.min(clo);
                hi = hi.max(chi);
                let meta = node.meta[slot];
                if meta & LEAF_BIT != 0 {
                    cost += area(clo, chi) * super::super::leaf_count(meta) as f32 * C_PRIM;
                }
            }
            cost += area(lo, hi) * C_NODE;
        }
        cost
    }

    #[test]
    fn the_collapse_finds_the_least_cost_tree_over_its_splits() {
        for (n, seed) in [(9, 1), (23, 2), (40, 3), (61, 4)] {
            let boxes = random_boxes(n, seed);
            let mut refs = prim_refs(&boxes);
            let run = Run::of(&refs);
            let (bin, costs) = build_bin(&mut refs, 0, run);
            let least = best_by_trying_every_cut(&bin);
            let built = cost_of(&build(&boxes));
            let close = |a: f32, b: f32| (a - b).abs() <= 1e-5 * a.abs().max(b.abs());
            assert!(
                close(costs[0], least),
                "{n}: programme {} against {least}",
                costs[0]
            );
            assert!(close(built, least), "{n}: tree {built} against {least}");
        }
    }

    #[test]
    fn trees_hold_every_primitive_in_exact_boxes() {
        for (n, seed) in [
            (1, 1),
            (3, 2),
            (4, 3),
            (5, 4),
            (25, 5),
            (100, 6),
            (20_000, 7),
        ] {
            let boxes = random_boxes(n, seed);
            check(&boxes, &build(&boxes));
        }
        assert!(build(&[]).nodes.is_empty());
    }

    /// The parallel partition puts every primitive where the one-pass partition does (the
    /// left side in order, the right side reversed), for runs that are not a whole number of
    /// parts and for one-sided splits.
    #[test]
    fn parallel_partition_is_the_one_pass_partition() {
        for (n, threshold) in [
            (100_003usize, 0.3f32),
            (PARALLEL_RUN + 1, 0.9),
            (70_000, 20.0),
            (40_000, -20.0),
        ] {
            let refs = prim_refs(&random_boxes(n, n as u64));
            let right = |p: &PrimRef| p.lo.x > threshold;
            let mut expected = refs.clone();
            let (mut l, mut r) = (0, n);
            for p in &refs {
                if right(p) {
                    r -= 1;
                    expected[r] = *p;
                } else {
                    expected[l] = *p;
                    l += 1;
                }
            }
            let mut got = refs.clone();
            assert_eq!(partition_parallel(&mut got, right), l);
            let ids = |v: &[PrimRef]| v.iter().map(|p| p.id).collect::<Vec<_>>();
            assert_eq!(ids(&got), ids(&expected));
        }
    }

    /// The tree depends on the boxes only: built on one thread and on four, it is the same
    /// node for node and in the same primitive order.
    #[test]
    fn the_tree_does_not_depend_on_the_thread_count() {
        // More than `PARALLEL_RUN`, so that both partitions serve.
        let boxes = random_boxes(100_000, 11);
        let on = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("a thread pool")
                .install(|| build(&boxes))
        };
        let (one, four) = (on(1), on(4));
        assert_eq!(one.order, four.order);
        assert_eq!(one.nodes.len(), four.nodes.len());
        for (a, b) in one.nodes.iter().zip(&four.nodes) {
            assert_eq!(a.meta, b.meta);
            for k in 0..6 {
                let bits = |x: &[f32; 8]| x.map(f32::to_bits);
                assert_eq!(bits(&a.bounds[k]), bits(&b.bounds[k]));
            }
        }
    }

    /// Identical boxes, points on a line at exponentially growing distances, and boxes far
    /// out: the build ends with a shallow tree (no run is split into an empty part).
    #[test]
    fn degenerate_inputs_give_shallow_trees() {
        let same = vec![OAabb::new(Vec3A::ZERO, Vec3A::ONE); 10_000];
        let t = build(&same);
        check(&same, &t);
        assert!(t.max_depth < 12, "depth {}", t.max_depth);
        let line: Vec<(Vec3, Vec3)> = (0..2000)
            .map(|i| {
                let p = Vec3::new(1.04f32.powi(i), 0.0, 0.0);
                (p, p)
            })
            .collect();
        let line = boxes_of(&line);
        let t = build(&line);
        check(&line, &t);
        assert!(t.max_depth < 64, "depth {}", t.max_depth);
        let far: Vec<(Vec3, Vec3)> = (0..1000)
            .map(|i| {
                let p = Vec3::splat(1e18 - i as f32 * 1e11);
                (p - 1.0, p + 1e12)
            })
            .collect();
        let far = boxes_of(&far);
        check(&far, &build(&far));
    }
}
