//! An SDF object's field as an octree of region-specialised tapes, for rays of any origin.
//!
//! Each leaf of the octree over the object's bounds holds the tape specialised to its box
//! ([`crate::sdf::simplify`]), whether the box is empty, full or crossed by the surface, and,
//! for a crossed box, a bound on |∇f| there. A point is evaluated with the tape of the leaf
//! that holds it, which gives the whole tape's value at a fraction of its cost; a ray skips
//! empty leaves without evaluating anything; steps inside a leaf may be scaled by its
//! Lipschitz bound. Outside the octree's box the whole tape is used. The structure depends
//! only on the object, so camera, shadow, ambient-occlusion, penumbra, reflection and
//! refraction rays share it (screen tiles would serve camera rays only).
//!
//! The tree is built top down (Keeter 2020, §4; fidget and libfive subdivide the same way):
//! the top [`CULL_DEPTH`] levels are split regardless (cells proven empty or full are culled
//! there), and below them a box is split in eight while its children's tapes are markedly
//! shorter, down to [`MAX_DEPTH`]. Finer empty boxes near the surface would save a ray little
//! (sphere-tracing steps there are short anyway) and cost it lookups, so emptiness alone
//! stops counting below the top levels. Memory is bounded: at most [`MAX_NODES`] nodes and
//! [`MAX_INSTRUCTIONS`] specialised instructions per object, counted before identical tapes
//! are merged (so at most 16 + 64 MiB); a split that would exceed them leaves the box a leaf
//! with its own tape.

use crate::geom::{Aabb, Ray};
use crate::sdf::simplify::{Simplifier, Specialised, Verdict};
use crate::sdf::ssa::SsaTape;
use crate::sdf::tape::{Registers, Tape};
use glam::Vec3;
use rayon::prelude::*;
use rustc_hash::FxHashMap as HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Deepest subdivision: cells of 1/256 of the box along each axis.
pub const MAX_DEPTH: u32 = 8;

/// Most nodes per object (4 bytes each, plus 16 per leaf): 32 MiB at most.
pub const MAX_NODES: usize = 1 << 21;

/// Most instructions over an object's distinct specialised tapes (8 bytes each): 64 MiB.
pub const MAX_INSTRUCTIONS: usize = 1 << 23;

/// Tapes shorter than this gain too little from specialisation to pay for a tree, or for a
/// further split.
pub const MIN_TAPE: usize = 12;

/// Levels split regardless of what their children gain.
pub const CULL_DEPTH: u32 = 3;

/// One leaf: its tapes, what its box holds, and the Lipschitz bound of the field there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Leaf {
    /// Index into [`FieldOctree::tapes`]: the distance tape.
    pub tape: u32,
    /// Index into [`FieldOctree::shading`]: distance and blended material.
    pub shading: u32,
    /// Empty, full or crossed.
    pub verdict: Verdict,
    /// An upper bound on |∇f| over the box, at most 1 (the field's global bound).
    pub lipschitz: f32,
    /// A lower bound on f over the box (the interval enclosure's lower end).
    pub min_value: f32,
}

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

/// A node: the first of its eight children, or (top bit set) a leaf.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Node(u32);

const LEAF_BIT: u32 = 1 << 31;

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
}

/// A subtree under construction.
enum Built {
    Leaf(LeafBuild),
    Inner(Box<[Built; 8]>),
}

struct LeafBuild {
    program: SsaTape,
    verdict: Verdict,
    lipschitz: f32,
    min_value: f32,
}

/// Shared budgets while building.
struct Budget {
    nodes: AtomicUsize,
    instructions: AtomicUsize,
}

impl Budget {
    fn take(&self, nodes: usize, instructions: usize) -> bool {
        let n = self.nodes.fetch_add(nodes, Ordering::Relaxed);
        let i = self.instructions.fetch_add(instructions, Ordering::Relaxed);
        n + nodes <= MAX_NODES && i + instructions <= MAX_INSTRUCTIONS
    }
}

impl FieldOctree {
    /// Builds the octree of `program` (an object's distance program) over `region`; `None`
    /// when specialisation cannot pay (a tiny tape, or an empty or unbounded region).
    pub fn build(program: &SsaTape, region: Aabb) -> Option<FieldOctree> {
        let whole_len = program.live_len();
        if whole_len < MIN_TAPE
            || !region.min.is_finite()
            || !region.max.is_finite()
            || region.is_empty()
        {
            return None;
        }
        // A little room around the bounds, so that surface points on them are inside.
        let pad = 1e-4 * (region.max - region.min).max_element() + 1e-6;
        let (lo, hi) = (region.min - Vec3::splat(pad), region.max + Vec3::splat(pad));
        let budget = Budget {
            nodes: AtomicUsize::new(1),
            instructions: AtomicUsize::new(0),
        };
        let mut simplifier = Simplifier::new();
        let sp = simplifier.specialise(program, lo, hi);
        let root = build_node(sp, lo, hi, 0, &budget, &mut simplifier);
        let mut tree = FieldOctree {
            lo,
            hi,
            nodes: Vec::new(),
            leaves: Vec::new(),
            tapes: Vec::new(),
            shading: Vec::new(),
            whole_len,
        };
        let mut dedup = [Dedup::default(), Dedup::default()];
        tree.nodes.push(Node(0));
        tree.flatten(root, 0, &mut dedup);
        Some(tree)
    }

