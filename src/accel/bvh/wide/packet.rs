//! Packet traversal: one walk of the tree for up to [`PACKET`] coherent rays (neighbouring
//! primary rays of a camera), each node tested once for all of them against the packet's
//! interval bounds, each leaf tested ray by ray.
//!
//! The node test bounds every ray of the packet at once with interval arithmetic (Wald,
//! Boulos & Shirley, "Ray Tracing Deformable Scenes Using Dynamic Bounding Volume
//! Hierarchies", ACM TOG 26(1), 2007, §4.2): with the origins in `[o_lo, o_hi]` and the
//! inverse directions in `[inv_lo, inv_hi]` per axis, all of one sign, a slab distance
//! `(plane − o)·inv` is bilinear in `(o, inv)`, so its smallest and largest value over the
//! packet are among the four corner products. The test is conservative *in floating point*,
//! not only in exact arithmetic: rounding is monotonic, so `fl(plane − o_hi) <= fl(plane − o)
//! <= fl(plane − o_lo)` for every ray's `o`, and a rounded product is monotonic in each factor
//! when the other is fixed; the smallest rounded corner product is therefore ≤ the value the
//! single-ray test ([`super::child_hits`]) computes for each ray of the packet, and the largest
//! is ≥ it. The entry and exit bounds are then widened exactly as in the single-ray test. A box
//! that any ray's own test hits within its `[tmin, tmax]` is hit by the packet test within
//! `[tmin, max tmax]` — so a packet walk reaches every leaf that any of its rays' walks reaches.
//!
//! Rays are only ever *dropped* from a child by their own exact 8-wide test (the single-ray
//! walk's, with the ray's own current `tmax`): at a node with leaf children, before any ray's
//! leaf test, and where the rays part ways (see [`traverse_packet`]). A leaf test therefore
//! sees exactly the leaf slots the ray's own test hits, and a child is pruned for a ray only
//! when its entry distance exceeds the ray's nearest hit so far, as in its single-ray walk. The
//! visiting order differs, but closest-hit ties are broken by index (see the query contract in
//! `super::super`), so the answers are bit for bit the single-ray ones
//! (`packets_give_the_single_ray_answers` and
//! `packets_give_the_single_ray_answers_on_the_bench_models` in `tests/bvh.rs`).

use std::mem::MaybeUninit;
use std::ops::ControlFlow;

use glam::{BVec3A, BVec4A, Vec3, Vec3A, Vec4};

use super::lanes::{PacketLanes, hand_leaves};
use super::{
    Entry, LEAF_BIT, NodeRay, NodeRays, PACKET, PacketLeaf, Stack, WIDEN, WideNode, child_hits,
    entry_planes, finish_alone, has_avx2, lanes, leaf_slots_with, prefetch_node, query_tmin,
};

/// Interval bounds of a packet's rays, per axis, for [`frustum_hits`].
#[derive(Clone, Copy, Debug)]
pub(crate) struct Frustum {
    o_lo: [f32; 3],
    o_hi: [f32; 3],
    inv_lo: [f32; 3],
    inv_hi: [f32; 3],
    /// Shared by every ray of the packet (see [`NodeRay`]).
    near: [usize; 3],
    /// All rays start at one point (`o_lo == o_hi`: a pinhole camera's rays): two corner
    /// products per plane instead of four, with the same result.
    one_origin: bool,
}

