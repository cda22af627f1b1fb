//! Lane walks: up to sixteen rays walk a tree together, one ray per lane of an AVX-512
//! register (or of two AVX2 registers), each child box tested for all of them at once — the
//! packet traversal of rays that start close together but share no frustum (AO and diffuse
//! rays of neighbouring pixels).
//!
//! This is the ray-per-lane packet traversal of Wald, Slusallek, Benthin & Wagner ("Interactive
//! Rendering with Coherent Ray Tracing", CGF 20(3), 2001), as Embree runs it for its 16-ray
//! queries on AVX-512 (Wald, Woop, Benthin, Johnson & Ernst, "Embree: A Kernel Framework for
//! Efficient CPU Ray Tracing", ACM TOG 33(4), 2014, §4.2): a single-ray walk of an 8-wide
//! tree fills eight lanes with one ray's eight children; this fills sixteen with sixteen rays'
//! one child. It pays while many rays share a node, near the top of the tree; where fewer
//! than [`SOLO`] + 1 rays are left in a subtree, each finishes it with its own single-ray walk.
//! Rays from all over the scene share only the root, and one order of children serves each of
//! them worse than its own nearest-first walk: the caller keeps those to single-ray walks
//! (`InstanceBvh::near_origins`).
//!
//! **Same answers.** Each lane computes its ray's slab distances with the operations of the
//! single-ray test ([`super::child_hits_avx2`]) in the same order, on the same `f32` values
//! (the entry plane's distance is the smaller of the two planes', see [`node_lanes`]; the
//! margin grows the box as there; the widening is the same). So a lane's mask and entry
//! distance for a child are bit for bit its ray's own. A ray leaves a child only by its own
//! test with its own current `tmax`, and leaves are handed over per ray, so each ray's leaf
//! tests are a superset of what its single-ray walk performs; closest-hit ties are broken by
//! index (the query contract in `super::super`), so the answers are the single-ray ones
//! (`lane_walks_give_the_single_ray_answers` in `tests/bvh.rs`).
//!
//! Rays parallel to an axis (a containment test there) or with a non-finite origin are left to
//! the single-ray walk: [`lanes_take`] turns such a set away.
//!
//! **Two instruction sets, one walk.** The walk and its node test are written once over
//! [`Lanes16`], sixteen `f32` lanes with the few operations they need, which one AVX-512
//! register or a pair of AVX2 registers provides ([`lane_set`] picks at run time). The single-ray
//! walk is bound by the latency of its node-to-child chain (about 50 ns per visit on the bench
//! models), not by its arithmetic, so a lane walk pays on AVX2 too, where a child's test of
//! sixteen rays takes two registers' operations instead of one.

use std::mem::MaybeUninit;
use std::ops::ControlFlow;

use glam::Vec4;

use super::{LEAF_BIT, NodeRay, PacketLeaf, RAYS_TOGETHER, Stack, WideNode};

/// Most rays in a lane walk: one per lane of a 512-bit register.
pub(crate) const LANES: usize = 16;

/// At or below this many rays, a lane walk lets each ray finish the subtree alone: a node's
/// eight lane tests then cost more than the rays' own 8-wide tests. (Measured on the bench's
/// AO rays: 2 and 3 within 3 % of each other, 5 and more slower.)
const SOLO: u32 = 2;

/// Whether this CPU has AVX-512F (and AVX2), detected at run time; std caches it.
#[inline(always)]
pub(crate) fn has_avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The registers a lane walk's sixteen lanes live in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum LaneSet {
    /// One 512-bit register.
    Avx512,
    /// Two 256-bit registers.
    Avx2,
}

