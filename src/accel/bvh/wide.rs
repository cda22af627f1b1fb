//! The node layout and the traversal shared by [`MeshBvh`](super::MeshBvh),
//! [`InstanceBvh`](super::InstanceBvh) and [`AabbBvh`](super::AabbBvh).
//!
//! **Building.** obvhs builds the tree: PLOC (Meister & Bittner, "Parallel Locally-Ordered
//! Clustering for Bounding Volume Hierarchy Construction", IEEE TVCG 2018) over the primitive
//! boxes, then its reinsertion optimiser (Meister & Bittner, "Parallel Reinsertion for Bounding
//! Volume Hierarchy Optimization", CGF 2018), then the conversion to an 8-wide compressed BVH
//! (Ylitie, Karras & Laine, "Efficient Incoherent Ray Traversal on GPUs Through Compressed Wide
//! BVHs", HPG 2017). This is what `obvhs::cwbvh::builder::build_cwbvh_from_tris` does, repeated
//! here step by step so that (a) pre-split boxes can be padded (see `super::split_boxes`) and
//! (b) obvhs's debug-build validation pass is not run on every build.
//!
//! **Decoding.** The CWBVH topology (which children a node has, which primitives a leaf holds,
//! the child order) is kept as it is, node for node, but each child box is replaced by the
//! exact `f32` union of what lies below it. The quantised 8-bit child boxes of a `CwBvhNode`
//! are conservative only as far as obvhs's rounding goes: the decoded plane `p + q·2^e` is
//! rounded, and the grid exponent comes from a rounded `log2` that, if it came out one step
//! low, would clamp a child's top plane at 255 short of the child. (We found no violation in
//! 700,000 child boxes of random scenes — but nothing promises it.) Exact boxes make the
//! conservativeness argument below self-contained, are tighter (less traversal), and cost 224
//! bytes a node instead of 80 (about 1.6 MB for the 69k-triangle bunny). The instance tree
//! then gives each instance of a leaf a box of its own, one node more below such a leaf
//! ([`one_primitive_per_leaf`]).
//!
//! **Node test.** obvhs's `CwBvhNode::intersect_ray` clamps the entry distance to a fixed
//! `1e-4` and ignores `ray.tmin`, so a ray with `tmax < 1e-4`, or one that starts on a surface
//! with `tmin = 0`, loses the boxes it needs; it also replaces 1/d by ±1/ε for |d| ≤ ε, which
//! can cull a box when an axis-parallel ray runs exactly along one of its faces. Its stack holds
//! 32 entries and overwrites the top when full. The traversal here instead:
//! - uses the caller's `[tmin, tmax]` unchanged;
//! - handles axis-parallel rays exactly: an axis whose 1/d is not finite is a containment test
//!   `lo <= o <= hi` on that axis (the slab for that axis is all or nothing);
//! - is conservative in floating point: each slab distance `(plane − o)·(1/d)` has a relative
//!   error of at most γ₃ = 3u/(1 − 3u) (Ize, "Robust BVH Ray Traversal", JCGT 2(2), 2013), so
//!   the entry distance is scaled down and the exit distance up by [`WIDEN`] before they are
//!   compared: a box that the exact ray meets within `[tmin, tmax]` is never culled;
//! - visits hit children nearest first (sorted by entry distance) and skips a popped entry
//!   whose entry distance exceeds the current `tmax`;
//! - keeps its stack in a 32-entry array that spills to the heap, so no depth loses entries.

use std::cell::{Cell, UnsafeCell};
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};
use std::mem::MaybeUninit;
use std::ops::ControlFlow;

use glam::{BVec4A, Vec3, Vec3A, Vec4};
use obvhs::BvhBuildParams;
use obvhs::aabb::Aabb as OAabb;
use obvhs::bvh2::reinsertion::ReinsertionOptimizer;
use obvhs::cwbvh::bvh2_to_cwbvh::bvh2_to_cwbvh;
use obvhs::ploc::PlocBuilder;

use crate::geom::Ray;

mod binned;
mod lanes;
mod packet;
pub(crate) use binned::build as build_binned;
pub(crate) use lanes::{LANES, has_avx512, has_lanes, lanes_take, traverse_lanes};
pub(crate) use packet::{Frustum, traverse_packet};

/// Marks a leaf child in [`WideNode::meta`]; the other bits of a leaf are `(count − 1) << 29 |
/// first`, where `first` indexes the primitive order and `count` is 1..=4 (CWBVH leaves hold at
/// most three primitives, the binned builder's four). An internal child's meta is its node
/// index.
pub(crate) const LEAF_BIT: u32 = 1 << 31;
pub(crate) const FIRST_MASK: u32 = (1 << 29) - 1;
/// Largest number of primitive references a tree can hold with this encoding.
pub(crate) const MAX_PRIMS: usize = FIRST_MASK as usize;

/// Relative widening of slab distances. Each computed distance is the exact one times
/// (1 + θ), |θ| ≤ γ₃ ≈ 3·2⁻²⁴ (one rounding for `plane − o`, one for `1/d`, one for the
/// product); 8·2⁻²³ = 16·2⁻²⁴ covers that with room for the rounding of the widening itself.
pub(crate) const WIDEN: f32 = 8.0 * f32::EPSILON;

/// One node: the boxes of its (up to) eight children, structure-of-arrays. Empty slots hold the
/// inverted box (min = +∞, max = −∞), which no ray enters.
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C, align(32))]
pub(crate) struct WideNode {
    /// `bounds[2·axis]` are the children's minima on `axis`, `bounds[2·axis + 1]` the maxima.
    pub bounds: [[f32; 8]; 6],
    /// Per child: node index, or [`LEAF_BIT`]-tagged primitive range.
    pub meta: [u32; 8],
}

impl WideNode {
    pub(crate) const EMPTY: WideNode = WideNode {
        bounds: [
            [f32::INFINITY; 8],
            [f32::NEG_INFINITY; 8],
            [f32::INFINITY; 8],
            [f32::NEG_INFINITY; 8],
            [f32::INFINITY; 8],
            [f32::NEG_INFINITY; 8],
        ],
        meta: [0; 8],
    };
}

/// A built tree: nodes (root at 0, absent when there are no primitives) and the primitive
/// order (`order[i]` is the index, in the slice given to [`build`], of the i-th primitive
/// reference of the leaves).
#[derive(Clone, Debug, Default)]
pub(crate) struct WideBvh {
    pub nodes: Vec<WideNode>,
    pub order: Vec<u32>,
    pub max_depth: u32,
    /// Exact bounds of everything (min > max when empty).
    pub bounds: (Vec3, Vec3),
}

/// What both builders do first: the tree of no boxes when there are none (returned), and a
/// panic past [`MAX_PRIMS`].
fn empty_tree_of(boxes: &[OAabb]) -> Option<WideBvh> {
    assert!(
        boxes.len() <= MAX_PRIMS,
        "a BVH holds at most {MAX_PRIMS} primitive references"
    );
    boxes.is_empty().then(|| WideBvh {
        bounds: (Vec3::INFINITY, Vec3::NEG_INFINITY),
        ..Default::default()
    })
}

