//! Mesh leaves stored eight triangles to a block and tested eight at a time.
//!
//! A node has up to eight children and a leaf child holds one to four triangles (three in
//! obvhs's CWBVH trees, four from the binned builder), so a node's leaf children hold at most
//! 32. [`group`] copies the triangles of each node's leaf
//! children, in slot order, into blocks of eight lanes laid out as structure of arrays (the x
//! coordinates of the eight first vertices together, and so on), the way Embree's Triangle4/8
//! leaves are laid out, and points every leaf slot of the node at the node's blocks. The
//! traversal then hands over a node's hit leaf children together
//! ([`super::wide::traverse_grouped`]) and [`block_hits`] runs the watertight test of
//! [`crate::accel::triangle`] on all lanes whose slot the ray met, eight lanes per AVX2
//! instruction where the CPU has AVX2.
//!
//! The vectorised test performs, lane by lane, the very floating-point operations of
//! [`WatertightRay::intersect_nondegenerate`] in the same order (separate multiplies and
//! subtractions, no fused multiply-add, a true division for 1/det), so every lane's result is
//! bit for bit the scalar one; lanes where an edge function rounds to exactly 0 are handed to
//! the scalar test, whose `f64` fallback decides them (`simd_lanes_match_the_scalar_test`).

use arrayvec::ArrayVec;
use bytemuck::Pod;
use glam::Vec3;

use super::huge_pages::HugePageArray;
use super::wide::{LEAF_BIT, MAX_PRIMS, PACKET, WideNode};
use crate::accel::triangle::{TriHit, WatertightRay};

/// Eight triangles, structure of arrays: `v[3·k + axis][lane]` is coordinate `axis` of vertex k
/// (0, 1, 2 = the triangle's a, b, c) of the lane's triangle. 320 bytes: five cache lines.
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C, align(64))]
pub(crate) struct TriBlock {
    pub v: [[f32; 8]; 9],
    /// `1 << slot` of the leaf child the lane's triangle belongs to; 0 for an unused lane.
    pub slot: [u32; 8],
}

/// The hits of one block: lane i hit when bit i of `mask` is set, and then `t[i]`, `u[i]`,
/// `v[i]` are what the scalar test returns for it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct LaneHits {
    pub mask: u32,
    pub t: [f32; 8],
    pub u: [f32; 8],
    pub v: [f32; 8],
}

impl LaneHits {
    /// The hit of lane `i` (meaningful when bit i of `mask` is set).
    #[inline(always)]
    pub fn hit(&self, i: usize) -> TriHit {
        TriHit {
            t: self.t[i],
            u: self.u[i],
            v: self.v[i],
        }
    }
}

/// The watertight shears of a packet's rays as lanes (structure of arrays), for the test of
/// one triangle against sixteen rays at once ([`block_together`]). Lanes of rays not yet set
/// hold zeros; the test never reports them.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
pub(crate) struct ShearLanes {
    /// `o[j][i]`: ray i's origin along its own axis `[kx, ky, kz][j]`.
    pub o: [[f32; PACKET]; 3],
    /// `s[j][i]`: ray i's `[sx, sy, sz][j]`.
    pub s: [[f32; PACKET]; 3],
}

impl ShearLanes {
    /// No ray set.
    pub const EMPTY: ShearLanes = ShearLanes {
        o: [[0.0; PACKET]; 3],
        s: [[0.0; PACKET]; 3],
    };

    /// Lane `ray` takes the shear `wr`.
    #[inline(always)]
    pub fn set(&mut self, ray: usize, wr: &WatertightRay) {
        let o = wr.origin.to_array();
        for (j, axis) in [wr.kx, wr.ky, wr.kz].into_iter().enumerate() {
            self.o[j][ray] = o[axis];
        }
        self.s[0][ray] = wr.sx;
        self.s[1][ray] = wr.sy;
        self.s[2][ray] = wr.sz;
    }
}

/// Up to sixteen rays of a packet that share shear axes, gathered into the lanes of one
/// register each (for [`block_together`]), with the `tmax` of each as the caller keeps it.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
pub(crate) struct RayLanes {
    o: [[f32; 16]; 3],
    s: [[f32; 16]; 3],
    /// Each lane's `tmax`.
    far: [f32; 16],
    /// The packet's ray in each lane.
    ray: [u32; 16],
    /// Per leaf slot, the lanes whose rays meet it.
    by_slot: [u16; 8],
    /// The packet's rays in the lanes (bit j for ray j).
    rays: u32,
}

impl RayLanes {
    /// Lanes of no ray, to be gathered (the gather reads all sixteen of `ray`).
    pub const EMPTY: RayLanes = RayLanes {
        o: [[0.0; 16]; 3],
        s: [[0.0; 16]; 3],
        far: [0.0; 16],
        ray: [0; 16],
        by_slot: [0; 8],
        rays: 0,
    };