/// The lanes this CPU runs lane walks in: AVX-512 where present, else AVX2, else none (then
/// every ray walks alone).
#[inline(always)]
pub(crate) fn lane_set() -> Option<LaneSet> {
    #[cfg(target_arch = "x86_64")]
    {
        if has_avx512() {
            Some(LaneSet::Avx512)
        } else if std::arch::is_x86_feature_detected!("avx2") {
            Some(LaneSet::Avx2)
        } else {
            None
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        None
    }
}

/// Whether lane walks run on this CPU.
#[inline(always)]
pub(crate) fn has_lanes() -> bool {
    lane_set().is_some()
}

/// Whether `rays` can share a lane walk here: lanes present, 1..=[`LANES`] rays, all
/// [`plain`].
#[inline(always)]
pub(crate) fn lanes_take(rays: &[NodeRay]) -> bool {
    has_lanes() && (1..=LANES).contains(&rays.len()) && rays.iter().all(plain)
}

/// A ray the lane test takes as the single-ray test does: none of its axes parallel (there the
/// single-ray test is a containment test) and a finite origin.
#[inline(always)]
fn plain(r: &NodeRay) -> bool {
    r.parallel == 0 && Vec4::from_array(r.o).is_finite()
}

/// Hands each ray its own leaf slots of `node`, as its single-ray walk would: `by_child[i]`
/// holds the rays whose own test meets child i, `leaves` the node's leaf slots among them.
/// When `TOGETHER`, on a CPU that tests one triangle against sixteen rays at once
/// (`leaf::together_runs`), and at least [`RAYS_TOGETHER`] rays meet them, all in one
/// [`PacketLeaf::Rays`]; else one [`PacketLeaf::Ray`] per ray. Breaks when `leaf` does.
/// (Where that test does not run, handing the rays over ray by ray traced the bench's shadow
/// rays 1–5 % faster than together, primary rays −2 to +3 %: the group's bookkeeping bought
/// the same block tests.)
#[inline(always)]
pub(super) fn hand_leaves<const TOGETHER: bool>(
    node: &WideNode,
    by_child: &[u32; 8],
    leaves: u32,
    tmax: &mut [f32],
    leaf: &mut impl FnMut(PacketLeaf, &mut [f32]) -> ControlFlow<()>,
) -> ControlFlow<()> {
    let mut meeting = 0u32;
    let mut by_slot = [0u32; 8];
    let mut l = leaves;
    while l != 0 {
        let slot = l.trailing_zeros() as usize;
        l &= l - 1;
        meeting |= by_child[slot];
        by_slot[slot] = by_child[slot];
    }
    if TOGETHER && meeting.count_ones() >= RAYS_TOGETHER && super::super::leaf::together_runs() {
        let meta = node.meta[leaves.trailing_zeros() as usize];
        let rays = meeting;
        return leaf(
            PacketLeaf::Rays {
                rays,
                meta,
                by_slot,
            },
            tmax,
        );
    }
    // The loop written twice: one loop choosing per ray between the two reads measured 2–3 %
    // slower on the engine's primary rays.
    #[cfg(target_arch = "x86_64")]
    if has_lanes() {
        // SAFETY: either lane set includes AVX2.
        let column = unsafe { LeafColumns::new(by_child, leaves) };
        while meeting != 0 {
            let ray = meeting.trailing_zeros() as usize;
            meeting &= meeting - 1;
            // SAFETY: as above.
            let slots = unsafe { column.of(ray) };
            let meta = node.meta[slots.trailing_zeros() as usize];
            leaf(PacketLeaf::Ray { ray, meta, slots }, tmax)?;
        }
        return ControlFlow::Continue(());
    }
    while meeting != 0 {
        let ray = meeting.trailing_zeros() as usize;
        meeting &= meeting - 1;
        let slots = super::slots_of(&by_slot, ray);
        let meta = node.meta[slots.trailing_zeros() as usize];
        leaf(PacketLeaf::Ray { ray, meta, slots }, tmax)?;
    }
    ControlFlow::Continue(())
}

/// The ray masks of a node's leaf slots in one register, to read one ray's slots out of all
/// eight at once: bit `ray` of each slot's mask shifted to its lane's sign and gathered by one
/// `movemask` (slot by slot, the loop of [`hand_leaves`] was a tenth of a packet walk's time).
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
struct LeafColumns(std::arch::x86_64::__m256i);

#[cfg(target_arch = "x86_64")]
impl LeafColumns {
    /// `by_child[slot]` in lane `slot` for the slots of `leaves`, 0 in the others.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[target_feature(enable = "avx2")]
    #[inline]
    unsafe fn new(by_child: &[u32; 8], leaves: u32) -> Self {
        use std::arch::x86_64::*;
        let bit = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
        let is_leaf =
            _mm256_cmpeq_epi32(_mm256_and_si256(_mm256_set1_epi32(leaves as i32), bit), bit);
        // SAFETY: an unaligned load of the eight u32 of `by_child`.
        let masks = unsafe { _mm256_loadu_si256(by_child.as_ptr() as *const __m256i) };
        LeafColumns(_mm256_and_si256(masks, is_leaf))
    }

    /// [`super::slots_of`] `ray`.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[target_feature(enable = "avx2")]
    #[inline]
    unsafe fn of(self, ray: usize) -> u32 {
        use std::arch::x86_64::*;
        let to_sign = _mm256_set1_epi32(31 - ray as i32);
        _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_sllv_epi32(self.0, to_sign))) as u32
    }
}

/// A pending child of a lane walk: each lane's entry distance and the lanes that may meet it.
#[derive(Clone, Copy)]
#[repr(C, align(64))]
struct LaneEntry {
    t: [f32; LANES],
    meta: u32,
    rays: u16,
}