/// Builds over `boxes`, which must be finite with min ≤ max (the callers filter).
pub(crate) fn build(boxes: &[OAabb], params: &BvhBuildParams) -> WideBvh {
    if let Some(empty) = empty_tree_of(boxes) {
        return empty;
    }
    let empty = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    // As in obvhs::cwbvh::builder::build_cwbvh (obvhs 0.4), without the debug validation, and
    // with ties broken for the builder only (see `spread_for_the_builder`).
    let spread = spread_for_the_builder(boxes);
    let indices: Vec<u32> = (0..boxes.len() as u32).collect();
    let mut bvh2 = PlocBuilder::with_capacity(boxes.len()).build(
        params.ploc_search_distance,
        &spread,
        indices,
        params.sort_precision,
        params.search_depth_threshold,
    );
    bvh2.uses_spatial_splits = params.pre_split;
    ReinsertionOptimizer::default().run(&mut bvh2, params.reinsertion_batch_ratio, None);
    let cw = bvh2_to_cwbvh(&bvh2, params.max_prims_per_leaf.clamp(1, 3), true, false);

    // Decode. Children always have larger indices than their parent (the converter appends
    // them after it), so one backward pass computes every subtree box from finished ones.
    let order = cw.primitive_indices;
    let n = cw.nodes.len();
    let mut nodes = vec![WideNode::EMPTY; n];
    let mut node_box = vec![empty; n];
    for ni in (0..n).rev() {
        let cn = &cw.nodes[ni];
        let mut total = empty;
        for slot in 0..8 {
            if cn.is_child_empty(slot) {
                continue;
            }
            let (lo, hi, meta) = if !cn.is_leaf(slot) {
                let ci = cn.child_node_index(slot) as usize;
                debug_assert!(ci > ni);
                let (lo, hi) = node_box[ci];
                (lo, hi, ci as u32)
            } else {
                let (first, count) = cn.child_primitives(slot);
                debug_assert!((1..=3).contains(&count));
                let (mut lo, mut hi) = empty;
                for &p in &order[first as usize..(first + count) as usize] {
                    let b = &boxes[p as usize];
                    lo = lo.min(b.min.into());
                    hi = hi.max(b.max.into());
                }
                (lo, hi, LEAF_BIT | (count - 1) << 29 | first)
            };
            for axis in 0..3 {
                nodes[ni].bounds[2 * axis][slot] = lo[axis];
                nodes[ni].bounds[2 * axis + 1][slot] = hi[axis];
            }
            nodes[ni].meta[slot] = meta;
            total = (total.0.min(lo), total.1.max(hi));
        }
        node_box[ni] = total;
    }
    // Depth, forwards.
    let mut depth = vec![0u32; n];
    let mut max_depth = 0;
    for ni in 0..n {
        max_depth = max_depth.max(depth[ni] + 1);
        for slot in 0..8 {
            let m = nodes[ni].meta[slot];
            if nodes[ni].bounds[0][slot] <= nodes[ni].bounds[1][slot] && m & LEAF_BIT == 0 {
                depth[m as usize] = depth[ni] + 1;
            }
        }
    }
    WideBvh {
        nodes,
        order,
        max_depth,
        bounds: node_box[0],
    }
}

/// Gives every primitive of a leaf of several its own box: each leaf child that holds two or
/// more primitives becomes an inner child whose node (appended, so children still come after
/// their parents) has one leaf of one primitive per slot, with that primitive's box from
/// `boxes` (indexed as [`build`]'s). The primitive order is unchanged. A walk then tests each
/// primitive's box before handing it over, as Embree's instance leaves of one do, while the
/// tree above stays the one built (obvhs's trees with leaves of one instance were deeper:
/// slower on ReciprocatingSaw's 113 instances). Meant for the instance tree, where handing
/// over an instance costs a mapping of each ray into its space and a walk of its tree.
pub(crate) fn one_primitive_per_leaf(tree: &mut WideBvh, boxes: &[OAabb]) {
    let parents = tree.nodes.len();
    let mut added = false;
    for ni in 0..parents {
        for slot in 0..8 {
            let meta = tree.nodes[ni].meta[slot];
            let used = tree.nodes[ni].bounds[0][slot] <= tree.nodes[ni].bounds[1][slot];
            if !used || meta & LEAF_BIT == 0 || leaf_count(meta) < 2 {
                continue;
            }
            let first = leaf_first(meta);
            let mut node = WideNode::EMPTY;
            for k in 0..leaf_count(meta) {
                let b = &boxes[tree.order[(first + k) as usize] as usize];
                let (lo, hi) = (b.min.to_array(), b.max.to_array());
                for axis in 0..3 {
                    node.bounds[2 * axis][k as usize] = lo[axis];
                    node.bounds[2 * axis + 1][k as usize] = hi[axis];
                }
                node.meta[k as usize] = LEAF_BIT | (first + k);
            }
            tree.nodes[ni].meta[slot] = tree.nodes.len() as u32;
            tree.nodes.push(node);
            added = true;
        }
    }
    if added {
        // (at most one level more: the new nodes hang below leaves' parents)
        tree.max_depth += 1;
    }
}

/// Boxes for the *builder* in which ties are broken: every box is moved by δ·(h₁, h₂, h₃),
/// and each member of a group of g bitwise-identical boxes by δ·∛g·(h₁, h₂, h₃), with h
/// pseudo-random in [0, 1) (hashed from the box's position in the list, or its rank in the
/// group) and δ = 2⁻²⁰ × the extent of everything.
///
/// PLOC pairs nodes that are each other's cheapest merge (by the surface area of the union).
/// Among identical boxes every merge costs the same, obvhs breaks ties towards the farthest
/// candidate, few pairs are mutual, and the tree degenerates into a chain: n copies of one
/// triangle gave depth n/7 and a quadratic build (20,000 copies: 14 s), and obvhs's recursive
/// BVH2→CWBVH conversion would overflow the stack for a few hundred thousand. Evenly spaced
/// boxes tie the same way (each box's two neighbours cost the same): 20,000 instances in a
/// row took 6 s, 200,000 more than a minute, until every box was moved by a hair as well.
/// Only the topology depends on these boxes: the node boxes are recomputed from the real ones.
fn spread_for_the_builder(boxes: &[OAabb]) -> Vec<OAabb> {
    // A 64-bit fingerprint of the six coordinates' bits stands for the box. Two different
    // boxes sharing one (odds ~n²/2⁶⁵) would merely be spread too, which only moves the
    // builder's view of them by a hair.
    let key = |b: &OAabb| {
        let mut h = 0u64;
        for c in [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z] {
            h = (h.rotate_left(21) ^ u64::from(c.to_bits())).wrapping_mul(0x9e37_79b9_7f4a_7c15);
        }
        h ^ (h >> 29)
    };
    let mut groups: HashMap<u64, (u32, u32), BuildHasherDefault<PassThrough>> =
        HashMap::with_capacity_and_hasher(boxes.len(), Default::default());
    let (mut lo, mut hi) = (Vec3A::INFINITY, Vec3A::NEG_INFINITY);
    for b in boxes {
        let g = groups.entry(key(b)).or_insert((0, 0));
        g.0 += 1;
        lo = lo.min(b.min);
        hi = hi.max(b.max);
    }
    let extent = (hi - lo).max_element();
    let magnitude = lo.abs().max(hi.abs()).max_element();
    let delta = if extent > 0.0 {
        extent
    } else {
        magnitude.max(1.0)
    } * (-20.0f32).exp2();
    // SplitMix64's finaliser as a hash to [0, 1).
    let unit = |k: u64, axis: u64| {
        let mut z =
            k.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ axis.wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    };
    boxes
        .iter()
        .enumerate()
        .map(|(i, b)| {
            let g = groups.get_mut(&key(b)).expect("counted above");
            let (size, rank) = (g.0, g.1);
            g.1 += 1;
            // A lone box hashed by its place in the list, a group's member by its rank in the
            // group (on other hash streams, so the two kinds of offset are unrelated).
            let (k, scale, axes) = if size == 1 {
                (i as u64, delta, [4, 5, 6])
            } else {
                (u64::from(rank), delta * (size as f32).cbrt(), [1, 2, 3])
            };
            let s = Vec3A::new(unit(k, axes[0]), unit(k, axes[1]), unit(k, axes[2])) * scale;
            OAabb::new(b.min + s, b.max + s)
        })
        .collect()
}

/// A hasher for keys that are already well-mixed 64-bit fingerprints.
#[derive(Default)]
struct PassThrough(u64);

impl Hasher for PassThrough {
    fn write(&mut self, bytes: &[u8]) {
        // Only `write_u64` is used by `u64` keys; this is the generic fallback.
        for &b in bytes {
            self.0 = (self.0.rotate_left(8) ^ u64::from(b)).wrapping_mul(0x9e37_79b9_7f4a_7c15);
        }
    }
    fn write_u64(&mut self, i: u64) {
        self.0 = i;
    }
    fn finish(&self) -> u64 {
        self.0
    }
}

/// Most rays in a packet. 32 is one row of a 32×32 render tile; with the bench's and the
/// renderer's tile order, 32 consecutive primary rays span 32 neighbouring pixels.
pub(crate) const PACKET: usize = 32;

/// The mask of the first `n` rays of a packet.
#[inline(always)]
pub(crate) fn all_rays(n: usize) -> u32 {
    if n == 0 {
        0
    } else {
        u32::MAX >> (32 - n.min(32))
    }
}