    /// Gathers the rays of `rays` (at most sixteen, each set in `shears` and below
    /// `tmax.len()`) in ray order, with their `tmax`; `by_slot[i]` holds the packet's rays
    /// that meet leaf slot i. Only on CPUs where [`together_runs`].
    #[inline(always)]
    pub fn gather(
        &mut self,
        shears: &ShearLanes,
        tmax: &[f32],
        rays: u32,
        by_slot: &[u32; 8],
    ) -> &mut RayLanes {
        assert!(rays.count_ones() <= 16 && u64::from(rays) < 1u64 << tmax.len());
        assert!(
            together_runs(),
            "rays are tested together only on CPUs with AVX-512F"
        );
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the CPU runs AVX-512F and BMI2 code (just checked); the rays are below
        // `tmax.len()` (asserted).
        unsafe {
            self.gather_avx512(shears, tmax, rays, by_slot)
        };
        #[cfg(not(target_arch = "x86_64"))]
        let _ = (shears, by_slot);
        self
    }

    /// # Safety
    /// The CPU must support AVX-512F and BMI2; at most sixteen rays, all below `tmax.len()`.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,bmi2")]
    #[inline]
    unsafe fn gather_avx512(
        &mut self,
        shears: &ShearLanes,
        tmax: &[f32],
        rays: u32,
        by_slot: &[u32; 8],
    ) {
        use std::arch::x86_64::*;
        let mut m = rays;
        let mut lane = 0;
        while m != 0 {
            self.ray[lane] = m.trailing_zeros();
            m &= m - 1;
            lane += 1;
        }
        self.rays = rays;
        self.by_slot = by_slot.map(|slot_rays| _pext_u32(slot_rays, rays) as u16);
        // SAFETY (whole body): loads of sixteen f32 within arrays of `PACKET` (32, two
        // registers), masked loads of `tmax` that read only entries below its length, stores
        // into arrays of sixteen; AVX-512F is enabled.
        unsafe {
            let idx = _mm512_loadu_si512(self.ray.as_ptr() as *const __m512i);
            // Lane j takes entry ray[j] of the 32 in two registers.
            let pick = |row: &[f32; PACKET]| {
                let (lo, hi) = (row.as_ptr(), row.as_ptr().add(16));
                _mm512_permutex2var_ps(_mm512_loadu_ps(lo), idx, _mm512_loadu_ps(hi))
            };
            for j in 0..3 {
                _mm512_storeu_ps(self.o[j].as_mut_ptr(), pick(&shears.o[j]));
                _mm512_storeu_ps(self.s[j].as_mut_ptr(), pick(&shears.s[j]));
            }
            let n = tmax.len();
            let below = |count: usize| ((1u32 << count.min(16)) - 1) as u16;
            let lo = _mm512_maskz_loadu_ps(below(n), tmax.as_ptr());
            let hi = _mm512_maskz_loadu_ps(below(n.saturating_sub(16)), tmax.as_ptr().add(16));
            _mm512_storeu_ps(self.far.as_mut_ptr(), _mm512_permutex2var_ps(lo, idx, hi));
        }
    }

    /// The lane of the packet's ray `ray` (one of the gathered rays).
    #[inline(always)]
    pub fn lane_of(&self, ray: usize) -> usize {
        (self.rays & ((1 << ray) - 1)).count_ones() as usize
    }

    /// Lane `lane`'s ray now has `tmax` = `t`.
    #[inline(always)]
    pub fn set_far(&mut self, lane: usize, t: f32) {
        self.far[lane] = t;
    }
}

/// Whether this CPU tests one triangle against sixteen rays at once (AVX-512F and BMI2,
/// detected at run time; std caches it).
#[inline(always)]
pub(crate) fn together_runs() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        super::wide::has_avx512() && std::arch::is_x86_feature_detected!("bmi2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The triangles of `block` in the leaf slots `slots`, in lane order, each tested against the
/// gathered rays of `here` (packet ray mask) whose leaf slots hold it, sixteen rays at once,
/// all sharing the shear axes `axes` (`[kx, ky, kz]`), for hits with `tmin <= t <=` each
/// ray's `tmax`. `hit(ray, lane, hit)` is called for each hit of a ray (`lane` the block's
/// lane) and returns the ray's `tmax` after it; a ray whose `tmax` falls to −∞ is tested no
/// further. `made(ray)` is the ray's shear, for the scalar test of edge functions of exactly
/// 0. Returns the rays of `here` still live.
///
/// Each lane performs the operations of [`block_hits`]'s lanes in the same order, so it is
/// bit for bit its ray's own test of the triangle (`rays_together_match_the_scalar_test`).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn block_together<'w>(
    block: &TriBlock,
    slots: u32,
    here: u32,
    axes: [usize; 3],
    lanes: &mut RayLanes,
    tmin: f32,
    made: impl Fn(usize) -> &'w WatertightRay,
    hit: impl FnMut(usize, usize, TriHit) -> f32,
) -> u32 {
    assert!(
        together_runs(),
        "rays are tested together only on CPUs with AVX-512F"
    );
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU runs AVX-512F and BMI2 code (just checked).
    unsafe {
        block_together_avx512(block, slots, here, axes, lanes, tmin, made, hit)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (made, hit);
        unreachable!("{block:?} {slots} {here} {axes:?} {lanes:?} {tmin}")
    }
}