/// Walks the tree once for the rays of `active` (bit i for `rays[i]`), calling `leaf(what,
/// tmax)` as [`PacketLeaf`] describes, with the contract of [`super::traverse_packet`]: the
/// callback may shrink entries of `tmax`, set one to −∞ to retire its ray, or break. `rays`
/// must pass [`lanes_take`] and `tmin` must be a query tmin (`super::query_tmin`).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(crate) fn traverse_lanes<const MARGIN: bool, const ORDERED: bool, const GROUPED: bool>(
    nodes: &[WideNode],
    rays: &[NodeRay],
    active: u32,
    tmin: f32,
    tmax: &mut [f32],
    margin: f32,
    leaf: impl FnMut(PacketLeaf, &mut [f32]) -> ControlFlow<()>,
) {
    assert!(
        lanes_take(rays) && tmax.len() == rays.len(),
        "a lane walk takes what lanes_take accepts"
    );
    #[cfg(target_arch = "x86_64")]
    // SAFETY: `lanes_take` checked that this CPU has the lane set `lane_set` names.
    unsafe {
        let set = lane_set().expect("lanes_take holds only where lanes run");
        traverse_lanes_in::<MARGIN, ORDERED, GROUPED>(
            set, nodes, rays, active, tmin, tmax, margin, leaf,
        );
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (nodes, active, tmin, margin, leaf);
}

/// [`traverse_lanes`] in lane set `set`.
///
/// # Safety
/// The CPU must support `set`'s instruction set.
#[allow(clippy::too_many_arguments)]
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn traverse_lanes_in<const MARGIN: bool, const ORDERED: bool, const GROUPED: bool>(
    set: LaneSet,
    nodes: &[WideNode],
    rays: &[NodeRay],
    active: u32,
    tmin: f32,
    tmax: &mut [f32],
    margin: f32,
    leaf: impl FnMut(PacketLeaf, &mut [f32]) -> ControlFlow<()>,
) {
    // SAFETY: per the contract.
    unsafe {
        match set {
            LaneSet::Avx512 => lanes_avx512::<MARGIN, ORDERED, GROUPED>(
                nodes, rays, active, tmin, tmax, margin, leaf,
            ),
            LaneSet::Avx2 => lanes_avx2::<MARGIN, ORDERED, GROUPED>(
                nodes, rays, active, tmin, tmax, margin, leaf,
            ),
        }
    }
}

/// The lane walk in one AVX-512 register.
///
/// # Safety
/// The CPU must support AVX-512F and AVX2.
#[allow(clippy::too_many_arguments)]
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2")]
unsafe fn lanes_avx512<const MARGIN: bool, const ORDERED: bool, const GROUPED: bool>(
    nodes: &[WideNode],
    rays: &[NodeRay],
    active: u32,
    tmin: f32,
    tmax: &mut [f32],
    margin: f32,
    leaf: impl FnMut(PacketLeaf, &mut [f32]) -> ControlFlow<()>,
) {
    // SAFETY: AVX-512F is enabled here.
    unsafe {
        lane_walk::<simd::Zmm, MARGIN, ORDERED, GROUPED>(
            nodes, rays, active, tmin, tmax, margin, leaf,
        )
    }
}

/// The lane walk in pairs of AVX2 registers.
///
/// # Safety
/// The CPU must support AVX2.
#[allow(clippy::too_many_arguments)]
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn lanes_avx2<const MARGIN: bool, const ORDERED: bool, const GROUPED: bool>(
    nodes: &[WideNode],
    rays: &[NodeRay],
    active: u32,
    tmin: f32,
    tmax: &mut [f32],
    margin: f32,
    leaf: impl FnMut(PacketLeaf, &mut [f32]) -> ControlFlow<()>,
) {
    // SAFETY: AVX2 is enabled here.
    unsafe {
        lane_walk::<simd::YmmPair, MARGIN, ORDERED, GROUPED>(
            nodes, rays, active, tmin, tmax, margin, leaf,
        )
    }
}

/// The lane walk, in lanes `V`; inlined into a function that enables `V`'s instruction set.
///
/// # Safety
/// The CPU must support `V`'s instruction set ([`Lanes16`]).
#[allow(clippy::too_many_arguments)]
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn lane_walk<V: Lanes16, const MARGIN: bool, const ORDERED: bool, const GROUPED: bool>(
    nodes: &[WideNode],
    rays: &[NodeRay],
    active: u32,
    tmin: f32,
    tmax: &mut [f32],
    margin: f32,
    mut leaf: impl FnMut(PacketLeaf, &mut [f32]) -> ControlFlow<()>,
) {
    if nodes.is_empty() || tmin.is_nan() {
        return;
    }
    let all = super::all_rays(rays.len()) as u16;
    // SAFETY (whole body): `V`'s operations, which the caller's CPU supports.
    unsafe {
        let (o, inv) = PacketLanes::of(rays).group::<V>(0);
        let m = V::splat(margin);
        let low = V::splat(tmin);
        let mut stack: Stack<LaneEntry> = Stack::new();
        let mut next = Some(LaneEntry {
            t: [tmin; LANES],
            meta: 0,
            rays: active as u16 & all,
        });
        while let Some(e) = next.take().or_else(|| stack.pop()) {
            // Each lane's current tmax (a retired or NaN one fails every comparison).
            let far = V::load_first(tmax, f32::NEG_INFINITY);
            let entry = V::load(&e.t);
            // (entry ≥ tmin, so a ray whose tmax fell below tmin is dropped too)
            let live = entry.le(far, e.rays);
            if live == 0 {
                continue;
            }
            if !GROUPED && e.meta & LEAF_BIT != 0 {
                let what = PacketLeaf::Packet {
                    meta: e.meta,
                    rays: u32::from(live),
                };
                if leaf(what, tmax).is_break() {
                    return;
                }
                continue;
            }
            if live.count_ones() <= SOLO {
                // Each remaining ray finishes this subtree alone.
                if super::finish_alone::<MARGIN, true, ORDERED, GROUPED>(
                    nodes,
                    e.meta,
                    rays,
                    u32::from(live),
                    tmin,
                    tmax,
                    margin,
                    &mut leaf,
                )
                .is_break()
                {
                    return;
                }
                continue;
            }
            let node = &nodes[e.meta as usize];
            let (entries, hits, mut slots) =
                node_lanes::<V, MARGIN>(node, &o, &inv, low, far, m, live, 0xff);
            if GROUPED {
                let leaves = slots & super::leaf_slots_with::<true>(node);
                if leaves != 0 {
                    let by_child = hits.map(u32::from);
                    // Ray by ray: rays that share no frustum seldom meet one block eight at
                    // a time (on the bench's AO rays, handing them over together was 4 %
                    // slower).
                    if hand_leaves::<false>(node, &by_child, leaves, tmax, &mut leaf).is_break() {
                        return;
                    }
                    slots &= !leaves;
                }
            }
            // The inner children (and, in other trees, the leaves), nearest first as far as
            // one order can serve sixteen rays: by the nearest entry over the rays that meet
            // each (closest hit; any hit takes them in slot order). The nearest is visited
            // next, the others wait on the stack.
            // (Sorted as keys of the nearest entry and the slot, without branches, as in the
            // single-ray walk.)
            let mut order = [0u64; 8];
            let mut count = 0;
            while slots != 0 {
                let child = slots.trailing_zeros() as usize;
                slots &= slots - 1;
                let key = if ORDERED {
                    entries[child].min_where(hits[child])
                } else {
                    0.0
                };
                order[count] = super::child_key(key, child as u32);
                count += 1;
            }
            if ORDERED {
                super::sort_keys(&mut order, count);
            }
            for (j, &key) in order[..count].iter().enumerate().rev() {
                let child = (key & 7) as usize;
                let meta = node.meta[child];
                if meta & LEAF_BIT == 0 {
                    super::prefetch_node(nodes, meta);
                }
                let mut c = LaneEntry {
                    t: [0.0; LANES],
                    meta,
                    rays: hits[child],
                };
                entries[child].store(&mut c.t);
                if j == 0 {
                    next = Some(c);
                } else {
                    stack.push(c);
                }
            }
        }
    }
}

/// The rays of a frustum packet (at most [`super::PACKET`]) as lanes, for the packet walk's
/// per-ray tests where its rays part ways ([`super::traverse_packet`]): sixteen rays' tests of
/// a child in one register (or two) instead of each ray's own eight-child test in turn.
pub(crate) struct PacketLanes {
    o: [[f32; super::PACKET]; 3],
    inv: [[f32; super::PACKET]; 3],
    n: usize,
}

impl PacketLanes {
    /// The lanes of `rays`, made in `slot`, when this CPU runs lane walks and the rays are all
    /// [`plain`] (a frustum packet's rays are). In place: returned by value, the 776 bytes
    /// were copied twice on their way to the walk.
    #[inline(always)]
    pub fn make_in<'s>(
        slot: &'s mut MaybeUninit<PacketLanes>,
        rays: &[NodeRay],
    ) -> Option<&'s PacketLanes> {
        let fit = has_lanes() && rays.len() <= super::PACKET && rays.iter().all(plain);
        if !fit {
            return None;
        }
        let lanes = slot.write(PacketLanes::unfilled(rays.len()));
        lanes.fill(rays);
        Some(lanes)
    }

    /// The lanes of at most [`super::PACKET`] rays, unchecked.
    #[inline(always)]
    fn of(rays: &[NodeRay]) -> PacketLanes {
        let mut lanes = PacketLanes::unfilled(rays.len());
        lanes.fill(rays);
        lanes
    }

    /// `n` lanes of origin 0 and 1/d = 1, to be filled.
    #[inline(always)]
    fn unfilled(n: usize) -> PacketLanes {
        PacketLanes {
            o: [[0.0; super::PACKET]; 3],
            inv: [[1.0; super::PACKET]; 3],
            n,
        }
    }

    #[inline(always)]
    fn fill(&mut self, rays: &[NodeRay]) {
        for (k, r) in rays.iter().enumerate() {
            for axis in 0..3 {
                self.o[axis][k] = r.o[axis];
                self.inv[axis][k] = r.inv[axis];
            }
        }
    }

    /// The origins and 1/d of the sixteen rays from `first` on (a multiple of [`LANES`]; lanes
    /// past the rays hold the origin 0 and 1/d = 1).
    ///
    /// # Safety
    /// The CPU must support `V`'s instruction set.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn group<V: Lanes16>(&self, first: usize) -> ([V; 3], [V; 3]) {
        // (No closure: one is compiled without the caller's instruction set, and the loads
        // in it would be calls.)
        // SAFETY (whole body): per the contract.
        unsafe {
            let mut o = [V::splat(0.0); 3];
            let mut inv = [V::splat(0.0); 3];
            for axis in 0..3 {
                let lanes: &[f32; LANES] = self.o[axis][first..first + LANES]
                    .try_into()
                    .expect("sixteen");
                o[axis] = V::load(lanes);
                let lanes: &[f32; LANES] = self.inv[axis][first..first + LANES]
                    .try_into()
                    .expect("sixteen");
                inv[axis] = V::load(lanes);
            }
            (o, inv)
        }
    }

    /// Per child of `node` among `children` (bit i for child i), the mask of the rays of
    /// `alive` whose own test (the single-ray walk's, with their `tmax`) meets it: bit for bit
    /// [`super::child_hits`]'s verdicts. The other children's masks are 0: a packet walk asks
    /// only for the children its frustum meets (no ray meets another), which spares the tests
    /// of the rest — at the nodes where the rays part ways, often most of the eight.
    #[inline(always)]
    pub fn node_hits<const MARGIN: bool>(
        &self,
        node: &WideNode,
        tmin: f32,
        tmax: &[f32],
        alive: u32,
        children: u32,
        margin: f32,
    ) -> [u32; 8] {
        debug_assert_eq!(tmax.len(), self.n);
        #[cfg(target_arch = "x86_64")]
        {
            let set = lane_set().expect("lanes are made only where they run");
            // SAFETY: `lane_set` names a set this CPU has.
            unsafe {
                self.node_hits_in_set::<MARGIN>(set, node, tmin, tmax, alive, children, margin)
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        unreachable!(
            "lanes exist only on x86_64: {node:?} {tmin} {tmax:?} {alive} {children} {margin}"
        )
    }

    /// [`Self::node_hits`] in lane set `set` (an AVX-512 CPU runs both).
    ///
    /// # Safety
    /// The CPU must support `set`'s instruction set.
    #[cfg(target_arch = "x86_64")]
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    unsafe fn node_hits_in_set<const MARGIN: bool>(
        &self,
        set: LaneSet,
        node: &WideNode,
        tmin: f32,
        tmax: &[f32],
        alive: u32,
        children: u32,
        margin: f32,
    ) -> [u32; 8] {
        // SAFETY: per the contract.
        unsafe {
            match set {
                LaneSet::Avx512 => {
                    self.node_hits_avx512::<MARGIN>(node, tmin, tmax, alive, children, margin)
                }
                LaneSet::Avx2 => {
                    self.node_hits_avx2::<MARGIN>(node, tmin, tmax, alive, children, margin)
                }
            }
        }
    }

    /// # Safety
    /// The CPU must support AVX-512F.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn node_hits_avx512<const MARGIN: bool>(
        &self,
        node: &WideNode,
        tmin: f32,
        tmax: &[f32],
        alive: u32,
        children: u32,
        margin: f32,
    ) -> [u32; 8] {
        // SAFETY: AVX-512F is enabled here.
        unsafe { self.node_hits_in::<simd::Zmm, MARGIN>(node, tmin, tmax, alive, children, margin) }
    }

    /// # Safety
    /// The CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn node_hits_avx2<const MARGIN: bool>(
        &self,
        node: &WideNode,
        tmin: f32,
        tmax: &[f32],
        alive: u32,
        children: u32,
        margin: f32,
    ) -> [u32; 8] {
        // SAFETY: AVX2 is enabled here.
        unsafe {
            self.node_hits_in::<simd::YmmPair, MARGIN>(node, tmin, tmax, alive, children, margin)
        }
    }

    /// [`Self::node_hits`] in lanes `V`.
    ///
    /// # Safety
    /// The CPU must support `V`'s instruction set.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn node_hits_in<V: Lanes16, const MARGIN: bool>(
        &self,
        node: &WideNode,
        tmin: f32,
        tmax: &[f32],
        alive: u32,
        children: u32,
        margin: f32,
    ) -> [u32; 8] {
        let mut by_child = [0u32; 8];
        for group in (0..self.n).step_by(LANES) {
            let live = (alive >> group) as u16;
            if live == 0 {
                continue;
            }
            let count = (self.n - group).min(LANES);
            // SAFETY: per the contract.
            let hits = unsafe {
                let (o, inv) = self.group::<V>(group);
                let far = V::load_first(&tmax[group..group + count], f32::NEG_INFINITY);
                let (_, hits, _) = node_lanes::<V, MARGIN>(
                    node,
                    &o,
                    &inv,
                    V::splat(tmin),
                    far,
                    V::splat(margin),
                    live,
                    children,
                );
                hits
            };
            for child in 0..8 {
                by_child[child] |= u32::from(hits[child]) << group;
            }
        }
        by_child
    }
}

