//! An SDF object's field as an octree of region-specialised tapes, for rays of any origin.
//!
//! Each leaf of the octree over the object's box (for a finite object, the cube around its
//! bounds) holds the tape specialised to its box ([`crate::sdf::simplify`]), whether the box
//! is empty, full or crossed by the surface, and, for a crossed box, interval enclosures of
//! ∂f/∂x, ∂f/∂y, ∂f/∂z there. A point is evaluated
//! with the tape of the leaf that holds it, which gives the whole tape's value at a fraction of
//! its cost; a ray skips empty leaves without evaluating anything; steps inside a leaf may be
//! lengthened by how slowly the field can fall along the ray there ([`Leaf::fall`]). Outside
//! the octree's box the whole tape is used; where that tape is short ([`SHORT_TAPE`]), the
//! CPU evaluates it everywhere but in Hart's march, which walks the leaves only where they
//! save at least half of it ([`FieldOctree::marched_whole`], on both backends); in a scene of
//! many objects a tree whose leaves save less is one leaf ([`Keep::Walked`]), not even built
//! where cells sampled on the surface already keep much of the tape. The structure depends
//! only on the object, so camera, shadow, ambient-occlusion, penumbra, reflection and
//! refraction rays share it (screen tiles would serve camera rays only).
//!
//! The tree is built top down (Keeter 2020, §4; fidget and libfive subdivide the same way):
//! the top [`CULL_DEPTH`] levels of a tape of [`MIN_SPLIT_TAPE`] instructions or more are
//! split regardless (cells proven empty or full are culled
//! there), and below them a box is split in eight while its children's tapes are markedly
//! shorter, down to [`MAX_DEPTH`]. Finer empty boxes near the surface would save a ray little
//! (sphere-tracing steps there are short anyway) and cost it lookups, so emptiness alone
//! stops counting below the top levels. Memory is bounded: at most [`MAX_NODES`] nodes and
//! [`MAX_INSTRUCTIONS`] instructions of distinct specialised tapes per object (so at most
//! 8 MiB of nodes, 80 MiB of 40-byte leaf records and 128 MiB of tapes); a split that would
//! exceed them leaves the box a leaf with its own tape. The top [`PARALLEL_DEPTH`] levels share
//! the budget among their boxes in proportion to their tapes, and each box's subtree is then
//! built on one thread, level by level, spending its share coarse before fine (a depth-first
//! build spent it on the octants it reached first: on a union of 1,000 boxes, rays of the last
//! ones evaluated 400-instruction tapes, at 4× the frame time). Identical tapes are stored and
//! counted once (most leaves of a large union repeat another's). The order is fixed, so the
//! tree does not depend on the thread count.

use crate::geom::{Aabb, Ray};
use crate::sdf::LoweredSdf;
use crate::sdf::simplify::{Simplifier, Specialised, Verdict};
use crate::sdf::ssa::SsaTape;
use crate::sdf::tape::{Registers, Tape};
use glam::Vec3;
use rayon::prelude::*;
use rustc_hash::{FxHashMap as HashMap, FxHashSet};
use std::mem::MaybeUninit;

/// Deepest subdivision: cells of 1/256 of the box along each axis.
pub const MAX_DEPTH: u32 = 8;

/// Most nodes per object (4 bytes each, plus a 40-byte [`Leaf`] per leaf): 88 MiB at most.
pub const MAX_NODES: usize = 1 << 21;

/// Most bytes of native code per object ([`compile_native`]): 64 MiB, room for
/// about 3 M instructions at the measured 20 bytes each (a 1,000-box union's octree takes 52
/// MiB). Tapes past it are interpreted.
pub const NATIVE_CODE_BYTES: usize = 64 << 20;

/// Most instructions over an object's distinct specialised tapes (8 bytes each): 128 MiB.
pub const MAX_INSTRUCTIONS: usize = 1 << 24;

/// The unit of the split rule's tape lengths: a tape of fewer than two of it is never split
/// ([`MIN_SPLIT_TAPE`]), and one of four or more splits for a quarter of it saved (`propose`).
pub const MIN_TAPE: usize = 12;

/// Tapes shorter than this are not split at all, not even in the top levels: below them only
/// a tape of at least this length can gain a split (see `propose`), so the top levels of a
/// shorter one would only sort its boxes into empty, full and crossed, and on a tape this
/// short that saved no measurable time. It cost the build: 10,000 small objects (spheres,
/// rotated boxes, tori, capsules of 4 to 22 instructions, `hytrace generate`) took 7.4 s to
/// build their octrees of up to 489 nodes, 77 ms as single leaves, with frames the same
/// (63–65 ms at 640×360), as were the shipped scenes' (BENCHMARKS.md, "Many small objects").
pub const MIN_SPLIT_TAPE: usize = 2 * MIN_TAPE;

/// Levels split regardless of what their children gain (for tapes of at least
/// [`MIN_SPLIT_TAPE`] instructions).
pub const CULL_DEPTH: u32 = 3;

/// Relative amount by which [`Leaf::fall`] rounds its bound up (four ulps: the three products
/// and two sums before it each round once).
pub const FALL_ROUNDING: f32 = 4.0 * f32::EPSILON;

/// One leaf: its tapes, what its box holds, and enclosures of the field and its gradient there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Leaf {
    /// Index into [`FieldOctree::tapes`]: the distance tape.
    pub tape: u32,
    /// Index into [`FieldOctree::shading`]: distance and blended material.
    pub shading: u32,
    /// Empty, full or crossed.
    pub verdict: Verdict,
    /// Enclosures of ∂f/∂x, ∂f/∂y, ∂f/∂z over the box (lower then upper ends), for crossed
    /// leaves whose field intervals can differentiate; the whole line otherwise.
    pub gradient: [[f32; 3]; 2],
    /// A lower bound on f over the box (the interval enclosure's lower end).
    pub min_value: f32,
}

impl Leaf {
    /// How fast the field may fall along the unit direction d inside the leaf
    /// ([`fall_along`] its gradient enclosure).
    #[inline]
    pub fn fall(&self, d: Vec3) -> f32 {
        fall_along(&self.gradient, d)
    }

    /// [`Self::fall`] computed as written ([`fall_along_reference`]).
    #[inline]
    pub fn fall_reference(&self, d: Vec3) -> f32 {
        fall_along_reference(&self.gradient, d)
    }
}

/// How fast a field may fall along the unit direction d where its gradient lies in the
/// enclosure `gradient` (lower then upper ends): the largest −d·g over it, at least 0 (1, the
/// global bound, without one: [`ANY_GRADIENT`]).
///
/// Computed without arithmetic on subnormal numbers where that gives the same bits: the
/// interval enclosures round outward, so an axis along which the field does not vary (a
/// plane's tangents) has bounds of ±2⁻¹⁴⁹, and every multiplication or addition with a
/// subnormal operand costs the CPU a microcode assist of ~150 cycles — most of a march's
/// time on a ground plane. Such an axis's term, below 2⁻¹²⁶ in magnitude, leaves a sum with
/// a term above [`NEGLIGIBLE_NEXT_TO`] unchanged ([`fall_along_reference`] otherwise).
#[inline]
pub fn fall_along(gradient: &[[f32; 3]; 2], d: Vec3) -> f32 {
    if gradient[0][0] == f32::NEG_INFINITY {
        return 1.0;
    }
    let [g0, g1] = *gradient;
    // an axis whose bounds are subnormal or zero, at least one subnormal
    let flat = |a: usize| {
        (g0[a].is_subnormal() || g1[a].is_subnormal())
            && g0[a].abs() < f32::MIN_POSITIVE
            && g1[a].abs() < f32::MIN_POSITIVE
    };
    let (fx, fy, fz) = (flat(0), flat(1), flat(2));
    if !(fx || fy || fz) || !d.is_finite() || d.abs().max_element() > MAX_FLAT_DIRECTION {
        return fall_along_reference(gradient, d);
    }
    // glam's min, as the reference takes it (it decides the sign of a zero)
    let term = |a: usize| {
        let (lo, hi) = (g0[a] * d[a], g1[a] * d[a]);
        if lo < hi { lo } else { hi }
    };
    let big = |v: f32| v.abs() >= NEGLIGIBLE_NEXT_TO;
    // The reference's (x + y) + z with each sum of a flat term and a big one replaced by
    // the big one; `None` where that does not settle the bits. A flat term is below 2⁻⁹⁶,
    // two of them below 2⁻⁹⁵.
    let sum = match (fx, fy, fz) {
        (false, false, _) => {
            let xy = term(0) + term(1);
            if fz {
                big(xy).then_some(xy)
            } else {
                Some(xy + term(2))
            }
        }
        (true, false, _) | (false, true, _) => {
            let other = if fx { term(1) } else { term(0) };
            match (big(other), fz) {
                (false, _) => None,
                (true, false) => Some(other + term(2)),
                (true, true) => Some(other),
            }
        }
        (true, true, false) => Some(term(2)).filter(|&z| big(z)),
        (true, true, true) => None,
    };
    match sum {
        Some(sum) => {
            let f = -sum;
            (f + f.abs() * FALL_ROUNDING).max(0.0)
        }
        None => fall_along_reference(gradient, d),
    }
}

/// [`fall_along`] computed as written: −min over the enclosure of d·g, rounded up so that the
/// bound may only grow.
#[inline]
pub fn fall_along_reference(gradient: &[[f32; 3]; 2], d: Vec3) -> f32 {
    if gradient[0][0] == f32::NEG_INFINITY {
        return 1.0;
    }
    let lo = Vec3::from_array(gradient[0]) * d;
    let hi = Vec3::from_array(gradient[1]) * d;
    let f = -lo.min(hi).element_sum();
    (f + f.abs() * FALL_ROUNDING).max(0.0)
}

/// Largest direction component for which [`Leaf::fall`] drops flat axes: their terms are then
/// below 2⁻¹²⁶ · 2³⁰ = 2⁻⁹⁶.
const MAX_FLAT_DIRECTION: f32 = (1u64 << 30) as f32;

/// A term at least this large (2⁻⁶⁰) absorbs one below 2⁻⁹⁶ exactly: its ulp is at least
/// 2⁻⁸³, and round-to-nearest discards anything under half an ulp.
const NEGLIGIBLE_NEXT_TO: f32 = 1.0 / (1u64 << 60) as f32;

// The memory bound above counts 40 bytes per leaf.
const _: () = assert!(std::mem::size_of::<Leaf>() == 40);

/// A located leaf with its box.
#[derive(Debug, Clone, Copy)]
pub struct Cell<'a> {
    /// The leaf.
    pub leaf: &'a Leaf,
    /// Box minimum.
    pub lo: Vec3,
    /// Box maximum.
    pub hi: Vec3,
    /// The distance tape to evaluate inside the box.
    pub tape: &'a Tape,
    /// The shading tape of the box.
    pub shading: &'a Tape,
}

impl Cell<'_> {
    /// Whether p lies in the box (closed).
    #[inline]
    pub fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.lo).all() && p.cmple(self.hi).all()
    }

    /// Whether [`FieldOctree::locate`] may answer this box for p without descending from the
    /// root: p in the box, half open above as the descent splits (a point on a face between
    /// two leaves belongs to the upper one). A cached leaf that merely touches p would give a
    /// point's tape by history, and a ray's answer would then depend on what was looked up
    /// before; this way the tape at a point is a function of the point.
    #[inline]
    pub fn owns(&self, p: Vec3) -> bool {
        p.cmpge(self.lo).all() && p.cmplt(self.hi).all()
    }

    /// Where the ray leaves the box (the far end of its slab interval).
    #[inline]
    pub fn exit(&self, ray: &Ray, inv_dir: Vec3) -> f32 {
        let t0 = (self.lo - ray.origin) * inv_dir;
        let t1 = (self.hi - ray.origin) * inv_dir;
        let far = t0.max(t1);
        // a zero direction component gives ±∞ or NaN (0·∞): it does not bound the exit
        let far = Vec3::select(far.is_nan_mask(), Vec3::INFINITY, far);
        far.min_element()
    }
}