/// [`block_together`] with the sixteen lanes in 512-bit registers. The arithmetic is
/// [`block_hits_avx2`]'s, written out again at this width rather than shared through a lane
/// trait: AVX2 compares give vector masks and AVX-512 compares give mask registers, and each
/// form is held to the scalar test by its own unit test.
///
/// # Safety
/// The CPU must support AVX-512F and BMI2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,bmi2")]
#[inline]
#[allow(clippy::too_many_arguments)]
unsafe fn block_together_avx512<'w>(
    block: &TriBlock,
    slots: u32,
    here: u32,
    [kx, ky, kz]: [usize; 3],
    lanes: &mut RayLanes,
    tmin: f32,
    made: impl Fn(usize) -> &'w WatertightRay,
    mut hit: impl FnMut(usize, usize, TriHit) -> f32,
) -> u32 {
    use std::arch::x86_64::*;
    let mut live = _pext_u32(here, lanes.rays) as u16;
    // SAFETY (whole body): loads of sixteen f32 from arrays of sixteen, stores into arrays of
    // sixteen; AVX-512F is enabled.
    unsafe {
        let load = |row: &[f32; 16]| _mm512_loadu_ps(row.as_ptr());
        let [ox, oy, oz] = lanes.o.each_ref().map(load);
        let [sx, sy, sz] = lanes.s.each_ref().map(load);
        let zero = _mm512_setzero_ps();
        for lane in 0..8 {
            let slot = block.slot[lane];
            if slot & slots == 0 {
                continue;
            }
            let which = lanes.by_slot[slot.trailing_zeros() as usize] & live;
            if which == 0 {
                continue;
            }
            let at = |k: usize, axis: usize| _mm512_set1_ps(block.v[3 * k + axis][lane]);
            // As in `block_hits_avx2`: vertices relative to the origin, sheared, edge
            // functions.
            let rel = |k: usize| {
                (
                    _mm512_sub_ps(at(k, kx), ox),
                    _mm512_sub_ps(at(k, ky), oy),
                    _mm512_sub_ps(at(k, kz), oz),
                )
            };
            let shear = |(x, y, z): (__m512, __m512, __m512)| {
                (
                    _mm512_sub_ps(x, _mm512_mul_ps(sx, z)),
                    _mm512_sub_ps(y, _mm512_mul_ps(sy, z)),
                    z,
                )
            };
            let (ax, ay, arz) = shear(rel(0));
            let (bx, by, brz) = shear(rel(1));
            let (cx, cy, crz) = shear(rel(2));
            let cross = |p: __m512, q: __m512, r: __m512, s: __m512| {
                _mm512_sub_ps(_mm512_mul_ps(p, q), _mm512_mul_ps(r, s))
            };
            let u = cross(cx, by, cy, bx);
            let v = cross(ax, cy, ay, cx);
            let w = cross(bx, ay, by, ax);
            let eq0 = |x: __m512| _mm512_cmp_ps_mask::<_CMP_EQ_OQ>(x, zero);
            let lt0 = |x: __m512| _mm512_cmp_ps_mask::<_CMP_LT_OQ>(x, zero);
            let gt0 = |x: __m512| _mm512_cmp_ps_mask::<_CMP_GT_OQ>(x, zero);
            let exact_zero = which & (eq0(u) | eq0(v) | eq0(w));
            let neg = lt0(u) | lt0(v) | lt0(w);
            let pos = gt0(u) | gt0(v) | gt0(w);
            let mut ok = which & !exact_zero & !(neg & pos);
            // Most rays miss most triangles: the division only where a ray is inside all
            // edges (or an edge function is 0).
            if ok | exact_zero == 0 {
                continue;
            }
            let mut hits = RayHits {
                mask: 0,
                t: [0.0; 16],
                u: [0.0; 16],
                v: [0.0; 16],
            };
            if ok != 0 {
                let det = _mm512_add_ps(_mm512_add_ps(u, v), w);
                ok &= _mm512_cmp_ps_mask::<_CMP_NEQ_OQ>(det, zero);
                let t_scaled = _mm512_add_ps(
                    _mm512_add_ps(
                        _mm512_mul_ps(u, _mm512_mul_ps(sz, arz)),
                        _mm512_mul_ps(v, _mm512_mul_ps(sz, brz)),
                    ),
                    _mm512_mul_ps(w, _mm512_mul_ps(sz, crz)),
                );
                let rcp = _mm512_div_ps(_mm512_set1_ps(1.0), det);
                let t = _mm512_mul_ps(t_scaled, rcp);
                ok &= _mm512_cmp_ps_mask::<_CMP_GE_OQ>(t, _mm512_set1_ps(tmin))
                    & _mm512_cmp_ps_mask::<_CMP_LE_OQ>(t, load(&lanes.far));
                hits.mask = u32::from(ok);
                if ok != 0 {
                    _mm512_storeu_ps(hits.t.as_mut_ptr(), t);
                    _mm512_storeu_ps(hits.u.as_mut_ptr(), _mm512_mul_ps(v, rcp));
                    _mm512_storeu_ps(hits.v.as_mut_ptr(), _mm512_mul_ps(w, rcp));
                }
            }
            // Lanes with an edge function of exactly 0: the scalar test (its f64 fallback).
            let mut fallback = u32::from(exact_zero);
            while fallback != 0 {
                let i = fallback.trailing_zeros() as usize;
                fallback &= fallback - 1;
                let [a, b, c] = lane_triangle(block, lane);
                let wr = made(lanes.ray[i] as usize);
                if let Some(h) = wr.intersect_nondegenerate(a, b, c, tmin, lanes.far[i]) {
                    hits.mask |= 1 << i;
                    (hits.t[i], hits.u[i], hits.v[i]) = (h.t, h.u, h.v);
                }
            }
            let mut m = hits.mask;
            while m != 0 {
                let i = m.trailing_zeros() as usize;
                m &= m - 1;
                let far = hit(lanes.ray[i] as usize, lane, hits.hit(i));
                lanes.far[i] = far;
                if far == f32::NEG_INFINITY {
                    live &= !(1 << i);
                }
            }
        }
    }
    _pdep_u32(u32::from(live), lanes.rays)
}