/// Every filled child of `node` among `children` (bit i for child i) against the rays of `live`
/// (`o` and `inv` per axis, one ray per lane, `low` = tmin and `far` = each ray's tmax): per
/// child the lanes' entry distances and hit mask (none for the children not asked about), and
/// the mask of the children some ray meets. Lane by lane the operations of the
/// single-ray test ([`super::child_hits_avx2`]) on the same values.
///
/// # Safety
/// The CPU must support `V`'s instruction set.
#[allow(clippy::too_many_arguments)]
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn node_lanes<V: Lanes16, const MARGIN: bool>(
    node: &WideNode,
    o: &[V; 3],
    inv: &[V; 3],
    low: V,
    far: V,
    margin: V,
    live: u16,
    children: u32,
) -> ([V; 8], [u16; 8], u32) {
    // SAFETY (whole body): `V`'s operations, which the caller's CPU supports.
    unsafe {
        let shrink = V::splat(1.0 - super::WIDEN);
        let grow = V::splat(1.0 + super::WIDEN);
        let mut entries = [V::splat(0.0); 8];
        let mut hits = [0u16; 8];
        let mut slots = 0u32;
        let mut wanted = children & 0xff;
        while wanted != 0 {
            let child = wanted.trailing_zeros() as usize;
            wanted &= wanted - 1;
            if node.bounds[0][child] > node.bounds[1][child] {
                // An empty slot (the inverted box): no ray enters it.
                continue;
            }
            let mut tn = low;
            let mut tf = far;
            for axis in 0..3 {
                let mut lo = V::splat(node.bounds[2 * axis][child]);
                let mut hi = V::splat(node.bounds[2 * axis + 1][child]);
                if MARGIN {
                    lo = lo.sub(margin);
                    hi = hi.add(margin);
                }
                // Both planes' distances; the smaller is the entry plane's. For a filled slot
                // lo ≤ hi, and rounding is monotonic, so the smaller is exactly the value the
                // single-ray test computes from the entry plane its ray chose by the sign of
                // 1/d (for an empty slot, skipped above, it would not be).
                let t_lo = lo.sub(o[axis]).mul(inv[axis]);
                let t_hi = hi.sub(o[axis]).mul(inv[axis]);
                tn = tn.max(t_lo.min(t_hi));
                tf = tf.min(t_lo.max(t_hi));
            }
            let tn = tn.mul(shrink);
            let tf = tf.mul(grow);
            let hit = tn.le(tf, live);
            entries[child] = tn;
            hits[child] = hit;
            slots |= u32::from(hit != 0) << child;
        }
        (entries, hits, slots)
    }
}