/// What a packet walk hands to its caller.
#[derive(Clone, Copy, Debug)]
pub(crate) enum PacketLeaf {
    /// Grouped trees: ray `ray` meets the leaf children `slots` of a node (`meta` is the first
    /// one's [`WideNode::meta`]); its `tmax` is `tmax[ray]`.
    Ray { ray: usize, meta: u32, slots: u32 },
    /// Grouped trees, where many rays meet leaf children of one node (see [`RAYS_TOGETHER`]):
    /// `by_slot[i]` holds the rays (bit j for ray j) whose own test meets leaf child i, 0 for
    /// the node's other children; `rays` is their union. Ray j's leaf slots are
    /// [`slots_of`]`(by_slot, j)`, as [`PacketLeaf::Ray`] would have handed them.
    Rays {
        rays: u32,
        meta: u32,
        by_slot: [u32; 8],
    },
    /// Other trees: the rays of the mask `rays` (bit i for ray i) may meet the leaf child
    /// `meta`.
    Packet { meta: u32, rays: u32 },
}

/// From this many rays meeting leaf children of one node on, a frustum walk hands them over
/// together ([`PacketLeaf::Rays`], on CPUs that run the test below), and from this many meeting
/// one block of eight triangles on, the mesh tests each triangle against sixteen rays at once
/// rather than each ray against eight triangles at once: the two cost about the same at eight
/// rays. (Measured on the bench's primary and shadow rays: 6 and 12 no better, the instanced
/// models 5–15 % faster than without, the others within noise.)
pub(crate) const RAYS_TOGETHER: u32 = 8;

/// The leaf slots of a [`PacketLeaf::Rays`] that ray `ray` meets (bit i for slot i).
#[inline(always)]
pub(crate) fn slots_of(by_slot: &[u32; 8], ray: usize) -> u32 {
    let mut slots = 0;
    for (slot, &rays) in by_slot.iter().enumerate() {
        slots |= ((rays >> ray) & 1) << slot;
    }
    slots
}

/// The rays of `alive` finish the subtree under `root` one by one, each in its own single-ray
/// walk, their leaves handed to `leaf` as a packet walk hands them (a lane walk's and a
/// packet walk's way out where too few rays are left to share the node tests). Breaks when
/// `leaf` does.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(crate) fn finish_alone<
    const MARGIN: bool,
    const AVX2: bool,
    const ORDERED: bool,
    const GROUPED: bool,
>(
    nodes: &[WideNode],
    root: u32,
    rays: &[NodeRay],
    alive: u32,
    tmin: f32,
    tmax: &mut [f32],
    margin: f32,
    leaf: &mut impl FnMut(PacketLeaf, &mut [f32]) -> ControlFlow<()>,
) -> ControlFlow<()> {
    let mut m = alive;
    while m != 0 {
        let ray = m.trailing_zeros() as usize;
        m &= m - 1;
        let mut t = tmax[ray];
        let mut broke = false;
        traverse_impl::<MARGIN, AVX2, ORDERED, GROUPED>(
            nodes,
            root,
            &rays[ray],
            tmin,
            &mut t,
            margin,
            |meta, slots, t| {
                tmax[ray] = *t;
                let what = if GROUPED {
                    PacketLeaf::Ray { ray, meta, slots }
                } else {
                    PacketLeaf::Packet {
                        meta,
                        rays: 1 << ray,
                    }
                };
                let flow = leaf(what, tmax);
                *t = tmax[ray];
                broke |= flow.is_break();
                flow
            },
        );
        if broke {
            return ControlFlow::Break(());
        }
    }
    ControlFlow::Continue(())
}

/// The node rays of a packet's rays, made when a walk first needs them: a frustum walk tests
/// its nodes with the packet's bounds alone ([`Frustum`], made from the rays themselves), and
/// about half of the frustum walks on the bench models end without ever testing a ray on its
/// own (measured on 2CylinderEngine and ReciprocatingSaw: 48–71 % of the walks of primary and
/// shadow packets, instance trees included). Shared by reference: the walk of the instance
/// tree and the walks of its identity instances use the same world rays.
pub(crate) struct NodeRays<'a> {
    rays: &'a [Ray],
    made: Cell<bool>,
    node: UnsafeCell<[MaybeUninit<NodeRay>; PACKET]>,
}

impl<'a> NodeRays<'a> {
    /// The node rays of at most [`PACKET`] rays, none made yet.
    #[inline(always)]
    pub fn new(rays: &'a [Ray]) -> Self {
        assert!(rays.len() <= PACKET, "a packet holds at most {PACKET} rays");
        NodeRays {
            rays,
            made: Cell::new(false),
            node: UnsafeCell::new([const { MaybeUninit::uninit() }; PACKET]),
        }
    }

    /// How many rays.
    #[inline(always)]
    pub fn len(&self) -> usize {
        self.rays.len()
    }

    /// The node rays, `NodeRay::new` of each ray, made on the first call.
    #[inline(always)]
    pub fn get(&self) -> &[NodeRay] {
        if !self.made.get() {
            // SAFETY: before `made` is set no reference into `node` exists (this is the only
            // place that hands them out, after the flag), and nothing below calls back here.
            let node = unsafe { &mut *self.node.get() };
            for (slot, r) in node.iter_mut().zip(self.rays) {
                slot.write(NodeRay::new(r.origin, r.direction));
            }
            self.made.set(true);
        }
        // SAFETY: the first `rays.len()` entries were written above; `MaybeUninit<NodeRay>`
        // has the layout of `NodeRay`, and no mutable reference exists once `made` is set.
        unsafe { std::slice::from_raw_parts(self.node.get() as *const NodeRay, self.rays.len()) }
    }
}

/// Per-ray constants of the node test.
///
/// The origin and the reciprocals are each written with one 16-byte store (a fourth lane of
/// 0): the walk, entered right after, loads them in pairs, and a load that spans two earlier
/// stores cannot take its data from them (it waits until they reach the cache: written axis
/// by axis, that stalled every walk's entry).
#[derive(Clone, Copy, Debug)]
#[repr(C, align(16))]
pub(crate) struct NodeRay {
    /// The origin (x, y, z, 0).
    o: [f32; 4],
    /// 1/d, or 0 on a parallel axis (and in the fourth lane).
    inv: [f32; 4],
    /// Index into [`WideNode::bounds`] of the entry plane per axis (max plane when d < 0).
    near: [usize; 3],
    /// Bit `axis` set where 1/d is not finite (d = ±0, subnormal, or NaN): a containment
    /// test on that axis. One word, written once, so that the walk's first load of it is
    /// served from the store buffer (three separate byte stores read back as one word stalled
    /// every walk's entry).
    parallel: u32,
}

impl NodeRay {
    /// For a ray `origin + t·direction` (any length).
    #[inline]
    pub fn new(origin: Vec3, direction: Vec3) -> Self {
        // the three divisions at once (each lane is the IEEE quotient, as one by one), kept
        // in a register until the one store
        let inv = Vec3A::ONE / Vec3A::from(direction);
        // |d| < 2^-128 (1/d not finite): treated as exactly parallel, a containment test.
        // The real ray drifts by |d|·t on this axis, under 3e-39·t: far below any f32 box
        // tolerance.
        let finite = inv.is_finite_mask();
        let inv = Vec3A::select(finite, inv, Vec3A::ZERO);
        // The sign of 1/d, not of d, decides which plane is entered first (−0 has been
        // excluded: its inverse is −∞); a parallel axis keeps the min plane.
        let negative = inv.cmplt(Vec3A::ZERO).bitmask();
        NodeRay {
            o: Vec4::from((origin, 0.0)).to_array(),
            inv: inv.extend(0.0).to_array(),
            near: entry_planes(negative),
            parallel: !finite.bitmask() & 0b111,
        }
    }
}

/// Index into [`WideNode::bounds`] of the plane a ray enters first on each axis, from the
/// signs of its 1/d (bit `axis` of `negative` set where 1/d < 0): the max plane there, the min
/// plane elsewhere. One rule for node rays and frusta.
#[inline(always)]
pub(crate) fn entry_planes(negative: u32) -> [usize; 3] {
    std::array::from_fn(|axis| 2 * axis + ((negative >> axis) & 1) as usize)
}

#[inline(always)]
fn lanes(a: &[f32; 8], group: usize) -> Vec4 {
    Vec4::from_slice(&a[4 * group..4 * group + 4])
}