impl Frustum {
    /// The bounds of `rays` (each `(origin, direction)`), or `None` when they cannot share one
    /// walk: no rays, a ray parallel to an axis (1/d not finite, see [`NodeRay`]), rays in
    /// different octants (the slab planes they enter first differ), or a non-finite origin.
    ///
    /// No ray's 1/d is computed: on each axis the directions share one sign, on which 1/d is
    /// decreasing, and a correctly rounded quotient is monotonic, so the smallest and largest
    /// of the rays' `fl(1/d)` are `fl(1/d_max)` and `fl(1/d_min)` — the very bounds that the
    /// rays' node rays give (`frusta_from_directions_are_those_of_the_node_rays`). The node
    /// rays themselves are made only where a walk needs them ([`super::NodeRays`]).
    #[inline(always)]
    pub fn new(rays: impl ExactSizeIterator<Item = (Vec3, Vec3)>) -> Option<Frustum> {
        assert!(rays.len() <= PACKET, "a packet holds at most {PACKET} rays");
        let (mut o_lo, mut o_hi) = (Vec3A::INFINITY, Vec3A::NEG_INFINITY);
        let (mut d_lo, mut d_hi) = (Vec3A::INFINITY, Vec3A::NEG_INFINITY);
        // Signs and finiteness by lane masks, three components at once: component by component
        // (`Vec3::is_finite`) they were the largest share of an instance visit's own time.
        let mut finite = BVec3A::TRUE;
        let mut first_signs = None;
        for (o, d) in rays {
            let (o, d) = (Vec3A::from(o), Vec3A::from(d));
            // Rays in another octant than the first end it here: AO and incoherent rays almost
            // never make a packet, and should pay as little as possible for finding out.
            let signs = d.is_negative_bitmask();
            if *first_signs.get_or_insert(signs) != signs {
                return None;
            }
            finite &= o.is_finite_mask() & d.is_finite_mask();
            o_lo = o_lo.min(o);
            o_hi = o_hi.max(o);
            d_lo = d_lo.min(d);
            d_hi = d_hi.max(d);
        }
        let signs = first_signs?;
        // 1/d falls as d rises, on either side of 0.
        let (inv_lo, inv_hi) = (Vec3A::ONE / d_hi, Vec3A::ONE / d_lo);
        // A ray parallel to an axis (|d| below 2^-128, or 0) has the smallest |d| of its axis:
        // its 1/d is one of these two, and not finite.
        if !finite.all() || !inv_lo.is_finite() || !inv_hi.is_finite() {
            return None;
        }
        // The entry plane per axis, as `NodeRay::new` finds it (the sign of a finite, non-zero
        // 1/d is the sign of d).
        let near = entry_planes(signs);
        Some(Frustum {
            o_lo: o_lo.to_array(),
            o_hi: o_hi.to_array(),
            inv_lo: inv_lo.to_array(),
            inv_hi: inv_hi.to_array(),
            near,
            one_origin: o_lo == o_hi,
        })
    }
}

/// Entry distances (widened lower bounds over the packet) and the mask of the children that
/// some ray of the packet may meet within `[tmin, tmax]`, boxes grown by `margin` when
/// `MARGIN` (as in [`child_hits`]).
#[inline(always)]
fn frustum_hits<const MARGIN: bool>(
    node: &WideNode,
    f: &Frustum,
    tmin: f32,
    tmax: f32,
    margin: f32,
) -> ([f32; 8], u32) {
    let mut t_out = [0.0f32; 8];
    let mut mask = 0u32;
    for group in 0..2 {
        let mut tn = Vec4::splat(tmin);
        let mut tf = Vec4::splat(tmax);
        for axis in 0..3 {
            let near = f.near[axis];
            let mut pn = lanes(&node.bounds[near], group);
            let mut pf = lanes(&node.bounds[near ^ 1], group);
            if MARGIN {
                if near & 1 == 0 {
                    pn -= margin;
                    pf += margin;
                } else {
                    pn += margin;
                    pf -= margin;
                }
            }
            let (olo, ohi) = (Vec4::splat(f.o_lo[axis]), Vec4::splat(f.o_hi[axis]));
            let (ilo, ihi) = (Vec4::splat(f.inv_lo[axis]), Vec4::splat(f.inv_hi[axis]));
            let (a0, b0) = (pn - ohi, pf - ohi);
            let mut entry = (a0 * ilo).min(a0 * ihi);
            let mut exit = (b0 * ilo).max(b0 * ihi);
            if !f.one_origin {
                let (a1, b1) = (pn - olo, pf - olo);
                entry = entry.min((a1 * ilo).min(a1 * ihi));
                exit = exit.max((b1 * ilo).max(b1 * ihi));
            }
            tn = tn.max(entry);
            tf = tf.min(exit);
        }
        let tn = tn * Vec4::splat(1.0 - WIDEN);
        let tf = tf * Vec4::splat(1.0 + WIDEN);
        let hit: BVec4A = tn.cmple(tf);
        mask |= hit.bitmask() << (4 * group);
        tn.write_to_slice(&mut t_out[4 * group..4 * group + 4]);
    }
    (t_out, mask)
}