/// Sixteen `f32` lanes and the operations a lane walk performs on them. Each operation is the
/// IEEE operation of the single-ray test's instructions lane by lane (no FMA, the same min and
/// max), so a lane's values are bit for bit its ray's own whichever registers hold them.
///
/// Written by hand: `std::simd` is unstable, and the SIMD crates (`wide`, `pulp`) choose an
/// instruction set per build or through closures the walk's callbacks cannot cross; these
/// methods are inlined into a function that enables the set ([`lanes_avx512`],
/// [`lanes_avx2`]).
#[cfg(target_arch = "x86_64")]
trait Lanes16: Copy {
    /// Every lane `x`.
    unsafe fn splat(x: f32) -> Self;
    /// The sixteen values of `a`.
    unsafe fn load(a: &[f32; LANES]) -> Self;
    /// The values of `a` (at most sixteen) in its lanes, `fill` in the lanes past them.
    unsafe fn load_first(a: &[f32], fill: f32) -> Self;
    /// The lanes into `a`.
    unsafe fn store(self, a: &mut [f32; LANES]);
    unsafe fn add(self, b: Self) -> Self;
    unsafe fn sub(self, b: Self) -> Self;
    unsafe fn mul(self, b: Self) -> Self;
    /// The lane-wise minimum as `minps` takes it (`b` where either is NaN).
    unsafe fn min(self, b: Self) -> Self;
    /// The lane-wise maximum as `maxps` takes it (`b` where either is NaN).
    unsafe fn max(self, b: Self) -> Self;
    /// The lanes of `live` where `self ≤ b` (ordered: false for a NaN).
    unsafe fn le(self, b: Self, live: u16) -> u16;
    /// The least value among the lanes of `mask` (not empty).
    unsafe fn min_where(self, mask: u16) -> f32;
}

#[cfg(target_arch = "x86_64")]
mod simd {
    //! The two lane sets of [`super::Lanes16`].

    use std::arch::x86_64::*;

    use super::{LANES, Lanes16};

    /// The lane-wise operations of [`Lanes16`] for a lane set: one intrinsic per register
    /// (a macro, not a closure: a closure is compiled without the caller's instruction set).
    macro_rules! lane_wise {
        (Zmm: $($name:ident $op:ident),*) => {$(
            #[inline(always)]
            unsafe fn $name(self, b: Self) -> Self {
                unsafe { Zmm($op(self.0, b.0)) }
            }
        )*};
        (YmmPair: $($name:ident $op:ident),*) => {$(
            #[inline(always)]
            unsafe fn $name(self, b: Self) -> Self {
                unsafe { YmmPair([$op(self.0[0], b.0[0]), $op(self.0[1], b.0[1])]) }
            }
        )*};
    }

    /// Sixteen lanes in one AVX-512 register.
    #[derive(Clone, Copy)]
    pub(super) struct Zmm(__m512);

    // SAFETY (every method): AVX-512F, which the caller's CPU supports (the trait's contract);
    // loads and stores within the arrays given.
    impl Lanes16 for Zmm {
        #[inline(always)]
        unsafe fn splat(x: f32) -> Self {
            unsafe { Zmm(_mm512_set1_ps(x)) }
        }
        #[inline(always)]
        unsafe fn load(a: &[f32; LANES]) -> Self {
            unsafe { Zmm(_mm512_loadu_ps(a.as_ptr())) }
        }
        #[inline(always)]
        unsafe fn load_first(a: &[f32], fill: f32) -> Self {
            debug_assert!(a.len() <= LANES);
            let mask = super::super::all_rays(a.len()) as u16;
            // (the masked load reads only the first `a.len()` values)
            unsafe { Zmm(_mm512_mask_loadu_ps(_mm512_set1_ps(fill), mask, a.as_ptr())) }
        }
        #[inline(always)]
        unsafe fn store(self, a: &mut [f32; LANES]) {
            unsafe { _mm512_storeu_ps(a.as_mut_ptr(), self.0) }
        }
        lane_wise!(Zmm:
            add _mm512_add_ps,
            sub _mm512_sub_ps,
            mul _mm512_mul_ps,
            min _mm512_min_ps,
            max _mm512_max_ps
        );
        #[inline(always)]
        unsafe fn le(self, b: Self, live: u16) -> u16 {
            unsafe { _mm512_mask_cmp_ps_mask::<_CMP_LE_OQ>(live, self.0, b.0) }
        }
        #[inline(always)]
        unsafe fn min_where(self, mask: u16) -> f32 {
            unsafe { _mm512_mask_reduce_min_ps(mask, self.0) }
        }
    }