/// One node of a lookup path, with its box.
#[derive(Debug, Clone, Copy)]
struct PathEntry {
    node: Node,
    lo: Vec3,
    hi: Vec3,
}

impl PathEntry {
    /// Whether the descent from the root to p passes this node (half open above, as
    /// [`Cell::owns`]; the root's own box is checked closed apart).
    #[inline]
    fn holds(&self, p: Vec3) -> bool {
        p.cmpge(self.lo).all() && p.cmplt(self.hi).all()
    }
}

/// The nodes from the root to the last leaf found, for [`FieldOctree::locate_along`]. Only
/// the first `len` entries are written: a cursor is made for every query, most never look a
/// point up, and zeroing 250 bytes for each showed in profiles.
#[derive(Debug, Clone, Copy)]
pub struct Path {
    entries: [MaybeUninit<PathEntry>; MAX_DEPTH as usize + 1],
    len: usize,
}

impl Default for Path {
    #[inline]
    fn default() -> Self {
        Path {
            entries: [MaybeUninit::uninit(); MAX_DEPTH as usize + 1],
            len: 0,
        }
    }
}

impl Path {
    #[inline]
    fn top(&self) -> &PathEntry {
        assert!(self.len > 0, "an empty path has no top");
        // SAFETY: entries below `len` are written (`set` is the only writer of `len`).
        unsafe { self.entries[self.len - 1].assume_init_ref() }
    }

    /// Writes entry i and keeps the entries below it: the path is then i + 1 long.
    #[inline]
    fn set(&mut self, i: usize, e: PathEntry) {
        assert!(i <= self.len, "a path grows one entry at a time");
        self.entries[i] = MaybeUninit::new(e);
        self.len = i + 1;
    }
}

/// A node: the first of its eight children, or (top bit set) a leaf.
#[derive(Debug, Clone, Copy, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(transparent)]
struct Node(u32);

/// The bit of a raw node that marks a leaf ([`FieldOctree::raw_nodes`]).
pub const LEAF: u32 = 1 << 31;
const LEAF_BIT: u32 = LEAF;

/// The bit of a raw leaf node whose box is proven empty ([`FieldOctree::raw_nodes`]): a march
/// passes such a leaf without reading its record. Most leaves a ray crosses are empty (on a
/// union of 400 spheres, 7.7 of the 8.9 a camera ray meets), and their records, spread over
/// a megabyte, were loaded only to be passed.
pub const EMPTY_LEAF: u32 = 1 << 30;

impl Node {
    /// The leaf node of leaf `index`, marked when its box is empty.
    fn leaf(index: usize, verdict: Verdict) -> Node {
        let empty = if verdict == Verdict::Empty {
            EMPTY_LEAF
        } else {
            0
        };
        Node(LEAF_BIT | empty | index as u32)
    }

    /// Whether the node is a leaf.
    #[inline]
    fn is_leaf(self) -> bool {
        self.0 & LEAF_BIT != 0
    }

    /// A leaf node's leaf.
    #[inline]
    fn leaf_index(self) -> usize {
        (self.0 & !(LEAF_BIT | EMPTY_LEAF)) as usize
    }
}

/// The octree of one object.
#[derive(Debug, Clone)]
pub struct FieldOctree {
    lo: Vec3,
    hi: Vec3,
    nodes: Vec<Node>,
    leaves: Vec<Leaf>,
    /// Distinct specialised distance tapes.
    pub tapes: Vec<Tape>,
    /// Distinct specialised shading tapes.
    pub shading: Vec<Tape>,
    /// Instructions of the whole tape the leaves came from.
    pub whole_len: usize,
    /// Whether Hart's march takes the whole tape rather than these leaves
    /// ([`Self::marched_whole`]).
    marched_whole: bool,
}

/// Sizes of a built octree (for `hytrace info` and the bench).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct OctreeStats {
    /// Nodes, leaves included.
    pub nodes: usize,
    /// Leaves.
    pub leaves: usize,
    /// Leaves proven empty.
    pub empty: usize,
    /// Leaves proven full.
    pub full: usize,
    /// Distinct distance tapes.
    pub tapes: usize,
    /// Instructions over the distinct distance and shading tapes.
    pub instructions: usize,
    /// Mean instructions of a crossed leaf's tape.
    pub mean_surface_tape: f64,
    /// Bytes held.
    pub bytes: usize,
    /// Bytes of native code of the tapes ([`compile_native`]).
    pub native_bytes: usize,
}

struct LeafBuild {
    tape: Tape,
    /// The shading tape of a crossed leaf (hits lie there; others use the whole one).
    shading: Option<Tape>,
    verdict: Verdict,
    gradient: [[f32; 3]; 2],
    min_value: f32,
}

/// What the tree may still spend: nodes, and instructions not yet stored or reserved.
///
/// A split reserves what its children's tapes may take (distance and shading, each as long
/// as the child's program) for the children whose programs are not stored or reserved
/// already: identical programs make identical tapes, stored once (counting every leaf spent
/// the budget of a 1,000-box union on duplicates). A leaf, when stored, gives its reservation
/// back and is charged the instructions it adds. Within one subtree: subtrees built in
/// parallel count apart, so they do not wait on each other.
#[derive(Debug, Default)]
struct Budget {
    nodes: usize,
    instructions: i64,
    /// Hashes of the programs stored or reserved.
    programs: FxHashSet<u64>,
}

impl Budget {
    /// Reserves the nodes and instructions of splitting a box into `children`, if they are
    /// left; the children's reservations (0 for a program seen before) in `reserved`.
    fn take(&mut self, children: &[Specialised; 8], reserved: &mut [usize; 8]) -> bool {
        let mut fresh: Vec<u64> = Vec::with_capacity(8);
        let mut more = 0;
        for (k, r) in children.iter().zip(reserved.iter_mut()) {
            let key = program_key(&k.program);
            *r = 0;
            if !self.programs.contains(&key) && !fresh.contains(&key) {
                fresh.push(key);
                *r = 2 * k.len;
                more += *r;
            }
        }
        if self.nodes < 8 || self.instructions < more as i64 {
            return false;
        }
        self.nodes -= 8;
        self.instructions -= more as i64;
        self.programs.extend(fresh);
        true
    }
}

/// A hash of a program's operations and results.
fn program_key(program: &SsaTape) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = rustc_hash::FxHasher::default();
    program.ops.hash(&mut h);
    program.result.hash(&mut h);
    program.material.hash(&mut h);
    h.finish()
}

/// A box whose split is being decided: its specialised program and where it sits.
struct Candidate {
    sp: Specialised,
    lo: Vec3,
    hi: Vec3,
    slot: usize,
    /// The instructions reserved for its tapes.
    reserved: usize,
}

/// Levels split before the subtrees below them are built in parallel (64 boxes). Boxes
/// there are split whenever they may be ([`CULL_DEPTH`] is deeper).
const PARALLEL_DEPTH: u32 = 2;
const _: () = assert!(PARALLEL_DEPTH <= CULL_DEPTH);

/// What a level's look-ahead made of a candidate.
enum Proposal {
    /// It stays a leaf.
    Leaf(Candidate),
    /// Its children are empty (or full) all: one leaf with their verdict.
    Uniform(Candidate, Verdict),
    /// It gains from a split into these children.
    Split(Candidate, Box<[Specialised; 8]>),
}

impl FieldOctree {
    /// Builds the octree of `program` (an object's shading program) over `region`; `None`
    /// for an empty or unbounded region. A short tape gets a single leaf: its gradient bound
    /// still shortens the steps (to one step on a plane).
    pub fn build(program: &SsaTape, region: Aabb) -> Option<FieldOctree> {
        Self::build_shared(program, region, 1.0, Keep::Every)
    }

    /// [`Self::build`] within `share` (in (0, 1]) of an object's budget of nodes and
    /// instructions: the part of an object split into several ([`ObjectField::build_shared`]).
    pub fn build_shared(
        program: &SsaTape,
        region: Aabb,
        share: f64,
        keep: Keep,
    ) -> Option<FieldOctree> {
        if !region.min.is_finite() || !region.max.is_finite() || region.is_empty() {
            return None;
        }
        // A little room around the bounds, so that surface points on them are inside.
        let pad = 1e-4 * (region.max - region.min).max_element() + 1e-6;
        let (lo, hi) = (region.min - Vec3::splat(pad), region.max + Vec3::splat(pad));
        let of = |budget: usize| ((budget as f64 * share.clamp(0.0, 1.0)) as usize).max(1);
        Some(Self::build_within(
            program,
            lo,
            hi,
            of(MAX_NODES),
            of(MAX_INSTRUCTIONS),
            keep,
        ))
    }

    /// The tree over [lo, hi] within `nodes` nodes and `instructions` instructions (the whole
    /// shading tape, stored for the leaves that are not crossed, counted against them); with
    /// [`Keep::Walked`], one leaf where Hart's march would take the whole tape
    /// ([`Self::marched_whole`]), known before the build from sampled surface cells
    /// ([`surface_sample_tape`]) or after it.
    ///
    /// The top [`PARALLEL_DEPTH`] levels are split first (they always are: see
    /// [`CULL_DEPTH`]), the budget shared among their boxes in proportion to their tapes;
    /// each box's subtree is then built on one thread, level by level ([`build_subtree`]),
    /// and the subtrees are stored in box order, so the tree does not depend on the thread
    /// count.
    fn build_within(
        program: &SsaTape,
        lo: Vec3,
        hi: Vec3,
        nodes: usize,
        instructions: usize,
        keep: Keep,
    ) -> FieldOctree {
        if keep == Keep::Every {
            return Self::grow(program, lo, hi, nodes, instructions);
        }
        let whole_len = program.distance_only().live_len();
        if (MIN_SPLIT_TAPE..=SHORT_TAPE).contains(&whole_len)
            && surface_sample_tape(program, lo, hi)
                .is_some_and(|kept| kept >= SAMPLED_WHOLE * whole_len as f64)
        {
            return Self::grow(program, lo, hi, 1, instructions);
        }
        let tree = Self::grow(program, lo, hi, nodes, instructions);
        if tree.marched_whole && tree.nodes.len() > 1 {
            // (one leaf, as a short tape gets: see `Keep::Walked`)
            return Self::grow(program, lo, hi, 1, instructions);
        }
        tree
    }

    /// [`Self::build_within`] whatever its march takes.
    fn grow(
        program: &SsaTape,
        lo: Vec3,
        hi: Vec3,
        nodes: usize,
        instructions: usize,
    ) -> FieldOctree {
        let mut tree = FieldOctree {
            lo,
            hi,
            nodes: vec![Node(0)],
            leaves: Vec::new(),
            tapes: Vec::new(),
            shading: Vec::new(),
            whole_len: program.distance_only().live_len(),
            marched_whole: false,
        };
        let mut dedup = [Dedup::default(), Dedup::default()];
        // shading tape 0 is the whole one, for the leaves that are not crossed (stored
        // whatever the budget: without it no leaf could be shaded)
        let whole_shading = program
            .compile()
            .expect("the source program compiles (it was lowered)");
        let (_, added) = dedup[1].add(&mut tree.shading, whole_shading);
        let root = Job {
            sp: Simplifier::new().specialise(program, lo, hi),
            lo,
            hi,
            depth: 0,
            nodes: nodes.saturating_sub(1),
            instructions: instructions.saturating_sub(added),
        };
        tree.store_top(build_top(root), 0, &mut dedup);
        tree.marched_whole =
            tree.whole_len <= SHORT_TAPE && 2.0 * tree.mean_surface_tape() >= tree.whole_len as f64;
        tree
    }

    /// Whether Hart's march (on both backends) takes the whole tape over the octree's box
    /// rather than walking these leaves: when the whole tape is short ([`SHORT_TAPE`]) and
    /// the crossed leaves' tapes keep at least half of its instructions on average.
    ///
    /// Every leaf a ray enters costs a step of the walk, a new part and, in a bundle, a new
    /// round (the lane leaves the pass that steps it again at once); a ray leaving a surface
    /// crosses many small leaves in a few short steps each. Where the leaves save less than
    /// half of the instructions, the CPU's frames of the shipped scenes took 5–25 % less
    /// time marched whole (the whole tape's steps are bounded by the object's gradient
    /// enclosure over all of space, so a plane is still reached in one step). Where they
    /// save more — fidget's gyroid sphere, whose leaves drop the sphere and the box around
    /// the gyroid: 19 of 41 instructions — the GPU, whose steps cost their instructions,
    /// took 40 % longer marched whole, and the CPU 4–12 %.
    #[inline]
    pub fn marched_whole(&self) -> bool {
        self.marched_whole
    }