/// [`frustum_hits`] with the eight children in one register: the same operations on the same
/// values, so the same result bit for bit (`avx2_frustum_test_matches_the_portable_one`).
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn frustum_hits_avx2<const MARGIN: bool>(
    node: &WideNode,
    f: &Frustum,
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
        for axis in 0..3 {
            let near = f.near[axis];
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
            let (olo, ohi) = (_mm256_set1_ps(f.o_lo[axis]), _mm256_set1_ps(f.o_hi[axis]));
            let (ilo, ihi) = (
                _mm256_set1_ps(f.inv_lo[axis]),
                _mm256_set1_ps(f.inv_hi[axis]),
            );
            let (a0, b0) = (_mm256_sub_ps(pn, ohi), _mm256_sub_ps(pf, ohi));
            let mut entry = _mm256_min_ps(_mm256_mul_ps(a0, ilo), _mm256_mul_ps(a0, ihi));
            let mut exit = _mm256_max_ps(_mm256_mul_ps(b0, ilo), _mm256_mul_ps(b0, ihi));
            if !f.one_origin {
                let (a1, b1) = (_mm256_sub_ps(pn, olo), _mm256_sub_ps(pf, olo));
                entry = _mm256_min_ps(
                    entry,
                    _mm256_min_ps(_mm256_mul_ps(a1, ilo), _mm256_mul_ps(a1, ihi)),
                );
                exit = _mm256_max_ps(
                    exit,
                    _mm256_max_ps(_mm256_mul_ps(b1, ilo), _mm256_mul_ps(b1, ihi)),
                );
            }
            tn = _mm256_max_ps(tn, entry);
            tf = _mm256_min_ps(tf, exit);
        }
        let tn = _mm256_mul_ps(tn, _mm256_set1_ps(1.0 - WIDEN));
        let tf = _mm256_mul_ps(tf, _mm256_set1_ps(1.0 + WIDEN));
        let hit = _mm256_cmp_ps::<_CMP_LE_OQ>(tn, tf);
        let mut t_out = [0.0f32; 8];
        _mm256_storeu_ps(t_out.as_mut_ptr(), tn);
        (t_out, _mm256_movemask_ps(hit) as u32)
    }
}

/// One ray's own test of a node's children (the single-ray walk's), by AVX2 when `AVX2`.
#[inline(always)]
fn ray_hits<const MARGIN: bool, const AVX2: bool>(
    node: &WideNode,
    r: &NodeRay,
    tmin: f32,
    tmax: f32,
    margin: f32,
) -> u32 {
    #[cfg(target_arch = "x86_64")]
    if AVX2 {
        // SAFETY: `AVX2` is only true inside `packet_avx2`, which runs on AVX2 CPUs.
        return unsafe { super::child_hits_avx2::<MARGIN>(node, r, tmin, tmax, margin).1 };
    }
    child_hits::<MARGIN>(node, r, tmin, tmax, margin).1
}

/// Below this many rays a packet walk lets each ray finish the subtree on its own (the
/// single-ray walk), since the shared node test no longer pays for itself.
const SOLO: u32 = 2;

/// A pending child of a packet walk, with the mask of the rays that may meet it.
type PacketEntry = Entry<u32>;