/// The hits of one triangle among the lanes of a [`RayLanes`]: lane i hit when bit i of
/// `mask` is set, with `t[i]`, `u[i]`, `v[i]` what the scalar test returns.
#[derive(Clone, Copy, Debug)]
struct RayHits {
    mask: u32,
    t: [f32; 16],
    u: [f32; 16],
    v: [f32; 16],
}

impl RayHits {
    /// The hit of lane `i` (meaningful when bit i of `mask` is set).
    #[inline(always)]
    fn hit(&self, i: usize) -> TriHit {
        TriHit {
            t: self.t[i],
            u: self.u[i],
            v: self.v[i],
        }
    }
}

/// Grouped leaves of a tree: the blocks, and per block the caller's id of each lane's triangle.
#[derive(Clone, Debug, Default)]
pub(crate) struct Leaves {
    pub blocks: HugePageArray<TriBlock>,
    pub ids: HugePageArray<[u32; 8]>,
    /// Per block, the leaf slots its lanes belong to (bit i for child i): a block none of
    /// whose slots the ray met is skipped without loading it.
    pub slots: HugePageArray<u8>,
}

impl Leaves {
    /// The blocks of a grouped leaf `meta` that hold triangles of the leaf slots in `slots`.
    #[inline(always)]
    pub fn blocks_for(&self, meta: u32, slots: u32) -> impl Iterator<Item = usize> + '_ {
        let first = super::wide::leaf_first(meta) as usize;
        let count = super::wide::leaf_count(meta) as usize;
        (first..first + count).filter(move |&k| u32::from(self.slots[k]) & slots != 0)
    }
}

/// Asks for the cache line of `value` ahead of its use (a hint; nothing is read).
#[inline(always)]
pub(crate) fn prefetch<T>(value: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch is only a hint, of an address inside `value`.
    unsafe {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        _mm_prefetch::<_MM_HINT_T0>(value as *const T as *const i8)
    };
    #[cfg(not(target_arch = "x86_64"))]
    let _ = value;
}

/// Moves the triangles of every node's leaf children into blocks and rewrites each leaf
/// child's meta to `LEAF_BIT | (block count − 1) << 29 | first block` (the same for all leaf
/// children of a node; see [`super::wide::leaf_first`] and [`super::wide::leaf_count`]).
/// `tris[j]` and `ids[j]` are the triangle and id of primitive reference j of the tree.
///
/// Runs of [`GROUP_RUN`] nodes are grouped on the rayon pool, each numbering its blocks from
/// 0, then moved to where the runs before them end: the blocks and metas of one pass over the
/// nodes in order, on any number of threads (on one thread this pass was a sixth of a large
/// mesh's build).
pub(crate) fn group(nodes: &mut [WideNode], tris: &[[Vec3; 3]], ids: &[u32]) -> Leaves {
    use rayon::prelude::*;
    let runs: Vec<RunLeaves> = nodes
        .par_chunks_mut(GROUP_RUN)
        .map(|run| group_run(run, tris, ids))
        .collect();
    let mut first = 0usize;
    let starts: Vec<usize> = runs
        .iter()
        .map(|r| {
            let s = first;
            first += r.blocks.len();
            s
        })
        .collect();
    assert!(first <= MAX_PRIMS, "more leaf blocks than a meta encodes");
    nodes
        .par_chunks_mut(GROUP_RUN)
        .zip(&starts)
        .for_each(|(run, &start)| {
            for node in run {
                for slot in 0..8 {
                    let used = node.bounds[0][slot] <= node.bounds[1][slot];
                    if used && node.meta[slot] & LEAF_BIT != 0 {
                        // (first + start stays below MAX_PRIMS, checked above: no carry)
                        node.meta[slot] += start as u32;
                    }
                }
            }
        });
    // Each run's blocks copied to their place in parallel: a large mesh's blocks are tens of
    // megabytes, written once more into memory advised for huge pages (`super::huge_pages`).
    fn gather<T: Pod + Send + Sync>(
        out: &mut [T],
        runs: &[RunLeaves],
        part: impl Fn(&RunLeaves) -> &[T] + Sync,
    ) {
        let mut places = Vec::with_capacity(runs.len());
        let mut rest = out;
        for r in runs {
            let (place, tail) = rest.split_at_mut(part(r).len());
            places.push(place);
            rest = tail;
        }
        places
            .into_par_iter()
            .zip(runs)
            .for_each(|(place, r)| place.copy_from_slice(part(r)));
    }
    Leaves {
        blocks: HugePageArray::new_with(first, |out| gather(out, &runs, |r| &r.blocks)),
        ids: HugePageArray::new_with(first, |out| gather(out, &runs, |r| &r.ids)),
        slots: HugePageArray::new_with(first, |out| gather(out, &runs, |r| &r.slots)),
    }
}

