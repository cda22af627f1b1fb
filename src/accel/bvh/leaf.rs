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
use glam::Vec3;

use super::wide::{LEAF_BIT, MAX_PRIMS, WideNode};
use crate::accel::triangle::{TriHit, WatertightRay};

/// Eight triangles, structure of arrays: `v[3·k + axis][lane]` is coordinate `axis` of vertex k
/// (0, 1, 2 = the triangle's a, b, c) of the lane's triangle. 320 bytes: five cache lines.
#[derive(Clone, Copy, Debug)]
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

/// Grouped leaves of a tree: the blocks, and per block the caller's id of each lane's triangle.
#[derive(Clone, Debug, Default)]
pub(crate) struct Leaves {
    pub blocks: Vec<TriBlock>,
    pub ids: Vec<[u32; 8]>,
    /// Per block, the leaf slots its lanes belong to (bit i for child i): a block none of
    /// whose slots the ray met is skipped without loading it.
    pub slots: Vec<u8>,
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
pub(crate) fn group(nodes: &mut [WideNode], tris: &[[Vec3; 3]], ids: &[u32]) -> Leaves {
    let mut out = Leaves::default();
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