/// Walks the tree once for the rays of `active` (bit i for `rays[i]`; at most [`PACKET`] rays,
/// `frustum` must bound them), calling `leaf(what, tmax)` as [`PacketLeaf`] describes; the
/// callback may shrink entries of `tmax` (closest hit), set one to −∞ to retire its ray (any
/// hit), or break. A ray whose `tmax` is NaN or below `tmin` is never handed to a leaf.
///
/// Each pending child carries the rays that may meet it. Where the rays part ways — the
/// packet's test hits two or more inner children, or a node has leaf children — each ray runs
/// its own test (the single-ray walk's) and each child keeps only the rays that meet it; a
/// child left with fewer than [`SOLO`] + 1 rays is finished by single-ray walks. So a
/// coherent packet shares its walk down to where it splits, and an incoherent one (rays
/// through sub-pixel triangles) costs about its rays' own walks.
///
/// `ORDERED` visits hit children nearest first (by the packet's entry bound); `GROUPED` is
/// as in [`super::traverse_grouped`].
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(crate) fn traverse_packet<const MARGIN: bool, const ORDERED: bool, const GROUPED: bool>(
    nodes: &[WideNode],
    rays: &NodeRays<'_>,
    active: u32,
    frustum: &Frustum,
    tmin: f32,
    tmax: &mut [f32],
    margin: f32,
    leaf: impl FnMut(PacketLeaf, &mut [f32]) -> ControlFlow<()>,
) {
    debug_assert!(rays.len() <= PACKET && rays.len() == tmax.len());
    let tmin = query_tmin(tmin);
    #[cfg(target_arch = "x86_64")]
    if has_avx2() {
        // SAFETY: the CPU supports AVX2 (just checked).
        unsafe {
            packet_avx2::<MARGIN, ORDERED, GROUPED>(
                nodes, rays, active, frustum, tmin, tmax, margin, leaf,
            )
        };
        return;
    }
    packet_impl::<MARGIN, false, ORDERED, GROUPED>(
        nodes, rays, active, frustum, tmin, tmax, margin, leaf,
    )
}

/// [`packet_impl`] compiled with AVX2.
///
/// # Safety
/// The CPU must support AVX2.
#[allow(clippy::too_many_arguments)]
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn packet_avx2<const MARGIN: bool, const ORDERED: bool, const GROUPED: bool>(
    nodes: &[WideNode],
    rays: &NodeRays<'_>,
    active: u32,
    frustum: &Frustum,
    tmin: f32,
    tmax: &mut [f32],
    margin: f32,
    leaf: impl FnMut(PacketLeaf, &mut [f32]) -> ControlFlow<()>,
) {
    packet_impl::<MARGIN, true, ORDERED, GROUPED>(
        nodes, rays, active, frustum, tmin, tmax, margin, leaf,
    )
}

/// The rays of `mask` still in the walk (`tmax >= tmin`: not retired, not NaN) and the largest
/// of their `tmax` (−∞ when none is).
#[inline(always)]
fn live(tmin: f32, tmax: &[f32], mask: u32) -> (u32, f32) {
    let (mut alive, mut far) = (0u32, f32::NEG_INFINITY);
    let mut m = mask;
    while m != 0 {
        let i = m.trailing_zeros() as usize;
        m &= m - 1;
        // without branches (the rays' tmax come in any order), and the largest by a
        // comparison, not f32::max: a retired or NaN tmax counts as −∞ here, and f32::max's
        // NaN handling made each ray of this loop wait three dependent instructions on the
        // one before (the largest share of the packet walk's own time)
        let live = tmax[i] >= tmin;
        alive |= u32::from(live) << i;
        let t = if live { tmax[i] } else { f32::NEG_INFINITY };
        far = if t > far { t } else { far };
    }
    (alive, far)
}