    /// Mean instructions of a crossed leaf's distance tape (0 without crossed leaves).
    fn mean_surface_tape(&self) -> f64 {
        let (mut count, mut sum) = (0usize, 0usize);
        for leaf in self.leaves.iter().filter(|l| l.verdict == Verdict::Surface) {
            count += 1;
            sum += self.tapes[leaf.tape as usize].len();
        }
        if count == 0 {
            0.0
        } else {
            sum as f64 / count as f64
        }
    }

    /// Stores the top of a tree at node `slot`: its splits as inner nodes, its subtrees
    /// grafted below them, in octant order.
    fn store_top(&mut self, top: Top, slot: usize, dedup: &mut [Dedup; 2]) {
        match top {
            Top::Subtree(sub) => self.graft(slot, sub, dedup),
            Top::Split(children) => {
                let first = self.nodes.len();
                self.nodes[slot] = Node(first as u32);
                self.nodes.extend(std::iter::repeat_n(Node(0), 8));
                for (i, child) in children.into_iter().enumerate() {
                    self.store_top(child, first + i, dedup);
                }
            }
        }
    }

    /// Stores a subtree built apart at node `slot`: the nodes reachable from its root after
    /// the tree's (children still together), the tapes they use merged with the tree's.
    fn graft(&mut self, slot: usize, sub: SubTree, dedup: &mut [Dedup; 2]) {
        let mut tapes: Vec<Option<Tape>> = sub.tapes.into_iter().map(Some).collect();
        let mut shading: Vec<Option<Tape>> = sub.shading.into_iter().map(Some).collect();
        let mut tape_at: Vec<u32> = vec![u32::MAX; tapes.len()];
        let mut shading_at: Vec<u32> = vec![u32::MAX; shading.len()];
        // (local node, its place in the tree)
        let mut todo = vec![(0usize, slot)];
        while let Some((local, at)) = todo.pop() {
            let n = sub.nodes[local].0;
            if n & LEAF_BIT == 0 {
                let first = self.nodes.len();
                self.nodes[at] = Node(first as u32);
                self.nodes.extend(std::iter::repeat_n(Node(0), 8));
                todo.extend((0..8).map(|i| (n as usize + i, first + i)));
                continue;
            }
            let l = sub.leaves[(n & !LEAF_BIT) as usize];
            let t = l.tape as usize;
            if tape_at[t] == u32::MAX {
                let tape = tapes[t].take().expect("each tape is merged once");
                tape_at[t] = dedup[0].add(&mut self.tapes, tape).0;
            }
            let shade = if l.shading == WHOLE_SHADING {
                0
            } else {
                let k = l.shading as usize;
                if shading_at[k] == u32::MAX {
                    let tape = shading[k].take().expect("each tape is merged once");
                    shading_at[k] = dedup[1].add(&mut self.shading, tape).0;
                }
                shading_at[k]
            };
            self.nodes[at] = Node::leaf(self.leaves.len(), l.verdict);
            self.leaves.push(Leaf {
                tape: tape_at[t],
                shading: shade,
                ..l
            });
        }
    }

    /// The box the tree covers.
    pub fn bounds(&self) -> Aabb {
        Aabb::new(self.lo, self.hi)
    }

    /// The nodes as stored, for backends that walk the tree themselves (the GPU): node 0 is
    /// the root; a node is the index of the first of its eight children (octant order: bit 0
    /// x, bit 1 y, bit 2 z, set for the upper half), or [`LEAF`] | a leaf index, with
    /// [`EMPTY_LEAF`] set too where the leaf's box is empty.
    pub fn raw_nodes(&self) -> &[u32] {
        bytemuck::cast_slice(&self.nodes)
    }

    /// The leaves, indexed by the nodes.
    pub fn leaves(&self) -> &[Leaf] {
        &self.leaves
    }

    /// Every leaf with its box, in node order (a walk of [`Self::raw_nodes`]).
    pub fn leaf_boxes(&self) -> Vec<(&Leaf, Aabb)> {
        let mut out = Vec::with_capacity(self.leaves.len());
        let mut todo = vec![(self.nodes[0], self.lo, self.hi)];
        while let Some((node, lo, hi)) = todo.pop() {
            if node.is_leaf() {
                out.push((&self.leaves[node.leaf_index()], Aabb::new(lo, hi)));
                continue;
            }
            let mid = 0.5 * (lo + hi);
            // pushed in reverse so that the walk visits octant 0 first
            for octant in (0..8u32).rev() {
                let up = glam::BVec3::new(octant & 1 != 0, octant & 2 != 0, octant & 4 != 0);
                todo.push((
                    self.nodes[node.0 as usize + octant as usize],
                    Vec3::select(up, mid, lo),
                    Vec3::select(up, hi, mid),
                ));
            }
        }
        out
    }

    /// The leaf holding p, with its box; `None` outside the tree's box.
    #[inline]
    pub fn locate(&self, p: Vec3) -> Option<Cell<'_>> {
        let mut path = Path::default();
        self.locate_along(p, &mut path)
    }

    /// [`Self::locate`] starting from the deepest node of `path` (the last lookup's) that
    /// holds p, and leaving the new path there: consecutive points of a ray mostly lie in one
    /// leaf or its neighbours, which share all but the last levels.
    #[inline]
    pub fn locate_along(&self, p: Vec3, path: &mut Path) -> Option<Cell<'_>> {
        while path.len > 1 && !path.top().holds(p) {
            path.len -= 1;
        }
        if path.len <= 1 {
            if !(p.cmpge(self.lo).all() && p.cmple(self.hi).all()) {
                path.len = 0;
                return None;
            }
            path.len = 0;
            path.set(
                0,
                PathEntry {
                    node: self.nodes[0],
                    lo: self.lo,
                    hi: self.hi,
                },
            );
        }
        let mut e = *path.top();
        while !e.node.is_leaf() {
            let mid = 0.5 * (e.lo + e.hi);
            let up = p.cmpge(mid);
            let octant = up.bitmask() as usize;
            e = PathEntry {
                node: self.nodes[e.node.0 as usize + octant],
                lo: Vec3::select(up, mid, e.lo),
                hi: Vec3::select(up, e.hi, mid),
            };
            path.set(path.len, e);
        }
        let leaf = &self.leaves[e.node.leaf_index()];
        Some(Cell {
            leaf,
            lo: e.lo,
            hi: e.hi,
            tape: &self.tapes[leaf.tape as usize],
            shading: &self.shading[leaf.shading as usize],
        })
    }

    /// Sizes.
    pub fn stats(&self) -> OctreeStats {
        let instructions: usize = self.tapes.iter().map(|t| t.len()).sum::<usize>()
            + self.shading.iter().map(|t| t.len()).sum::<usize>();
        let mean_surface_tape = self.mean_surface_tape();
        OctreeStats {
            nodes: self.nodes.len(),
            leaves: self.leaves.len(),
            empty: self
                .leaves
                .iter()
                .filter(|l| l.verdict == Verdict::Empty)
                .count(),
            full: self
                .leaves
                .iter()
                .filter(|l| l.verdict == Verdict::Full)
                .count(),
            tapes: self.tapes.len(),
            instructions,
            mean_surface_tape,
            bytes: self.nodes.len() * std::mem::size_of::<Node>()
                + self.leaves.len() * std::mem::size_of::<Leaf>()
                + instructions * 8,
            native_bytes: crate::sdf::jit::code_bytes(&self.tapes),
        }
    }
}

/// Identical tapes of one table stored once: instructions and result registers as the key.
#[derive(Default)]
struct Dedup {
    seen: HashMap<Vec<u8>, u32>,
}

impl Dedup {
    /// The instructions storing `tape` would add: 0 if it is stored already.
    fn cost(&self, tape: &Tape) -> usize {
        if self.seen.contains_key(&Self::key(tape)) {
            0
        } else {
            tape.len()
        }
    }

    fn key(tape: &Tape) -> Vec<u8> {
        let mut key: Vec<u8> = bytemuck::cast_slice(tape.instrs()).to_vec();
        key.push(tape.result());
        key.push(tape.material_result().unwrap_or(u8::MAX));
        key
    }

    /// The tape's index, and the instructions it added (0 for one stored before).
    fn add(&mut self, tapes: &mut Vec<Tape>, tape: Tape) -> (u32, usize) {
        let key = Self::key(&tape);
        let id = tapes.len() as u32;
        let mut added = 0;
        let index = *self.seen.entry(key).or_insert_with(|| {
            added = tape.len();
            tapes.push(tape);
            id
        });
        (index, added)
    }
}

/// The eight children of the box [lo, hi], in octant order (bit 0: x, 1: y, 2: z).
fn child_box(lo: Vec3, hi: Vec3, i: usize) -> (Vec3, Vec3) {
    let mid = 0.5 * (lo + hi);
    let up = glam::BVec3::new(i & 1 != 0, i & 2 != 0, i & 4 != 0);
    (Vec3::select(up, mid, lo), Vec3::select(up, hi, mid))
}

/// A gradient enclosure that says nothing.
pub const ANY_GRADIENT: [[f32; 3]; 2] = [[f32::NEG_INFINITY; 3], [f32::INFINITY; 3]];

/// The gradient enclosure of `program`'s field over all of space (intervals of ±∞ for the
/// coordinates; 0·∞ counts as 0, so a linear field's constant gradient comes out exact).
pub fn gradient_everywhere(program: &SsaTape) -> [[f32; 3]; 2] {
    Simplifier::new()
        .gradient(program, Vec3::NEG_INFINITY, Vec3::INFINITY)
        .map_or(ANY_GRADIENT, |g| [g.map(|d| d.lo), g.map(|d| d.hi)])
}

/// A leaf for a box whose program is specialised.
fn make_leaf(simplifier: &mut Simplifier, sp: &Specialised, lo: Vec3, hi: Vec3) -> LeafBuild {
    let surface = sp.verdict == Verdict::Surface;
    let gradient = surface
        .then(|| simplifier.gradient(&sp.program, lo, hi))
        .flatten()
        .map_or(ANY_GRADIENT, |g| [g.map(|d| d.lo), g.map(|d| d.hi)]);
    LeafBuild {
        tape: sp.program.compile_distance().expect(FITS),
        shading: surface.then(|| sp.program.compile().expect(FITS)),
        verdict: sp.verdict,
        gradient,
        min_value: sp.value.lo,
    }
}

const FITS: &str = "a specialised program needs no more registers than its source";

/// A leaf that is empty (or full) throughout, with `program`'s distance tape (valid over its
/// box) for the points that are evaluated there all the same.
fn uniform_leaf(program: &SsaTape, verdict: Verdict, min_value: f32) -> LeafBuild {
    LeafBuild {
        tape: program.compile_distance().expect(FITS),
        shading: None,
        verdict,
        gradient: ANY_GRADIENT,
        min_value,
    }
}

/// Leaves whose shading tape is the whole one, in a [`SubTree`] (stored as 0 in the tree).
const WHOLE_SHADING: u32 = u32::MAX;

/// Which octrees a build keeps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Keep {
    /// Every tree its rules build. Where Hart's march takes the whole tape
    /// ([`FieldOctree::marched_whole`]) the leaves still serve point evaluations: the GPU
    /// evaluates a leaf's tape for a hit's confirmation, its normal, a penumbra or AO sample
    /// (the CPU, the short whole tape), each step costing its instructions there.
    Every,
    /// Only the trees Hart's march walks: a tree it would march whole is one leaf, found
    /// before the build from sampled surface cells ([`surface_sample_tape`]) or after it.
    /// For scenes of many objects ([`MANY_MARCHED_WHOLE`]): 3,000 small CSG objects (a box
    /// less a sphere, ...) built 1.9 M nodes in 7.7 s and held 295 MiB of leaf tapes and 273
    /// MiB of their native code, for frames no faster on the CPU (BENCHMARKS.md, "Octrees
    /// whose march takes the whole tape"); as one leaf each, 0.8 s and 4.5 MiB.
    Walked,
}