/// Entry distances (widened) and the hit mask of the node's children against `[tmin, tmax]`,
/// each box grown by `margin` when `MARGIN` (the grown bound is `fl(min − margin)`, the same
/// rounding as [`crate::geom::Aabb::expand`], so it contains every grown child box).
#[inline(always)]
fn child_hits<const MARGIN: bool>(
    node: &WideNode,
    r: &NodeRay,
    tmin: f32,
    tmax: f32,
    margin: f32,
) -> ([f32; 8], u32) {
    let mut t_out = [0.0f32; 8];
    let mut mask = 0u32;
    for group in 0..2 {
        let mut tn = Vec4::splat(tmin);
        let mut tf = Vec4::splat(tmax);
        let mut inside = BVec4A::splat(true);
        for axis in 0..3 {
            let o = Vec4::splat(r.o[axis]);
            if r.parallel & (1 << axis) != 0 {
                let mut lo = lanes(&node.bounds[2 * axis], group);
                let mut hi = lanes(&node.bounds[2 * axis + 1], group);
                if MARGIN {
                    lo -= margin;
                    hi += margin;
                }
                inside &= lo.cmple(o) & hi.cmpge(o);
            } else {
                let near = r.near[axis];
                // near ^ 1 is the other plane of the same axis.
                let mut pn = lanes(&node.bounds[near], group);
                let mut pf = lanes(&node.bounds[near ^ 1], group);
                if MARGIN {
                    // Entry plane is the min plane when near is even.
                    if near & 1 == 0 {
                        pn -= margin;
                        pf += margin;
                    } else {
                        pn += margin;
                        pf -= margin;
                    }
                }
                let inv = Vec4::splat(r.inv[axis]);
                // No NaN can arise: inv is finite and non-zero, planes are finite or the
                // ±∞ of an empty slot.
                tn = tn.max((pn - o) * inv);
                tf = tf.min((pf - o) * inv);
            }
        }
        // Conservative comparison (Ize 2013): entry scaled towards 0, exit away from it.
        // Multiplicative, so ±∞ stay ±∞. tn ≥ tmin ≥ 0 (see `dispatch`), so no sign test is
        // needed for it; a negative tf means a box behind the ray, a miss however it is
        // scaled, so tf needs none either.
        let tn = tn * Vec4::splat(1.0 - WIDEN);
        let tf = tf * Vec4::splat(1.0 + WIDEN);
        let hit = tn.cmple(tf) & inside;
        mask |= hit.bitmask() << (4 * group);
        tn.write_to_slice(&mut t_out[4 * group..4 * group + 4]);
    }
    (t_out, mask)
}

/// Whether the 8-wide AVX2 node test can run on this CPU (the detection is cached by std).
#[inline(always)]
fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The child-box tests in use.
pub(crate) fn node_test_name() -> &'static str {
    match lanes::lane_set() {
        Some(lanes::LaneSet::Avx512) => {
            "8-wide AVX2; 16-ray lane walks in AVX-512 (runtime-detected)"
        }
        Some(lanes::LaneSet::Avx2) => {
            "8-wide AVX2; 16-ray lane walks in pairs of AVX2 registers (runtime-detected)"
        }
        None if has_avx2() => "8-wide AVX2 (runtime-detected)",
        None => "2×4-wide SSE (glam Vec4, AVX2 not available)",
    }
}

/// [`child_hits`] with all eight children in one 256-bit register: the same operations in
/// the same order on the same `f32` values (no FMA, which could change roundings), so the
/// entry distances and the mask are bit for bit those of the portable version (checked by
/// `avx2_node_test_matches_the_portable_one`).
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn child_hits_avx2<const MARGIN: bool>(
    node: &WideNode,
    r: &NodeRay,
    tmin: f32,
    tmax: f32,
    margin: f32,
) -> ([f32; 8], u32) {
    use std::arch::x86_64::*;
    // SAFETY (whole body): unaligned loads and stores of eight f32 from and to arrays of
    // eight f32; AVX2 is enabled for this function.
    unsafe {
        let load = |a: &[f32; 8]| _mm256_loadu_ps(a.as_ptr());
        let m = _mm256_set1_ps(margin);
        let mut tn = _mm256_set1_ps(tmin);
        let mut tf = _mm256_set1_ps(tmax);
        let mut inside = _mm256_castsi256_ps(_mm256_set1_epi32(-1));
        for axis in 0..3 {
            let o = _mm256_set1_ps(r.o[axis]);
            if r.parallel & (1 << axis) != 0 {
                let mut lo = load(&node.bounds[2 * axis]);
                let mut hi = load(&node.bounds[2 * axis + 1]);
                if MARGIN {
                    lo = _mm256_sub_ps(lo, m);
                    hi = _mm256_add_ps(hi, m);
                }
                let ok = _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_LE_OQ>(lo, o),
                    _mm256_cmp_ps::<_CMP_GE_OQ>(hi, o),
                );
                inside = _mm256_and_ps(inside, ok);
            } else {
                let near = r.near[axis];
                let mut pn = load(&node.bounds[near]);
                let mut pf = load(&node.bounds[near ^ 1]);
                if MARGIN {
                    if near & 1 == 0 {
                        pn = _mm256_sub_ps(pn, m);
                        pf = _mm256_add_ps(pf, m);
                    } else {
                        pn = _mm256_add_ps(pn, m);
                        pf = _mm256_sub_ps(pf, m);
                    }
                }
                let inv = _mm256_set1_ps(r.inv[axis]);
                tn = _mm256_max_ps(tn, _mm256_mul_ps(_mm256_sub_ps(pn, o), inv));
                tf = _mm256_min_ps(tf, _mm256_mul_ps(_mm256_sub_ps(pf, o), inv));
            }
        }
        // As in `child_hits`: tn ≥ tmin ≥ 0, and a negative tf is a miss either way.
        let tn = _mm256_mul_ps(tn, _mm256_set1_ps(1.0 - WIDEN));
        let tf = _mm256_mul_ps(tf, _mm256_set1_ps(1.0 + WIDEN));
        let hit = _mm256_and_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(tn, tf), inside);
        let mut t_out = [0.0f32; 8];
        _mm256_storeu_ps(t_out.as_mut_ptr(), tn);
        (t_out, _mm256_movemask_ps(hit) as u32)
    }
}