/// [`live`] eight rays at a time: the same mask, and the same largest `tmax` (a maximum is
/// exact; ±0 may come out with either sign, which no comparison tells apart). The rays' loop
/// was the largest share of the packet walk's own time.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn live_avx2(tmin: f32, tmax: &[f32], mask: u32) -> (u32, f32) {
    use std::arch::x86_64::*;
    let n = tmax.len().min(PACKET);
    let whole = n / 8 * 8;
    let low = _mm256_set1_ps(tmin);
    let none = _mm256_set1_ps(f32::NEG_INFINITY);
    // lane k of a group of eight tests bit k of the group's byte of `mask`
    let bit = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
    let mut far8 = none;
    let mut alive = 0u32;
    for group in (0..whole).step_by(8) {
        // SAFETY: the slice holds the eight floats read.
        let t = unsafe { _mm256_loadu_ps(tmax[group..group + 8].as_ptr()) };
        // `>=` is false for NaN, as the scalar test's
        let live = _mm256_cmp_ps::<_CMP_GE_OQ>(t, low);
        let asked = _mm256_set1_epi32(((mask >> group) & 0xff) as i32);
        let asked = _mm256_cmpeq_epi32(_mm256_and_si256(asked, bit), bit);
        let live = _mm256_and_ps(live, _mm256_castsi256_ps(asked));
        alive |= (_mm256_movemask_ps(live) as u32) << group;
        far8 = _mm256_max_ps(far8, _mm256_blendv_ps(none, t, live));
    }
    let half = _mm_max_ps(
        _mm256_castps256_ps128(far8),
        _mm256_extractf128_ps::<1>(far8),
    );
    let half = _mm_max_ps(half, _mm_movehl_ps(half, half));
    let mut far = _mm_cvtss_f32(_mm_max_ss(half, _mm_shuffle_ps::<1>(half, half)));
    // the rays past the whole groups (a packet that is not a multiple of eight), one by one
    let grouped = if whole >= 32 {
        u32::MAX
    } else {
        (1u32 << whole) - 1
    };
    let (rest_alive, rest_far) = live(tmin, tmax, mask & !grouped);
    alive |= rest_alive;
    if rest_far > far {
        far = rest_far;
    }
    (alive, far)
}