/// The blocks of one run of [`group`], numbered from 0.
#[derive(Default)]
struct RunLeaves {
    blocks: Vec<TriBlock>,
    ids: Vec<[u32; 8]>,
    slots: Vec<u8>,
}

/// Nodes per run of [`group`].
const GROUP_RUN: usize = 1024;

/// [`group`] of the nodes of one run, its blocks numbered from 0.
fn group_run(nodes: &mut [WideNode], tris: &[[Vec3; 3]], ids: &[u32]) -> RunLeaves {
    let mut out = RunLeaves::default();
    for node in nodes.iter_mut() {
        let mut lanes: ArrayVec<(usize, usize), 32> = ArrayVec::new();
        let mut leaf_slots: ArrayVec<usize, 8> = ArrayVec::new();
        for slot in 0..8 {
            let meta = node.meta[slot];
            let used = node.bounds[0][slot] <= node.bounds[1][slot];
            if !used || meta & LEAF_BIT == 0 {
                continue;
            }
            leaf_slots.push(slot);
            let first = super::wide::leaf_first(meta) as usize;
            let count = super::wide::leaf_count(meta) as usize;
            lanes.extend((first..first + count).map(|j| (slot, j)));
        }
        if lanes.is_empty() {
            continue;
        }
        let first_block = out.blocks.len();
        let count = lanes.len().div_ceil(8);
        // Leaves hold at most four triangles (three from obvhs, four from the binned builder):
        // at most 32 lanes, four blocks, which the two count bits of the meta encode.
        assert!((1..=4).contains(&count) && first_block + count <= MAX_PRIMS);
        for chunk in lanes.chunks(8) {
            let mut block = TriBlock {
                v: [[0.0; 8]; 9],
                slot: [0; 8],
            };
            let mut block_ids = [u32::MAX; 8];
            let mut block_slots = 0u8;
            for (lane, &(slot, j)) in chunk.iter().enumerate() {
                block_slots |= 1 << slot;
                for (k, vertex) in tris[j].iter().enumerate() {
                    for axis in 0..3 {
                        block.v[3 * k + axis][lane] = vertex[axis];
                    }
                }
                block.slot[lane] = 1 << slot;
                block_ids[lane] = ids[j];
            }
            out.blocks.push(block);
            out.ids.push(block_ids);
            out.slots.push(block_slots);
        }
        let meta = LEAF_BIT | ((count as u32 - 1) << 29) | first_block as u32;
        for slot in leaf_slots {
            node.meta[slot] = meta;
        }
    }
    out
}

/// The watertight test of `wr` against the lanes of `block` whose leaf slot is in `slots`,
/// for hits with `tmin <= t <= tmax`.
#[inline(always)]
pub(crate) fn block_hits(
    block: &TriBlock,
    wr: &WatertightRay,
    slots: u32,
    tmin: f32,
    tmax: f32,
) -> LaneHits {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (just checked; std caches the detection).
        return unsafe { block_hits_avx2(block, wr, slots, tmin, tmax) };
    }
    block_hits_scalar(block, wr, slots, tmin, tmax)
}

/// The lane's triangle.
#[inline(always)]
fn lane_triangle(block: &TriBlock, lane: usize) -> [Vec3; 3] {
    let c = |k: usize| {
        Vec3::new(
            block.v[3 * k][lane],
            block.v[3 * k + 1][lane],
            block.v[3 * k + 2][lane],
        )
    };
    [c(0), c(1), c(2)]
}

/// Lane `lane` through the scalar test, recorded in `hits`.
#[inline(always)]
fn scalar_lane(
    hits: &mut LaneHits,
    block: &TriBlock,
    lane: usize,
    wr: &WatertightRay,
    tmin: f32,
    tmax: f32,
) {
    let [a, b, c] = lane_triangle(block, lane);
    if let Some(h) = wr.intersect_nondegenerate(a, b, c, tmin, tmax) {
        hits.mask |= 1 << lane;
        hits.t[lane] = h.t;
        hits.u[lane] = h.u;
        hits.v[lane] = h.v;
    }
}

/// [`block_hits`] one lane at a time (CPUs without AVX2).
fn block_hits_scalar(
    block: &TriBlock,
    wr: &WatertightRay,
    slots: u32,
    tmin: f32,
    tmax: f32,
) -> LaneHits {
    let mut hits = LaneHits {
        mask: 0,
        t: [0.0; 8],
        u: [0.0; 8],
        v: [0.0; 8],
    };
    for lane in 0..8 {
        if block.slot[lane] & slots != 0 {
            scalar_lane(&mut hits, block, lane, wr, tmin, tmax);
        }
    }
    hits
}