/// Asks for the four cache lines of a child node that the walk will visit (the nearest child
/// next, the others later from the stack): traversal is bound by memory latency, and the
/// child's index is known a whole box test before its boxes are needed.
#[inline(always)]
fn prefetch_node(nodes: &[WideNode], index: u32) {
    #[cfg(target_arch = "x86_64")]
    if let Some(n) = nodes.get(index as usize) {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        let p = n as *const WideNode as *const i8;
        for line in 0..size_of::<WideNode>().div_ceil(64) {
            // SAFETY: a prefetch is only a hint; the address lies inside the node.
            #[allow(unused_unsafe)]
            unsafe {
                _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(64 * line))
            };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (nodes, index);
}

/// A pending child: its entry distance and meta, and what else a walk keeps with it (`X`: the
/// packet walk's ray mask).
#[derive(Clone, Copy, Default)]
struct Entry<X = ()> {
    t: f32,
    meta: u32,
    rays: X,
}

/// LIFO of pending children: a fixed array, spilling to a `Vec` only for trees deeper than
/// about five levels whose children are nearly all hit (each level leaves at most seven
/// entries). The array is left uninitialised: zeroing its 256 bytes on every walk (one per
/// instance a ray visits) cost more than the rest of a short walk.
struct Stack<E = Entry> {
    arr: [MaybeUninit<E>; 32],
    len: usize,
    spill: Vec<E>,
}

impl<E: Copy> Stack<E> {
    #[inline(always)]
    fn new() -> Self {
        Stack {
            arr: [const { MaybeUninit::uninit() }; 32],
            len: 0,
            spill: Vec::new(),
        }
    }
    #[inline(always)]
    fn push(&mut self, e: E) {
        if self.len < self.arr.len() {
            self.arr[self.len] = MaybeUninit::new(e);
            self.len += 1;
        } else {
            self.spill.push(e);
        }
    }
    #[inline(always)]
    fn pop(&mut self) -> Option<E> {
        // Spilled entries are the newest.
        if let Some(e) = self.spill.pop() {
            return Some(e);
        }
        if self.len == 0 {
            return None;
        }
        self.len -= 1;
        // SAFETY: every slot below `len` was written by `push`.
        Some(unsafe { self.arr[self.len].assume_init() })
    }
}

/// Walks the tree nearest-child-first, calling `leaf(first, count, tmax)` for every leaf whose
/// box the ray meets within `[tmin, *tmax]` (the primitives are `order[first..first + count]`).
/// The callback may shrink `*tmax` (closest hit) or break (any hit).
///
/// On CPUs with AVX2 (detected at run time) the whole walk, leaf callback included, is
/// compiled for AVX2 and tests the eight children of a node at once; elsewhere it tests them
/// four at a time. Both visit the same leaves in the same order.
#[inline(always)]
pub(crate) fn traverse<const MARGIN: bool>(
    nodes: &[WideNode],
    r: &NodeRay,
    tmin: f32,
    tmax: &mut f32,
    margin: f32,
    mut leaf: impl FnMut(u32, u32, &mut f32) -> ControlFlow<()>,
) {
    dispatch::<MARGIN, true, false>(nodes, r, tmin, tmax, margin, |meta, _, tmax| {
        leaf(meta & FIRST_MASK, leaf_count(meta), tmax)
    })
}

/// [`traverse`] for any-hit queries: the hit children are not sorted by distance (the first
/// hit anywhere ends the walk, so the order only costs time). Visits the same set of leaves
/// when the callback never breaks or shrinks `tmax`.
#[inline(always)]
pub(crate) fn traverse_any<const MARGIN: bool>(
    nodes: &[WideNode],
    r: &NodeRay,
    tmin: f32,
    tmax: &mut f32,
    margin: f32,
    mut leaf: impl FnMut(u32, u32, &mut f32) -> ControlFlow<()>,
) {
    dispatch::<MARGIN, false, false>(nodes, r, tmin, tmax, margin, |meta, _, tmax| {
        leaf(meta & FIRST_MASK, leaf_count(meta), tmax)
    })
}

/// The walk for trees whose leaves are grouped per node (the mesh trees, see `super::leaf`):
/// when a node is visited, `leaf(meta, mask, tmax)` is called once for all of its leaf children
/// that the ray meets, `mask` holding their slots and `meta` the [`WideNode::meta`] of the first
/// of them, before the node's inner children are ordered and pushed (those the shrunk `tmax`
/// now excludes are dropped). `ORDERED` sorts the inner children nearest first (closest hit);
/// without it they are taken in slot order (any hit).
#[inline(always)]
pub(crate) fn traverse_grouped<const ORDERED: bool>(
    nodes: &[WideNode],
    r: &NodeRay,
    tmin: f32,
    tmax: &mut f32,
    leaf: impl FnMut(u32, u32, &mut f32) -> ControlFlow<()>,
) {
    dispatch::<false, ORDERED, true>(nodes, r, tmin, tmax, 0.0, leaf)
}

/// [`traverse_grouped`] for two rays at once, their walks interleaved node by node: each
/// visits the same leaves in the same order as alone, and `leaf(k, meta, mask, tmax)` is
/// called for ray `k` as `traverse_grouped` would call it (a break ends that ray's walk only).
///
/// **Why two at a time.** A walk waits on each node it loads, and on a tree far larger than
/// the caches (tens of megabytes of nodes and leaf blocks: a mesh of a million triangles) the
/// wait is a trip to memory; with two independent walks in the instruction window, the
/// processor overlaps one's wait with the other's work (the latency hiding of interleaved
/// traversal, as GPUs get it from many threads in flight). On trees that fit the caches it
/// only adds the switching: see [`super::INTERLEAVE_BYTES`] for who takes it.
#[inline(always)]
pub(crate) fn traverse_grouped_pair<const ORDERED: bool>(
    nodes: &[WideNode],
    rays: [&NodeRay; 2],
    tmin: f32,
    tmax: &mut [f32; 2],
    leaf: impl FnMut(usize, u32, u32, &mut f32) -> ControlFlow<()>,
) {
    let tmin = query_tmin(tmin);
    #[cfg(target_arch = "x86_64")]
    if has_avx2() {
        // SAFETY: the CPU supports AVX2 (just checked).
        unsafe { traverse_pair_avx2::<ORDERED>(nodes, rays, tmin, tmax, leaf) };
        return;
    }
    traverse_pair::<false, ORDERED>(nodes, rays, tmin, tmax, leaf)
}

/// [`traverse_pair`] compiled with AVX2.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn traverse_pair_avx2<const ORDERED: bool>(
    nodes: &[WideNode],
    rays: [&NodeRay; 2],
    tmin: f32,
    tmax: &mut [f32; 2],
    leaf: impl FnMut(usize, u32, u32, &mut f32) -> ControlFlow<()>,
) {
    traverse_pair::<true, ORDERED>(nodes, rays, tmin, tmax, leaf)
}

/// The interleaved walks of [`traverse_grouped_pair`]: a step of each in turn while both
/// last, then the one left alone.
#[inline(always)]
fn traverse_pair<const AVX2: bool, const ORDERED: bool>(
    nodes: &[WideNode],
    rays: [&NodeRay; 2],
    tmin: f32,
    tmax: &mut [f32; 2],
    mut leaf: impl FnMut(usize, u32, u32, &mut f32) -> ControlFlow<()>,
) {
    let [t0, t1] = tmax;
    let (r0, r1) = (rays[0], rays[1]);
    let (mut a, mut b) = (Walk::new(0, tmin), Walk::new(0, tmin));
    let mut a_on = Walk::can_start(nodes, tmin, *t0);
    let mut b_on = Walk::can_start(nodes, tmin, *t1);
    while a_on && b_on {
        a_on = a
            .step::<false, AVX2, ORDERED, true>(nodes, r0, tmin, t0, 0.0, &mut |m, s, t| {
                leaf(0, m, s, t)
            })
            .is_continue();
        b_on = b
            .step::<false, AVX2, ORDERED, true>(nodes, r1, tmin, t1, 0.0, &mut |m, s, t| {
                leaf(1, m, s, t)
            })
            .is_continue();
    }
    while a_on {
        a_on = a
            .step::<false, AVX2, ORDERED, true>(nodes, r0, tmin, t0, 0.0, &mut |m, s, t| {
                leaf(0, m, s, t)
            })
            .is_continue();
    }
    while b_on {
        b_on = b
            .step::<false, AVX2, ORDERED, true>(nodes, r1, tmin, t1, 0.0, &mut |m, s, t| {
                leaf(1, m, s, t)
            })
            .is_continue();
    }
}

/// Number of primitives (or, in a grouped tree, of blocks) of a leaf child's `meta`.
#[inline(always)]
pub(crate) fn leaf_count(meta: u32) -> u32 {
    ((meta >> 29) & 3) + 1
}

/// First primitive (or, in a grouped tree, first block) of a leaf child's `meta`.
#[inline(always)]
pub(crate) fn leaf_first(meta: u32) -> u32 {
    meta & FIRST_MASK
}

/// The slots of `node` that hold leaves (bit i for child i).
#[inline(always)]
fn leaf_slots(node: &WideNode) -> u32 {
    let mut m = 0;
    for (i, meta) in node.meta.iter().enumerate() {
        m |= (meta >> 31) << i;
    }
    m
}

/// [`leaf_slots`] in one instruction: [`LEAF_BIT`] is the sign bit of each `meta`.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn leaf_slots_avx2(node: &WideNode) -> u32 {
    use std::arch::x86_64::*;
    const _: () = assert!(LEAF_BIT == 1 << 31);
    // SAFETY: an unaligned load of the eight u32 of `meta`.
    unsafe {
        let meta = _mm256_loadu_si256(node.meta.as_ptr() as *const __m256i);
        _mm256_movemask_ps(_mm256_castsi256_ps(meta)) as u32
    }
}

/// The `tmin` every walk (and the leaf tests under it) uses: a negative one is taken as 0, so
/// nothing behind the origin is reported (Embree likewise requires tnear ≥ 0). With tmin ≥ 0
/// every entry distance is ≥ 0, which the node tests' widening relies on. NaN stays NaN (and is
/// turned away by the walk).
#[inline(always)]
pub(crate) fn query_tmin(tmin: f32) -> f32 {
    if tmin < 0.0 { 0.0 } else { tmin }
}

/// [`leaf_slots`], by one `movemask` when `AVX2` (only true inside [`traverse_avx2`]).
#[inline(always)]
fn leaf_slots_with<const AVX2: bool>(node: &WideNode) -> u32 {
    #[cfg(target_arch = "x86_64")]
    if AVX2 {
        // SAFETY: `AVX2` is only true inside `traverse_avx2`, which runs on AVX2 CPUs.
        return unsafe { leaf_slots_avx2(node) };
    }
    leaf_slots(node)
}

#[inline(always)]
fn dispatch<const MARGIN: bool, const ORDERED: bool, const GROUPED: bool>(
    nodes: &[WideNode],
    r: &NodeRay,
    tmin: f32,
    tmax: &mut f32,
    margin: f32,
    leaf: impl FnMut(u32, u32, &mut f32) -> ControlFlow<()>,
) {
    let tmin = query_tmin(tmin);
    #[cfg(target_arch = "x86_64")]
    if has_avx2() {
        // SAFETY: the CPU supports AVX2 (just checked).
        unsafe { traverse_avx2::<MARGIN, ORDERED, GROUPED>(nodes, r, tmin, tmax, margin, leaf) };
        return;
    }
    traverse_impl::<MARGIN, false, ORDERED, GROUPED>(nodes, 0, r, tmin, tmax, margin, leaf)
}