/// Objects whose tapes could be marched whole (of [`MIN_SPLIT_TAPE`] to [`SHORT_TAPE`]
/// instructions) that a scene may hold before its build keeps only the trees Hart's march
/// walks ([`Keep::Walked`]): each other tree costs a few milliseconds and a few hundred KiB.
pub const MANY_MARCHED_WHOLE: usize = 64;

/// Grid points per axis at which [`surface_sample_tape`] looks for the surface.
const SAMPLE_GRID: usize = 9;

/// Most surface points [`surface_sample_tape`] specialises the program around.
const SAMPLE_POINTS: usize = 24;

/// The depth of the cells [`surface_sample_tape`] specialises the program to.
const SAMPLE_DEPTH: u32 = 6;

/// The share of the whole tape that the sampled cells' tapes ([`surface_sample_tape`]) keep
/// from which a tree is not built: its leaves would keep more than half of it, and Hart's
/// march would take the whole tape ([`FieldOctree::marched_whole`]).
const SAMPLED_WHOLE: f64 = 0.4;

/// The mean length of `program`'s distance tape specialised to cells of the octree over
/// [lo, hi] ([`SAMPLE_DEPTH`] levels down) that hold sampled surface points, or `None` when
/// fewer than eight points were found (a surface finer than the grid). The surface is found
/// where the whole tape changes sign along the edges of a coarse grid, and then by bisection.
///
/// A tree's crossed leaves are rarely finer than these cells, and keep about what they keep
/// or more: over the shipped scenes and the SDF peer's models, the trees whose leaves saved
/// more than half of the tape (walked by Hart's march) had cells keeping 22–29 % of it, those
/// marched whole 26–67 %, their leaves 1.0–2.4 times as long as the cells' tapes
/// (`sampled_cells_skip_only_trees_marched_whole` checks every one of them). Cells keeping
/// [`SAMPLED_WHOLE`] of it or more mark a tree not worth building; below, the tree is built
/// and its leaves decide. The samples cost 0.1–0.5 ms an object, the trees they spare 1–7
/// ms.
fn surface_sample_tape(program: &SsaTape, lo: Vec3, hi: Vec3) -> Option<f64> {
    let tape = program.compile_distance().ok()?;
    let n = SAMPLE_GRID;
    let at = |i: usize, j: usize, k: usize| {
        lo + (hi - lo) * Vec3::new(i as f32, j as f32, k as f32) / (n - 1) as f32
    };
    let mut values = vec![0.0f32; n * n * n];
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                values[(k * n + j) * n + i] = tape.eval(at(i, j, k));
            }
        }
    }
    let inside = |v: f32| v <= 0.0;
    // the grid edges whose ends the surface separates
    let mut edges: Vec<(Vec3, Vec3)> = Vec::new();
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let v = values[(k * n + j) * n + i];
                for (di, dj, dk) in [(1, 0, 0), (0, 1, 0), (0, 0, 1)] {
                    let (a, b, c) = (i + di, j + dj, k + dk);
                    if a < n && b < n && c < n {
                        let w = values[(c * n + b) * n + a];
                        if v.is_finite() && w.is_finite() && inside(v) != inside(w) {
                            edges.push((at(i, j, k), at(a, b, c)));
                        }
                    }
                }
            }
        }
    }
    let cells = (1u32 << SAMPLE_DEPTH) as f32;
    let size = (hi - lo) / cells;
    let mut simplifier = Simplifier::new();
    let (mut count, mut sum) = (0usize, 0usize);
    let step = edges.len().div_ceil(SAMPLE_POINTS).max(1);
    for &(mut a, mut b) in edges.iter().step_by(step) {
        let a_inside = inside(tape.eval(a));
        for _ in 0..12 {
            let m = 0.5 * (a + b);
            if inside(tape.eval(m)) == a_inside {
                a = m;
            } else {
                b = m;
            }
        }
        let p = 0.5 * (a + b);
        let cell = ((p - lo) / size)
            .floor()
            .clamp(Vec3::ZERO, Vec3::splat(cells - 1.0));
        let (clo, chi) = (lo + cell * size, lo + (cell + Vec3::ONE) * size);
        let sp = simplifier.specialise(program, clo, chi);
        if sp.verdict == Verdict::Surface {
            count += 1;
            sum += sp.program.compile_distance().ok()?.len();
        }
    }
    (count >= 8).then(|| sum as f64 / count as f64)
}

/// A box whose subtree is built on one thread, with what it may spend.
struct Job {
    sp: Specialised,
    lo: Vec3,
    hi: Vec3,
    depth: u32,
    nodes: usize,
    instructions: usize,
}

/// The top [`PARALLEL_DEPTH`] levels of a tree: boxes split regardless, and the subtrees below
/// them.
enum Top {
    Split(Vec<Top>),
    Subtree(SubTree),
}

/// The top of the tree of `job`'s box: split while above [`PARALLEL_DEPTH`] (the top levels
/// always are, see [`CULL_DEPTH`]), the budget shared among the children in proportion to
/// their tapes, the children built in parallel; below, one subtree per box. Each box's
/// children are specialised only when it is built, so few programs are alive at once (every
/// box of the second level holding its program cost a 100,000-sphere union 650 MB).
fn build_top(job: Job) -> Top {
    let splits = job.depth < PARALLEL_DEPTH
        && job.sp.verdict == Verdict::Surface
        && job.sp.len >= MIN_SPLIT_TAPE
        && job.nodes >= 8;
    if !splits {
        return Top::Subtree(build_subtree(job));
    }
    let mut simplifier = Simplifier::new();
    let children: Vec<Specialised> = (0..8)
        .map(|i| {
            let (clo, chi) = child_box(job.lo, job.hi, i);
            simplifier.specialise(&job.sp.program, clo, chi)
        })
        .collect();
    // Split whatever the children gain, but not past the budget: eight tapes where one was
    // afforded. A part of a union split into a thousand gets a thousandth of the object's
    // budget, and its top levels' 64 tapes of a few thousand instructions took 1.5 GB for a
    // union of 100,000 rotated boxes.
    let total = children.iter().map(|c| c.len).sum::<usize>();
    if total > job.instructions {
        return Top::Subtree(build_subtree(job));
    }
    drop(job.sp);
    let total = total.max(1) as u128;
    let nodes = (job.nodes - 8) / 8;
    let jobs: Vec<Job> = children
        .into_iter()
        .enumerate()
        .map(|(i, c)| {
            let (clo, chi) = child_box(job.lo, job.hi, i);
            let instructions = (job.instructions as u128 * c.len as u128 / total) as usize;
            Job {
                sp: c,
                lo: clo,
                hi: chi,
                depth: job.depth + 1,
                nodes,
                instructions,
            }
        })
        .collect();
    Top::Split(jobs.into_par_iter().map(build_top).collect())
}

/// A subtree built apart: nodes (0 its root) and leaves as in the tree, indexing its own
/// distinct tapes.
struct SubTree {
    nodes: Vec<Node>,
    leaves: Vec<Leaf>,
    tapes: Vec<Tape>,
    shading: Vec<Tape>,
}

/// The subtree of a job's box, built level by level into its node array (the root first,
/// each split's eight children appended together). Each level's candidates look one level
/// ahead: their children are specialised, and a box is split only if they gain (a subtree is
/// never built to be thrown away). The budget is given out level by level, coarse before
/// fine, the longest tapes first (they gain most from a split): when it runs out, the finest
/// level is missing throughout the subtree, not whole regions refined coarsely (as a
/// depth-first build leaves the octants it reaches last).
fn build_subtree(job: Job) -> SubTree {
    let mut sub = SubTree {
        nodes: vec![Node(0)],
        leaves: Vec::new(),
        tapes: Vec::new(),
        shading: Vec::new(),
    };
    let mut dedup = [Dedup::default(), Dedup::default()];
    let mut simplifier = Simplifier::new();
    let mut budget = Budget {
        nodes: job.nodes,
        instructions: job.instructions as i64,
        programs: FxHashSet::default(),
    };
    let reserved = 2 * job.sp.len;
    budget.instructions -= reserved as i64;
    budget.programs.insert(program_key(&job.sp.program));
    let mut level = vec![Candidate {
        sp: job.sp,
        lo: job.lo,
        hi: job.hi,
        slot: 0,
        reserved,
    }];
    let mut depth = job.depth;
    // the programs of the boxes split, for the leaf a box becomes if its children all turn
    // out empty (or full)
    let mut programs: HashMap<usize, SsaTape> = HashMap::default();
    while !level.is_empty() {
        let mut proposals: Vec<Proposal> = level
            .into_iter()
            .map(|c| propose(c, depth, budget.nodes >= 8, &mut simplifier))
            .collect();
        // Longest tapes first; ties in node order (the order of the boxes).
        proposals.sort_by_key(|p| match p {
            Proposal::Split(c, _) => (std::cmp::Reverse(c.sp.len), c.slot),
            Proposal::Leaf(c) | Proposal::Uniform(c, _) => (std::cmp::Reverse(0), c.slot),
        });
        let mut leaves = Vec::new();
        let mut next = Vec::new();
        let mut reserved = [0; 8];
        for proposal in proposals {
            match proposal {
                Proposal::Split(c, children) if budget.take(&children, &mut reserved) => {
                    // its own tapes will not be stored
                    budget.instructions += c.reserved as i64;
                    let first = sub.nodes.len();
                    sub.nodes[c.slot] = Node(first as u32);
                    programs.insert(c.slot, c.sp.program);
                    sub.nodes.extend(std::iter::repeat_n(Node(0), 8));
                    for (i, k) in (*children).into_iter().enumerate() {
                        let (clo, chi) = child_box(c.lo, c.hi, i);
                        next.push(Candidate {
                            sp: k,
                            lo: clo,
                            hi: chi,
                            slot: first + i,
                            reserved: reserved[i],
                        });
                    }
                }
                Proposal::Split(c, _) | Proposal::Leaf(c) => leaves.push((c, None)),
                Proposal::Uniform(c, verdict) => leaves.push((c, Some(verdict))),
            }
        }
        leaves.sort_by_key(|(c, _)| c.slot);
        for (c, uniform) in leaves {
            let leaf = match uniform {
                Some(verdict) => uniform_leaf(&c.sp.program, verdict, c.sp.value.lo),
                None => make_leaf(&mut simplifier, &c.sp, c.lo, c.hi),
            };
            let (tape, added) = dedup[0].add(&mut sub.tapes, leaf.tape);
            let (shading, shading_added) = match leaf.shading {
                Some(s) => dedup[1].add(&mut sub.shading, s),
                None => (WHOLE_SHADING, 0),
            };
            budget.instructions += c.reserved as i64 - (added + shading_added) as i64;
            sub.nodes[c.slot] = Node(LEAF_BIT | sub.leaves.len() as u32);
            sub.leaves.push(Leaf {
                tape,
                shading,
                verdict: leaf.verdict,
                gradient: leaf.gradient,
                min_value: leaf.min_value,
            });
        }
        next.sort_by_key(|c| c.slot);
        level = next;
        depth += 1;
    }
    // Eight empty (or eight full) leaves are one: a ray passes the box at once. Bottom up
    // (children come after their parents), while the budget pays for the box's tape.
    for slot in (0..sub.nodes.len()).rev() {
        let first = sub.nodes[slot].0;
        if first & LEAF_BIT != 0 || !programs.contains_key(&slot) {
            continue;
        }
        let children: Vec<&Leaf> = (0..8)
            .map_while(|i| {
                let n = sub.nodes[first as usize + i].0;
                (n & LEAF_BIT != 0).then(|| &sub.leaves[(n & !LEAF_BIT) as usize])
            })
            .collect();
        let Some(kind) = children.first().map(|l| l.verdict) else {
            continue;
        };
        if children.len() < 8
            || kind == Verdict::Surface
            || children.iter().any(|l| l.verdict != kind)
        {
            continue;
        }
        let min_value = children
            .iter()
            .map(|l| l.min_value)
            .fold(f32::INFINITY, f32::min);
        let leaf = uniform_leaf(&programs[&slot], kind, min_value);
        if dedup[0].cost(&leaf.tape) as i64 > budget.instructions {
            continue;
        }
        let (tape, added) = dedup[0].add(&mut sub.tapes, leaf.tape);
        budget.instructions -= added as i64;
        sub.nodes[slot] = Node(LEAF_BIT | sub.leaves.len() as u32);
        sub.leaves.push(Leaf {
            tape,
            shading: WHOLE_SHADING,
            verdict: kind,
            gradient: leaf.gradient,
            min_value,
        });
    }
    sub
}