    /// Sixteen lanes in two AVX2 registers, lanes 0–7 in the first.
    #[derive(Clone, Copy)]
    pub(super) struct YmmPair([__m256; 2]);

    impl YmmPair {
        /// Lanes `first..first + 8` of `mask` as an all-ones or all-zeros lane each.
        ///
        /// # Safety
        /// The CPU must support AVX2.
        #[inline(always)]
        unsafe fn lanes_of(mask: u16, first: u32) -> __m256 {
            unsafe {
                let bit = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
                let m = _mm256_set1_epi32(i32::from(mask >> first) & 0xff);
                _mm256_castsi256_ps(_mm256_cmpeq_epi32(_mm256_and_si256(m, bit), bit))
            }
        }
    }

    // SAFETY (every method): AVX2, which the caller's CPU supports (the trait's contract);
    // loads and stores within the arrays given.
    impl Lanes16 for YmmPair {
        #[inline(always)]
        unsafe fn splat(x: f32) -> Self {
            unsafe { YmmPair([_mm256_set1_ps(x); 2]) }
        }
        #[inline(always)]
        unsafe fn load(a: &[f32; LANES]) -> Self {
            unsafe {
                YmmPair([
                    _mm256_loadu_ps(a.as_ptr()),
                    _mm256_loadu_ps(a[8..].as_ptr()),
                ])
            }
        }
        #[inline(always)]
        unsafe fn load_first(a: &[f32], fill: f32) -> Self {
            debug_assert!(a.len() <= LANES);
            if a.len() == LANES {
                let a: &[f32; LANES] = a.try_into().expect("sixteen");
                return unsafe { Self::load(a) };
            }
            // Through a copy: a masked load of the second half would start past a short
            // slice's end.
            let mut lanes = [fill; LANES];
            lanes[..a.len()].copy_from_slice(a);
            unsafe { Self::load(&lanes) }
        }
        #[inline(always)]
        unsafe fn store(self, a: &mut [f32; LANES]) {
            unsafe {
                _mm256_storeu_ps(a.as_mut_ptr(), self.0[0]);
                _mm256_storeu_ps(a[8..].as_mut_ptr(), self.0[1]);
            }
        }
        lane_wise!(YmmPair:
            add _mm256_add_ps,
            sub _mm256_sub_ps,
            mul _mm256_mul_ps,
            min _mm256_min_ps,
            max _mm256_max_ps
        );
        #[inline(always)]
        unsafe fn le(self, b: Self, live: u16) -> u16 {
            unsafe {
                let lo = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(self.0[0], b.0[0]));
                let hi = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(self.0[1], b.0[1]));
                (lo | hi << 8) as u16 & live
            }
        }
        #[inline(always)]
        unsafe fn min_where(self, mask: u16) -> f32 {
            unsafe {
                let inf = _mm256_set1_ps(f32::INFINITY);
                let lo = _mm256_blendv_ps(inf, self.0[0], Self::lanes_of(mask, 0));
                let hi = _mm256_blendv_ps(inf, self.0[1], Self::lanes_of(mask, 8));
                let m = _mm256_min_ps(lo, hi);
                let m = _mm_min_ps(_mm256_castps256_ps128(m), _mm256_extractf128_ps::<1>(m));
                let m = _mm_min_ps(m, _mm_movehl_ps(m, m));
                let m = _mm_min_ss(m, _mm_shuffle_ps::<0b01>(m, m));
                _mm_cvtss_f32(m)
            }
        }
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use glam::Vec3;

    use super::super::tests::{grid, record_leaf};
    use super::super::{all_rays, child_hits, traverse};
    use super::*;
    use crate::rng::Rng;

    /// The lane sets this CPU runs, each to be checked (an AVX-512 CPU runs both). An x86_64
    /// CPU without AVX2 runs no lane walk, and these tests then have nothing to check.
    fn lane_sets_here() -> Vec<LaneSet> {
        let mut sets = Vec::new();
        if has_avx512() {
            sets.push(LaneSet::Avx512);
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            sets.push(LaneSet::Avx2);
        }
        if sets.is_empty() {
            eprintln!("no AVX2 on this CPU: lane walks are never taken here");
        }
        sets
    }

    #[test]
    fn leaf_columns_give_each_ray_its_slots() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            eprintln!("no AVX2 on this CPU: leaf columns are never used here");
            return;
        }
        let mut rng = Rng::new(11);
        for case in 0..2000 {
            let by_child: [u32; 8] = std::array::from_fn(|_| rng.next_u64() as u32);
            // every subset of slots early on, random ones after
            let leaves = if case < 256 {
                case as u32
            } else {
                rng.next_u64() as u32 & 0xff
            };
            let by_slot: [u32; 8] =
                std::array::from_fn(|slot| by_child[slot] * (leaves >> slot & 1));
            // SAFETY: AVX2 is present (checked above).
            let columns = unsafe { LeafColumns::new(&by_child, leaves) };
            for ray in 0..super::super::PACKET {
                // SAFETY: as above.
                let got = unsafe { columns.of(ray) };
                assert_eq!(
                    got,
                    super::super::slots_of(&by_slot, ray),
                    "{by_child:?} {leaves:b} {ray}"
                );
            }
        }
    }

    /// [`node_lanes`] in lane set `set` for sixteen rays: per child the lanes' entry
    /// distances and hit mask, and the children some ray meets.
    fn node_lanes_in(
        set: LaneSet,
        node: &WideNode,
        rays: &[NodeRay],
        tmin: f32,
        tmax: &[f32; LANES],
        margin: f32,
    ) -> ([[f32; LANES]; 8], [u16; 8], u32) {
        /// # Safety
        /// The CPU must support `V`'s instruction set.
        unsafe fn run<V: Lanes16>(
            node: &WideNode,
            rays: &[NodeRay],
            tmin: f32,
            tmax: &[f32; LANES],
            margin: f32,
        ) -> ([[f32; LANES]; 8], [u16; 8], u32) {
            // SAFETY: per the contract.
            unsafe {
                let (o, inv) = PacketLanes::of(rays).group::<V>(0);
                let (low, far, m) = (V::splat(tmin), V::load(tmax), V::splat(margin));
                let (entries, hits, slots) = if margin > 0.0 {
                    node_lanes::<V, true>(node, &o, &inv, low, far, m, u16::MAX, 0xff)
                } else {
                    node_lanes::<V, false>(node, &o, &inv, low, far, m, u16::MAX, 0xff)
                };
                let mut t = [[0.0; LANES]; 8];
                for (t, e) in t.iter_mut().zip(entries) {
                    e.store(t);
                }
                (t, hits, slots)
            }
        }
        // SAFETY: `set` is one of `lane_sets_here`.
        unsafe {
            match set {
                LaneSet::Avx512 => run::<simd::Zmm>(node, rays, tmin, tmax, margin),
                LaneSet::Avx2 => run::<simd::YmmPair>(node, rays, tmin, tmax, margin),
            }
        }
    }

    /// Lane by lane, the node test gives each ray's own entry distances and hit mask (the
    /// single-ray test's), bit for bit: random boxes (some flat, some slots empty), rays in
    /// every octant, per-ray tmax, margins.
    #[test]
    fn the_lane_node_test_is_each_rays_own() {
        for set in lane_sets_here() {
            the_lane_node_test_is_each_rays_own_in(set);
        }
    }

    fn the_lane_node_test_is_each_rays_own_in(set: LaneSet) {
        let mut rng = Rng::new(41);
        let mut hits = 0;
        for case in 0..4000 {
            let mut node = WideNode::EMPTY;
            for slot in 0..1 + case % 8 {
                let lo = rng.vec3_in(-2.0, 2.0);
                let mut hi = lo + rng.vec3_in(0.0, 1.0);
                if slot % 3 == 1 {
                    hi.y = lo.y;
                }
                for axis in 0..3 {
                    node.bounds[2 * axis][slot] = lo[axis];
                    node.bounds[2 * axis + 1][slot] = hi[axis];
                }
            }
            let centre = rng.vec3_in(-4.0, 4.0);
            let rays: Vec<NodeRay> = (0..LANES)
                .map(|_| {
                    let o = centre + rng.vec3_in(-0.5, 0.5);
                    NodeRay::new(o, rng.vec3_in(-2.0, 3.0) - o)
                })
                .collect();
            assert!(lanes_take(&rays));
            let tmin = if case % 2 == 0 {
                0.0
            } else {
                rng.range_f32(0.0, 1.0)
            };
            let tmax: Vec<f32> = (0..LANES)
                .map(|k| match k % 4 {
                    0 => f32::INFINITY,
                    1 => rng.range_f32(0.0, 3.0),
                    _ => rng.range_f32(0.0, 20.0),
                })
                .collect();
            let margin = if case % 3 == 0 {
                rng.range_f32(0.0, 0.5)
            } else {
                0.0
            };
            let tmax: [f32; LANES] = tmax.try_into().expect("sixteen");
            let (entries, lane_hits, slots) = node_lanes_in(set, &node, &rays, tmin, &tmax, margin);
            let mut any = 0;
            for (k, r) in rays.iter().enumerate() {
                let (t, mask) = if margin > 0.0 {
                    child_hits::<true>(&node, r, tmin, tmax[k], margin)
                } else {
                    child_hits::<false>(&node, r, tmin, tmax[k], margin)
                };
                any |= mask;
                for child in 0..8 {
                    let lane = u32::from((lane_hits[child] >> k) & 1);
                    assert_eq!(
                        lane,
                        (mask >> child) & 1,
                        "{set:?} case {case}, ray {k}, child {child}"
                    );
                    if lane != 0 {
                        let e = entries[child][k];
                        assert_eq!(e.to_bits(), t[child].to_bits(), "{set:?} case {case}");
                        hits += 1;
                    }
                }
            }
            assert_eq!(slots, any, "{set:?} case {case}");
        }
        assert!(hits > 5_000, "the cases must hit boxes: {hits}");
    }

    /// Leaves each ray of a lane walk is handed, per ray, sorted.
    fn lane_leaves(
        set: LaneSet,
        nodes: &[WideNode],
        rays: &[NodeRay],
        tmax: &mut [f32],
        margin: f32,
        ordered: bool,
    ) -> Vec<Vec<u32>> {
        let mut seen = vec![Vec::new(); rays.len()];
        let visit = |what, _: &mut [f32]| {
            record_leaf(&mut seen, what);
            ControlFlow::Continue(())
        };
        let all = all_rays(rays.len());
        match (margin > 0.0, ordered) {
            (false, true) => {
                // SAFETY: `set` is one of `lane_sets_here`.
                unsafe {
                    traverse_lanes_in::<false, true, false>(
                        set, nodes, rays, all, 0.0, tmax, 0.0, visit,
                    )
                }
            }
            (false, false) => {
                // SAFETY: `set` is one of `lane_sets_here`.
                unsafe {
                    traverse_lanes_in::<false, false, false>(
                        set, nodes, rays, all, 0.0, tmax, 0.0, visit,
                    )
                }
            }
            (true, true) => {
                // SAFETY: `set` is one of `lane_sets_here`.
                unsafe {
                    traverse_lanes_in::<true, true, false>(
                        set, nodes, rays, all, 0.0, tmax, margin, visit,
                    )
                }
            }
            (true, false) => {
                // SAFETY: `set` is one of `lane_sets_here`.
                unsafe {
                    traverse_lanes_in::<true, false, false>(
                        set, nodes, rays, all, 0.0, tmax, margin, visit,
                    )
                }
            }
        }
        for s in &mut seen {
            s.sort_unstable();
            s.dedup();
        }
        seen
    }

    /// A lane walk hands each ray every leaf its own walk reaches, and nothing to a retired
    /// ray: rays from nearby origins in all directions, 1 to 16 of them, with and without a
    /// margin, in both orders.
    #[test]
    fn a_lane_walk_reaches_every_leaf_its_rays_reach() {
        for set in lane_sets_here() {
            a_lane_walk_reaches_every_leaf_its_rays_reach_in(set);
        }
    }

    fn a_lane_walk_reaches_every_leaf_its_rays_reach_in(set: LaneSet) {
        let (_, bvh) = grid();
        let mut rng = Rng::new(77);
        let mut reached = 0;
        for case in 0..600 {
            let centre = rng.vec3_in(-1.0, 10.0);
            let rays: Vec<NodeRay> = (0..1 + case % LANES)
                .map(|_| NodeRay::new(centre + rng.vec3_in(-0.3, 0.3), rng.direction()))
                .collect();
            let limit = if case % 2 == 0 { f32::INFINITY } else { 4.0 };
            let mut tmax = vec![limit; rays.len()];
            // One ray retired from the start.
            let retired = (case % 5 == 0).then_some(case % rays.len());
            if let Some(k) = retired {
                tmax[k] = f32::NEG_INFINITY;
            }
            let margin = if case % 3 == 0 { 0.01 } else { 0.0 };
            let got = lane_leaves(set, &bvh.nodes, &rays, &mut tmax, margin, case % 4 != 0);
            for (k, (r, got)) in rays.iter().zip(got).enumerate() {
                if retired == Some(k) {
                    assert!(
                        got.is_empty(),
                        "case {case}: a retired ray was handed leaves"
                    );
                    continue;
                }
                let mut t = limit;
                let mut own = Vec::new();
                if margin > 0.0 {
                    traverse::<true>(&bvh.nodes, r, 0.0, &mut t, margin, |f, c, _| {
                        own.extend(f..f + c);
                        ControlFlow::Continue(())
                    });
                } else {
                    traverse::<false>(&bvh.nodes, r, 0.0, &mut t, 0.0, |f, c, _| {
                        own.extend(f..f + c);
                        ControlFlow::Continue(())
                    });
                }
                for p in &own {
                    assert!(
                        got.binary_search(p).is_ok(),
                        "case {case}: ray {k} missed leaf {p}"
                    );
                }
                reached += own.len();
            }
        }
        assert!(reached > 1_500, "the rays must reach leaves: {reached}");
    }

    /// A frustum packet's per-ray tests in lanes give each ray's own verdicts, for packets of
    /// 1 to 32 rays (one or two registers), any subset of live rays and of children asked about.
    #[test]
    fn packet_lanes_give_each_rays_own_verdicts() {
        for set in lane_sets_here() {
            packet_lanes_give_each_rays_own_verdicts_in(set);
        }
    }

    fn packet_lanes_give_each_rays_own_verdicts_in(set: LaneSet) {
        let (_, bvh) = grid();
        let mut rng = Rng::new(5);
        let mut met = 0;
        for case in 0..3000 {
            let n = 1 + case % super::super::PACKET;
            let node = &bvh.nodes[rng.below(bvh.nodes.len() as u64) as usize];
            // Aimed near the node's first child, from around one point.
            let b = &node.bounds;
            let aim = Vec3::new(b[0][0] + b[1][0], b[2][0] + b[3][0], b[4][0] + b[5][0]) * 0.5;
            let o = rng.vec3_in(-2.0, 12.0);
            let rays: Vec<NodeRay> = (0..n)
                .map(|_| {
                    let o = o + rng.vec3_in(-0.2, 0.2);
                    NodeRay::new(o, aim + rng.vec3_in(-1.0, 1.0) - o)
                })
                .collect();
            let tmax: Vec<f32> = (0..n)
                .map(|k| if k % 3 == 0 { 6.0 } else { f32::INFINITY })
                .collect();
            let alive = (rng.next_u64() as u32) & all_rays(n);
            let margin = if case % 2 == 0 { 0.0 } else { 0.05 };
            let mut slot = MaybeUninit::uninit();
            let lanes = PacketLanes::make_in(&mut slot, &rays).expect("lanes and plain rays");
            // all children, or some (a frustum's): the others' masks are then empty
            let children = if case % 3 == 0 {
                0xff
            } else {
                rng.next_u64() as u32 & 0xff
            };
            // SAFETY: `set` is one of `lane_sets_here`.
            let got = unsafe {
                if margin > 0.0 {
                    lanes.node_hits_in_set::<true>(set, node, 0.0, &tmax, alive, children, margin)
                } else {
                    lanes.node_hits_in_set::<false>(set, node, 0.0, &tmax, alive, children, margin)
                }
            };
            let mut want = [0u32; 8];
            for (k, r) in rays.iter().enumerate() {
                if alive & (1 << k) == 0 {
                    continue;
                }
                let (_, mask) = if margin > 0.0 {
                    child_hits::<true>(node, r, 0.0, tmax[k], margin)
                } else {
                    child_hits::<false>(node, r, 0.0, tmax[k], margin)
                };
                for (child, w) in want.iter_mut().enumerate() {
                    *w |= ((mask & children) >> child & 1) << k;
                }
            }
            assert_eq!(got, want, "{set:?} case {case}");
            met += want.iter().map(|w| w.count_ones()).sum::<u32>();
        }
        assert!(met > 5_000, "the rays must meet children: {met}");
    }

    #[test]
    fn rays_parallel_to_an_axis_or_from_nowhere_are_left_to_single_walks() {
        if lane_sets_here().is_empty() {
            return;
        }
        let ok = NodeRay::new(Vec3::ZERO, Vec3::new(1.0, 2.0, 3.0));
        assert!(lanes_take(&[ok; LANES]));
        assert!(!lanes_take(&[ok; LANES + 1]));
        assert!(!lanes_take(&[]));
        let parallel = NodeRay::new(Vec3::ZERO, Vec3::new(1.0, 0.0, 3.0));
        assert!(!lanes_take(&[ok, parallel]));
        let nowhere = NodeRay::new(Vec3::new(f32::NAN, 0.0, 0.0), Vec3::ONE);
        assert!(!lanes_take(&[ok, nowhere]));
        let far = NodeRay::new(Vec3::new(f32::INFINITY, 0.0, 0.0), Vec3::ONE);
        assert!(!lanes_take(&[far, ok]));
    }
}