/// [`traverse_impl`] compiled with AVX2.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn traverse_avx2<const MARGIN: bool, const ORDERED: bool, const GROUPED: bool>(
    nodes: &[WideNode],
    r: &NodeRay,
    tmin: f32,
    tmax: &mut f32,
    margin: f32,
    leaf: impl FnMut(u32, u32, &mut f32) -> ControlFlow<()>,
) {
    traverse_impl::<MARGIN, true, ORDERED, GROUPED>(nodes, 0, r, tmin, tmax, margin, leaf)
}

/// The walk; `AVX2` selects [`child_hits_avx2`] (only reached through [`traverse_avx2`]);
/// `ORDERED` sorts the hit children nearest first; `GROUPED` hands a node's hit leaf children
/// to `leaf(meta, mask, tmax)` together when the node is visited (see [`traverse_grouped`]),
/// otherwise each leaf child is stacked like a node and handed over alone as `leaf(meta, 0,
/// tmax)` when its turn comes.
#[inline(always)]
fn traverse_impl<const MARGIN: bool, const AVX2: bool, const ORDERED: bool, const GROUPED: bool>(
    nodes: &[WideNode],
    root: u32,
    r: &NodeRay,
    tmin: f32,
    tmax: &mut f32,
    margin: f32,
    mut leaf: impl FnMut(u32, u32, &mut f32) -> ControlFlow<()>,
) {
    if !Walk::can_start(nodes, tmin, *tmax) {
        return;
    }
    let mut walk = Walk::new(root, tmin);
    while walk
        .step::<MARGIN, AVX2, ORDERED, GROUPED>(nodes, r, tmin, tmax, margin, &mut leaf)
        .is_continue()
    {}
}

/// Where a walk stands: the child it takes next and the pending ones.
struct Walk {
    next: Option<Entry>,
    stack: Stack,
}

impl Walk {
    /// Whether there is anything to walk over `[tmin, tmax]`: nodes, no NaN bound, not an
    /// empty interval.
    #[inline(always)]
    fn can_start(nodes: &[WideNode], tmin: f32, tmax: f32) -> bool {
        // (NaN bounds fail too.)
        !(nodes.is_empty() || tmin.is_nan() || tmax.is_nan() || tmin > tmax)
    }

    /// A walk from `root`, made where it stays (a walk moved after it was made copied its
    /// stack's 256 bytes: the saw's incoherent rays, which walk many small instances, were
    /// several per cent slower).
    #[inline(always)]
    fn new(root: u32, tmin: f32) -> Walk {
        Walk {
            next: Some(Entry {
                t: tmin,
                meta: root,
                rays: (),
            }),
            stack: Stack::new(),
        }
    }

    /// Takes the next pending child and visits it: a node is tested and its hit children
    /// pushed (the nearest kept as the next), a leaf handed to `leaf` (see [`traverse_impl`]).
    /// Breaks when the walk is over: nothing pending, or `leaf` broke.
    #[inline(always)]
    fn step<const MARGIN: bool, const AVX2: bool, const ORDERED: bool, const GROUPED: bool>(
        &mut self,
        nodes: &[WideNode],
        r: &NodeRay,
        tmin: f32,
        tmax: &mut f32,
        margin: f32,
        leaf: &mut impl FnMut(u32, u32, &mut f32) -> ControlFlow<()>,
    ) -> ControlFlow<()> {
        let Some(e) = self.next.take().or_else(|| self.stack.pop()) else {
            return ControlFlow::Break(());
        };
        if e.t > *tmax {
            return ControlFlow::Continue(());
        }
        if !GROUPED && e.meta & LEAF_BIT != 0 {
            return leaf(e.meta, 0, tmax);
        }
        let node = &nodes[e.meta as usize];
        #[cfg(target_arch = "x86_64")]
        let (t, mut mask) = if AVX2 {
            // SAFETY: `AVX2` is only true inside functions compiled for AVX2, which run on
            // AVX2 CPUs.
            unsafe { child_hits_avx2::<MARGIN>(node, r, tmin, *tmax, margin) }
        } else {
            child_hits::<MARGIN>(node, r, tmin, *tmax, margin)
        };
        #[cfg(not(target_arch = "x86_64"))]
        let (t, mut mask) = child_hits::<MARGIN>(node, r, tmin, *tmax, margin);
        if GROUPED {
            let leaves = mask & leaf_slots_with::<AVX2>(node);
            if leaves != 0 {
                let meta = node.meta[leaves.trailing_zeros() as usize];
                leaf(meta, leaves, tmax)?;
                mask &= !leaves;
            }
        }
        if mask == 0 {
            return ControlFlow::Continue(());
        }
        if mask & (mask - 1) == 0 {
            // One child hit (the common case near the leaves): no sorting, no stack.
            let i = mask.trailing_zeros() as usize;
            let e = Entry {
                t: t[i],
                meta: node.meta[i],
                rays: (),
            };
            if e.meta & LEAF_BIT == 0 {
                prefetch_node(nodes, e.meta);
            }
            self.next = Some(e);
            return ControlFlow::Continue(());
        }
        // Gather the hit children as keys of their entry distance and meta ([`child_key`]),
        // and sort them nearest first: by compare-exchange networks for two to four
        // children, whose minima and maxima compile to selects (the insertion sort before
        // branched on every comparison, and which way cannot be predicted).
        let mut keys = [0u64; 8];
        let mut n = 0;
        while mask != 0 {
            let i = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            let (ti, meta) = (t[i], node.meta[i]);
            // In a grouped walk the leaves may just have shrunk tmax.
            if GROUPED && ti > *tmax {
                continue;
            }
            if meta & LEAF_BIT == 0 {
                prefetch_node(nodes, meta);
            }
            keys[n] = child_key(ti, meta);
            n += 1;
        }
        if n == 0 {
            return ControlFlow::Continue(());
        }
        if ORDERED {
            sort_keys(&mut keys, n);
        }
        let entry = |key: u64| Entry {
            t: f32::from_bits((key >> 32) as u32),
            meta: key as u32,
            rays: (),
        };
        // Farthest first onto the stack; the nearest is handled next without a round trip.
        for &key in keys[1..n].iter().rev() {
            self.stack.push(entry(key));
        }
        self.next = Some(entry(keys[0]));
        ControlFlow::Continue(())
    }
}

/// A child's sort key: its entry distance's bits above `low` (its meta, or its slot), so that
/// keys order as the distances, ties by `low`. Entry distances are ≥ 0, where the bits order
/// as the values; a −0 is taken as +0.
#[inline(always)]
fn child_key(t: f32, low: u32) -> u64 {
    u64::from(t.to_bits() & 0x7fff_ffff) << 32 | u64::from(low)
}