/// Whether a candidate box at `depth` gains from a split, from its children's tapes. Without
/// `room` in the budget for them, none are made: the box could only become a leaf, and their
/// eight specialisations would at most find it empty or full throughout (a tree asked to be
/// one leaf, [`FieldOctree::build_within`], spends none).
fn propose(c: Candidate, depth: u32, room: bool, simplifier: &mut Simplifier) -> Proposal {
    let len = c.sp.len;
    if !room || c.sp.verdict != Verdict::Surface || depth >= MAX_DEPTH || len < MIN_SPLIT_TAPE {
        return Proposal::Leaf(c);
    }
    let children: [Specialised; 8] = std::array::from_fn(|i| {
        let (clo, chi) = child_box(c.lo, c.hi, i);
        simplifier.specialise(&c.sp.program, clo, chi)
    });
    // Eight empty (or eight full) children are one leaf: a ray passes the box at once.
    for kind in [Verdict::Empty, Verdict::Full] {
        if children.iter().all(|k| k.verdict == kind) {
            return Proposal::Uniform(c, kind);
        }
    }
    // Splitting pays when the crossed children's tapes are markedly shorter on average and
    // this tape is long (one short child is not enough, nor a few instructions saved: near a
    // crease between two shapes, or where two branches of a max trade places, a shorter
    // child always exists, and the refinement would follow that surface to the finest
    // level), or near the top when a child is empty or full; otherwise the children evaluate
    // what this box would, and the split only costs lookups. A quarter off a long tape, or
    // half off a middling one, is worth a level of lookups and leaf changes; less is not (a
    // 20-instruction tape costs ~30 ns, a leaf change ~20).
    let crossed: Vec<usize> = children
        .iter()
        .filter(|k| k.verdict == Verdict::Surface)
        .map(|k| k.len)
        .collect();
    let (n, total) = (crossed.len(), crossed.iter().sum::<usize>());
    let shorter =
        n > 0 && ((len >= 4 * MIN_TAPE && 4 * total <= 3 * n * len) || 2 * total <= n * len);
    // The top levels split regardless: intervals over large boxes decide little (a union
    // folded one shape at a time keeps every shape over an eighth of a spiral of spheres),
    // and their children would not show the gain their grandchildren have.
    if shorter || depth < CULL_DEPTH {
        Proposal::Split(c, Box::new(children))
    } else {
        Proposal::Leaf(c)
    }
}

/// An error model of the values a tape computes: within `relative`·(`scale` + |p|∞) of the
/// exact function at p, |p|∞ the point's largest coordinate. Each operation rounds to half
/// a unit in the last place of its result; on quantities no larger than the point's
/// coordinates and the tape's constants (true of the shapes, transforms and maxima a convex
/// field is made of: [`crate::sdf::SdfNode::is_convex`]), the errors of a chain of n of them
/// add up to n/2 units of the largest, and the model allows n/2 + 4 (the point itself is
/// computed as o + t·d, a few units off the ray). Tested against dense samples in
/// `src/trace/sphere.rs`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoundingModel {
    /// The error per unit of magnitude.
    pub relative: f32,
    /// 1 + the largest constant of the tape.
    pub scale: f32,
}

impl RoundingModel {
    /// The model of `tape`'s values.
    pub fn of(tape: &Tape) -> Self {
        RoundingModel {
            relative: (4.0 + 0.5 * tape.len() as f32) * f32::EPSILON,
            scale: 1.0 + tape.largest_constant(),
        }
    }

    /// The largest error of a value computed at a point whose coordinates are at most
    /// `reach` in magnitude.
    pub fn error(&self, reach: f32) -> f32 {
        self.relative * (self.scale + reach)
    }
}

/// Whole tapes at most this long are evaluated as they are where only the field's value at a
/// few points per ray is wanted — penumbra samples, the normal's stencil, a candidate hit's
/// confirmation, ambient occlusion — without finding each point's leaf: a leaf's tape equals
/// the whole tape at every point of the leaf, bit for bit (tests/evaluators.rs), and a walk
/// set up per ray, or a descent per point, costs more than the instructions the leaf drops.
/// Measured on 640×360 CPU frames (`examples/frame_time`, penumbra samples alone): a
/// 16-instruction ground 7 % of a hybrid.ron frame, a 235-instruction union of 40 spheres
/// 12 % of its frame, 900 instructions even, 2,300 the leaves 15 % faster. Hart's march takes
/// the whole tape too where the leaves save less than half of it
/// ([`FieldOctree::marched_whole`]).
pub const SHORT_TAPE: usize = 256;

/// An evaluation cursor over an object's field: the last leaf found, so that consecutive
/// points in one box skip the descent, and the interpreter's registers.
pub struct FieldCursor<'f, 'r> {
    octree: Option<&'f FieldOctree>,
    whole: &'f Tape,
    cell: Option<Cell<'f>>,
    path: Path,
    convex: Option<RoundingModel>,
    outside: &'f [[f32; 3]; 2],
    /// Scalar registers.
    pub regs: &'r mut Registers,
}

/// An object's field: its octree where one pays, and its whole tapes.
#[derive(Debug, Clone)]
pub struct ObjectField {
    /// The octree, if built.
    pub octree: Option<FieldOctree>,
    /// The whole distance tape (outside the octree, or without one).
    pub whole: Tape,
    /// The whole shading tape.
    pub whole_shading: Tape,
    /// For a convex field ([`crate::sdf::SdfNode::is_convex`]), the error model of its whole
    /// tape's values (the leaves' tapes compute the same values); `None` otherwise.
    pub convex: Option<RoundingModel>,
    /// Enclosures of the field's gradient everywhere, for the steps outside the octree
    /// ([`fall_along`]): exact on a plane, whose field falls along a ray by the cosine of its
    /// angle to the normal, so that a camera ray reaches the ground beyond the tree in one
    /// step where Hart's steps shrink geometrically towards it; [`ANY_GRADIENT`] where
    /// intervals over all of space say nothing.
    pub outside: [[f32; 3]; 2],
    /// For a convex field whose gradient enclosure over all of space is at most
    /// [`NEARLY_LINEAR`] wide (a plane), that enclosure widened to at least [`FLAT_BOUND`] in
    /// magnitude where it is smaller: a ray's least slope is then computed without subnormal
    /// products (each one a microcode assist), and it only becomes more cautious. `None`
    /// otherwise: a wider enclosure (a slab's holds both its normals, a sphere's the unit
    /// cube) bounds a ray's fall by about its length, which rarely tells a march's answer
    /// from its first sample, and the sample would cost every ray that asks.
    pub slopes: Option<[[f32; 3]; 2]>,
}

/// The widest gradient enclosure, per axis, that [`ObjectField::slopes`] keeps.
pub const NEARLY_LINEAR: f32 = 1.0 / 1024.0;

/// The magnitude [`ObjectField::slopes`] widens the bounds of a flat axis to.
pub const FLAT_BOUND: f32 = 1e-30;

/// `gradient` widened outwards past subnormal bounds ([`ObjectField::slopes`]), if it is
/// finite and narrow.
fn slopes_of(gradient: [[f32; 3]; 2]) -> Option<[[f32; 3]; 2]> {
    let narrow = (0..3).all(|a| gradient[1][a] - gradient[0][a] <= NEARLY_LINEAR);
    let finite = gradient.iter().flatten().all(|g| g.is_finite());
    (finite && narrow).then(|| {
        let [lo, hi] = gradient;
        let tiny = |g: f32| g.abs() < FLAT_BOUND;
        [
            lo.map(|g| if tiny(g) { -FLAT_BOUND } else { g }),
            hi.map(|g| if tiny(g) { FLAT_BOUND } else { g }),
        ]
    })
}

/// What the tracer needs to know about the region around a point.
#[derive(Debug, Clone, Copy)]
pub struct Region<'a> {
    /// The tape valid there.
    pub tape: &'a Tape,
    /// The leaf (`None` outside the octree).
    pub cell: Option<Cell<'a>>,
}

/// Compiles the fields' distance tapes (each field's whole one, then its octree's) to native
/// code where the CPU runs it ([`crate::sdf::jit`]): the same values, without the
/// interpreter's dispatch, each field within `shares[i]` (in (0, 1]) of [`NATIVE_CODE_BYTES`]
/// (see [`ObjectField::build_shared`]). The tapes of all fields are compiled together so that
/// small objects share executable buffers ([`crate::sdf::jit::compile_grouped`] says why).
pub fn compile_native(fields: &mut [ObjectField], shares: &[f64]) {
    let budgets: Vec<usize> = (0..fields.len())
        .map(|i| {
            let share = shares.get(i).copied().unwrap_or(1.0).clamp(0.0, 1.0);
            (NATIVE_CODE_BYTES as f64 * share) as usize
        })
        .collect();
    let mut tapes: Vec<(&mut Tape, usize)> = fields
        .iter_mut()
        .enumerate()
        .flat_map(|(group, field)| {
            let octree = field.octree.iter_mut().flat_map(|o| o.tapes.iter_mut());
            std::iter::once(&mut field.whole)
                .chain(octree)
                .map(move |tape| (tape, group))
        })
        .collect();
    crate::sdf::jit::compile_grouped(&mut tapes, &budgets);
}

impl ObjectField {
    /// The field of an object from its lowering: an octree over `region` (the cube around
    /// the object's bounds, or its bounds clipped to a finite box for an unbounded object)
    /// when one pays.
    pub fn build(lowered: &LoweredSdf, region: Aabb) -> Self {
        Self::build_shared(lowered, region, 1.0, Keep::Every)
    }

    /// [`Self::build`] within `share` (in (0, 1]) of an object's budgets ([`MAX_NODES`],
    /// [`MAX_INSTRUCTIONS`], and [`NATIVE_CODE_BYTES`] in [`compile_native`]):
    /// the parts of an object split into several share its budgets, so that the object's
    /// fields together stay within them (a union of 100,000 spheres made 1,021 parts whose
    /// octrees, each within a whole budget, took 352 MB).
    pub fn build_shared(lowered: &LoweredSdf, region: Aabb, share: f64, keep: Keep) -> Self {
        let outside = gradient_everywhere(&lowered.program);
        ObjectField {
            octree: FieldOctree::build_shared(&lowered.program, region, share, keep),
            whole: lowered.distance.clone(),
            whole_shading: lowered.shading.clone(),
            convex: lowered.convex.then(|| RoundingModel::of(&lowered.distance)),
            outside,
            slopes: slopes_of(outside).filter(|_| lowered.convex),
        }
    }

    /// The whole tapes only, marched without shortcuts: the reference the octree and the
    /// penumbra's convexity bound are tested against.
    pub fn whole(whole: &Tape, whole_shading: &Tape) -> Self {
        ObjectField {
            octree: None,
            whole: whole.clone(),
            whole_shading: whole_shading.clone(),
            convex: None,
            outside: ANY_GRADIENT,
            slopes: None,
        }
    }

    /// The shading tape valid at p (the leaf's, or the whole one).
    pub fn shading_at(&self, p: Vec3) -> &Tape {
        match self.octree.as_ref().and_then(|o| o.locate(p)) {
            Some(c) => c.shading,
            None => &self.whole_shading,
        }
    }