#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn packet_impl<const MARGIN: bool, const AVX2: bool, const ORDERED: bool, const GROUPED: bool>(
    nodes: &[WideNode],
    rays: &NodeRays<'_>,
    active: u32,
    frustum: &Frustum,
    tmin: f32,
    tmax: &mut [f32],
    margin: f32,
    mut leaf: impl FnMut(PacketLeaf, &mut [f32]) -> ControlFlow<()>,
) {
    if nodes.is_empty() || tmin.is_nan() {
        return;
    }
    let mut stack: Stack<PacketEntry> = Stack::new();
    let mut next = Some(PacketEntry {
        t: tmin,
        meta: 0,
        rays: active,
    });
    // The rays as lanes, made where they first part ways (many walks never do).
    let mut lanes_slot = MaybeUninit::uninit();
    let (mut lanes_made, mut lanes_tried) = (false, false);
    while let Some(e) = next.take().or_else(|| stack.pop()) {
        let (alive, far) = if AVX2 {
            // SAFETY: `AVX2` is only set on the path behind `has_avx2` (`packet_avx2`).
            #[cfg(target_arch = "x86_64")]
            unsafe {
                live_avx2(tmin, tmax, e.rays)
            }
            #[cfg(not(target_arch = "x86_64"))]
            live(tmin, tmax, e.rays)
        } else {
            live(tmin, tmax, e.rays)
        };
        if alive == 0 || e.t > far {
            continue;
        }
        if !GROUPED && e.meta & LEAF_BIT != 0 {
            let what = PacketLeaf::Packet {
                meta: e.meta,
                rays: alive,
            };
            if leaf(what, tmax).is_break() {
                return;
            }
            continue;
        }
        if alive.count_ones() <= SOLO {
            if finish_alone::<MARGIN, AVX2, ORDERED, GROUPED>(
                nodes,
                e.meta,
                rays.get(),
                alive,
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
        #[cfg(target_arch = "x86_64")]
        let (t, mut mask) = if AVX2 {
            // SAFETY: `AVX2` is only true inside `packet_avx2`, which runs on AVX2 CPUs.
            unsafe { frustum_hits_avx2::<MARGIN>(node, frustum, tmin, far, margin) }
        } else {
            frustum_hits::<MARGIN>(node, frustum, tmin, far, margin)
        };
        #[cfg(not(target_arch = "x86_64"))]
        let (t, mut mask) = frustum_hits::<MARGIN>(node, frustum, tmin, far, margin);
        if mask == 0 {
            continue;
        }
        let leaves = if GROUPED {
            mask & leaf_slots_with::<AVX2>(node)
        } else {
            0
        };
        let inner = mask & !leaves;
        // The rays of each child: all of them, unless the rays part ways here.
        let mut child_rays = [alive; 8];
        if leaves != 0 || inner & inner.wrapping_sub(1) != 0 {
            child_rays = [0; 8];
            let rays = rays.get();
            if AVX2 && !lanes_tried {
                lanes_made = PacketLanes::make_in(&mut lanes_slot, rays).is_some();
                lanes_tried = true;
            }
            // SAFETY: `make_in` wrote the slot when it made the lanes.
            let lanes = lanes_made.then(|| unsafe { lanes_slot.assume_init_ref() });
            if let Some(lanes) = lanes {
                // Each ray's own test, sixteen rays to a register (or two): the same verdicts as
                // the loop below, which runs where there is no AVX2. (This node's leaf tests
                // come after all of its rays' node tests here, but a leaf test of one ray
                // changes no other ray's `tmax`.)
                let by_child = lanes.node_hits::<MARGIN>(node, tmin, tmax, alive, mask, margin);
                if hand_leaves::<true>(node, &by_child, leaves, tmax, &mut leaf).is_break() {
                    return;
                }
                let mut c = inner;
                while c != 0 {
                    let i = c.trailing_zeros() as usize;
                    c &= c - 1;
                    child_rays[i] = by_child[i];
                }
            }
            let mut m = if lanes.is_some() { 0 } else { alive };
            while m != 0 {
                let ray = m.trailing_zeros() as usize;
                m &= m - 1;
                let hit =
                    ray_hits::<MARGIN, AVX2>(node, &rays[ray], tmin, tmax[ray], margin) & mask;
                let slots = hit & leaves;
                if slots != 0 {
                    let meta = node.meta[slots.trailing_zeros() as usize];
                    if leaf(PacketLeaf::Ray { ray, meta, slots }, tmax).is_break() {
                        return;
                    }
                }
                let mut c = hit & inner;
                while c != 0 {
                    let i = c.trailing_zeros() as usize;
                    c &= c - 1;
                    child_rays[i] |= 1 << ray;
                }
            }
        }
        mask = inner;
        // Nearest first, as in `traverse_impl`. Written out in both walks: a shared helper
        // measured 5–7% slower on shadow rays.
        let mut hits = [PacketEntry::default(); 8];
        let mut n = 0;
        while mask != 0 {
            let i = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            if child_rays[i] == 0 {
                continue;
            }
            let e = PacketEntry {
                t: t[i],
                meta: node.meta[i],
                rays: child_rays[i],
            };
            if e.meta & LEAF_BIT == 0 {
                prefetch_node(nodes, e.meta);
            }
            let mut j = n;
            while ORDERED && j > 0 && hits[j - 1].t > e.t {
                hits[j] = hits[j - 1];
                j -= 1;
            }
            hits[j] = e;
            n += 1;
        }
        if n == 0 {
            continue;
        }
        for h in hits[1..n].iter().rev() {
            stack.push(*h);
        }
        next = Some(hits[0]);
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::{grid, record_leaf};
    use super::super::{all_rays, traverse};
    use super::*;
    use crate::geom::Ray;
    use crate::rng::Rng;
    use glam::Vec3;

    /// The eight-at-a-time live-ray scan gives the scalar one's mask and largest `tmax`, on
    /// packets of every length, with retired, NaN, infinite and signed-zero `tmax`.
    #[test]
    #[cfg(target_arch = "x86_64")]
    fn live_rays_eight_at_a_time_are_the_scalar_scan() {
        if !has_avx2() {
            return;
        }
        let mut rng = Rng::new(23);
        for case in 0..20_000 {
            let n = 1 + case % PACKET;
            let tmin = [0.0, -0.0, 1.0, 1e-4][case % 4];
            let tmax: Vec<f32> = (0..n)
                .map(|_| match rng.below(8) {
                    0 => f32::NAN,
                    1 => f32::INFINITY,
                    2 => -1.0,
                    3 => 0.0,
                    4 => -0.0,
                    5 => tmin,
                    _ => 10.0 * rng.next_f32(),
                })
                .collect();
            let mask = (rng.below(1 << 32) as u32) & all_rays(n);
            let (alive, far) = live(tmin, &tmax, mask);
            // SAFETY: AVX2 is present (checked above).
            let (alive8, far8) = unsafe { live_avx2(tmin, &tmax, mask) };
            assert_eq!(alive8, alive, "case {case}: {tmax:?}, mask {mask:b}");
            assert!(far8 == far, "case {case}: {far8} against {far}");
        }
    }

    /// Leaves each ray of a packet is handed, per ray, sorted.
    fn packet_leaves(nodes: &[WideNode], rays: &[(Vec3, Vec3)], tmax: f32) -> Vec<Vec<u32>> {
        let f = Frustum::new(rays.iter().copied()).expect("coherent packet");
        let rays: Vec<Ray> = rays
            .iter()
            .map(|&(origin, direction)| Ray { origin, direction })
            .collect();
        let node_rays = NodeRays::new(&rays);
        let mut seen = vec![Vec::new(); rays.len()];
        let mut tmaxs = vec![tmax; rays.len()];
        traverse_packet::<false, true, false>(
            nodes,
            &node_rays,
            all_rays(rays.len()),
            &f,
            0.0,
            &mut tmaxs,
            0.0,
            |what, _| {
                record_leaf(&mut seen, what);
                ControlFlow::Continue(())
            },
        );
        seen
    }

    #[test]
    fn a_packet_reaches_every_leaf_its_rays_reach() {
        let (_, bvh) = grid();
        let mut rng = Rng::new(7);
        for _ in 0..300 {
            // A pinhole's neighbouring rays: one origin, directions in a small cone, or
            // spread origins (shadow-like rays towards one point).
            let target = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 8.0;
            let shared = rng.next_f32() < 0.5;
            let o0 = Vec3::new(-3.0, -2.0, -4.0) + rng.direction() * 0.5;
            let rays: Vec<(Vec3, Vec3)> = (0..1 + (rng.next_f32() * 31.0) as usize)
                .map(|_| {
                    let o = if shared {
                        o0
                    } else {
                        o0 + rng.direction() * 0.2
                    };
                    (o, target + rng.direction() * 0.3 - o)
                })
                .collect();
            if Frustum::new(rays.iter().copied()).is_none() {
                continue;
            }
            let got = packet_leaves(&bvh.nodes, &rays, f32::INFINITY);
            for (r, got) in rays.iter().zip(got) {
                let r = &NodeRay::new(r.0, r.1);
                let mut t = f32::INFINITY;
                traverse::<false>(&bvh.nodes, r, 0.0, &mut t, 0.0, |first, count, _| {
                    for p in first..first + count {
                        assert!(got.contains(&p), "the packet skipped leaf {p}");
                    }
                    ControlFlow::Continue(())
                });
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_frustum_test_matches_the_portable_one() {
        if !has_avx2() {
            eprintln!("no AVX2 on this CPU: only the portable frustum test exists here");
            return;
        }
        let (_, bvh) = grid();
        let mut rng = Rng::new(11);
        for _ in 0..2000 {
            let o = rng.in_box(Vec3::splat(-2.0), Vec3::splat(10.0));
            let d = rng.direction();
            let rays: Vec<(Vec3, Vec3)> = (0..4)
                .map(|_| (o + rng.direction() * 0.1, d + rng.direction() * 0.05))
                .collect();
            let Some(f) = Frustum::new(rays.clone().into_iter()) else {
                continue;
            };
            let node = &bvh.nodes[(rng.next_f32() * bvh.nodes.len() as f32) as usize];
            let tmax = if rng.next_f32() < 0.5 {
                f32::INFINITY
            } else {
                5.0
            };
            let margin = rng.next_f32() * 0.01;
            // SAFETY: AVX2 checked above.
            let a = unsafe { frustum_hits_avx2::<true>(node, &f, 0.0, tmax, margin) };
            let p = frustum_hits::<true>(node, &f, 0.0, tmax, margin);
            assert_eq!(a.1, p.1);
            for i in 0..8 {
                if a.1 & (1 << i) != 0 {
                    assert_eq!(a.0[i].to_bits(), p.0[i].to_bits());
                }
            }
        }
    }

    /// A frustum made from the rays' directions bounds their node rays exactly as the node
    /// rays' own smallest and largest 1/d and origin do, bit for bit, on packets of every
    /// size with directions of both signs, tiny and huge components, one origin or many.
    #[test]
    fn frusta_from_directions_are_those_of_the_node_rays() {
        let mut rng = Rng::new(5);
        let mut made = 0;
        for case in 0..3000 {
            let signs = Vec3::new(
                if case & 1 == 0 { 1.0 } else { -1.0 },
                if case & 2 == 0 { 1.0 } else { -1.0 },
                if case & 4 == 0 { 1.0 } else { -1.0 },
            );
            let scale = [1.0, 1e-30, 1e30, 1e-38][case / 8 % 4];
            let o0 = rng.vec3_in(-5.0, 5.0);
            let rays: Vec<(Vec3, Vec3)> = (0..1 + case % PACKET)
                .map(|k| {
                    let d = (rng.vec3_in(0.01, 1.0) * signs) * Vec3::new(scale, 1.0, 1.0);
                    let o = if case % 3 == 0 {
                        o0
                    } else {
                        o0 + rng.vec3_in(-1.0, 1.0) * k as f32
                    };
                    (o, d)
                })
                .collect();
            let node: Vec<NodeRay> = rays.iter().map(|r| NodeRay::new(r.0, r.1)).collect();
            let parallel = node.iter().any(|r| r.parallel != 0);
            let Some(f) = Frustum::new(rays.iter().copied()) else {
                assert!(parallel, "case {case}: a frustum of coherent rays");
                continue;
            };
            assert!(
                !parallel,
                "case {case}: a ray parallel to an axis made a frustum"
            );
            made += 1;
            for axis in 0..3 {
                let lo =
                    |v: &mut dyn Iterator<Item = f32>| v.reduce(|a, b| if b < a { b } else { a });
                let hi =
                    |v: &mut dyn Iterator<Item = f32>| v.reduce(|a, b| if b > a { b } else { a });
                let inv = || node.iter().map(|r| r.inv[axis]);
                let o = || node.iter().map(|r| r.o[axis]);
                let bits = |x: Option<f32>| x.unwrap().to_bits();
                assert_eq!(
                    f.inv_lo[axis].to_bits(),
                    bits(lo(&mut inv())),
                    "case {case}"
                );
                assert_eq!(
                    f.inv_hi[axis].to_bits(),
                    bits(hi(&mut inv())),
                    "case {case}"
                );
                assert_eq!(f.o_lo[axis].to_bits(), bits(lo(&mut o())), "case {case}");
                assert_eq!(f.o_hi[axis].to_bits(), bits(hi(&mut o())), "case {case}");
                assert_eq!(f.near[axis], node[0].near[axis], "case {case}");
            }
        }
        assert!(made > 1000, "{made} frusta");
    }

    #[test]
    fn incoherent_rays_make_no_packet() {
        let a = (Vec3::ZERO, Vec3::new(1.0, 1.0, 1.0));
        let b = (Vec3::ZERO, Vec3::new(-1.0, 1.0, 1.0));
        let c = (Vec3::ZERO, Vec3::new(0.0, 1.0, 1.0));
        let nan = (Vec3::new(f32::NAN, 0.0, 0.0), Vec3::new(1.0, 1.0, 1.0));
        assert!(Frustum::new([a, a].into_iter()).is_some());
        assert!(Frustum::new([a, b].into_iter()).is_none());
        assert!(Frustum::new([a, c].into_iter()).is_none());
        assert!(Frustum::new([a, nan].into_iter()).is_none());
        assert!(Frustum::new([].into_iter()).is_none());
    }
}