    fn flatten(&mut self, built: Built, at: usize, dedup: &mut [Dedup; 2]) {
        match built {
            Built::Leaf(l) => {
                let compile = |p: &SsaTape| {
                    p.compile()
                        .expect("a specialised program needs no more registers than its source")
                };
                let tape = dedup[0].add(&mut self.tapes, compile(&l.program.distance_only()));
                let shading = dedup[1].add(&mut self.shading, compile(&l.program));
                self.nodes[at] = Node(LEAF_BIT | self.leaves.len() as u32);
                self.leaves.push(Leaf {
                    tape,
                    shading,
                    verdict: l.verdict,
                    lipschitz: l.lipschitz,
                    min_value: l.min_value,
                });
            }
            Built::Inner(children) => {
                let first = self.nodes.len();
                self.nodes[at] = Node(first as u32);
                self.nodes.extend(std::iter::repeat_n(Node(0), 8));
                let children: Vec<Built> = (children as Box<[Built]>).into_vec();
                for (i, c) in children.into_iter().enumerate() {
                    self.flatten(c, first + i, dedup);
                }
            }
        }
    }

    /// The box the tree covers.
    pub fn bounds(&self) -> Aabb {
        Aabb::new(self.lo, self.hi)
    }

    /// The leaf holding p, with its box; `None` outside the tree's box.
    #[inline]
    pub fn locate(&self, p: Vec3) -> Option<Cell<'_>> {
        if !(p.cmpge(self.lo).all() && p.cmple(self.hi).all()) {
            return None;
        }
        let (mut lo, mut hi) = (self.lo, self.hi);
        let mut node = self.nodes[0];
        while node.0 & LEAF_BIT == 0 {
            let mid = 0.5 * (lo + hi);
            let up = p.cmpge(mid);
            let octant = up.bitmask() as usize;
            lo = Vec3::select(up, mid, lo);
            hi = Vec3::select(up, hi, mid);
            node = self.nodes[node.0 as usize + octant];
        }
        let leaf = &self.leaves[(node.0 & !LEAF_BIT) as usize];
        Some(Cell {
            leaf,
            lo,
            hi,
            tape: &self.tapes[leaf.tape as usize],
            shading: &self.shading[leaf.shading as usize],
        })
    }

    /// Sizes.
    pub fn stats(&self) -> OctreeStats {
        let instructions: usize = self.tapes.iter().map(|t| t.len()).sum::<usize>()
            + self.shading.iter().map(|t| t.len()).sum::<usize>();
        let surface: Vec<&Leaf> = self
            .leaves
            .iter()
            .filter(|l| l.verdict == Verdict::Surface)
            .collect();
        let mean_surface_tape = if surface.is_empty() {
            0.0
        } else {
            surface
                .iter()
                .map(|l| self.tapes[l.tape as usize].len() as f64)
                .sum::<f64>()
                / surface.len() as f64
        };
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
        }
    }
}

/// Identical tapes of one table stored once: instructions and result registers as the key.
#[derive(Default)]
struct Dedup {
    seen: HashMap<Vec<u8>, u32>,
}

impl Dedup {
    fn add(&mut self, tapes: &mut Vec<Tape>, tape: Tape) -> u32 {
        let mut key: Vec<u8> = bytemuck::cast_slice(tape.instrs()).to_vec();
        key.push(tape.result());
        key.push(tape.material_result().unwrap_or(u8::MAX));
        let id = tapes.len() as u32;
        *self.seen.entry(key).or_insert_with(|| {
            tapes.push(tape);
            id
        })
    }
}

/// Subtrees shallower than this are built in parallel.
const PARALLEL_DEPTH: u32 = 2;

/// The eight children of the box [lo, hi], in octant order (bit 0: x, 1: y, 2: z).
fn child_box(lo: Vec3, hi: Vec3, i: usize) -> (Vec3, Vec3) {
    let mid = 0.5 * (lo + hi);
    let up = glam::BVec3::new(i & 1 != 0, i & 2 != 0, i & 4 != 0);
    (Vec3::select(up, mid, lo), Vec3::select(up, hi, mid))
}