    /// A cursor for evaluating this field with the caller's registers.
    pub fn cursor<'r>(&self, regs: &'r mut Registers) -> FieldCursor<'_, 'r> {
        FieldCursor {
            octree: self.octree.as_ref(),
            whole: &self.whole,
            cell: None,
            path: Path::default(),
            convex: self.convex,
            outside: &self.outside,
            regs,
        }
    }
}

impl<'f, 'r> FieldCursor<'f, 'r> {
    /// A cursor over a whole tape alone (no octree): what reference code evaluates.
    pub fn whole(tape: &'f Tape, regs: &'r mut Registers) -> Self {
        FieldCursor {
            octree: None,
            whole: tape,
            cell: None,
            path: Path::default(),
            convex: None,
            outside: &ANY_GRADIENT,
            regs,
        }
    }

    /// For a convex field, the error model of its computed values; `None` for a field not
    /// known to be convex.
    pub fn convex(&self) -> Option<RoundingModel> {
        self.convex
    }

    /// The whole tape.
    pub fn whole_tape(&self) -> &'f Tape {
        self.whole
    }

    /// How fast the field may fall along the unit direction d outside the octree
    /// ([`ObjectField::outside`]).
    #[inline]
    pub fn fall_outside(&self, d: Vec3) -> f32 {
        fall_along(self.outside, d)
    }

    /// The whole tape where it is short enough ([`SHORT_TAPE`]) to evaluate at any point
    /// instead of finding the point's leaf, whose tape has the same value there.
    #[inline]
    pub fn short_whole_tape(&self) -> Option<&'f Tape> {
        (self.whole.len() <= SHORT_TAPE).then_some(self.whole)
    }

    /// The octree, if the field has one.
    pub fn octree(&self) -> Option<&'f FieldOctree> {
        self.octree
    }

    /// The region holding p: the cached leaf if p is still in it.
    #[inline]
    pub fn region(&mut self, p: Vec3) -> Region<'f> {
        let mut cell = self.cell;
        let found = self.region_cached(p, &mut cell);
        self.cell = cell;
        found
    }

    /// [`Self::region`] with the leaf cache `cell` of the caller's (rays of a bundle keep one
    /// each and share the cursor's path); what it answers depends on p alone.
    ///
    /// The cached leaf's test is inlined into every caller and the lookup is not: left to the
    /// compiler, whether the normal's six samples inlined the whole of it changed with
    /// unrelated code elsewhere, and a frame of the 400 spheres with it by 5 %.
    #[inline(always)]
    pub fn region_cached(&mut self, p: Vec3, cell: &mut Option<Cell<'f>>) -> Region<'f> {
        if let Some(c) = *cell
            && c.owns(p)
        {
            return Region {
                tape: c.tape,
                cell: Some(c),
            };
        }
        self.locate_region(p, cell)
    }

    /// [`Self::region_cached`] past its cached leaf.
    #[inline(never)]
    fn locate_region(&mut self, p: Vec3, cell: &mut Option<Cell<'f>>) -> Region<'f> {
        let found = match self.octree {
            Some(o) => o.locate_along(p, &mut self.path),
            None => None,
        };
        match found {
            Some(c) => {
                *cell = Some(c);
                Region {
                    tape: c.tape,
                    cell: Some(c),
                }
            }
            None => Region {
                tape: self.whole,
                cell: None,
            },
        }
    }

    /// The field at p.
    #[inline]
    pub fn eval(&mut self, p: Vec3) -> f32 {
        let tape = self.tape_at(p);
        tape.eval_in(p, self.regs)
    }

    /// The tape [`Self::eval`] evaluates at p (every tape valid there gives the same value).
    #[inline]
    pub fn tape_at(&mut self, p: Vec3) -> &'f Tape {
        match self.short_whole_tape() {
            Some(whole) => whole,
            None => self.region(p).tape,
        }
    }
}

/// A leaf met by a ray, with the parameters where the ray enters and leaves its box.
#[derive(Debug, Clone, Copy)]
pub struct Crossed<'a> {
    /// The leaf.
    pub leaf: &'a Leaf,
    /// Its distance tape.
    pub tape: &'a Tape,
    /// Where the ray enters the box.
    pub enter: f32,
    /// Where it leaves.
    pub exit: f32,
}

/// One level of the walk: a node's slab parameters and the next child to visit (32 bytes:
/// a bundle keeps a stack of them per lane, so it is kept small; boxes are not needed).
#[derive(Debug, Clone, Copy)]
struct Frame {
    node: Node,
    t0: Vec3,
    t1: Vec3,
    next: u8,
}

impl Frame {
    /// The frame of `node`, whose slab parameters are [t0, t1], before any child is visited.
    #[inline]
    fn of(node: Node, t0: Vec3, t1: Vec3) -> Frame {
        let next = if node.is_leaf() {
            0
        } else {
            first_child(t0, 0.5 * (t0 + t1))
        };
        Frame { node, t0, t1, next }
    }
}

/// The leaves a ray crosses, front to back: the parametric octree traversal of Revelles,
/// Ureña & Lastra ("An efficient parametric algorithm for octree traversal", WSCG 2000). The
/// ray is mirrored so that every direction component is positive (child numbers are mirrored
/// with it), each node's slab parameters are halved into its children's, and the next child
/// is the one across the nearest exit plane: every node on the ray's path is visited once,
/// with a few additions and comparisons, and no point is ever located.
pub struct RayWalk<'a, 's> {
    tree: &'a FieldOctree,
    mirror: u8,
    len: u8,
    from: f32,
    to: f32,
    /// The caller's stack: frames below `len` are written by this walk, the rest are not.
    stack: &'s mut WalkStack,
}

/// The frames of a [`RayWalk`], kept by its caller: a walk is made for every ray and object a
/// march starts through, and its nine frames (288 bytes) inside the walk were copied with it
/// into every lane of a bundle — a tenth of a showcase frame in copies, most of them of frames
/// never written. A bundle keeps one stack per lane for all its walks instead; a stack is
/// never read above the depth its current walk wrote.
pub struct WalkStack([MaybeUninit<Frame>; MAX_DEPTH as usize + 1]);

impl WalkStack {
    /// An unwritten stack.
    #[inline]
    pub fn new() -> Self {
        WalkStack([MaybeUninit::uninit(); MAX_DEPTH as usize + 1])
    }
}

impl Default for WalkStack {
    fn default() -> Self {
        Self::new()
    }
}

/// A direction component this small counts as this (after mirroring, so positive): the slab
/// parameters of a ray parallel to a slab stay finite, and their midpoints defined.
pub const TINY_DIRECTION: f32 = 1e-20;

impl<'a, 's> RayWalk<'a, 's> {
    /// The walk over the leaves the ray crosses within [from, to], its frames on `stack`.
    /// Always inlined, and made in one expression: returned through memory, or built in a
    /// local and changed there, the walk was copied into its caller's in wider words than it
    /// was written in, before those stores could forward (a stall on every lane).
    #[inline(always)]
    pub fn new(
        tree: &'a FieldOctree,
        ray: &Ray,
        from: f32,
        to: f32,
        stack: &'s mut WalkStack,
    ) -> Self {
        let mut mirror = 0u8;
        let mut o = ray.origin;
        let mut d = ray.direction;
        for axis in 0..3 {
            if d[axis] < 0.0 {
                o[axis] = tree.lo[axis] + tree.hi[axis] - o[axis];
                d[axis] = -d[axis];
                mirror |= 1 << axis;
            }
            d[axis] = d[axis].max(TINY_DIRECTION);
        }
        let inv = d.recip();
        let t0 = (tree.lo - o) * inv;
        let t1 = (tree.hi - o) * inv;
        let enters = t0.max_element() < t1.min_element() && t1.min_element() >= from;
        if enters {
            let root = tree.nodes[0];
            stack.0[0] = MaybeUninit::new(Frame::of(root, t0, t1));
        }
        RayWalk {
            tree,
            mirror,
            len: u8::from(enters),
            from,
            to,
            stack,
        }
    }

    /// The frame at `len` (just popped).
    #[inline]
    fn frame(&self) -> Frame {
        // SAFETY: frames are written at `len` before `len` grows past them (`push` and
        // `next_leaf` are the only writers of `len`), and this reads one below a former `len`.
        unsafe { self.stack.0[self.len as usize].assume_init() }
    }

    /// Leaves that end before `t` will not be wanted: the walk passes over every subtree the
    /// ray leaves before `t` without descending into it. A march that steps across many
    /// small leaves (a long step through the empty space around a sparse union) then visits
    /// the nodes on its way, not every leaf under them.
    #[inline]
    pub fn skip_to(&mut self, t: f32) {
        if t > self.from {
            self.from = t;
        }
    }

    /// The next leaf along the ray, or `None` past `to` or the tree. Leaves that end before
    /// the start of the walk or the last [`Self::skip_to`] may still be returned (each
    /// subtree is tested, not each leaf), never one that starts after `to`.
    #[inline]
    pub fn next_leaf(&mut self) -> Option<Crossed<'a>> {
        self.next::<false>()
    }

    /// [`Self::next_leaf`] passing over the leaves proven empty, as a march does: they are
    /// told by their node ([`EMPTY_LEAF`]) and cost the walk one sibling step each, with
    /// neither a return nor a frame stored and read back.
    #[inline]
    pub fn next_nonempty_leaf(&mut self) -> Option<Crossed<'a>> {
        self.next::<true>()
    }

    /// The walk behind [`Self::next_leaf`] and [`Self::next_nonempty_leaf`].
    ///
    /// The frame being looked at is held in registers, apart from the stack: a frame goes
    /// to the stack only when the walk descends below it, and is read back once its children
    /// are done. (Reading back a frame just stored, field by field with other widths than it
    /// was written with, defeats the CPU's store-to-load forwarding: that stall was a quarter
    /// of the time of a march through a sparse union of spheres.) A leaf child is returned
    /// from its parent's frame, without a frame of its own.
    #[inline]
    fn next<const SKIP_EMPTY: bool>(&mut self) -> Option<Crossed<'a>> {
        if self.len == 0 {
            return None;
        }
        self.len -= 1;
        let mut f = self.frame();
        if f.node.is_leaf() {
            // the root alone
            let (enter, exit) = (f.t0.max_element(), f.t1.min_element());
            self.len = 0;
            if enter > self.to || (SKIP_EMPTY && f.node.0 & EMPTY_LEAF != 0) {
                return None;
            }
            return Some(self.crossed(f.node, enter, exit));
        }
        loop {
            if f.next >= 8 {
                if self.len == 0 {
                    return None;
                }
                self.len -= 1;
                f = self.frame();
                continue;
            }
            // Child `c` in the mirrored frame: bit 0 = x, 1 = y, 2 = z, as stored.
            let c = f.next as usize;
            let tm = 0.5 * (f.t0 + f.t1);
            let up = glam::BVec3::new(c & 1 != 0, c & 2 != 0, c & 4 != 0);
            let ct0 = Vec3::select(up, tm, f.t0);
            let ct1 = Vec3::select(up, f.t1, tm);
            // the next sibling: across the nearest exit plane of this child, if it is inside
            let exit_axis = if ct1.x <= ct1.y && ct1.x <= ct1.z {
                0
            } else if ct1.y <= ct1.z {
                1
            } else {
                2
            };
            f.next = if c & (1 << exit_axis) != 0 {
                8
            } else {
                (c | (1 << exit_axis)) as u8
            };
            let (enter, exit) = (ct0.max_element(), ct1.min_element());
            if exit < self.from || enter > self.to {
                continue;
            }
            // mirrored axes take the other half of the stored children
            let real = c ^ self.mirror as usize;
            let node = self.tree.nodes[f.node.0 as usize + real];
            if node.is_leaf() {
                if SKIP_EMPTY && node.0 & EMPTY_LEAF != 0 {
                    continue;
                }
                if f.next < 8 {
                    // siblings are left: this frame is needed again
                    self.stack.0[self.len as usize] = MaybeUninit::new(f);
                    self.len += 1;
                }
                return Some(self.crossed(node, enter, exit));
            }
            if f.next < 8 {
                self.stack.0[self.len as usize] = MaybeUninit::new(f);
                self.len += 1;
            }
            f = Frame {
                node,
                t0: ct0,
                t1: ct1,
                next: first_child(ct0, 0.5 * (ct0 + ct1)),
            };
        }
    }

    /// Leaf `node` met over [enter, exit].
    #[inline]
    fn crossed(&self, node: Node, enter: f32, exit: f32) -> Crossed<'a> {
        let leaf = &self.tree.leaves[node.leaf_index()];
        Crossed {
            leaf,
            tape: &self.tree.tapes[leaf.tape as usize],
            enter,
            exit,
        }
    }
}