/// [`block_hits`] with the eight lanes in 256-bit registers.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn block_hits_avx2(
    block: &TriBlock,
    wr: &WatertightRay,
    slots: u32,
    tmin: f32,
    tmax: f32,
) -> LaneHits {
    use std::arch::x86_64::*;
    // SAFETY (whole body): aligned loads of eight f32/u32 from 32-byte aligned rows of a
    // 64-byte aligned block, unaligned stores into arrays of eight f32; AVX2 is enabled.
    unsafe {
        let active = {
            let s = _mm256_load_si256(block.slot.as_ptr() as *const __m256i);
            let hit = _mm256_and_si256(s, _mm256_set1_epi32(slots as i32));
            let none = _mm256_cmpeq_epi32(hit, _mm256_setzero_si256());
            // active = not none
            _mm256_castsi256_ps(_mm256_xor_si256(none, _mm256_set1_epi32(-1)))
        };
        let (kx, ky, kz) = (wr.kx, wr.ky, wr.kz);
        let o = wr.origin.to_array();
        let load = |k: usize, axis: usize| _mm256_load_ps(block.v[3 * k + axis].as_ptr());
        // "calculate vertices relative to ray origin" (only the three axes used).
        let rel = |k: usize| {
            (
                _mm256_sub_ps(load(k, kx), _mm256_set1_ps(o[kx])),
                _mm256_sub_ps(load(k, ky), _mm256_set1_ps(o[ky])),
                _mm256_sub_ps(load(k, kz), _mm256_set1_ps(o[kz])),
            )
        };
        let (sx, sy, sz) = (
            _mm256_set1_ps(wr.sx),
            _mm256_set1_ps(wr.sy),
            _mm256_set1_ps(wr.sz),
        );
        // "perform shear and scale of vertices": x − s·z as a product then a difference.
        let shear = |(x, y, z): (__m256, __m256, __m256)| {
            (
                _mm256_sub_ps(x, _mm256_mul_ps(sx, z)),
                _mm256_sub_ps(y, _mm256_mul_ps(sy, z)),
                z,
            )
        };
        let (ax, ay, arz) = shear(rel(0));
        let (bx, by, brz) = shear(rel(1));
        let (cx, cy, crz) = shear(rel(2));
        let cross = |p: __m256, q: __m256, r: __m256, s: __m256| {
            _mm256_sub_ps(_mm256_mul_ps(p, q), _mm256_mul_ps(r, s))
        };
        let u = cross(cx, by, cy, bx);
        let v = cross(ax, cy, ay, cx);
        let w = cross(bx, ay, by, ax);
        let zero = _mm256_setzero_ps();
        let eq0 = |x: __m256| _mm256_cmp_ps::<_CMP_EQ_OQ>(x, zero);
        let lt0 = |x: __m256| _mm256_cmp_ps::<_CMP_LT_OQ>(x, zero);
        let gt0 = |x: __m256| _mm256_cmp_ps::<_CMP_GT_OQ>(x, zero);
        // Lanes with an edge function of exactly 0 go to the scalar test (its f64 fallback).
        let exact_zero = _mm256_and_ps(active, _mm256_or_ps(_mm256_or_ps(eq0(u), eq0(v)), eq0(w)));
        let neg = _mm256_or_ps(_mm256_or_ps(lt0(u), lt0(v)), lt0(w));
        let pos = _mm256_or_ps(_mm256_or_ps(gt0(u), gt0(v)), gt0(w));
        let mut ok = _mm256_andnot_ps(exact_zero, active);
        ok = _mm256_andnot_ps(_mm256_and_ps(neg, pos), ok);
        let det = _mm256_add_ps(_mm256_add_ps(u, v), w);
        // Ordered "not equal": false for det = 0 and for NaN.
        ok = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_NEQ_OQ>(det, zero));
        let t_scaled = _mm256_add_ps(
            _mm256_add_ps(
                _mm256_mul_ps(u, _mm256_mul_ps(sz, arz)),
                _mm256_mul_ps(v, _mm256_mul_ps(sz, brz)),
            ),
            _mm256_mul_ps(w, _mm256_mul_ps(sz, crz)),
        );
        let rcp = _mm256_div_ps(_mm256_set1_ps(1.0), det);
        let t = _mm256_mul_ps(t_scaled, rcp);
        ok = _mm256_and_ps(
            ok,
            _mm256_and_ps(
                _mm256_cmp_ps::<_CMP_GE_OQ>(t, _mm256_set1_ps(tmin)),
                _mm256_cmp_ps::<_CMP_LE_OQ>(t, _mm256_set1_ps(tmax)),
            ),
        );
        let mut hits = LaneHits {
            mask: _mm256_movemask_ps(ok) as u32,
            t: [0.0; 8],
            u: [0.0; 8],
            v: [0.0; 8],
        };
        if hits.mask != 0 {
            _mm256_storeu_ps(hits.t.as_mut_ptr(), t);
            _mm256_storeu_ps(hits.u.as_mut_ptr(), _mm256_mul_ps(v, rcp));
            _mm256_storeu_ps(hits.v.as_mut_ptr(), _mm256_mul_ps(w, rcp));
        }
        let mut fallback = _mm256_movemask_ps(exact_zero) as u32;
        while fallback != 0 {
            let lane = fallback.trailing_zeros() as usize;
            fallback &= fallback - 1;
            scalar_lane(&mut hits, block, lane, wr, tmin, tmax);
        }
        hits
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// A node whose leaf children hold triangles 0..n, three to a slot.
    fn leaf_node(n: usize) -> WideNode {
        let mut node = WideNode::EMPTY;
        for (slot, first) in (0..n).step_by(3).enumerate() {
            let count = (n - first).min(3);
            for axis in 0..3 {
                node.bounds[2 * axis][slot] = -1e9;
                node.bounds[2 * axis + 1][slot] = 1e9;
            }
            node.meta[slot] = LEAF_BIT | ((count as u32 - 1) << 29) | first as u32;
        }
        node
    }

    fn block_of(tris: &[[Vec3; 3]]) -> TriBlock {
        let mut nodes = vec![leaf_node(tris.len())];
        let ids: Vec<u32> = (0..tris.len() as u32).collect();
        let leaves = group(&mut nodes, tris, &ids);
        assert_eq!(leaves.blocks.len(), 1);
        leaves.blocks[0]
    }

    /// Every lane of the vectorised test equals the scalar test bit for bit, on random
    /// triangles and rays and on rays through shared vertices and edges (exact-zero edge
    /// functions, the scalar fallback's case).
    #[test]
    fn simd_lanes_match_the_scalar_test() {
        let mut rng = Rng::new(7);
        let mut v3 = |s: f32| {
            Vec3::new(
                rng.next_f32() * 2.0 - 1.0,
                rng.next_f32() * 2.0 - 1.0,
                rng.next_f32() * 2.0 - 1.0,
            ) * s
        };
        let mut compared = 0;
        let mut hits = 0;
        for round in 0..4000 {
            // Small integer grids make rays pass exactly through vertices and edges.
            let grid = round % 2 == 0;
            let mut pick = |s: f32| {
                let p = v3(s);
                if grid { p.round() } else { p }
            };
            let tris: Vec<[Vec3; 3]> = (0..8).map(|_| [pick(3.0), pick(3.0), pick(3.0)]).collect();
            if tris
                .iter()
                .any(|t| crate::accel::triangle::is_degenerate(t[0], t[1], t[2]))
            {
                continue;
            }
            let block = block_of(&tris);
            let o = pick(6.0) + Vec3::new(0.0, 0.0, 8.0);
            let target = tris[round % 8][(round / 8) % 3];
            let d = if round % 3 == 0 {
                target - o
            } else {
                pick(1.0)
            };
            let wr = WatertightRay::new(o, d);
            let (tmin, tmax) = (0.0, if round % 5 == 0 { 1.0 } else { f32::INFINITY });
            let lanes = block_hits(&block, &wr, 0xff, tmin, tmax);
            let reference = block_hits_scalar(&block, &wr, 0xff, tmin, tmax);
            assert_eq!(lanes.mask, reference.mask, "round {round}");
            for (lane, tri) in tris.iter().enumerate() {
                let scalar = wr.intersect_nondegenerate(tri[0], tri[1], tri[2], tmin, tmax);
                compared += 1;
                match scalar {
                    Some(h) => {
                        hits += 1;
                        assert!(lanes.mask & (1 << lane) != 0, "round {round} lane {lane}");
                        let got = lanes.hit(lane);
                        assert_eq!(got.t.to_bits(), h.t.to_bits(), "round {round}");
                        assert_eq!(got.u.to_bits(), h.u.to_bits(), "round {round}");
                        assert_eq!(got.v.to_bits(), h.v.to_bits(), "round {round}");
                    }
                    None => assert!(lanes.mask & (1 << lane) == 0, "round {round} lane {lane}"),
                }
            }
        }
        assert!(
            compared > 20_000 && hits > 500,
            "{compared} lanes, {hits} hits"
        );
    }

    /// Every hit that the test of one triangle against sixteen rays reports is bit for bit
    /// the scalar test's, and it misses none: on random triangles and rays and on rays through
    /// shared vertices and edges (exact-zero edge functions, the scalar fallback's case), for
    /// rays gathered from both halves of a packet, with leaf slots that only some rays meet.
    /// A ray whose `tmax` falls to −∞ is tested no further.
    #[test]
    fn rays_together_match_the_scalar_test() {
        if !together_runs() {
            eprintln!("no AVX-512F and BMI2 on this CPU: rays are never tested together here");
            return;
        }
        let mut rng = Rng::new(19);
        let mut compared = 0;
        let mut hits = 0;
        for round in 0..3000 {
            let grid = round % 2 == 0;
            let mut pick = |s: f32| {
                let p = Vec3::new(
                    rng.next_f32() * 2.0 - 1.0,
                    rng.next_f32() * 2.0 - 1.0,
                    rng.next_f32() * 2.0 - 1.0,
                ) * s;
                if grid { p.round() } else { p }
            };
            let tris: Vec<[Vec3; 3]> = (0..8).map(|_| [pick(3.0), pick(3.0), pick(3.0)]).collect();
            if tris
                .iter()
                .any(|t| crate::accel::triangle::is_degenerate(t[0], t[1], t[2]))
            {
                continue;
            }
            // Two triangles to a leaf slot: slots 0..4.
            let mut block = block_of(&tris);
            for lane in 0..8 {
                block.slot[lane] = 1 << (lane / 2);
            }
            // Rays down −z from above, aimed at vertices on grid rounds: one frame for all.
            let n = 32;
            let rays: Vec<WatertightRay> = (0..n)
                .map(|i| {
                    let o = pick(1.0) + Vec3::new(0.0, 0.0, 9.0);
                    let target = if grid { tris[i % 8][i % 3] } else { pick(2.0) };
                    WatertightRay::new(o, target - o)
                })
                .collect();
            let axes = [rays[0].kx, rays[0].ky, rays[0].kz];
            assert!(rays.iter().all(|r| [r.kx, r.ky, r.kz] == axes));
            let mut shears = ShearLanes::EMPTY;
            for (i, wr) in rays.iter().enumerate() {
                shears.set(i, wr);
            }
            let tmax: Vec<f32> = (0..n)
                .map(|i| if i % 5 == 0 { 9.5 } else { f32::INFINITY })
                .collect();
            // Up to sixteen rays from all 32; each slot met by some of them.
            let mut chosen = 0u32;
            while chosen.count_ones() < 16 {
                chosen |= 1 << (rng.next_u64() % 32);
                if rng.next_u64().is_multiple_of(9) {
                    break;
                }
            }
            let by_slot: [u32; 8] = std::array::from_fn(|slot| {
                if slot < 4 {
                    chosen & rng.next_u64() as u32
                } else {
                    0
                }
            });
            let here = by_slot.iter().fold(0, |m, r| m | r);
            let retire = round % 7 == 0;
            let mut lanes = RayLanes::EMPTY;
            lanes.gather(&shears, &tmax, chosen, &by_slot);
            let mut got = std::collections::HashMap::new();
            let live = block_together(
                &block,
                0xf,
                here,
                axes,
                &mut lanes,
                0.0,
                |ray| &rays[ray],
                |ray, lane, h| {
                    assert!(
                        got.insert((ray, lane), h).is_none(),
                        "round {round}: ray {ray} lane {lane} reported twice"
                    );
                    if retire { f32::NEG_INFINITY } else { tmax[ray] }
                },
            );
            let mut first_hit = std::collections::HashMap::new();
            for ray in 0..n {
                for lane in 0..8 {
                    let met = by_slot[lane / 2] >> ray & 1 == 1 && here >> ray & 1 == 1;
                    let [a, b, c] = tris[lane];
                    let scalar = rays[ray].intersect_nondegenerate(a, b, c, 0.0, tmax[ray]);
                    compared += usize::from(met);
                    match (met, scalar) {
                        (true, Some(h)) if !(retire && first_hit.contains_key(&ray)) => {
                            hits += 1;
                            first_hit.entry(ray).or_insert(lane);
                            let g = got.get(&(ray, lane)).unwrap_or_else(|| {
                                panic!("round {round}: ray {ray} lane {lane} missed")
                            });
                            assert_eq!(g.t.to_bits(), h.t.to_bits(), "round {round}");
                            assert_eq!(g.u.to_bits(), h.u.to_bits(), "round {round}");
                            assert_eq!(g.v.to_bits(), h.v.to_bits(), "round {round}");
                        }
                        _ => assert!(
                            !got.contains_key(&(ray, lane)),
                            "round {round}: ray {ray} lane {lane} reported"
                        ),
                    }
                }
            }
            let expected_live = if retire {
                here & !first_hit.keys().fold(0, |m, &r| m | 1 << r)
            } else {
                here
            };
            assert_eq!(live, expected_live, "round {round}");
        }
        assert!(
            compared > 50_000 && hits > 1_000,
            "{compared} pairs, {hits} hits"
        );
    }

    /// Lanes whose slot is not asked for, and unused lanes, never hit.
    #[test]
    fn only_the_asked_slots_are_tested() {
        let tri = [
            Vec3::new(-1.0, -1.0, 0.0),
            Vec3::new(1.0, -1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        let mut nodes = vec![leaf_node(3)];
        let leaves = group(&mut nodes, &[tri, tri, tri], &[10, 11, 12]);
        let wr = WatertightRay::new(Vec3::new(0.0, 0.0, 5.0), Vec3::NEG_Z);
        let block = &leaves.blocks[0];
        assert_eq!(block_hits(block, &wr, 1, 0.0, 10.0).mask, 0b111);
        assert_eq!(block_hits(block, &wr, 0, 0.0, 10.0).mask, 0);
        assert_eq!(block_hits(block, &wr, 0xfe, 0.0, 10.0).mask, 0);
        assert_eq!(leaves.ids[0][..4], [10, 11, 12, u32::MAX]);
    }
}