/// A leaf for a box whose program is specialised.
fn make_leaf(simplifier: &mut Simplifier, sp: Specialised, lo: Vec3, hi: Vec3) -> Built {
    let lipschitz = if sp.verdict == Verdict::Surface {
        simplifier.lipschitz(&sp.program, lo, hi).min(1.0)
    } else {
        1.0
    };
    Built::Leaf(LeafBuild {
        verdict: sp.verdict,
        lipschitz,
        min_value: sp.value.lo,
        program: sp.program,
    })
}

/// The subtree of a box whose program `sp` is specialised already. The children are
/// specialised first, and the box is split only if they gain (one level of look-ahead: a
/// subtree is never built to be thrown away).
fn build_node(
    sp: Specialised,
    lo: Vec3,
    hi: Vec3,
    depth: u32,
    budget: &Budget,
    simplifier: &mut Simplifier,
) -> Built {
    let len = sp.len;
    if sp.verdict != Verdict::Surface || depth >= MAX_DEPTH || len < MIN_TAPE {
        return make_leaf(simplifier, sp, lo, hi);
    }
    let children: Vec<Specialised> = (0..8)
        .map(|i| {
            let (clo, chi) = child_box(lo, hi, i);
            simplifier.specialise(&sp.program, clo, chi)
        })
        .collect();
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
        .filter(|c| c.verdict == Verdict::Surface)
        .map(|c| c.len)
        .collect();
    let (n, total) = (crossed.len(), crossed.iter().sum::<usize>());
    let shorter = n > 0
        && ((len >= 4 * MIN_TAPE && 4 * total <= 3 * n * len)
            || (len >= 2 * MIN_TAPE && 2 * total <= n * len));
    // The top levels split regardless: intervals over large boxes decide little (a union
    // folded one shape at a time keeps every shape over an eighth of a spiral of spheres),
    // and their children would not show the gain their grandchildren have.
    let top = depth < CULL_DEPTH;
    if !(shorter || top) || !budget.take(8, children.iter().map(|c| c.len).sum()) {
        return make_leaf(simplifier, sp, lo, hi);
    }
    let built: Vec<Built> = if depth < PARALLEL_DEPTH {
        children
            .into_par_iter()
            .enumerate()
            .map(|(i, c)| {
                let (clo, chi) = child_box(lo, hi, i);
                build_node(c, clo, chi, depth + 1, budget, &mut Simplifier::new())
            })
            .collect()
    } else {
        children
            .into_iter()
            .enumerate()
            .map(|(i, c)| {
                let (clo, chi) = child_box(lo, hi, i);
                build_node(c, clo, chi, depth + 1, budget, simplifier)
            })
            .collect()
    };
    let built: [Built; 8] = built
        .try_into()
        .unwrap_or_else(|_| unreachable!("eight children"));
    Built::Inner(Box::new(built))
}

/// An evaluation cursor over an object's field: the last leaf found, so that consecutive
/// points in one box skip the descent, and the interpreter's registers.
pub struct FieldCursor<'f, 'r> {
    octree: Option<&'f FieldOctree>,
    whole: &'f Tape,
    cell: Option<Cell<'f>>,
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
}

/// What the tracer needs to know about the region around a point.
#[derive(Debug, Clone, Copy)]
pub struct Region<'a> {
    /// The tape valid there.
    pub tape: &'a Tape,
    /// The leaf (`None` outside the octree).
    pub cell: Option<Cell<'a>>,
}

impl ObjectField {
    /// The field of an object from its shading program and tapes: an octree over `region`
    /// (the object's bounds, clipped to a finite box for unbounded objects) when one pays.
    pub fn build(program: &SsaTape, whole: &Tape, whole_shading: &Tape, region: Aabb) -> Self {
        ObjectField {
            octree: FieldOctree::build(program, region),
            whole: whole.clone(),
            whole_shading: whole_shading.clone(),
        }
    }

    /// The whole tapes only (the reference the octree is tested against).
    pub fn whole(whole: &Tape, whole_shading: &Tape) -> Self {
        ObjectField {
            octree: None,
            whole: whole.clone(),
            whole_shading: whole_shading.clone(),
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
            regs,
        }
    }

    /// The whole tape.
    pub fn whole_tape(&self) -> &'f Tape {
        self.whole
    }

    /// The region holding p: the cached leaf if p is still in it.
    #[inline]
    pub fn region(&mut self, p: Vec3) -> Region<'f> {
        if let Some(c) = self.cell {
            if c.contains(p) {
                return Region {
                    tape: c.tape,
                    cell: Some(c),
                };
            }
        }
        match self.octree.and_then(|o| o.locate(p)) {
            Some(c) => {
                self.cell = Some(c);
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
        let tape = self.region(p).tape;
        tape.eval_in(p, self.regs)
    }
}