/// The first child a ray enters (Revelles et al., Table 1, in our bit order): across the entry
/// plane (the largest of the entry parameters), the halves whose midplane is crossed before
/// entering.
#[inline]
fn first_child(t0: Vec3, tm: Vec3) -> u8 {
    let entry = t0.max_element();
    let mut c = 0u8;
    for axis in 0..3 {
        if tm[axis] < entry {
            c |= 1 << axis;
        }
    }
    c
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::rng::Rng;

    /// A value for a gradient bound: zeros of both signs, subnormals, tiny and ordinary
    /// normals, infinities and NaN, most often the kinds a plane's enclosure has.
    fn bound(rng: &mut Rng) -> f32 {
        let sign = if rng.chance(0.5) { -1.0 } else { 1.0 };
        sign * match rng.below(9) {
            0 => 0.0,
            1 | 2 => f32::from_bits(1 + rng.below(8) as u32),
            3 => f32::from_bits(1 + rng.below(0x7f_ffff) as u32),
            4 => f32::MIN_POSITIVE * rng.range_f32(1.0, 2.0),
            5 => 2f32.powi(-(rng.below(120) as i32)) * rng.range_f32(1.0, 2.0),
            6 => f32::INFINITY,
            7 if rng.chance(0.1) => f32::NAN,
            _ => rng.range_f32(0.0, 2.0),
        }
    }

    #[test]
    fn a_short_whole_tape_stands_for_its_leaves_and_a_long_one_does_not() {
        // four tiles: a short tape, evaluated whole; 64 tiles: past SHORT_TAPE, by leaf
        let mut rng = Rng::new(4);
        for (n, short) in [(2, true), (8, false)] {
            let lowered = tiles(n, n);
            let field = ObjectField::build(&lowered, lowered.bounds);
            assert!(field.octree.is_some(), "{n}×{n} tiles have an octree");
            assert_eq!(
                field.whole.len() <= SHORT_TAPE,
                short,
                "{}",
                field.whole.len()
            );
            let (mut regs, mut alone) = (Registers::new(), Registers::new());
            let mut cursor = field.cursor(&mut regs);
            assert_eq!(cursor.short_whole_tape().is_some(), short);
            for _ in 0..2000 {
                let p = rng.vec3_in(-1.0, 1.0) * Vec3::new(1.0, 1.0, 0.2);
                let leaf = field.cursor(&mut alone).region(p).tape.eval(p);
                assert_eq!(cursor.eval(p).to_bits(), leaf.to_bits(), "at {p}");
            }
        }
    }

    #[test]
    fn fall_gives_the_bits_of_the_formula_as_written() {
        let mut rng = Rng::new(11);
        for i in 0..400_000 {
            let mut gradient = [[0.0; 3]; 2];
            let [low, high] = &mut gradient;
            for (l, h) in low.iter_mut().zip(high.iter_mut()) {
                let (x, y) = (bound(&mut rng), bound(&mut rng));
                *l = if x < y { x } else { y };
                *h = if x < y { y } else { x };
            }
            let leaf = Leaf {
                tape: 0,
                shading: 0,
                verdict: Verdict::Surface,
                gradient,
                min_value: 0.0,
            };
            let d = match i % 4 {
                // unit directions, some along an axis or a diagonal plane
                0 => rng.vec3_in(-1.0, 1.0).normalize_or(Vec3::X),
                1 => Vec3::select(
                    rng.vec3_in(-1.0, 1.0).cmpgt(Vec3::ZERO),
                    Vec3::ZERO,
                    Vec3::Y,
                ),
                // tiny, huge and non-finite components
                2 => Vec3::new(bound(&mut rng), bound(&mut rng), bound(&mut rng)),
                _ => rng.vec3_in(-1.0, 1.0) * 2f32.powi(rng.below(80) as i32 - 40),
            };
            assert_eq!(
                leaf.fall(d).to_bits(),
                leaf.fall_reference(d).to_bits(),
                "{gradient:?} along {d:?}"
            );
        }
    }

    /// A union of `nx`·`ny` boxes tiling a square edge to edge, of depths varying from box
    /// to box: many shapes, each near few of the others.
    fn tiles(nx: usize, ny: usize) -> crate::sdf::LoweredSdf {
        tiles_scene(nx, ny).objects[0].lowered.clone()
    }

    #[test]
    fn a_tape_too_short_to_gain_a_split_is_one_leaf_and_a_longer_one_is_split() {
        let object = |shape: &str| {
            let src = format!(
                "Scene(camera: Orthographic(position: (0, 0, 3), look_at: (0, 0, 0), height: 2),
                       objects: [(rotate: (0, 37, 0), shape: {shape})])"
            );
            let scene = crate::scene::Scene::from_source(&src, std::path::Path::new("t.ron"))
                .unwrap_or_else(|e| panic!("{e}"));
            let o = &scene.objects[0];
            (
                o.lowered.distance.len(),
                ObjectField::build(&o.lowered, o.bounds()),
            )
        };
        // a rotated box: its top levels held hundreds of nodes, which its march passed by
        let (len, field) = object("Box(half_extents: (0.5, 0.3, 0.2))");
        assert!(
            (MIN_TAPE..2 * MIN_TAPE).contains(&len),
            "{len} instructions"
        );
        let stats = field.octree.as_ref().expect("an octree").stats();
        assert_eq!((stats.nodes, stats.leaves), (1, 1), "{stats:?}");
        // a box with a scoop and a bore taken out: long enough, and its leaves save more than
        // half of it, so its top levels are split and its march walks them
        let (len, field) = object(
            "Subtraction(base: Box(half_extents: (0.65, 0.65, 0.65)), cut: Union([
                Transform(translate: (0.65, 0.65, 0.65), shape: Sphere(radius: 0.6)),
                Transform(rotate: (90, 0, 0), shape: Cylinder(half_height: 1, radius: 0.3))]))",
        );
        assert!(len >= MIN_SPLIT_TAPE, "{len} instructions");
        let tree = field.octree.as_ref().expect("an octree");
        assert!(tree.stats().nodes > 73, "{:?}", tree.stats());
        assert!(!tree.marched_whole());
    }

    /// The sampled surface cells never keep a tree from being built whose march would walk its
    /// leaves: over every object of the shipped scenes and of the SDF peer's models with a
    /// tape that may be marched whole, a tree the samples skip is, built, marched whole (or
    /// one leaf all the same).
    #[test]
    fn sampled_cells_skip_only_trees_marched_whole() {
        let mut scenes = crate::scene::shipped_scenes();
        for (name, src) in crate::bench::peer::generated() {
            let scene = crate::scene::Scene::from_source(&src, std::path::Path::new(&name))
                .unwrap_or_else(|e| panic!("{name}: {e}"));
            scenes.push((name, scene));
        }
        let (mut skipped, mut walked, mut built_whole) = (0, 0, 0);
        for (name, scene) in &scenes {
            for (i, o) in scene.objects.iter().enumerate() {
                let l = &o.lowered;
                let whole = l.program.distance_only().live_len();
                let finite = l.bounds.min.is_finite() && l.bounds.max.is_finite();
                if !(MIN_SPLIT_TAPE..=SHORT_TAPE).contains(&whole) || !finite {
                    continue;
                }
                let pad = Vec3::splat(1e-4 * (l.bounds.max - l.bounds.min).max_element() + 1e-6);
                let (lo, hi) = (l.bounds.min - pad, l.bounds.max + pad);
                let tree = FieldOctree::grow(&l.program, lo, hi, MAX_NODES, MAX_INSTRUCTIONS);
                let kept = surface_sample_tape(&l.program, lo, hi);
                if kept.is_some_and(|k| k >= SAMPLED_WHOLE * whole as f64) {
                    skipped += 1;
                    // (a tree of one leaf anyway, as fidget's gyroid sphere is, loses nothing)
                    assert!(
                        tree.marched_whole() || tree.stats().nodes == 1,
                        "{name}, object {i}: skipped ({kept:?} of {whole}) but walked: {:?}",
                        tree.stats()
                    );
                } else if tree.marched_whole() {
                    built_whole += 1;
                } else {
                    walked += 1;
                }
            }
        }
        // the check has teeth: trees walked and trees skipped both occur
        assert!(
            skipped >= 10 && walked >= 4,
            "{skipped} skipped, {walked} walked, {built_whole} built and marched whole"
        );
    }

    /// A tree whose march would take the whole tape (its leaves keeping more than half of it)
    /// is one leaf: a box with a sphere cut from it, found so by its sampled surface cells
    /// before any of the tree is built, and by the built tree where the samples are not sure.
    #[test]
    fn a_tree_marched_whole_is_one_leaf() {
        let lowered = |shape: &str| {
            let node = crate::sdf::conformance::parse_node(shape);
            crate::sdf::lower(&node, &|_| Some(0), 0).unwrap_or_else(|e| panic!("{e}"))
        };
        let l = lowered(
            "Transform(rotate: (10, 37, -20), shape: Subtraction(
                base: Box(half_extents: (0.5, 0.3, 0.2)), cut: Sphere(radius: 0.4)))",
        );
        let whole = l.program.distance_only().live_len();
        assert!((MIN_SPLIT_TAPE..=SHORT_TAPE).contains(&whole), "{whole}");
        let pad = Vec3::splat(1e-3);
        let (lo, hi) = (l.bounds.min - pad, l.bounds.max + pad);
        let grown = FieldOctree::grow(&l.program, lo, hi, MAX_NODES, MAX_INSTRUCTIONS);
        assert!(
            grown.marched_whole() && grown.stats().nodes > 73,
            "{:?}",
            grown.stats()
        );
        let kept = surface_sample_tape(&l.program, lo, hi).expect("surface samples");
        assert!(kept >= SAMPLED_WHOLE * whole as f64, "{kept} of {whole}");
        let build =
            |keep| FieldOctree::build_within(&l.program, lo, hi, MAX_NODES, MAX_INSTRUCTIONS, keep);
        let tree = build(Keep::Walked);
        assert_eq!(tree.stats().nodes, 1);
        assert!(tree.marched_whole());
        assert_eq!(build(Keep::Every).stats(), grown.stats());
        // where the sampled cells keep less, the tree is built, and then found marched whole
        let l = lowered(
            "SmoothUnion(k: 0.05, shapes: [Box(half_extents: (0.3, 0.3, 0.3)),
            Transform(translate: (0.2, 0.3, 0), shape: Sphere(radius: 0.2))])",
        );
        let whole = l.program.distance_only().live_len();
        let (lo, hi) = (l.bounds.min - pad, l.bounds.max + pad);
        let kept = surface_sample_tape(&l.program, lo, hi);
        let grown = FieldOctree::grow(&l.program, lo, hi, MAX_NODES, MAX_INSTRUCTIONS);
        let tree = FieldOctree::build_within(
            &l.program,
            lo,
            hi,
            MAX_NODES,
            MAX_INSTRUCTIONS,
            Keep::Walked,
        );
        assert!(
            kept.is_some_and(|k| k < SAMPLED_WHOLE * whole as f64),
            "{kept:?} of {whole}"
        );
        assert!(
            grown.marched_whole() && grown.stats().nodes > 73,
            "{:?}",
            grown.stats()
        );
        assert_eq!(tree.stats().nodes, 1);
        assert!(tree.marched_whole());
    }

    /// [`tiles`] as a scene of one object traced as one field, for the tracer's tests (the
    /// scene loader would trace each tile as an object of its own: these tests are about the
    /// octree of a union of many shapes).
    pub(crate) fn tiles_scene(nx: usize, ny: usize) -> crate::scene::Scene {
        let (wx, wy) = (1.8 / nx as f32, 1.8 / ny as f32);
        let shapes: Vec<String> = (0..nx * ny)
            .map(|k| {
                let (i, j) = (k % nx, k / nx);
                let depth = 0.05 + 0.1 * ((i * 7919 + j * 104729) % 101) as f32 / 100.0;
                format!(
                    "Transform(translate: ({}, {}, 0), shape: Box(half_extents: ({}, {}, {depth})))",
                    -0.9 + (i as f32 + 0.5) * wx,
                    -0.9 + (j as f32 + 0.5) * wy,
                    0.5 * wx,
                    0.5 * wy
                )
            })
            .collect();
        let src = format!(
            "Scene(camera: Orthographic(position: (0, 0, 3), look_at: (0, 0, 0), height: 2),
                   objects: [(shape: Union([{}]))])",
            shapes.join(", ")
        );
        let mut scene = crate::scene::Scene::from_source(&src, std::path::Path::new("tiles.ron"))
            .unwrap_or_else(|e| panic!("{e}"));
        let node =
            crate::sdf::SdfNode::Union(scene.objects.iter().map(|o| o.node.clone()).collect());
        let lowered = crate::sdf::lower(&node, &|_| Some(0), 0).unwrap_or_else(|e| panic!("{e}"));
        scene.objects = vec![crate::scene::SdfObject {
            name: "tiles".into(),
            node,
            lowered,
            part: None,
        }];
        scene
    }

    #[test]
    fn a_ray_across_a_flat_object_crosses_few_leaves_of_its_cubic_octree() {
        // 20 × 20 boxes tiling a square six times wider than the tiles are deep, seen face on
        let scene = tiles_scene(20, 20);
        let tracer = crate::trace::SceneTracer::new(&scene);
        let tree = tracer.fields()[0]
            .octree
            .as_ref()
            .expect("the union has an octree");
        let size = tree.hi - tree.lo;
        assert!(
            size.max_element() - size.min_element() <= 1e-6 * size.max_element(),
            "a cube: {size}"
        );
        let bounds = scene.objects[0].bounds();
        assert!(
            tree.lo.cmple(bounds.min).all() && tree.hi.cmpge(bounds.max).all(),
            "the cube holds the bounds"
        );
        // the leaves each camera ray walks from the object's bounds to its hit
        let (mut rays, mut leaves) = (0, 0);
        let mut stack = WalkStack::new();
        for j in 0..40 {
            for i in 0..40 {
                let (x, y) = (-0.88 + 0.044 * i as f32, -0.88 + 0.044 * j as f32);
                let ray = Ray::new(Vec3::new(x, y, 3.0), Vec3::NEG_Z);
                let hit = tracer
                    .closest_hit(&ray, 0.0, f32::INFINITY)
                    .expect("a tile");
                let (enter, _) = bounds.ray_interval(&ray, 0.0, hit.t).expect("inside");
                let mut walk = RayWalk::new(tree, &ray, enter, hit.t, &mut stack);
                while walk.next_leaf().is_some() {
                    leaves += 1;
                }
                rays += 1;
            }
        }
        // over the flat box's own octree (cells six times flatter than wide) this was 6.6
        let mean = leaves as f64 / rays as f64;
        assert!(mean <= 3.0, "{mean} leaves per ray");
    }

    /// A walk's leaves, each as (leaf index, enter bits, exit bits), the walk moved on as a
    /// march moves it: to `skip` of the last non-empty leaf's exit before each leaf
    /// ([`RayWalk::skip_to`]).
    fn walk_leaves(
        tree: &FieldOctree,
        ray: &Ray,
        (from, to): (f32, f32),
        nonempty_only: bool,
        skip: &dyn Fn(f32) -> f32,
    ) -> Vec<(usize, u32, u32)> {
        let mut stack = WalkStack::new();
        let mut walk = RayWalk::new(tree, ray, from, to, &mut stack);
        let mut out = Vec::new();
        let mut at = from;
        loop {
            walk.skip_to(at);
            let next = if nonempty_only {
                walk.next_nonempty_leaf()
            } else {
                walk.next_leaf()
            };
            let Some(x) = next else { break };
            let index = (std::ptr::from_ref(x.leaf) as usize
                - std::ptr::from_ref(&tree.leaves[0]) as usize)
                / size_of::<Leaf>();
            out.push((index, x.enter.to_bits(), x.exit.to_bits()));
            if x.leaf.verdict != Verdict::Empty {
                at = skip(x.exit);
            }
        }
        out
    }

    #[test]
    fn a_march_passes_empty_leaves_by_their_nodes_as_the_whole_walk_would() {
        // a sparse union (most leaves empty), a dense one, and a tree of one leaf
        let spheres: Vec<String> = (0..60)
            .map(|i| {
                let a = i as f32 * 0.7;
                format!(
                    "Transform(translate: ({}, {}, {}), shape: Sphere(radius: 0.05))",
                    0.8 * a.cos(),
                    -0.9 + 0.03 * i as f32,
                    0.8 * a.sin()
                )
            })
            .collect();
        let sources = [
            format!("Union([{}])", spheres.join(", ")),
            "Sphere(radius: 0.7)".to_string(),
        ];
        let mut trees: Vec<FieldOctree> = sources
            .iter()
            .map(|shape| {
                // lowered as one field (a scene would trace the union's spheres one by one)
                let node = crate::sdf::conformance::parse_node(shape);
                let lowered =
                    crate::sdf::lower(&node, &|_| Some(0), 0).unwrap_or_else(|e| panic!("{e}"));
                FieldOctree::build(&lowered.program, lowered.bounds).expect("a finite object")
            })
            .collect();
        trees.push(FieldOctree::build(&tiles(12, 12).program, tiles(12, 12).bounds).unwrap());
        let stats = trees[0].stats();
        assert!(
            stats.empty * 2 > stats.leaves,
            "the sparse union is mostly empty leaves: {stats:?}"
        );
        assert_eq!(
            trees[1].stats().leaves,
            1,
            "a sphere's tape is short: one leaf"
        );
        let mut rng = Rng::new(17);
        for (t, tree) in trees.iter().enumerate() {
            let mut met = [0usize; 2];
            let (lo, hi) = (tree.lo, tree.hi);
            for k in 0..3000 {
                let origin = rng.vec3_in(-2.0, 2.0);
                let mut direction = (rng.vec3_in(lo.min_element(), hi.max_element()) - origin)
                    .normalize_or(Vec3::X);
                if k % 5 == 0 {
                    // along an axis, or in a coordinate plane
                    direction = Vec3::select(
                        glam::BVec3::new(k % 3 == 0, true, k % 2 == 0),
                        Vec3::ZERO,
                        direction,
                    )
                    .normalize_or(Vec3::NEG_Z);
                }
                let ray = Ray::new(origin, direction);
                let (from, to) = (rng.range_f32(0.0, 1.0), rng.range_f32(1.0, 6.0));
                let jump = rng.range_f32(0.0, 0.3);
                let skips: [&dyn Fn(f32) -> f32; 2] = [&|t| t, &move |t| t + jump];
                for skip in skips {
                    let all = walk_leaves(tree, &ray, (from, to), false, skip);
                    let nonempty = walk_leaves(tree, &ray, (from, to), true, skip);
                    let expected: Vec<_> = all
                        .iter()
                        .copied()
                        .filter(|&(i, _, _)| tree.leaves[i].verdict != Verdict::Empty)
                        .collect();
                    assert_eq!(nonempty, expected, "{ray:?} over [{from}, {to}]");
                    met[0] += all.len();
                    met[1] += nonempty.len();
                }
            }
            assert!(met[1] > 1000, "tree {t}: non-empty leaves met: {met:?}");
            if t == 0 {
                assert!(
                    met[0] > 2 * met[1],
                    "the sparse union's leaves met: {met:?}"
                );
            }
        }
    }

    fn same_tree(a: &FieldOctree, b: &FieldOctree) -> bool {
        a.raw_nodes() == b.raw_nodes()
            && a.leaves() == b.leaves()
            && a.tapes.len() == b.tapes.len()
            && a.tapes
                .iter()
                .zip(&b.tapes)
                .all(|(x, y)| x.instrs() == y.instrs())
    }

    #[test]
    fn the_tree_does_not_depend_on_the_thread_count() {
        let lowered = tiles(12, 6);
        let build = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("a pool")
                .install(|| FieldOctree::build(&lowered.program, lowered.bounds).expect("a tree"))
        };
        let one = build(1);
        assert!(one.stats().leaves > 1000, "{:?}", one.stats());
        for threads in [2, 3, 8] {
            assert!(same_tree(&one, &build(threads)), "{threads} threads");
        }
    }

    #[test]
    fn a_budget_that_runs_out_is_kept_and_still_specialises_everywhere() {
        let lowered = tiles(24, 12);
        let (lo, hi) = (lowered.bounds.min, lowered.bounds.max);
        let build = |instructions| {
            FieldOctree::build_within(
                &lowered.program,
                lo,
                hi,
                MAX_NODES,
                instructions,
                Keep::Every,
            )
        };
        let full = build(MAX_INSTRUCTIONS);
        let full_stats = full.stats();
        // Half of what the whole tree stores.
        let allowed = full_stats.instructions / 2;
        let cut = build(allowed);
        let stats = cut.stats();
        assert!(stats.instructions <= allowed, "{stats:?} over {allowed}");
        assert!(
            stats.nodes < full_stats.nodes,
            "{stats:?}: the budget binds"
        );
        // Spent coarse before fine, on every part of the tree: the crossed leaves' tapes stay
        // short on average and nowhere near the whole tape (a depth-first build left the
        // octants it reached last with the tapes of their first levels).
        let longest = cut
            .leaves()
            .iter()
            .filter(|l| l.verdict == Verdict::Surface)
            .map(|l| cut.tapes[l.tape as usize].len())
            .max()
            .expect("crossed leaves");
        assert!(
            longest * 5 < full.whole_len
                && stats.mean_surface_tape < 3.0 * full_stats.mean_surface_tape,
            "longest crossed tape {longest} of {} ({stats:?}, full tree {full_stats:?})",
            full.whole_len
        );
    }

    #[test]
    fn the_tape_at_a_point_does_not_depend_on_the_lookups_before() {
        // Points on the faces between leaves, each looked up by a fresh cursor and by one
        // that has just found the leaf on the lower side of the face: the same leaf both ways,
        // so that a ray marched alone and in a bundle evaluates the same tapes.
        let lowered = tiles(12, 6);
        let tree = FieldOctree::build(&lowered.program, lowered.bounds).expect("a tree");
        let field = ObjectField {
            octree: Some(tree.clone()),
            whole: Tape::default(),
            whole_shading: Tape::default(),
            convex: None,
            outside: ANY_GRADIENT,
            slopes: None,
        };
        let mut rng = Rng::new(3);
        let mut regs = Registers::new();
        let mut checked = 0;
        for _ in 0..2000 {
            let p = tree.lo + rng.vec3_in(0.0, 1.0) * (tree.hi - tree.lo);
            let Some(cell) = tree.locate(p) else { continue };
            for axis in 0..3 {
                // a point on the cell's upper face, and one just below it
                let mut on = p;
                on[axis] = cell.hi[axis];
                let mut below = on;
                // the next float down (`f32::next_down` is newer than our minimum Rust)
                let x = on[axis];
                below[axis] = if x == 0.0 {
                    -f32::from_bits(1)
                } else if x > 0.0 {
                    f32::from_bits(x.to_bits() - 1)
                } else {
                    f32::from_bits(x.to_bits() + 1)
                };
                if on[axis] >= tree.hi[axis] || !cell.contains(below) {
                    continue;
                }
                let fresh = field.cursor(&mut regs).region(on).cell.map(|c| c.lo);
                let mut primed = field.cursor(&mut regs);
                assert!(primed.region(below).cell.is_some());
                let after = primed.region(on).cell.map(|c| c.lo);
                assert_eq!(fresh, after, "{on} after {below}");
                assert_eq!(
                    fresh.map(|lo| lo[axis]),
                    Some(on[axis]),
                    "the upper leaf owns {on}"
                );
                checked += 1;
            }
        }
        assert!(checked > 1000, "{checked} faces");
    }
}