/// Sorts `keys[..n]` ascending: compare-exchange networks (selects, no branches) up to four,
/// an insertion sort above.
#[inline(always)]
fn sort_keys(keys: &mut [u64; 8], n: usize) {
    let mut exchange = |a: usize, b: usize| {
        let (x, y) = (keys[a], keys[b]);
        keys[a] = x.min(y);
        keys[b] = x.max(y);
    };
    match n {
        0 | 1 => {}
        2 => exchange(0, 1),
        3 => {
            exchange(0, 1);
            exchange(1, 2);
            exchange(0, 1);
        }
        4 => {
            exchange(0, 1);
            exchange(2, 3);
            exchange(0, 2);
            exchange(1, 3);
            exchange(1, 2);
        }
        _ => keys[..n].sort_unstable(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn leaves(bvh: &WideBvh, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Vec<u32> {
        let mut out = Vec::new();
        let mut tmax = tmax;
        traverse::<false>(
            &bvh.nodes,
            &NodeRay::new(o, d),
            tmin,
            &mut tmax,
            0.0,
            |f, c, _| {
                out.extend(&bvh.order[f as usize..(f + c) as usize]);
                ControlFlow::Continue(())
            },
        );
        out.sort_unstable();
        out
    }

    /// Adds the primitives of a [`PacketLeaf::Packet`] to the list of each of its rays.
    pub(super) fn record_leaf(seen: &mut [Vec<u32>], what: PacketLeaf) {
        if let PacketLeaf::Packet { meta, rays } = what {
            let (first, count) = (leaf_first(meta), leaf_count(meta));
            for (i, s) in seen.iter_mut().enumerate() {
                if rays & (1 << i) != 0 {
                    s.extend(first..first + count);
                }
            }
        }
    }

    pub(super) fn grid() -> (Vec<OAabb>, WideBvh) {
        let boxes: Vec<OAabb> = (0..200)
            .map(|i| {
                let c = Vec3A::new((i % 10) as f32, ((i / 10) % 5) as f32, (i / 50) as f32);
                OAabb::new(c, c + Vec3A::new(0.5, 0.25, 0.75))
            })
            .collect();
        let bvh = build(&boxes, &BvhBuildParams::medium_build());
        (boxes, bvh)
    }

    #[test]
    fn axis_parallel_rays_on_faces_and_edges_are_kept() {
        let (boxes, bvh) = grid();
        assert_eq!(bvh.order.len(), boxes.len());
        for (i, b) in boxes.iter().enumerate() {
            // Along +x / −x exactly on the box's max-y face, and along its min corner edge.
            let on_face = Vec3::new(b.min.x - 0.1, b.max.y, b.min.z + 0.1);
            assert!(leaves(&bvh, on_face, Vec3::X, 0.0, 100.0).contains(&(i as u32)));
            let on_edge = Vec3::new(b.max.x + 0.1, b.min.y, b.min.z);
            assert!(leaves(&bvh, on_edge, -Vec3::X, 0.0, 100.0).contains(&(i as u32)));
            // −0.0 components are parallel too.
            let d = Vec3::new(-0.0, -0.0, 1.0);
            let below = Vec3::new(b.max.x, b.max.y, b.min.z - 1.0);
            assert!(leaves(&bvh, below, d, 0.0, 100.0).contains(&(i as u32)));
        }
    }

    #[test]
    fn short_intervals_and_touching_rays_are_kept() {
        let (boxes, bvh) = grid();
        for (i, b) in boxes.iter().enumerate() {
            // Entering at t = 3e-5 with tmax = 5e-5 (obvhs clamps the entry at 1e-4).
            let o = Vec3::new(b.min.x - 3e-5, b.min.y + 0.1, b.min.z + 0.1);
            assert!(leaves(&bvh, o, Vec3::X, 0.0, 5e-5).contains(&(i as u32)));
            // Touching the box only at its max corner, from a diagonal direction.
            let corner = Vec3::from(b.max);
            let d = Vec3::new(1.0, -1.0, 0.5);
            let o = corner - 2.0 * d;
            let got = leaves(&bvh, o, d, 0.0, 10.0);
            let exact = crate::accel::bvh::ray_box_interval(
                &crate::geom::Aabb::new(b.min.into(), b.max.into()),
                &crate::geom::Ray {
                    origin: o,
                    direction: d,
                },
                0.0,
                10.0,
            );
            if exact.is_some() {
                assert!(got.contains(&(i as u32)));
            }
        }
    }

    /// The walk's child order: every count of hit children, keys with repeated distances and
    /// metas, against a full sort.
    #[test]
    fn child_keys_sort_ascending() {
        let mut rng = crate::rng::Rng::new(17);
        for case in 0..20_000 {
            let n = case % 9;
            let mut keys = [0u64; 8];
            for k in keys.iter_mut().take(n) {
                // Few distinct distances and metas, so that ties are common.
                let t = rng.below(4) as f32 * 0.5;
                *k = u64::from(t.to_bits()) << 32 | rng.below(3);
            }
            let mut expected = keys;
            expected[..n].sort_unstable();
            sort_keys(&mut keys, n);
            assert_eq!(keys[..n], expected[..n], "case {case}");
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_node_test_matches_the_portable_one() {
        if !has_avx2() {
            eprintln!("no AVX2 on this CPU: only the portable node test exists here");
            return;
        }
        let mut rng = crate::rng::Rng::new(99);
        let mut hits = 0;
        for i in 0..20_000 {
            let mut node = WideNode::EMPTY;
            let filled = 1 + i % 8;
            for slot in 0..filled {
                let lo = rng.vec3_in(-2.0, 2.0);
                let hi = lo + rng.vec3_in(0.0, 1.0);
                for axis in 0..3 {
                    node.bounds[2 * axis][slot] = lo[axis];
                    node.bounds[2 * axis + 1][slot] = hi[axis];
                }
            }
            let o = rng.vec3_in(-4.0, 4.0);
            // Aimed at the first child's minimum corner region, so that most rays hit.
            let aim = Vec3::new(node.bounds[0][0], node.bounds[2][0], node.bounds[4][0]);
            let mut d = (aim + rng.vec3_in(0.0, 0.5) - o).normalize_or(Vec3::X);
            // Axis-parallel and −0 components too.
            match i % 5 {
                0 => d.x = 0.0,
                1 => d = Vec3::new(-0.0, d.y, 0.0),
                _ => {}
            }
            let r = NodeRay::new(o, d);
            // tmin ≥ 0, as `dispatch` makes it (0 half of the time).
            let (tmin, tmax) = (rng.range_f32(-1.0, 1.0).max(0.0), rng.range_f32(0.0, 20.0));
            let margin = if i % 3 == 0 {
                rng.range_f32(0.0, 0.5)
            } else {
                0.0
            };
            let portable = if margin > 0.0 {
                child_hits::<true>(&node, &r, tmin, tmax, margin)
            } else {
                child_hits::<false>(&node, &r, tmin, tmax, margin)
            };
            // SAFETY: AVX2 was detected above.
            let avx = unsafe {
                if margin > 0.0 {
                    child_hits_avx2::<true>(&node, &r, tmin, tmax, margin)
                } else {
                    child_hits_avx2::<false>(&node, &r, tmin, tmax, margin)
                }
            };
            assert_eq!(portable.1, avx.1, "mask, case {i}");
            for k in 0..8 {
                assert_eq!(
                    portable.0[k].to_bits(),
                    avx.0[k].to_bits(),
                    "entry distance {k}, case {i}"
                );
            }
            hits += portable.1.count_ones();
        }
        assert!(hits > 5_000, "the cases must hit boxes: {hits}");
    }

    #[test]
    fn portable_and_avx2_walks_visit_the_same_leaves() {
        let (_, bvh) = grid();
        let mut rng = crate::rng::Rng::new(5);
        for _ in 0..2000 {
            let o = rng.vec3_in(-2.0, 12.0);
            let d = rng.direction();
            let r = NodeRay::new(o, d);
            let walk = |avx: bool, grouped: bool| {
                let mut seen = Vec::new();
                let mut tmax = 30.0;
                let leaf = |meta: u32, mask: u32, tmax: &mut f32| {
                    seen.push((meta, mask));
                    // Shrink like a closest-hit query so the pruning is exercised.
                    *tmax = (*tmax * 0.9).max(5.0);
                    ControlFlow::Continue(())
                };
                match (avx, grouped) {
                    (true, false) => {
                        dispatch::<false, true, false>(&bvh.nodes, &r, 0.0, &mut tmax, 0.0, leaf)
                    }
                    (false, false) => traverse_impl::<false, false, true, false>(
                        &bvh.nodes, 0, &r, 0.0, &mut tmax, 0.0, leaf,
                    ),
                    (true, true) => traverse_grouped::<true>(&bvh.nodes, &r, 0.0, &mut tmax, leaf),
                    (false, true) => traverse_impl::<false, false, true, true>(
                        &bvh.nodes, 0, &r, 0.0, &mut tmax, 0.0, leaf,
                    ),
                }
                seen
            };
            assert_eq!(walk(true, false), walk(false, false));
            assert_eq!(walk(true, true), walk(false, true));
        }
    }

    /// A grouped walk hands over every leaf that the one-leaf-at-a-time walk visits (with the
    /// same shrinking of tmax the set can only differ by the order the leaves come in, which
    /// changes what is pruned; without shrinking it is the same set).
    #[test]
    fn grouped_walk_reaches_the_same_leaves() {
        let (_, bvh) = grid();
        let mut rng = crate::rng::Rng::new(9);
        for _ in 0..2000 {
            let o = rng.vec3_in(-2.0, 12.0);
            let d = rng.direction();
            let r = NodeRay::new(o, d);
            let mut single = Vec::new();
            traverse::<false>(&bvh.nodes, &r, 0.0, &mut 30.0, 0.0, |f, c, _| {
                single.push((f, c));
                ControlFlow::Continue(())
            });
            let mut grouped = Vec::new();
            traverse_grouped::<true>(&bvh.nodes, &r, 0.0, &mut 30.0, |meta, mask, _| {
                let node = bvh
                    .nodes
                    .iter()
                    .find(|n| n.meta.contains(&meta))
                    .expect("the meta of a node's leaf");
                for slot in 0..8 {
                    if mask & (1 << slot) != 0 {
                        let m = node.meta[slot];
                        grouped.push((leaf_first(m), leaf_count(m)));
                    }
                }
                ControlFlow::Continue(())
            });
            single.sort_unstable();
            grouped.sort_unstable();
            assert_eq!(single, grouped);
        }
    }

    /// Two interleaved walks make, for each ray, the very calls of its own walk in the same
    /// order, with the same tmax, whether the callback shrinks tmax (closest hit) or breaks
    /// (any hit), and whichever of the two rays finishes first.
    #[test]
    fn a_pair_walk_makes_each_rays_own_calls() {
        let (_, bvh) = grid();
        let mut rng = crate::rng::Rng::new(21);
        // The callback: record the call, shrink tmax towards a point fixed by the leaf, and
        // break at the `stop`-th call of the ray.
        let visit =
            |log: &mut Vec<(u32, u32, u32)>, stop: usize, meta: u32, mask: u32, t: &mut f32| {
                log.push((meta, mask, t.to_bits()));
                *t = t.min(2.0 + (meta % 7) as f32);
                if log.len() == stop {
                    ControlFlow::Break(())
                } else {
                    ControlFlow::Continue(())
                }
            };
        for case in 0..3000 {
            let rays: [NodeRay; 2] =
                std::array::from_fn(|_| NodeRay::new(rng.vec3_in(-2.0, 12.0), rng.direction()));
            let tmax = [rng.range_f32(0.0, 30.0), rng.range_f32(0.0, 30.0)];
            let stop = [rng.below(6) as usize, rng.below(6) as usize];
            let alone: Vec<Vec<(u32, u32, u32)>> = (0..2)
                .map(|k| {
                    let mut log = Vec::new();
                    let mut t = tmax[k];
                    traverse_grouped::<true>(&bvh.nodes, &rays[k], 0.0, &mut t, |m, s, t| {
                        visit(&mut log, stop[k], m, s, t)
                    });
                    log
                })
                .collect();
            let mut logs = [Vec::new(), Vec::new()];
            let mut t = tmax;
            traverse_grouped_pair::<true>(
                &bvh.nodes,
                [&rays[0], &rays[1]],
                0.0,
                &mut t,
                |k, m, s, t| visit(&mut logs[k], stop[k], m, s, t),
            );
            assert_eq!(logs[0], alone[0], "case {case}, ray 0");
            assert_eq!(logs[1], alone[1], "case {case}, ray 1");
            // The portable node test (CPUs without AVX2) interleaves alike.
            let mut logs = [Vec::new(), Vec::new()];
            let mut t = tmax;
            traverse_pair::<false, true>(
                &bvh.nodes,
                [&rays[0], &rays[1]],
                0.0,
                &mut t,
                |k, m, s, t| visit(&mut logs[k], stop[k], m, s, t),
            );
            assert_eq!(
                logs,
                [alone[0].clone(), alone[1].clone()],
                "case {case}, portable"
            );
        }
    }

    #[test]
    fn stack_spills_in_lifo_order() {
        let mut s = Stack::new();
        for i in 0..100 {
            s.push(Entry {
                t: i as f32,
                meta: i,
                rays: (),
            });
        }
        for i in (0..100).rev() {
            assert_eq!(s.pop().map(|e| e.meta), Some(i));
        }
        assert!(s.pop().is_none());
    }

    /// After `one_primitive_per_leaf` every leaf holds one primitive under its own box, each
    /// primitive once, children still after their parents, and a walk hands over exactly the
    /// primitives of the leaves its ray enters: those whose own box it meets, out of those the
    /// tree before the change handed over.
    #[test]
    fn one_primitive_per_leaf_gives_each_its_own_box() {
        let mut rng = crate::rng::Rng::new(3);
        let boxes: Vec<OAabb> = (0..500)
            .map(|_| {
                let lo = Vec3A::from(rng.vec3_in(0.0, 10.0));
                OAabb::new(lo, lo + Vec3A::from(rng.vec3_in(0.01, 1.5)))
            })
            .collect();
        let before = build(&boxes, &BvhBuildParams::medium_build());
        let mut after = before.clone();
        one_primitive_per_leaf(&mut after, &boxes);
        assert!(
            after.nodes.len() > before.nodes.len(),
            "leaves of several were split"
        );
        assert!(after.max_depth <= before.max_depth + 1);
        let mut seen = vec![0; boxes.len()];
        for (ni, node) in after.nodes.iter().enumerate() {
            for slot in 0..8 {
                let (meta, used) = (
                    node.meta[slot],
                    node.bounds[0][slot] <= node.bounds[1][slot],
                );
                if !used {
                    continue;
                }
                if meta & LEAF_BIT == 0 {
                    assert!(meta as usize > ni, "a child before its parent");
                    continue;
                }
                assert_eq!(leaf_count(meta), 1);
                let p = after.order[leaf_first(meta) as usize] as usize;
                seen[p] += 1;
                let b = &boxes[p];
                for axis in 0..3 {
                    assert_eq!(node.bounds[2 * axis][slot], b.min[axis]);
                    assert_eq!(node.bounds[2 * axis + 1][slot], b.max[axis]);
                }
            }
        }
        assert!(seen.iter().all(|&n| n == 1), "each primitive in one leaf");
        for _ in 0..300 {
            let (o, d) = (rng.vec3_in(-2.0, 12.0), rng.direction());
            let got = leaves(&after, o, d, 0.0, f32::INFINITY);
            let all = leaves(&before, o, d, 0.0, f32::INFINITY);
            let ray = crate::geom::Ray {
                origin: o,
                direction: d,
            };
            for p in 0..boxes.len() as u32 {
                let b = &boxes[p as usize];
                let aabb = crate::geom::Aabb::new(b.min.into(), b.max.into());
                let meets = aabb.ray_interval(&ray, 0.0, f32::INFINITY).is_some();
                if meets {
                    assert!(
                        got.contains(&p),
                        "the walk skipped primitive {p}, whose box it meets"
                    );
                }
                if got.contains(&p) {
                    assert!(all.contains(&p), "primitive {p} handed over, not before");
                }
            }
            assert!(got.len() <= all.len());
        }
    }

    #[test]
    fn identical_boxes_give_a_shallow_tree() {
        let b = OAabb::new(Vec3A::ZERO, Vec3A::ONE);
        let bvh = build(&vec![b; 10_000], &BvhBuildParams::fast_build());
        assert!(bvh.max_depth < 20, "depth {}", bvh.max_depth);
        let all = leaves(&bvh, Vec3::splat(0.5), Vec3::X, 0.0, 1.0);
        assert_eq!(all.len(), 10_000);
        let p = OAabb::new(Vec3A::ONE, Vec3A::ONE);
        let bvh = build(&vec![p; 5000], &BvhBuildParams::fast_build());
        assert!(bvh.max_depth < 20, "depth {}", bvh.max_depth);
    }

    /// Boxes evenly spaced along a line (instances in a row) tie as identical ones do: each
    /// box's two neighbours make equally cheap merges, few pairs form per round, and the build
    /// was quadratic (20,000 boxes: 6.4 s; 200,000: about ten minutes, by that rate). Built on
    /// a thread of its own, so that a return of the quadratic build fails within a minute
    /// instead of hanging the suite; it now takes well under a second.
    #[test]
    fn evenly_spaced_boxes_build_without_a_quadratic_search() {
        let (done, finished) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let boxes: Vec<OAabb> = (0..200_000)
                .map(|i| {
                    let x = 3.0 * i as f32;
                    OAabb::new(
                        Vec3A::new(x - 0.5, -0.5, -0.5),
                        Vec3A::new(x + 0.5, 0.5, 0.5),
                    )
                })
                .collect();
            let bvh = build(&boxes, &BvhBuildParams::medium_build());
            let _ = done.send(leaves(&bvh, Vec3::new(-1.0, 0.0, 0.0), Vec3::X, 0.0, 1e7).len());
        });
        let reached = finished
            .recv_timeout(std::time::Duration::from_secs(60))
            .expect("200,000 boxes in a row not built within a minute: the ties are unbroken");
        assert_eq!(reached, 200_000);
    }
}
