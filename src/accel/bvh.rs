//! Bounding volume hierarchies for meshes, instances of meshes, and boxes.
//!
//! - [`MeshBvh`]: a bottom-level tree (BLAS) over one triangle mesh, queried with the
//!   watertight test of [`super::triangle`];
//! - [`InstanceBvh`]: a top-level tree (TLAS) over instances `(mesh, object→world transform)`
//!   of [`MeshBvh`]es; instances of one mesh share its tree (a two-level BVH);
//! - [`AabbBvh`]: a tree over arbitrary boxes (the SDF objects' world bounds) with a
//!   nearest-first walk that the caller steers (shrink `tmax`, or stop).
//!
//! All three are built by obvhs 0.4 (PLOC + reinsertion + conversion to an 8-wide compressed
//! BVH) and traversed by our own code over the decoded nodes; `wide.rs` explains why (obvhs's
//! node test clamps the entry distance at 1e-4 and ignores the ray's tmin, among other things)
//! and how the traversal stays conservative in floating point.
//!
//! **Query contract** (all three): a ray is `origin + t·direction`; the direction need not be
//! unit length (t is in units of it) but must be finite and non-zero. Hits are reported for
//! `tmin <= t <= tmax` (closed); `tmin > tmax` or NaN bounds give no hit. Closest-hit queries
//! return the smallest t, ties broken by the smallest (instance, then) triangle index, so the
//! answer is a function of the geometry alone: identical for every [`BuildQuality`], equal to a
//! brute-force loop over the triangles with the same test, and independent of threads.
//!
//! **Rays that start on a surface.** With `tmin = 0` a ray whose origin lies on a triangle may
//! or may not report that triangle: its computed t is a rounding-level number (0 when the
//! origin is exactly a vertex, otherwise of either sign), and it is reported exactly when that
//! number is ≥ 0. The tree never loses it — unlike obvhs's own traversal, nothing clamps the
//! entry distance — so the answer is the same as the brute-force one. Secondary rays should
//! therefore use a `tmin` larger than the rounding error of the hit point (a small multiple of
//! `f32::EPSILON` times the scene's coordinates) or offset the origin along the normal.
//!
//! **Determinism.** obvhs's `parallel` feature (rayon in PLOC) is off, which this crate relies
//! on: every build is single-threaded and a function of its input.

mod huge_pages;
mod leaf;
mod wide;

use huge_pages::HugePageArray;

use std::ops::ControlFlow;
use std::time::{Duration, Instant};

use glam::{Affine3A, Vec3, Vec3A};
use obvhs::BvhBuildParams;
use obvhs::aabb::Aabb as OAabb;

use super::triangle::{self, TriHit, WatertightRay};
use crate::geom::{Aabb, Ray};
use arrayvec::ArrayVec;
use wide::{Frustum, NodeRay, NodeRays, PACKET, PacketLeaf};

// The trees' own layout, for the GPU's walker (`crate::gpu::scene` uploads these very nodes
// and leaf blocks, so both backends traverse one structure).
#[cfg(feature = "gpu")]
pub(crate) use leaf::Leaves;
pub(crate) use wide::WideNode;
#[cfg(feature = "gpu")]
pub(crate) use wide::{FIRST_MASK, LEAF_BIT, WIDEN, leaf_first};

pub use crate::scene::file::BuildQuality;

// The scene file names the preset; how it maps onto the builders is this module's business.
impl BuildQuality {
    /// The obvhs parameters of this preset: what obvhs builds the instance and box trees with
    /// at every preset, and the mesh trees at `High` and `Highest`.
    pub fn params(self) -> BvhBuildParams {
        match self {
            BuildQuality::Fast => BvhBuildParams::fast_build(),
            BuildQuality::Medium => BvhBuildParams::medium_build(),
            BuildQuality::High => BvhBuildParams::slow_build(),
            BuildQuality::Highest => BvhBuildParams::very_slow_build(),
        }
    }

    /// Whether a mesh's tree comes from the binned-SAH builder (`wide::build_binned`, `Fast`
    /// and `Medium`) rather than from obvhs with [`Self::params`] (`High`, `Highest`).
    pub fn binned(self) -> bool {
        matches!(self, BuildQuality::Fast | BuildQuality::Medium)
    }

    /// Whether a mesh's large triangles are split into several boxes before its tree is built
    /// (see `split_boxes`): at every preset but `Fast`.
    pub fn pre_split(self) -> bool {
        !matches!(self, BuildQuality::Fast)
    }
}

/// What a build kept, dropped and produced.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BuildStats {
    /// Number of primitives given (triangles, instances or boxes).
    pub input: usize,
    /// Primitives in the tree.
    pub kept: usize,
    /// Primitive references in the leaves: more than `kept` when spatial splits put one
    /// triangle into several leaves ([`BuildQuality::pre_split`]).
    pub references: usize,
    /// Triangles with a NaN or infinite coordinate, dropped.
    pub dropped_nonfinite: usize,
    /// Zero-area triangles (never hit, see [`triangle::is_degenerate`]) or empty boxes
    /// (min > max on some axis), dropped.
    pub dropped_degenerate: usize,
    /// Triangles with a vertex index outside the positions; instances of an unknown or empty
    /// mesh or with a singular or non-finite transform. Dropped.
    pub dropped_invalid: usize,
    /// Nodes of the tree (8-wide; as many as obvhs's CWBVH has).
    pub nodes: usize,
    /// Levels of nodes.
    pub max_depth: u32,
    /// Wall-clock time of the whole build call, filtering and decoding included.
    pub build_time: Duration,
}

fn to_oaabb(lo: Vec3, hi: Vec3) -> OAabb {
    OAabb::new(lo.into(), hi.into())
}

fn geom_bounds(b: (Vec3, Vec3)) -> Aabb {
    if b.0.cmple(b.1).all() {
        Aabb::new(b.0, b.1)
    } else {
        Aabb::EMPTY
    }
}

/// Spatial pre-splits as in `obvhs::cwbvh::builder::build_cwbvh_from_tris` (obvhs 0.4), with
/// one change: obvhs clips the triangle against the split plane in `f32`, so the clipped
/// corners are off by a few ulps and the split boxes may not quite cover their triangle. Each
/// split box is grown by 16·ε·(largest |coordinate| of its triangle) — several times the
/// clipping error — and clamped back to the triangle's own box. Returns the boxes and, per
/// box, the triangle it bounds.
///
/// The triangles are split in runs of [`SPLIT_RUN`] on the rayon pool: a box's splits depend
/// only on its own triangle and the mesh's area statistics, so the boxes are those of one pass
/// over all, in an order fixed by the runs (the same on any number of threads). Merged meshes
/// made this pass a fifth of a large build when it ran on one thread.
fn split_boxes(tris: &[[Vec3; 3]]) -> (Vec<OAabb>, Vec<u32>) {
    use rayon::prelude::*;
    let tri_box = |t: &[Vec3; 3]| (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]));
    // Per run: its boxes, the sum and the largest of their half areas (summed run by run in
    // order below, so the mean does not depend on the thread count).
    let runs: Vec<(Vec<OAabb>, f32, f32)> = tris
        .par_chunks(SPLIT_RUN)
        .map(|run| {
            let (mut sum, mut largest) = (0.0f32, 0.0f32);
            let boxes = run
                .iter()
                .map(|t| {
                    let (lo, hi) = tri_box(t);
                    let b = to_oaabb(lo, hi);
                    let half_area = b.half_area();
                    largest = largest.max(half_area);
                    sum += half_area;
                    b
                })
                .collect();
            (boxes, sum, largest)
        })
        .collect();
    let largest_half_area = runs.iter().fold(0.0f32, |m, r| m.max(r.2));
    let avg_area = runs.iter().map(|r| r.1).sum::<f32>() / tris.len() as f32;
    let otris: Vec<obvhs::triangle::Triangle> = tris
        .par_iter()
        .map(|t| obvhs::triangle::Triangle {
            v0: t[0].into(),
            v1: t[1].into(),
            v2: t[2].into(),
        })
        .collect();
    let split: Vec<(Vec<OAabb>, Vec<u32>)> = runs
        .into_par_iter()
        .enumerate()
        .map(|(k, (mut boxes, _, _))| {
            let first = (k * SPLIT_RUN) as u32;
            let mut owner: Vec<u32> = (first..first + boxes.len() as u32).collect();
            obvhs::splits::split_aabbs_preset(
                &mut boxes,
                &mut owner,
                &otris,
                avg_area,
                largest_half_area,
            );
            for (b, &o) in boxes.iter_mut().zip(&owner) {
                let t = &tris[o as usize];
                let (lo, hi) = tri_box(t);
                let m = t[0].abs().max(t[1].abs()).max(t[2].abs()).max_element();
                let pad = Vec3A::splat(16.0 * f32::EPSILON * m);
                b.min = (b.min - pad).max(lo.into());
                b.max = (b.max + pad).min(hi.into());
            }
            (boxes, owner)
        })
        .collect();
    let total = split.iter().map(|r| r.0.len()).sum();
    let (mut boxes, mut owner) = (Vec::with_capacity(total), Vec::with_capacity(total));
    for (b, o) in split {
        boxes.extend(b);
        owner.extend(o);
    }
    (boxes, owner)
}

/// Triangles per run of [`split_boxes`].
const SPLIT_RUN: usize = 8192;

/// Which triangle hits count, for surfaces with holes (glTF's alpha masks): a query asks
/// [`HitFilter::tests`] once per instance it reaches, and [`HitFilter::accept`] for each hit
/// on an instance that is tested. A rejected hit is as if the triangle were not there: the
/// closest-hit walk goes on to the next one, the any-hit walk keeps looking.
pub trait HitFilter: Sync {
    /// Whether hits on instance `instance` need [`HitFilter::accept`] (false: all count).
    fn tests(&self, instance: u32) -> bool;
    /// Whether the hit at barycentrics (u, v) of `triangle` of `instance` counts.
    fn accept(&self, instance: u32, triangle: u32, u: f32, v: f32) -> bool;
}

/// Every hit counts.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoFilter;

impl HitFilter for NoFilter {
    #[inline(always)]
    fn tests(&self, _: u32) -> bool {
        false
    }
    #[inline(always)]
    fn accept(&self, _: u32, _: u32, _: f32, _: f32) -> bool {
        true
    }
}

/// One instance's hit test in a mesh walk: `accept(triangle, u, v)`, or `None` when every hit
/// counts (the common case, which costs the leaves nothing).
type Accept<'a> = Option<&'a dyn Fn(u32, f32, f32) -> bool>;

/// A closest hit on a mesh.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshHit {
    /// Ray parameter of the hit.
    pub t: f32,
    /// Index of the triangle in the slice given to [`MeshBvh::build`].
    pub triangle: u32,
    /// Barycentric weight of the triangle's second vertex.
    pub u: f32,
    /// Barycentric weight of the triangle's third vertex (the point is
    /// `(1 − u − v)·p0 + u·p1 + v·p2`).
    pub v: f32,
}

/// A bottom-level BVH over one triangle mesh.
///
/// Built once from positions and index triples; it keeps its own copy of the triangles'
/// vertices, eight to a block per node (see `leaf.rs`: about 40 bytes per triangle reference),
/// and the map back to the original triangle indices, so the caller's buffers can be dropped. Triangles with non-finite
/// coordinates, out-of-range indices or zero area are left out and counted in
/// [`MeshBvh::stats`]; none of them could be hit.
#[derive(Debug, Clone)]
pub struct MeshBvh {
    /// Leaf children point at blocks of `leaves` (see [`leaf::group`]).
    nodes: HugePageArray<WideNode>,
    leaves: leaf::Leaves,
    bounds: Aabb,
    stats: BuildStats,
}

impl MeshBvh {
    /// Builds the tree over `triangles` (indices into `positions`). Never panics on bad
    /// geometry: an empty mesh gives an empty tree that nothing hits.
    pub fn build(positions: &[Vec3], triangles: &[[u32; 3]], quality: BuildQuality) -> MeshBvh {
        use rayon::prelude::*;
        let start = Instant::now();
        let mut stats = BuildStats {
            input: triangles.len(),
            ..Default::default()
        };
        let mut kept: Vec<[Vec3; 3]> = Vec::with_capacity(triangles.len());
        let mut kept_ids: Vec<u32> = Vec::with_capacity(triangles.len());
        for (i, idx) in triangles.iter().enumerate() {
            let v = idx.map(|k| positions.get(k as usize).copied());
            let [Some(a), Some(b), Some(c)] = v else {
                stats.dropped_invalid += 1;
                continue;
            };
            if !triangle::is_finite(a, b, c) {
                stats.dropped_nonfinite += 1;
            } else if triangle::is_degenerate(a, b, c) {
                stats.dropped_degenerate += 1;
            } else {
                kept.push([a, b, c]);
                kept_ids.push(i as u32);
            }
        }
        let (boxes, owner) = if quality.pre_split() && !kept.is_empty() {
            split_boxes(&kept)
        } else {
            let boxes = kept
                .iter()
                .map(|t| to_oaabb(t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2])))
                .collect();
            (boxes, (0..kept.len() as u32).collect())
        };
        let mut tree = if quality.binned() {
            wide::build_binned(&boxes)
        } else {
            wide::build(&boxes, &quality.params())
        };
        let tris: Vec<[Vec3; 3]> = tree
            .order
            .par_iter()
            .map(|&b| kept[owner[b as usize] as usize])
            .collect();
        let ids: Vec<u32> = tree
            .order
            .par_iter()
            .map(|&b| kept_ids[owner[b as usize] as usize])
            .collect();
        let leaves = leaf::group(&mut tree.nodes, &tris, &ids);
        stats.kept = kept.len();
        stats.references = tris.len();
        stats.nodes = tree.nodes.len();
        stats.max_depth = tree.max_depth;
        stats.build_time = start.elapsed();
        MeshBvh {
            nodes: HugePageArray::from_vec(tree.nodes),
            leaves,
            bounds: geom_bounds(tree.bounds),
            stats,
        }
    }

    /// The nearest hit with `tmin <= t <= tmax` (see the module's query contract); a negative
    /// `tmin` is taken as 0: nothing behind the origin is reported.
    pub fn closest_hit(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<MeshHit> {
        self.closest_in(
            &mut Shear::new(ray.origin, ray.direction),
            &NodeRay::new(ray.origin, ray.direction),
            tmin,
            tmax,
            None,
        )
    }

    /// Whether any triangle is hit with `max(tmin, 0) <= t <= tmax` (shadow rays); stops at the
    /// first.
    pub fn any_hit(&self, ray: &Ray, tmin: f32, tmax: f32) -> bool {
        self.any_in(
            &mut Shear::new(ray.origin, ray.direction),
            &NodeRay::new(ray.origin, ray.direction),
            tmin,
            tmax,
            None,
        )
    }

    fn closest_in(
        &self,
        shear: &mut Shear,
        nr: &NodeRay,
        tmin: f32,
        mut tmax: f32,
        accept: Accept<'_>,
    ) -> Option<MeshHit> {
        // The leaves use the walk's tmin.
        let tmin = wide::query_tmin(tmin);
        let mut best: Option<MeshHit> = None;
        wide::traverse_grouped::<true>(&self.nodes, nr, tmin, &mut tmax, |meta, slots, tmax| {
            self.closest_in_leaves(shear.get(), meta, slots, tmin, tmax, &mut best, accept);
            ControlFlow::Continue(())
        });
        best
    }

    /// [`Self::closest_in`] for a packet of rays that share one walk (see `wide::packet`):
    /// `best[i]` and `tmax[i]` are updated for ray i as `closest_in` would.
    fn closest_in_packet(
        &self,
        w: &mut PacketWalk<'_, '_>,
        tmin: f32,
        tmax: &mut [f32],
        best: &mut [Option<MeshHit>],
        accept: Accept<'_>,
    ) {
        self.walk_packet::<true>(w, tmin, tmax, |shears, what, tmin, tmax| match what {
            PacketLeaf::Ray { ray, meta, slots } => {
                let (wr, tmax) = (shears.get(ray), &mut tmax[ray]);
                self.closest_in_leaves(wr, meta, slots, tmin, tmax, &mut best[ray], accept);
            }
            PacketLeaf::Rays {
                rays,
                meta,
                by_slot,
            } => shears.together(rays, meta, &by_slot, |rays| {
                self.closest_together(&rays, tmin, tmax, best, accept);
            }),
            PacketLeaf::Packet { .. } => {}
        });
    }

    /// [`Self::any_in`] for a packet of rays that share one walk: `found[i]` is set for each
    /// ray i that hits something, and the ray is retired (`tmax[i]` = −∞).
    fn any_in_packet(
        &self,
        w: &mut PacketWalk<'_, '_>,
        tmin: f32,
        tmax: &mut [f32],
        found: &mut [bool],
        accept: Accept<'_>,
    ) {
        self.walk_packet::<false>(w, tmin, tmax, |shears, what, tmin, tmax| match what {
            PacketLeaf::Ray { ray, meta, slots } => {
                if self.any_in_leaves(shears.get(ray), meta, slots, tmin, tmax[ray], accept) {
                    found[ray] = true;
                    tmax[ray] = f32::NEG_INFINITY;
                }
            }
            PacketLeaf::Rays {
                rays,
                meta,
                by_slot,
            } => shears.together(rays, meta, &by_slot, |rays| {
                self.any_together(&rays, tmin, tmax, found, accept);
            }),
            PacketLeaf::Packet { .. } => {}
        });
    }

    /// The packet walk of this mesh's tree, nearest first when `ORDERED`: `leaf(shears, what,
    /// tmin, tmax)` for each [`PacketLeaf::Ray`] and [`PacketLeaf::Rays`] the walk hands over,
    /// with the rays' shears and their `tmax`.
    #[inline(always)]
    fn walk_packet<const ORDERED: bool>(
        &self,
        w: &mut PacketWalk<'_, '_>,
        tmin: f32,
        tmax: &mut [f32],
        mut leaf: impl FnMut(&mut PacketShears<'_>, PacketLeaf, f32, &mut [f32]),
    ) {
        let tmin = wide::query_tmin(tmin);
        let shears = &mut *w.shears;
        let visit = |what, tmax: &mut [f32]| {
            leaf(shears, what, tmin, tmax);
            ControlFlow::Continue(())
        };
        match w.frustum {
            Some(frustum) => wide::traverse_packet::<false, ORDERED, true>(
                &self.nodes,
                w.rays,
                w.active,
                frustum,
                tmin,
                tmax,
                0.0,
                visit,
            ),
            None => wide::traverse_lanes::<false, ORDERED, true>(
                &self.nodes,
                w.rays.get(),
                w.active,
                tmin,
                tmax,
                0.0,
                visit,
            ),
        }
    }

    /// The any-hit leaf test: whether one ray hits a triangle of the leaf slots `slots` of a
    /// node (`meta` as the walk hands it over) within `[tmin, tmax]`.
    #[inline(always)]
    fn any_in_leaves(
        &self,
        wr: &WatertightRay,
        meta: u32,
        slots: u32,
        tmin: f32,
        tmax: f32,
        accept: Accept<'_>,
    ) -> bool {
        // A loop, not `Iterator::any`: called from two places, `any`'s fold was no longer
        // inlined (6 % of the bunny's shadow rays).
        for k in self.leaves.blocks_for(meta, slots) {
            let hits = leaf::block_hits(&self.leaves.blocks[k], wr, slots, tmin, tmax);
            let Some(accept) = accept else {
                if hits.mask != 0 {
                    return true;
                }
                continue;
            };
            let mut mask = hits.mask;
            while mask != 0 {
                let lane = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                let h = hits.hit(lane);
                if accept(self.leaves.ids[k][lane], h.u, h.v) {
                    return true;
                }
            }
        }
        false
    }

    /// The closest-hit leaf test: the triangles of the leaf slots `slots` of a node (`meta` as
    /// the walk hands it over) against one ray, keeping the nearest in `best` and `tmax`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn closest_in_leaves(
        &self,
        wr: &WatertightRay,
        meta: u32,
        slots: u32,
        tmin: f32,
        tmax: &mut f32,
        best: &mut Option<MeshHit>,
        accept: Accept<'_>,
    ) {
        for k in self.leaves.blocks_for(meta, slots) {
            // The ids are read only for a hit, after the test: asked for now, they arrive
            // while the block is tested (a miss on them was 7 % of an incoherent walk).
            leaf::prefetch(&self.leaves.ids[k]);
            let hits = leaf::block_hits(&self.leaves.blocks[k], wr, slots, tmin, *tmax);
            let mut mask = hits.mask;
            while mask != 0 {
                let lane = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                keep_nearest(best, tmax, hits.hit(lane), self.leaves.ids[k][lane], accept);
            }
        }
    }

    /// [`Self::closest_in_leaves`] for rays handed over together ([`Self::leaves_together`]):
    /// `best[i]` and `tmax[i]` are updated for each ray i as `closest_in_leaves` would.
    #[inline(always)]
    fn closest_together(
        &self,
        g: &Together<'_, '_>,
        tmin: f32,
        tmax: &mut [f32],
        best: &mut [Option<MeshHit>],
        accept: Accept<'_>,
    ) {
        self.leaves_together(g, tmin, tmax, |ray, hit, id, tmax| {
            keep_nearest(&mut best[ray], &mut tmax[ray], hit, id, accept);
        });
    }

    /// [`Self::any_in_leaves`] for rays handed over together ([`Self::leaves_together`]):
    /// `found[i]` is set for each ray i that hits something, and the ray is retired
    /// (`tmax[i]` = −∞).
    #[inline(always)]
    fn any_together(
        &self,
        g: &Together<'_, '_>,
        tmin: f32,
        tmax: &mut [f32],
        found: &mut [bool],
        accept: Accept<'_>,
    ) {
        self.leaves_together(g, tmin, tmax, |ray, hit, id, tmax| {
            if accept.is_none_or(|accept| accept(id, hit.u, hit.v)) {
                found[ray] = true;
                tmax[ray] = f32::NEG_INFINITY;
            }
        });
    }

    /// The leaf tests of rays handed over together: the blocks of their leaf slots in order,
    /// each block tested by each ray whose own leaf slots it holds — eight triangles against
    /// one ray at a time ([`leaf::block_hits`]), or, where at least [`wide::RAYS_TOGETHER`] rays
    /// that share shear axes meet the block, each triangle against sixteen rays at once
    /// ([`leaf::block_together`]). Either way each ray meets the triangles its own walk hands
    /// it, in the same order, so its answer is its own, bit for bit. `hit(ray, hit, id,
    /// tmax)` for each hit of a ray, which may lower `tmax[ray]`; a ray whose `tmax` falls to
    /// −∞ is tested no further.
    #[inline(always)]
    fn leaves_together(
        &self,
        g: &Together<'_, '_>,
        tmin: f32,
        tmax: &mut [f32],
        mut hit: impl FnMut(usize, TriHit, u32, &mut [f32]),
    ) {
        let mut slots = 0;
        for (slot, &rays) in g.by_slot.iter().enumerate() {
            slots |= u32::from(rays & g.rays != 0) << slot;
        }
        // Sixteen rays to a register: the first sixteen, then the rest (at most sixteen more).
        let mut low = g.rays;
        for _ in 16..low.count_ones() {
            low &= !(1 << (31 - low.leading_zeros()));
        }
        let chunks = [low, g.rays & !low];
        // Each chunk's lanes, gathered where a block is first tested together.
        let mut gathered = [const { std::mem::MaybeUninit::<leaf::RayLanes>::uninit() }; 2];
        let mut made = [false; 2];
        let mut left = g.rays;
        for k in self.leaves.blocks_for(g.meta, slots) {
            let block_slots = u32::from(self.leaves.slots[k]) & slots;
            let mut meeting = 0;
            let mut bs = block_slots;
            while bs != 0 {
                meeting |= g.by_slot[bs.trailing_zeros() as usize];
                bs &= bs - 1;
            }
            meeting &= left;
            if meeting == 0 {
                continue;
            }
            // The ids are read only for a hit, after the test: asked for now, they arrive
            // while the block is tested.
            leaf::prefetch(&self.leaves.ids[k]);
            let block = &self.leaves.blocks[k];
            let ids = &self.leaves.ids[k];
            for (c, &chunk) in chunks.iter().enumerate() {
                let here = meeting & chunk;
                if here == 0 {
                    continue;
                }
                if let Some(axes) = g.axes
                    && here.count_ones() >= wide::RAYS_TOGETHER
                {
                    let lanes = if made[c] {
                        // SAFETY: written when `made[c]` was set.
                        unsafe { gathered[c].assume_init_mut() }
                    } else {
                        made[c] = true;
                        let lanes = gathered[c].write(leaf::RayLanes::EMPTY);
                        lanes.gather(g.shears.lanes(), tmax, chunk, g.by_slot)
                    };
                    let made = |ray| g.shears.made(ray);
                    let live = leaf::block_together(
                        block,
                        block_slots,
                        here,
                        axes,
                        lanes,
                        tmin,
                        made,
                        |ray, lane, h| {
                            hit(ray, h, ids[lane], tmax);
                            tmax[ray]
                        },
                    );
                    left &= !here | live;
                    continue;
                }
                let mut m = here;
                while m != 0 {
                    let ray = m.trailing_zeros() as usize;
                    m &= m - 1;
                    let ray_slots = wide::slots_of(g.by_slot, ray) & block_slots;
                    let wr = g.shears.made(ray);
                    let hits = leaf::block_hits(block, wr, ray_slots, tmin, tmax[ray]);
                    let mut lanes_hit = hits.mask;
                    while lanes_hit != 0 && tmax[ray] != f32::NEG_INFINITY {
                        let lane = lanes_hit.trailing_zeros() as usize;
                        lanes_hit &= lanes_hit - 1;
                        hit(ray, hits.hit(lane), self.leaves.ids[k][lane], tmax);
                    }
                    if tmax[ray] == f32::NEG_INFINITY {
                        left &= !(1 << ray);
                    }
                    if made[c] {
                        // The ray's lane keeps its `tmax` for the blocks tested together.
                        // SAFETY: written when `made[c]` was set.
                        let lanes = unsafe { gathered[c].assume_init_mut() };
                        lanes.set_far(lanes.lane_of(ray), tmax[ray]);
                    }
                }
            }
            if left == 0 {
                return;
            }
        }
    }

    fn any_in(
        &self,
        shear: &mut Shear,
        nr: &NodeRay,
        tmin: f32,
        mut tmax: f32,
        accept: Accept<'_>,
    ) -> bool {
        let tmin = wide::query_tmin(tmin);
        let mut found = false;
        wide::traverse_grouped::<false>(&self.nodes, nr, tmin, &mut tmax, |meta, slots, tmax| {
            found = self.any_in_leaves(shear.get(), meta, slots, tmin, *tmax, accept);
            if found {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            }
        });
        found
    }

    /// Bytes of the tree as the walk reads them: nodes and leaf blocks with their ids.
    fn walked_bytes(&self) -> usize {
        self.nodes.len() * size_of::<WideNode>()
            + self.leaves.blocks.len() * size_of::<leaf::TriBlock>()
            + self.leaves.ids.len() * size_of::<[u32; 8]>()
            + self.leaves.slots.len()
    }

    /// Whether the tree is large enough for its single rays to be walked two at a time
    /// ([`INTERLEAVE_BYTES`]; see [`InstanceBvh::walks_pairs`]).
    pub(crate) fn interleaves(&self) -> bool {
        self.walked_bytes() >= INTERLEAVE_BYTES
    }

    /// [`Self::closest_in`] of two rays, their walks interleaved: the same answers.
    fn closest_in_pair(
        &self,
        mut shears: [&mut Shear; 2],
        nrs: [&NodeRay; 2],
        tmin: f32,
        mut tmax: [f32; 2],
        accept: Accept<'_>,
    ) -> [Option<MeshHit>; 2] {
        let tmin = wide::query_tmin(tmin);
        let mut best = [None; 2];
        wide::traverse_grouped_pair::<true>(
            &self.nodes,
            nrs,
            tmin,
            &mut tmax,
            |k, meta, slots, tmax| {
                self.closest_in_leaves(
                    shears[k].get(),
                    meta,
                    slots,
                    tmin,
                    tmax,
                    &mut best[k],
                    accept,
                );
                ControlFlow::Continue(())
            },
        );
        best
    }

    /// [`Self::any_in`] of two rays, their walks interleaved: the same answers.
    fn any_in_pair(
        &self,
        mut shears: [&mut Shear; 2],
        nrs: [&NodeRay; 2],
        tmin: f32,
        mut tmax: [f32; 2],
        accept: Accept<'_>,
    ) -> [bool; 2] {
        let tmin = wide::query_tmin(tmin);
        let mut found = [false; 2];
        wide::traverse_grouped_pair::<false>(
            &self.nodes,
            nrs,
            tmin,
            &mut tmax,
            |k, meta, slots, tmax| {
                found[k] = self.any_in_leaves(shears[k].get(), meta, slots, tmin, *tmax, accept);
                if found[k] {
                    ControlFlow::Break(())
                } else {
                    ControlFlow::Continue(())
                }
            },
        );
        found
    }

    /// The nodes as the walk reads them (root at 0; none for an empty mesh); leaf children
    /// point at blocks of [`MeshBvh::leaf_blocks`].
    #[cfg(feature = "gpu")]
    pub(crate) fn wide_nodes(&self) -> &[WideNode] {
        &self.nodes
    }

    /// The triangles in the leaves' blocks, with the mesh's index of each.
    #[cfg(feature = "gpu")]
    pub(crate) fn leaf_blocks(&self) -> &Leaves {
        &self.leaves
    }

    /// Number of nodes (8-wide) in the tree; 0 for an empty mesh.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Exact bounds of the triangles in the tree ([`Aabb::EMPTY`] when there are none).
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// Whether the tree holds no triangle.
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// Triangles dropped because a coordinate is NaN or infinite.
    pub fn dropped_nonfinite(&self) -> usize {
        self.stats.dropped_nonfinite
    }

    /// Counts and timing of the build.
    pub fn stats(&self) -> &BuildStats {
        &self.stats
    }
}

/// One placement of a mesh: `transform` maps the mesh's object space to world space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Instance {
    /// Index of the mesh in the `&[MeshBvh]` given to [`InstanceBvh::build`] and the queries.
    pub mesh: usize,
    /// Object → world.
    pub transform: Affine3A,
}

impl From<(usize, Affine3A)> for Instance {
    fn from((mesh, transform): (usize, Affine3A)) -> Self {
        Instance { mesh, transform }
    }
}

/// A closest hit on an instanced scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InstanceHit {
    /// Ray parameter of the hit, in the world ray's units (the object-space ray is not
    /// renormalised, so this is the same t).
    pub t: f32,
    /// Index of the instance in the slice given to [`InstanceBvh::build`].
    pub instance: u32,
    /// Index of the triangle in its mesh.
    pub triangle: u32,
    /// Barycentric weight of the triangle's second vertex.
    pub u: f32,
    /// Barycentric weight of the triangle's third vertex.
    pub v: f32,
}

#[derive(Debug, Clone, Copy)]
struct PlacedInstance {
    index: u32,
    mesh: u32,
    world_to_object: Affine3A,
    /// The transform is exactly the identity: the world ray is the object ray.
    identity: bool,
}

/// A ray's watertight shear ([`WatertightRay`]), computed when a leaf first needs it: a mesh
/// walk that reaches no leaf — most instance visits of a ray that only crosses an instance's
/// box — never pays for its divisions.
struct Shear {
    origin: Vec3,
    direction: Vec3,
    ray: Option<WatertightRay>,
}

impl Shear {
    #[inline(always)]
    fn new(origin: Vec3, direction: Vec3) -> Self {
        Shear {
            origin,
            direction,
            ray: None,
        }
    }

    #[inline(always)]
    fn get(&mut self) -> &WatertightRay {
        let (o, d) = (self.origin, self.direction);
        self.ray.get_or_insert_with(|| WatertightRay::new(o, d))
    }
}

/// The watertight shears of a packet's rays, each computed when a leaf first needs it (as
/// [`Shear`] does for one ray), and as lanes once rays are handed over together.
struct PacketShears<'a> {
    rays: &'a [Ray],
    shears: [std::mem::MaybeUninit<WatertightRay>; PACKET],
    /// Bit i set when `shears[i]` has been computed.
    ready: u32,
    /// The ready rays by their shear axes: bit i of `by_axes[key]` for ray i of key
    /// [`axes_key`].
    by_axes: [u32; 6],
    /// The ready shears as lanes, written when `lanes_made` (the first time rays are handed
    /// over together; many walks never are).
    lanes: std::mem::MaybeUninit<leaf::ShearLanes>,
    lanes_made: bool,
}

/// Which of the six frames a shear uses: `2·kz`, plus 1 where `kx` and `ky` are swapped.
#[inline(always)]
fn axes_key(wr: &WatertightRay) -> usize {
    2 * wr.kz + usize::from(wr.kx != (wr.kz + 1) % 3)
}

impl<'a> PacketShears<'a> {
    #[inline(always)]
    fn new(rays: &'a [Ray]) -> Self {
        PacketShears {
            rays,
            shears: [const { std::mem::MaybeUninit::uninit() }; PACKET],
            ready: 0,
            by_axes: [0; 6],
            lanes: std::mem::MaybeUninit::uninit(),
            lanes_made: false,
        }
    }

    #[inline(always)]
    fn get(&mut self, i: usize) -> &WatertightRay {
        if self.ready & (1 << i) == 0 {
            self.make(i);
        }
        // SAFETY: bit i of `ready` is set only once `shears[i]` has been written.
        unsafe { self.shears[i].assume_init_ref() }
    }

    /// Computes ray i's shear (not ready yet).
    #[inline(always)]
    fn make(&mut self, i: usize) {
        let r = &self.rays[i];
        let wr = self.shears[i].write(WatertightRay::new(r.origin, r.direction));
        self.ready |= 1 << i;
        self.by_axes[axes_key(wr)] |= 1 << i;
        if self.lanes_made {
            // SAFETY: written when `lanes_made` was set.
            unsafe { self.lanes.assume_init_mut() }.set(i, wr);
        }
    }

    /// Makes the shears of the rays of `rays`, and the lanes of all shears made.
    #[inline(always)]
    fn make_with_lanes(&mut self, rays: u32) {
        if !self.lanes_made {
            let lanes = self.lanes.write(leaf::ShearLanes::EMPTY);
            let mut m = self.ready;
            while m != 0 {
                let i = m.trailing_zeros() as usize;
                m &= m - 1;
                // SAFETY: bit i of `ready` is set only once `shears[i]` has been written.
                lanes.set(i, unsafe { self.shears[i].assume_init_ref() });
            }
            self.lanes_made = true;
        }
        let mut m = rays & !self.ready;
        while m != 0 {
            let i = m.trailing_zeros() as usize;
            m &= m - 1;
            self.make(i);
        }
    }

    /// Hands the rays of a [`PacketLeaf::Rays`] to `f` in groups that share shear axes (the
    /// leaf test of one triangle against sixteen rays takes the triangle's coordinates along
    /// one frame), their shears made; a group of fewer than [`wide::RAYS_TOGETHER`] rays goes
    /// without `axes`, to be tested ray by ray.
    #[inline(always)]
    fn together<'s>(
        &'s mut self,
        rays: u32,
        meta: u32,
        by_slot: &'s [u32; 8],
        mut f: impl FnMut(Together<'s, 'a>),
    ) {
        self.make_with_lanes(rays);
        let shears = &*self;
        let mut left = rays;
        while left != 0 {
            let wr = shears.made(left.trailing_zeros() as usize);
            let group = left & shears.by_axes[axes_key(wr)];
            left &= !group;
            let many = group.count_ones() >= wide::RAYS_TOGETHER && leaf::together_runs();
            let axes = many.then_some([wr.kx, wr.ky, wr.kz]);
            f(Together {
                shears,
                rays: group,
                axes,
                meta,
                by_slot,
            });
        }
    }

    /// The lanes of the shears made (after [`Self::make_with_lanes`]).
    #[inline(always)]
    fn lanes(&self) -> &leaf::ShearLanes {
        assert!(self.lanes_made, "the shears' lanes are not made");
        // SAFETY: written when `lanes_made` was set.
        unsafe { self.lanes.assume_init_ref() }
    }

    /// Ray i's shear, made before.
    #[inline(always)]
    fn made(&self, i: usize) -> &WatertightRay {
        assert!(self.ready & (1 << i) != 0, "ray {i}'s shear is not made");
        // SAFETY: bit i of `ready` is set only once `shears[i]` has been written.
        unsafe { self.shears[i].assume_init_ref() }
    }
}

/// Rays of a [`PacketLeaf::Rays`] that share shear axes, with their shears made.
struct Together<'s, 'a> {
    shears: &'s PacketShears<'a>,
    rays: u32,
    /// `[kx, ky, kz]` of the rays, or `None` for too few rays to test together.
    axes: Option<[usize; 3]>,
    meta: u32,
    by_slot: &'s [u32; 8],
}

const _: () = assert!(PACKET <= 32, "PacketShears::ready is a u32");

/// Keeps the hit `h` of triangle `id` in `best` (and its distance in `tmax`) if it is nearer,
/// or as near with a smaller triangle index (which makes the answer independent of the
/// traversal order), and `accept` takes it.
#[inline(always)]
fn keep_nearest(
    best: &mut Option<MeshHit>,
    tmax: &mut f32,
    h: TriHit,
    id: u32,
    accept: Accept<'_>,
) {
    let better = match best {
        None => true,
        Some(b) => h.t < b.t || (h.t == b.t && id < b.triangle),
    } && accept.is_none_or(|accept| accept(id, h.u, h.v));
    if better {
        *best = Some(MeshHit {
            t: h.t,
            triangle: id,
            u: h.u,
            v: h.v,
        });
        *tmax = h.t;
    }
}

/// Whether a hit `(t, instance, triangle)` beats `best`: nearer, or as near with a smaller
/// instance and then triangle index (the order-independent tie rule of the module contract).
#[inline(always)]
fn beats(best: &Option<InstanceHit>, t: f32, instance: u32, triangle: u32) -> bool {
    match best {
        None => true,
        Some(b) => {
            t < b.t
                || (t == b.t
                    && (instance < b.instance || (instance == b.instance && triangle < b.triangle)))
        }
    }
}

/// The rays of a packet as a mesh walk takes them: node rays (made when the walk first needs
/// them), the mask of those to trace, their bounds (a frustum walk) or none (a lane walk,
/// `wide::traverse_lanes`: the rays then pass `wide::lanes_take`), and their lazily computed
/// shears.
struct PacketWalk<'s, 'r> {
    shears: &'s mut PacketShears<'r>,
    rays: &'s NodeRays<'r>,
    active: u32,
    frustum: Option<&'s Frustum>,
}

/// A query that [`InstanceBvh::packet`] traces: what one mesh walk answers per ray.
trait PacketQuery {
    /// One ray's answer on one mesh.
    type Answer: Copy;
    /// The answer before anything is found.
    const NONE: Self::Answer;
    /// Whether the walks go nearest first (closest hit) or in any order (any hit).
    const ORDERED: bool;
    /// The packet walk of `mesh`, writing `answers[i]` for the active rays.
    fn walk(
        mesh: &MeshBvh,
        w: &mut PacketWalk<'_, '_>,
        tmin: f32,
        tmax: &mut [f32],
        answers: &mut [Self::Answer],
        accept: Accept<'_>,
    );
    /// The single-ray walk of `mesh` (object-space rays that cannot share one).
    fn walk_one(
        mesh: &MeshBvh,
        ray: &Ray,
        tmin: f32,
        tmax: f32,
        accept: Accept<'_>,
    ) -> Self::Answer;
}

/// Closest hit: the nearest triangle per mesh.
struct Closest;

impl PacketQuery for Closest {
    type Answer = Option<MeshHit>;
    const NONE: Option<MeshHit> = None;
    const ORDERED: bool = true;
    #[inline(always)]
    fn walk(
        mesh: &MeshBvh,
        w: &mut PacketWalk<'_, '_>,
        tmin: f32,
        tmax: &mut [f32],
        answers: &mut [Option<MeshHit>],
        accept: Accept<'_>,
    ) {
        mesh.closest_in_packet(w, tmin, tmax, answers, accept)
    }
    #[inline(always)]
    fn walk_one(
        mesh: &MeshBvh,
        r: &Ray,
        tmin: f32,
        tmax: f32,
        accept: Accept<'_>,
    ) -> Option<MeshHit> {
        let nr = NodeRay::new(r.origin, r.direction);
        mesh.closest_in(
            &mut Shear::new(r.origin, r.direction),
            &nr,
            tmin,
            tmax,
            accept,
        )
    }
}

/// Any hit: whether the ray is blocked.
struct Any;

impl PacketQuery for Any {
    type Answer = bool;
    const NONE: bool = false;
    const ORDERED: bool = false;
    #[inline(always)]
    fn walk(
        mesh: &MeshBvh,
        w: &mut PacketWalk<'_, '_>,
        tmin: f32,
        tmax: &mut [f32],
        answers: &mut [bool],
        accept: Accept<'_>,
    ) {
        mesh.any_in_packet(w, tmin, tmax, answers, accept)
    }
    #[inline(always)]
    fn walk_one(mesh: &MeshBvh, r: &Ray, tmin: f32, tmax: f32, accept: Accept<'_>) -> bool {
        let nr = NodeRay::new(r.origin, r.direction);
        mesh.any_in(
            &mut Shear::new(r.origin, r.direction),
            &nr,
            tmin,
            tmax,
            accept,
        )
    }
}

/// The index of the lowest set bit of `mask`, cleared.
#[inline(always)]
fn take_lowest(mask: &mut u32) -> usize {
    let i = mask.trailing_zeros() as usize;
    *mask &= *mask - 1;
    i
}

/// The largest spread of a lane walk's ray origins, as a fraction of the scene's extent (see
/// [`InstanceBvh::near_origins`]). Measured on the bench's AO rays, a tenth and a quarter
/// gave the same speed; incoherent rays (origins across the whole scene) are far above both.
const LANE_REACH: f32 = 0.25;

/// Trees of at least this many bytes (nodes and leaf blocks) are walked two rays at a time by
/// the batch queries' single rays ([`wide::traverse_grouped_pair`]): past the caches the two
/// walks overlap their waits on memory, within them the switching only costs. Measured one
/// thread, the bench's ray sets, both ways in one process in turns (incoherent rays, pairs
/// over one by one): Suzanne and the cow (under 1 MB) 2–3 % slower, the bunny (4 MB) 2 %
/// faster, the saw's merged tree (10 MB, beside its other instances) within ±4 %, the bunny
/// subdivided to 278 thousand triangles (18 MB) 5–26 % faster, to 1.1 million (70 MB) 8–14 %
/// (in two sittings of three), MetalRoughSpheres (68 MB) 15–16 % (its AO rays 5–15 %); other
/// ray kinds within the noise.
/// AMD EPYC (Zen 4): 1 MB of L2 cache per core, 32 MB of L3 (BENCHMARKS.md, "Two walks at
/// once").
pub(crate) const INTERLEAVE_BYTES: usize = 16 << 20;

/// A top-level BVH over instances of [`MeshBvh`]es (a two-level BVH: instances of one mesh
/// share its tree).
///
/// A query walks this tree in world space; at an instance it maps the ray into object space
/// with the stored inverse transform — origin as a point, direction as a vector, *not*
/// renormalised, so t stays the world ray's parameter — recomputes the watertight shear for
/// that ray (it depends on the direction) and walks the mesh's tree with the current `tmax`.
#[derive(Debug, Clone)]
pub struct InstanceBvh {
    nodes: HugePageArray<WideNode>,
    placed: Vec<PlacedInstance>,
    bounds: Aabb,
    /// Per-ray node margin = this × max |origin component| (see `build`).
    origin_margin: f32,
    mesh_count: usize,
    /// The merged mesh's instance index (the number of scene instances), or `u32::MAX`.
    merged_index: u32,
    /// The slot in `placed` of the scene's main tree: its only instance, or else its merged
    /// meshes (see [`Self::interleaved`]).
    main: Option<usize>,
    /// Per triangle of the merged mesh, its scene instance and triangle.
    origin: Vec<(u32, u32)>,
    stats: BuildStats,
}

/// Whether an instance can be placed with the object → world map `m`: finite, invertible,
/// with a finite inverse (the instance tree leaves the others out, and nothing merges them).
pub(crate) fn placeable(m: &Affine3A) -> bool {
    let finite = |a: &Affine3A| {
        a.matrix3.x_axis.is_finite()
            && a.matrix3.y_axis.is_finite()
            && a.matrix3.z_axis.is_finite()
            && a.translation.is_finite()
    };
    m.matrix3.determinant() != 0.0 && finite(m) && finite(&m.inverse())
}

/// Instances merged into one mesh for [`InstanceBvh::build_merged`]: the index of that mesh
/// (its triangles baked into world space) and, per triangle of it, the scene instance and
/// triangle it stands for, in increasing order (so that the walk's tie rule, smaller instance
/// then smaller triangle, is the merged mesh's own rule of the smaller triangle).
#[derive(Debug, Clone, Default)]
pub struct Merged {
    /// Index of the merged mesh in the `&[MeshBvh]` given to the build and the queries.
    pub mesh: usize,
    /// Per merged triangle: (scene instance, triangle of its mesh).
    pub origin: Vec<(u32, u32)>,
}

impl InstanceBvh {
    /// Builds over `instances` of `meshes`. Instances of a mesh index out of range, of an
    /// empty mesh, or with a singular or non-finite transform are left out (counted in
    /// [`BuildStats::dropped_invalid`]).
    pub fn build(meshes: &[MeshBvh], instances: &[Instance], quality: BuildQuality) -> Self {
        Self::build_merged(meshes, instances, None, quality)
    }

    /// [`Self::build`] with some instances merged into one mesh of world-space triangles
    /// (see [`Merged`]): those instances are left out of the tree, the merged mesh goes in
    /// untransformed, and a hit on its triangle `k` is reported as the hit on triangle
    /// `merged.origin[k].1` of instance `merged.origin[k].0`, as if the instance had been
    /// walked itself. Filters are not asked about merged triangles: the caller merges no
    /// instance a filter tests.
    pub fn build_merged(
        meshes: &[MeshBvh],
        instances: &[Instance],
        merged: Option<Merged>,
        quality: BuildQuality,
    ) -> Self {
        let start = Instant::now();
        let mut stats = BuildStats {
            input: instances.len(),
            ..Default::default()
        };
        let mut left_out = vec![false; instances.len()];
        let mut origin = Vec::new();
        let mut all: Vec<(usize, Instance)> = Vec::with_capacity(instances.len() + 1);
        let merged_index = match merged {
            Some(m) => {
                for &(i, _) in &m.origin {
                    if let Some(l) = left_out.get_mut(i as usize) {
                        *l = true;
                    }
                }
                origin = m.origin;
                // After every scene instance: the merged mesh's own slot.
                all.push((
                    instances.len(),
                    Instance {
                        mesh: m.mesh,
                        transform: Affine3A::IDENTITY,
                    },
                ));
                instances.len() as u32
            }
            None => u32::MAX,
        };
        all.extend(
            instances
                .iter()
                .copied()
                .enumerate()
                .filter(|&(i, _)| !left_out[i]),
        );
        let mut placed = Vec::with_capacity(all.len());
        let mut boxes = Vec::with_capacity(all.len());
        let mut max_cond = 1.0f32;
        for &(i, inst) in &all {
            let Some(mesh) = meshes.get(inst.mesh).filter(|m| !m.is_empty()) else {
                // (a merged mesh of nothing is nobody's instance)
                stats.dropped_invalid += usize::from(i < instances.len());
                continue;
            };
            let m = inst.transform;
            if !placeable(&m) {
                stats.dropped_invalid += 1;
                continue;
            }
            let inv = m.inverse();
            // World box: the transformed corners of the exact object box, grown so that the
            // world-space cull never rejects what the object-space test would hit. The ray
            // is mapped with rounding, so the object-space ray is the exact preimage only up
            // to about γ·cond(M)·(|p| + |origin|) at a point p; cond(M) is bounded by the
            // product of the Frobenius norms. The |p| part is padded here, the |origin| part
            // per ray (`origin_margin`).
            let frob = |a: &Affine3A| {
                (a.matrix3.x_axis.length_squared()
                    + a.matrix3.y_axis.length_squared()
                    + a.matrix3.z_axis.length_squared())
                .sqrt()
            };
            let cond = frob(&m) * frob(&inv);
            max_cond = max_cond.max(cond);
            let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
            for c in mesh.bounds().corners() {
                let w = m.transform_point3(c);
                lo = lo.min(w);
                hi = hi.max(w);
            }
            let scale = lo.abs().max(hi.abs()).max_element();
            let pad = Vec3::splat(64.0 * f32::EPSILON * cond * scale);
            boxes.push(to_oaabb(lo - pad, hi + pad));
            placed.push(PlacedInstance {
                index: i as u32,
                mesh: inst.mesh as u32,
                world_to_object: inv,
                identity: inv == Affine3A::IDENTITY,
            });
        }
        // The per-ray margin covers the rounding of mapping the ray into object space; where
        // no instance maps it (all untransformed: the world ray is walked as it is), there is
        // none, and the walk takes the cheaper node test without margins.
        let origin_margin = if placed.iter().all(|p| p.identity) {
            0.0
        } else {
            64.0 * f32::EPSILON * max_cond
        };
        let mut tree = wide::build(&boxes, &quality.params());
        wide::one_primitive_per_leaf(&mut tree, &boxes);
        let placed: Vec<PlacedInstance> = tree.order.iter().map(|&k| placed[k as usize]).collect();
        let merged_in = placed.iter().any(|p| p.index == merged_index);
        let main = match placed.as_slice() {
            [_] => Some(0),
            all => all.iter().position(|p| p.index == merged_index),
        };
        let merged_count = left_out.iter().filter(|&&l| l).count();
        // Scene instances traced: those in the tree and those merged into its merged mesh.
        stats.kept =
            placed.len() - usize::from(merged_in) + if merged_in { merged_count } else { 0 };
        stats.references = placed.len();
        stats.nodes = tree.nodes.len();
        stats.max_depth = tree.max_depth;
        stats.build_time = start.elapsed();
        InstanceBvh {
            nodes: HugePageArray::from_vec(tree.nodes),
            placed,
            bounds: geom_bounds(tree.bounds),
            origin_margin,
            mesh_count: meshes.len(),
            merged_index,
            main,
            origin,
            stats,
        }
    }

    /// The scene's (instance, triangle) of triangle `triangle` of the placed instance `p`:
    /// its own unless `p` is the merged mesh.
    #[inline(always)]
    fn scene_ids(&self, p: &PlacedInstance, triangle: u32) -> (u32, u32) {
        if p.index == self.merged_index {
            self.origin[triangle as usize]
        } else {
            (p.index, triangle)
        }
    }

    /// Whether `filter` tests the hits of the placed instance `p` (never the merged mesh's).
    #[inline(always)]
    fn filtered(&self, p: &PlacedInstance, filter: &impl HitFilter) -> bool {
        p.index != self.merged_index && filter.tests(p.index)
    }

    /// Walks the instances the world ray may meet; `f(instance, object-space ray, tmax)`.
    fn walk<const ORDERED: bool>(
        &self,
        meshes: &[MeshBvh],
        ray: &Ray,
        tmin: f32,
        mut tmax: f32,
        mut f: impl FnMut(&PlacedInstance, &MeshBvh, &mut Shear, &NodeRay, &mut f32) -> ControlFlow<()>,
    ) {
        debug_assert_eq!(
            meshes.len(),
            self.mesh_count,
            "query with the meshes the instances were built on"
        );
        let nr = NodeRay::new(ray.origin, ray.direction);
        let margin = self.origin_margin * ray.origin.abs().max_element();
        // The world ray's shear, computed the first time a leaf of an untransformed instance
        // needs it, and then shared by all of them.
        let mut world = Shear::new(ray.origin, ray.direction);
        let mut visit = |first: u32, count: u32, tmax: &mut f32| {
            for p in &self.placed[first as usize..(first + count) as usize] {
                let Some(mesh) = meshes.get(p.mesh as usize) else {
                    continue;
                };
                if p.identity {
                    // Mapping by the identity would only turn −0 components into +0, which
                    // neither test tells apart from −0 in what it reports.
                    f(p, mesh, &mut world, &nr, tmax)?;
                    continue;
                }
                let o = p.world_to_object.transform_point3(ray.origin);
                let d = p.world_to_object.transform_vector3(ray.direction);
                // The shear depends on the direction: one per instance (when a leaf needs it).
                let onr = NodeRay::new(o, d);
                f(p, mesh, &mut Shear::new(o, d), &onr, tmax)?;
            }
            ControlFlow::Continue(())
        };
        if self.placed.len() == 1 {
            // One instance (a model of one mesh): its tree's own root test culls what the
            // instance tree's would (and turns away NaN or empty intervals as it would), and a
            // walk of a one-node tree per ray is saved.
            let _ = visit(0, 1, &mut tmax);
            return;
        }
        match (margin > 0.0, ORDERED) {
            (true, true) => {
                wide::traverse::<true>(&self.nodes, &nr, tmin, &mut tmax, margin, visit)
            }
            (false, true) => wide::traverse::<false>(&self.nodes, &nr, tmin, &mut tmax, 0.0, visit),
            (true, false) => {
                wide::traverse_any::<true>(&self.nodes, &nr, tmin, &mut tmax, margin, visit)
            }
            (false, false) => {
                wide::traverse_any::<false>(&self.nodes, &nr, tmin, &mut tmax, 0.0, visit)
            }
        }
    }

    /// The nearest hit with `tmin <= t <= tmax` over all instances; ties go to the smaller
    /// instance index, then the smaller triangle index. `meshes` must be the slice the tree
    /// was built with.
    pub fn closest_hit(
        &self,
        meshes: &[MeshBvh],
        ray: &Ray,
        tmin: f32,
        tmax: f32,
    ) -> Option<InstanceHit> {
        self.closest_hit_filtered(meshes, ray, tmin, tmax, &NoFilter)
    }

    /// [`Self::closest_hit`] counting only the hits `filter` accepts (alpha masks).
    pub fn closest_hit_filtered(
        &self,
        meshes: &[MeshBvh],
        ray: &Ray,
        tmin: f32,
        tmax: f32,
        filter: &impl HitFilter,
    ) -> Option<InstanceHit> {
        self.closest_hit_after(meshes, ray, tmin, tmax, filter, (u32::MAX, None))
    }

    /// [`Self::closest_hit_filtered`] of a ray whose nearest hit within `tmax` in one instance
    /// is already known: `known` is that instance's index and hit, and the other instances are
    /// walked for a better one. The same answer, as each instance's walk finds its own
    /// nearest hit within the limit it is given and [`beats`] orders hits totally.
    fn closest_hit_after(
        &self,
        meshes: &[MeshBvh],
        ray: &Ray,
        tmin: f32,
        tmax: f32,
        filter: &impl HitFilter,
        known: (u32, Option<InstanceHit>),
    ) -> Option<InstanceHit> {
        let (done, mut best) = known;
        let tmax = best.map_or(tmax, |b| b.t);
        self.walk::<true>(meshes, ray, tmin, tmax, |p, mesh, shear, nr, tmax| {
            if p.index == done {
                return ControlFlow::Continue(());
            }
            let test = |t: u32, u: f32, v: f32| filter.accept(p.index, t, u, v);
            let accept: Accept<'_> = self.filtered(p, filter).then_some(&test);
            if let Some(h) = mesh.closest_in(shear, nr, tmin, *tmax, accept) {
                let (instance, triangle) = self.scene_ids(p, h.triangle);
                if beats(&best, h.t, instance, triangle) {
                    best = Some(InstanceHit {
                        t: h.t,
                        instance,
                        triangle,
                        u: h.u,
                        v: h.v,
                    });
                    *tmax = h.t;
                }
            }
            ControlFlow::Continue(())
        });
        best
    }

    /// [`Self::closest_hit`] of every ray `rays[i]` over `[tmin, tmax[i]]`, into `out[i]`: the
    /// same answers, bit for bit. Consecutive rays are traced together, [`PACKET`] at a time,
    /// when they are coherent (same octant, none parallel to an axis: neighbouring primary rays
    /// of a camera, shadow rays towards one light); otherwise, on CPUs with AVX-512 or AVX2,
    /// sixteen at a time in lane walks when they start close together (AO and diffuse rays of
    /// neighbouring pixels, see `wide::lanes`); the rest one by one, or two at a time with
    /// their walks interleaved through a scene's main tree far larger than the caches
    /// ([`Self::walks_pairs`]).
    ///
    /// # Panics
    /// When the three slices differ in length.
    pub fn closest_hits(
        &self,
        meshes: &[MeshBvh],
        rays: &[Ray],
        tmin: f32,
        tmax: &[f32],
        out: &mut [Option<InstanceHit>],
    ) {
        self.closest_hits_filtered(meshes, rays, tmin, tmax, out, &NoFilter)
    }

    /// [`Self::closest_hits`] counting only the hits `filter` accepts (alpha masks).
    ///
    /// # Panics
    /// When the three slices differ in length.
    pub fn closest_hits_filtered(
        &self,
        meshes: &[MeshBvh],
        rays: &[Ray],
        tmin: f32,
        tmax: &[f32],
        out: &mut [Option<InstanceHit>],
        filter: &impl HitFilter,
    ) {
        assert!(rays.len() == tmax.len() && rays.len() == out.len());
        for ((rays, tmax), out) in rays
            .chunks(PACKET)
            .zip(tmax.chunks(PACKET))
            .zip(out.chunks_mut(PACKET))
        {
            out.fill(None);
            let alone = self.chunk::<Closest>(meshes, rays, tmin, tmax, filter, |p, i, h, tmax| {
                let Some(h) = h else { return };
                let (instance, triangle) = self.scene_ids(p, h.triangle);
                if beats(&out[i], h.t, instance, triangle) {
                    out[i] = Some(InstanceHit {
                        t: h.t,
                        instance,
                        triangle,
                        u: h.u,
                        v: h.v,
                    });
                    *tmax = h.t;
                }
            });
            let others = self.placed.len() > 1;
            self.trace_alone(
                meshes,
                alone,
                out,
                |p, mesh, pair| {
                    let (pair_rays, pair_tmax) = (pair.map(|i| &rays[i]), pair.map(|i| tmax[i]));
                    let hits = self.closest_pair(p, mesh, pair_rays, tmin, pair_tmax, filter);
                    let after = |k: usize, hit| {
                        let (ray, tmax) = (&rays[pair[k]], tmax[pair[k]]);
                        self.closest_hit_after(meshes, ray, tmin, tmax, filter, (p.index, hit))
                    };
                    let [a, b] = hits;
                    if others {
                        [after(0, a), after(1, b)]
                    } else {
                        [a, b]
                    }
                },
                |i| self.closest_hit_filtered(meshes, &rays[i], tmin, tmax[i], filter),
            );
        }
    }

    /// [`Self::any_hit`] of every ray `rays[i]` over `[tmin, tmax[i]]`, into `out[i]`, with
    /// coherent neighbours traced together as in [`Self::closest_hits`]. The same answers.
    ///
    /// # Panics
    /// When the three slices differ in length.
    pub fn any_hits(
        &self,
        meshes: &[MeshBvh],
        rays: &[Ray],
        tmin: f32,
        tmax: &[f32],
        out: &mut [bool],
    ) {
        self.any_hits_filtered(meshes, rays, tmin, tmax, out, &NoFilter)
    }

    /// [`Self::any_hits`] counting only the hits `filter` accepts (alpha masks).
    ///
    /// # Panics
    /// When the three slices differ in length.
    pub fn any_hits_filtered(
        &self,
        meshes: &[MeshBvh],
        rays: &[Ray],
        tmin: f32,
        tmax: &[f32],
        out: &mut [bool],
        filter: &impl HitFilter,
    ) {
        assert!(rays.len() == tmax.len() && rays.len() == out.len());
        for ((rays, tmax), out) in rays
            .chunks(PACKET)
            .zip(tmax.chunks(PACKET))
            .zip(out.chunks_mut(PACKET))
        {
            out.fill(false);
            let alone = self.chunk::<Any>(meshes, rays, tmin, tmax, filter, |_, i, hit, tmax| {
                if hit {
                    out[i] = true;
                    // Retired: the walk drops the ray.
                    *tmax = f32::NEG_INFINITY;
                }
            });
            let others = self.placed.len() > 1;
            self.trace_alone(
                meshes,
                alone,
                out,
                |p, mesh, pair| {
                    let (pair_rays, pair_tmax) = (pair.map(|i| &rays[i]), pair.map(|i| tmax[i]));
                    let found = self.any_pair(p, mesh, pair_rays, tmin, pair_tmax, filter);
                    let after = |k: usize| {
                        let (ray, tmax) = (&rays[pair[k]], tmax[pair[k]]);
                        others && self.any_hit_after(meshes, ray, tmin, tmax, filter, p.index)
                    };
                    [found[0] || after(0), found[1] || after(1)]
                },
                |i| self.any_hit_filtered(meshes, &rays[i], tmin, tmax[i], filter),
            );
        }
    }

    /// Traces the rays of `alone` (bits of a chunk) that the packet and lane walks left: two
    /// at a time by `two` (given the main tree's instance and mesh and the two rays' indices)
    /// where the scene's main tree is walked in pairs ([`Self::interleaved`]), the rest one by
    /// one by `one`; each answer goes to its ray's slot of `out`.
    #[inline(always)]
    fn trace_alone<'m, T>(
        &self,
        meshes: &'m [MeshBvh],
        mut alone: u32,
        out: &mut [T],
        two: impl Fn(&PlacedInstance, &'m MeshBvh, [usize; 2]) -> [T; 2],
        one: impl Fn(usize) -> T,
    ) {
        if alone & alone.wrapping_sub(1) != 0
            && let Some((p, mesh)) = self.interleaved(meshes)
        {
            while alone & alone.wrapping_sub(1) != 0 {
                let pair = [take_lowest(&mut alone), take_lowest(&mut alone)];
                let [a, b] = two(p, mesh, pair);
                out[pair[0]] = a;
                out[pair[1]] = b;
            }
        }
        while alone != 0 {
            let i = take_lowest(&mut alone);
            out[i] = one(i);
        }
    }

    /// Whether the batch queries ([`Self::closest_hits`], [`Self::any_hits`]) walk the rays
    /// they trace one by one two at a time, their walks interleaved, through the scene's main
    /// tree (its only instance, or its merged meshes) when that tree is larger than the caches
    /// ([`INTERLEAVE_BYTES`]). The same answers either way.
    pub fn walks_pairs(&self, meshes: &[MeshBvh]) -> bool {
        self.interleaved(meshes).is_some()
    }

    /// The instance whose tree single rays walk two at a time ([`MeshBvh::interleaves`]), and
    /// its mesh: the scene's only instance, or else its merged meshes (the other instances
    /// are then walked ray by ray after it, see [`Self::closest_hit_after`]).
    fn interleaved<'m>(&self, meshes: &'m [MeshBvh]) -> Option<(&PlacedInstance, &'m MeshBvh)> {
        let p = &self.placed[self.main?];
        let mesh = meshes.get(p.mesh as usize)?;
        mesh.interleaves().then_some((p, mesh))
    }

    /// The rays in the object space of `p`, as [`Self::walk`] maps them.
    #[inline(always)]
    fn object_rays(p: &PlacedInstance, rays: [&Ray; 2]) -> [(Vec3, Vec3); 2] {
        rays.map(|r| {
            if p.identity {
                (r.origin, r.direction)
            } else {
                (
                    p.world_to_object.transform_point3(r.origin),
                    p.world_to_object.transform_vector3(r.direction),
                )
            }
        })
    }

    /// [`Self::closest_hit_filtered`] of two rays within the instance `p` alone (the scene's
    /// main tree, see [`Self::interleaved`]): the same answers there.
    fn closest_pair(
        &self,
        p: &PlacedInstance,
        mesh: &MeshBvh,
        rays: [&Ray; 2],
        tmin: f32,
        tmax: [f32; 2],
        filter: &impl HitFilter,
    ) -> [Option<InstanceHit>; 2] {
        let [(o0, d0), (o1, d1)] = Self::object_rays(p, rays);
        let nrs = [NodeRay::new(o0, d0), NodeRay::new(o1, d1)];
        let (mut s0, mut s1) = (Shear::new(o0, d0), Shear::new(o1, d1));
        let test = |t: u32, u: f32, v: f32| filter.accept(p.index, t, u, v);
        let accept: Accept<'_> = self.filtered(p, filter).then_some(&test);
        let hits = mesh.closest_in_pair([&mut s0, &mut s1], [&nrs[0], &nrs[1]], tmin, tmax, accept);
        hits.map(|h| {
            h.map(|h| {
                let (instance, triangle) = self.scene_ids(p, h.triangle);
                InstanceHit {
                    t: h.t,
                    instance,
                    triangle,
                    u: h.u,
                    v: h.v,
                }
            })
        })
    }

    /// [`Self::any_hit_filtered`] of two rays within the instance `p` alone (the scene's main
    /// tree, see [`Self::interleaved`]): the same answers there.
    fn any_pair(
        &self,
        p: &PlacedInstance,
        mesh: &MeshBvh,
        rays: [&Ray; 2],
        tmin: f32,
        tmax: [f32; 2],
        filter: &impl HitFilter,
    ) -> [bool; 2] {
        let [(o0, d0), (o1, d1)] = Self::object_rays(p, rays);
        let nrs = [NodeRay::new(o0, d0), NodeRay::new(o1, d1)];
        let (mut s0, mut s1) = (Shear::new(o0, d0), Shear::new(o1, d1));
        let test = |t: u32, u: f32, v: f32| filter.accept(p.index, t, u, v);
        let accept: Accept<'_> = self.filtered(p, filter).then_some(&test);
        mesh.any_in_pair([&mut s0, &mut s1], [&nrs[0], &nrs[1]], tmin, tmax, accept)
    }

    /// Whether `rays` start close enough together for a lane walk to pay: within a box at most
    /// [`LANE_REACH`] of the scene's extent on its longest axis. Rays from nearby origins (AO
    /// and diffuse rays of neighbouring pixels) share the upper levels of the tree whatever
    /// their directions; rays from anywhere (measured: origins uniform in the scene's box)
    /// share only the root, and a lane walk's one order of children then serves each ray worse
    /// than its own nearest-first walk (20–25 % slower than single rays on the bench models).
    fn near_origins(&self, rays: &[Ray]) -> bool {
        // (three components at a time: `Vec3` takes them one by one)
        let (mut lo, mut hi) = (Vec3A::INFINITY, Vec3A::NEG_INFINITY);
        for r in rays {
            let o = Vec3A::from(r.origin);
            lo = lo.min(o);
            hi = hi.max(o);
        }
        let scene = (self.bounds.max - self.bounds.min).max_element();
        (hi - lo).max_element() <= LANE_REACH * scene
    }

    /// Traces a chunk of at most [`PACKET`] rays with query `Q` (answers to `keep` as in
    /// [`Self::packet`]): as one frustum walk when they are coherent, otherwise in lane walks
    /// of [`wide::LANES`] neighbours. Returns the mask of the rays neither could take (on CPUs
    /// without AVX2, all of an incoherent chunk), which the caller traces one by one.
    fn chunk<Q: PacketQuery>(
        &self,
        meshes: &[MeshBvh],
        rays: &[Ray],
        tmin: f32,
        tmax: &[f32],
        filter: &impl HitFilter,
        mut keep: impl FnMut(&PlacedInstance, usize, Q::Answer, &mut f32),
    ) -> u32 {
        if self.packet::<Q, false>(meshes, rays, tmin, tmax, filter, &mut keep) {
            return 0;
        }
        if !wide::has_lanes() {
            // No lane walks here (no AVX2): the rays go one by one at once (asking each group would
            // compute every ray's node ray twice).
            return wide::all_rays(rays.len());
        }
        let mut alone = 0;
        for start in (0..rays.len()).step_by(wide::LANES) {
            let end = (start + wide::LANES).min(rays.len());
            if !self.near_origins(&rays[start..end]) {
                alone |= wide::all_rays(end - start) << start;
                continue;
            }
            let lanes = self.packet::<Q, true>(
                meshes,
                &rays[start..end],
                tmin,
                &tmax[start..end],
                filter,
                |p, i, answer, tmax| keep(p, start + i, answer, tmax),
            );
            if !lanes {
                alone |= wide::all_rays(end - start) << start;
            }
        }
        alone
    }

    /// Traces at most [`PACKET`] rays as one packet with query `Q`, handing each mesh walk's
    /// answer for ray i to `keep(instance, i, answer, &mut tmax[i])`. `LANES` chooses the walk:
    /// without it a frustum walk of coherent rays ([`Frustum::new`]), with it a lane walk of at
    /// most [`wide::LANES`] rays of any directions ([`wide::lanes_take`]). Returns false,
    /// having done nothing, when the rays cannot share the chosen walk.
    fn packet<Q: PacketQuery, const LANES: bool>(
        &self,
        meshes: &[MeshBvh],
        rays: &[Ray],
        tmin: f32,
        tmax_in: &[f32],
        filter: &impl HitFilter,
        mut keep: impl FnMut(&PlacedInstance, usize, Q::Answer, &mut f32),
    ) -> bool {
        let world = NodeRays::new(rays);
        let frustum = if LANES {
            if !wide::lanes_take(world.get()) {
                return false;
            }
            None
        } else {
            let Some(f) = Frustum::new(rays.iter().map(|r| (r.origin, r.direction))) else {
                return false;
            };
            Some(f)
        };
        let qtmin = wide::query_tmin(tmin);
        // Rays with nothing to find (NaN or empty interval) are retired from the start.
        // (written in place: collected into an ArrayVec, the array was then copied by memcpy)
        let mut tmax_buf = [f32::NEG_INFINITY; PACKET];
        for (t, &t_in) in tmax_buf.iter_mut().zip(tmax_in) {
            *t = if t_in >= qtmin {
                t_in
            } else {
                f32::NEG_INFINITY
            };
        }
        let tmax = &mut tmax_buf[..rays.len()];
        let mut world_shears = PacketShears::new(rays);
        let margin = if self.origin_margin > 0.0 {
            // The largest |origin component|, three components at a time (exact: every origin
            // is finite once a walk has taken the rays).
            self.origin_margin
                * rays
                    .iter()
                    .fold(Vec3A::ZERO, |m, r| m.max(Vec3A::from(r.origin).abs()))
                    .max_element()
        } else {
            0.0
        };
        let n = rays.len();
        let all = wide::all_rays(n);
        let mut answers = [Q::NONE; PACKET];
        let mut visit = |what: PacketLeaf, tmax: &mut [f32]| {
            let PacketLeaf::Packet { meta, rays: active } = what else {
                return ControlFlow::Continue(());
            };
            let (first, count) = (wide::leaf_first(meta), wide::leaf_count(meta));
            for p in &self.placed[first as usize..(first + count) as usize] {
                let Some(mesh) = meshes.get(p.mesh as usize) else {
                    continue;
                };
                let test = |t: u32, u: f32, v: f32| filter.accept(p.index, t, u, v);
                let accept: Accept<'_> = self.filtered(p, filter).then_some(&test);
                let answers = &mut answers[..n];
                if p.identity {
                    // The world rays themselves, bounded afresh (in a frustum walk) when only
                    // some of them may meet this instance.
                    let sub;
                    let f = match &frustum {
                        Some(f) if active == all => Some(f),
                        Some(whole) => {
                            // (any of a frustum's rays make one; were it not so, the whole
                            // packet's frustum bounds them too)
                            let mut m = active;
                            sub = Frustum::new((0..active.count_ones()).map(|_| {
                                let r = &rays[m.trailing_zeros() as usize];
                                m &= m - 1;
                                (r.origin, r.direction)
                            }));
                            Some(sub.as_ref().unwrap_or(whole))
                        }
                        None => None,
                    };
                    answers.fill(Q::NONE);
                    let mut w = PacketWalk {
                        shears: &mut world_shears,
                        rays: &world,
                        active,
                        frustum: f,
                    };
                    Q::walk(mesh, &mut w, tmin, tmax, answers, accept);
                } else {
                    // The rays that may meet the instance, mapped into its object space (not
                    // renormalised: t stays the world ray's parameter) and packed together.
                    let mut index: ArrayVec<u8, PACKET> = ArrayVec::new();
                    let mut object: ArrayVec<Ray, PACKET> = ArrayVec::new();
                    let mut sub_tmax: ArrayVec<f32, PACKET> = ArrayVec::new();
                    let mut m = active;
                    while m != 0 {
                        let i = m.trailing_zeros() as usize;
                        m &= m - 1;
                        index.push(i as u8);
                        sub_tmax.push(tmax[i]);
                        object.push(Ray {
                            origin: p.world_to_object.transform_point3(rays[i].origin),
                            direction: p.world_to_object.transform_vector3(rays[i].direction),
                        });
                    }
                    let k = object.len();
                    let packed = &mut answers[..k];
                    packed.fill(Q::NONE);
                    let nodes = NodeRays::new(&object);
                    let shared = if LANES {
                        wide::lanes_take(nodes.get()).then_some(None)
                    } else {
                        Frustum::new(object.iter().map(|r| (r.origin, r.direction))).map(Some)
                    };
                    match shared {
                        Some(f) => {
                            let mut w = PacketWalk {
                                shears: &mut PacketShears::new(&object),
                                rays: &nodes,
                                active: wide::all_rays(k),
                                frustum: f.as_ref(),
                            };
                            Q::walk(mesh, &mut w, tmin, &mut sub_tmax, packed, accept);
                        }
                        None => {
                            for (j, r) in object.iter().enumerate() {
                                packed[j] = Q::walk_one(mesh, r, tmin, sub_tmax[j], accept);
                            }
                        }
                    }
                    // Back to packet order (index[j] >= j, so from the back nothing is
                    // overwritten before it is moved).
                    for j in (0..k).rev() {
                        let i = index[j] as usize;
                        answers[i] = answers[j];
                    }
                }
                let mut m = active;
                while m != 0 {
                    let i = m.trailing_zeros() as usize;
                    m &= m - 1;
                    keep(p, i, answers[i], &mut tmax[i]);
                }
            }
            ControlFlow::Continue(())
        };
        if self.placed.len() == 1 {
            // One instance: its tree's root test culls what the instance tree's would (as in
            // `walk`).
            let _ = visit(
                PacketLeaf::Packet {
                    meta: wide::LEAF_BIT,
                    rays: all,
                },
                tmax,
            );
            return true;
        }
        let nodes = &self.nodes;
        match (&frustum, margin > 0.0, Q::ORDERED) {
            (Some(f), true, true) => wide::traverse_packet::<true, true, false>(
                nodes, &world, all, f, tmin, tmax, margin, visit,
            ),
            (Some(f), false, true) => wide::traverse_packet::<false, true, false>(
                nodes, &world, all, f, tmin, tmax, 0.0, visit,
            ),
            (Some(f), true, false) => wide::traverse_packet::<true, false, false>(
                nodes, &world, all, f, tmin, tmax, margin, visit,
            ),
            (Some(f), false, false) => wide::traverse_packet::<false, false, false>(
                nodes, &world, all, f, tmin, tmax, 0.0, visit,
            ),
            (None, true, true) => wide::traverse_lanes::<true, true, false>(
                nodes,
                world.get(),
                all,
                qtmin,
                tmax,
                margin,
                visit,
            ),
            (None, false, true) => wide::traverse_lanes::<false, true, false>(
                nodes,
                world.get(),
                all,
                qtmin,
                tmax,
                0.0,
                visit,
            ),
            (None, true, false) => wide::traverse_lanes::<true, false, false>(
                nodes,
                world.get(),
                all,
                qtmin,
                tmax,
                margin,
                visit,
            ),
            (None, false, false) => wide::traverse_lanes::<false, false, false>(
                nodes,
                world.get(),
                all,
                qtmin,
                tmax,
                0.0,
                visit,
            ),
        }
        true
    }

    /// Whether any instance is hit with `tmin <= t <= tmax`; stops at the first.
    pub fn any_hit(&self, meshes: &[MeshBvh], ray: &Ray, tmin: f32, tmax: f32) -> bool {
        self.any_hit_filtered(meshes, ray, tmin, tmax, &NoFilter)
    }

    /// [`Self::any_hit`] counting only the hits `filter` accepts (alpha masks).
    pub fn any_hit_filtered(
        &self,
        meshes: &[MeshBvh],
        ray: &Ray,
        tmin: f32,
        tmax: f32,
        filter: &impl HitFilter,
    ) -> bool {
        self.any_hit_after(meshes, ray, tmin, tmax, filter, u32::MAX)
    }

    /// [`Self::any_hit_filtered`] of a ray known to hit nothing in the instance `done`: the
    /// other instances are walked.
    fn any_hit_after(
        &self,
        meshes: &[MeshBvh],
        ray: &Ray,
        tmin: f32,
        tmax: f32,
        filter: &impl HitFilter,
        done: u32,
    ) -> bool {
        let mut found = false;
        self.walk::<false>(meshes, ray, tmin, tmax, |p, mesh, shear, nr, tmax| {
            if p.index == done {
                return ControlFlow::Continue(());
            }
            let test = |t: u32, u: f32, v: f32| filter.accept(p.index, t, u, v);
            let accept: Accept<'_> = self.filtered(p, filter).then_some(&test);
            if mesh.any_in(shear, nr, tmin, *tmax, accept) {
                found = true;
                return ControlFlow::Break(());
            }
            ControlFlow::Continue(())
        });
        found
    }

    /// The nodes as the walk reads them (root at 0; none without instances); a leaf child's
    /// range indexes [`InstanceBvh::leaf_instances`].
    #[cfg(feature = "gpu")]
    pub(crate) fn wide_nodes(&self) -> &[WideNode] {
        &self.nodes
    }

    /// The scene index of each instance in the tree, in leaf order (the merged mesh's is the
    /// number of scene instances, see [`Self::merged`]).
    #[cfg(feature = "gpu")]
    pub(crate) fn leaf_instances(&self) -> impl Iterator<Item = u32> + '_ {
        self.placed.iter().map(|p| p.index)
    }

    /// The merged mesh's instance index and, per triangle of it, the scene instance and
    /// triangle it stands for ([`Self::build_merged`]); `None` without one.
    pub fn merged(&self) -> Option<(u32, &[(u32, u32)])> {
        (self.merged_index != u32::MAX).then_some((self.merged_index, &self.origin[..]))
    }

    /// A ray's node-test margin is this times its origin's largest |component| (see
    /// [`InstanceBvh::build`]).
    #[cfg(feature = "gpu")]
    pub(crate) fn origin_margin(&self) -> f32 {
        self.origin_margin
    }

    /// Number of nodes of the top-level tree.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// World bounds of the instances in the tree (slightly padded, see `build`).
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// Counts and timing of the build.
    pub fn stats(&self) -> &BuildStats {
        &self.stats
    }
}

/// The child-box test the traversal uses on this CPU (for benchmark reports).
pub fn node_test_name() -> &'static str {
    wide::node_test_name()
}

/// [`Aabb::ray_interval`] as a free function (the BVH walks and their tests use it by name).
#[inline]
pub fn ray_box_interval(b: &Aabb, ray: &Ray, tmin: f32, tmax: f32) -> Option<(f32, f32)> {
    b.ray_interval(ray, tmin, tmax)
}

/// The interval of `ray` within [tmin, tmax] in an unbounded box grown by `margin` (when
/// `margin > 0`, through [`Aabb::expand`]): [`ray_box_interval`], or all of [tmin, tmax] for a
/// box with a NaN coordinate, whose extent is unknown.
#[inline]
fn unbounded_interval(
    b: &Aabb,
    ray: &Ray,
    tmin: f32,
    tmax: f32,
    margin: f32,
) -> Option<(f32, f32)> {
    if b.min.is_nan() || b.max.is_nan() {
        Some((tmin, tmax))
    } else if margin > 0.0 {
        ray_box_interval(&b.expand(margin), ray, tmin, tmax)
    } else {
        ray_box_interval(b, ray, tmin, tmax)
    }
}

/// At most this many finite boxes are scanned, not walked: see [`FewBoxes`].
const FEW_BOXES: usize = 8;

/// Rays culled together in [`AabbBvh::visit_rays_within`].
pub const RAY_GROUP: usize = 16;

/// At most this many finite boxes are culled group by group in
/// [`AabbBvh::visit_rays_within`] (beyond, each ray walks the tree: a group would test every
/// box).
pub const GROUPED_BOXES: usize = 64;

/// What interval arithmetic says of the slab parameters of a group of rays at once (the
/// packet culling of Wald, Boulos & Shirley, "Ray tracing deformable scenes using dynamic
/// bounding volume hierarchies", 2007, §4.2: bounds on the origins and reciprocal directions
/// bound every ray's entry and exit of a box).
#[derive(Debug, Clone, Copy)]
struct GroupBounds {
    /// Whether the group holds a ray that can cross anything.
    any: bool,
    o_lo: Vec3,
    o_hi: Vec3,
    inv_lo: Vec3,
    inv_hi: Vec3,
    /// Per axis: every ray's reciprocal direction is finite, and all of one sign (else the
    /// axis bounds nothing).
    usable: [bool; 3],
    tmin: f32,
    tmax: f32,
    margin: f32,
}

impl GroupBounds {
    /// The bounds of the rays `(ray, tmin, tmax, margin)`; those `visit_within` would not
    /// walk (a NaN or empty interval) are left out.
    fn of<'a>(rays: impl Iterator<Item = (&'a Ray, f32, f32, f32)>) -> Self {
        let mut g = GroupBounds {
            any: false,
            o_lo: Vec3::INFINITY,
            o_hi: Vec3::NEG_INFINITY,
            inv_lo: Vec3::INFINITY,
            inv_hi: Vec3::NEG_INFINITY,
            usable: [true; 3],
            tmin: f32::INFINITY,
            tmax: f32::NEG_INFINITY,
            margin: 0.0,
        };
        for (ray, tmin, tmax, margin) in rays {
            if tmin.is_nan() || tmax.is_nan() || tmin > tmax {
                continue;
            }
            g.any = true;
            let inv = Vec3::ONE / ray.direction;
            g.o_lo = g.o_lo.min(ray.origin);
            g.o_hi = g.o_hi.max(ray.origin);
            g.inv_lo = g.inv_lo.min(inv);
            g.inv_hi = g.inv_hi.max(inv);
            for axis in 0..3 {
                g.usable[axis] &= inv[axis].is_finite() && ray.origin[axis].is_finite();
            }
            g.tmin = g.tmin.min(tmin);
            g.tmax = g.tmax.max(tmax);
            // a NaN margin grows nothing in `visit_within` either (`margin > 0` fails)
            if margin > g.margin {
                g.margin = margin;
            }
        }
        for axis in 0..3 {
            g.usable[axis] &= g.inv_lo[axis] > 0.0 || g.inv_hi[axis] < 0.0;
        }
        g
    }

    /// False only when no ray of the group crosses `b` (grown by its margin) within its
    /// interval. Each ray's entry into a slab, fl(fl(lo − o)·inv), is monotone in o and in
    /// inv (correctly rounded operations keep the order of their exact values), so its least
    /// value over the group is at a corner of the origins' and reciprocals' bounds; likewise
    /// the largest exit.
    fn may_cross(&self, b: &Aabb) -> bool {
        if !self.any {
            return false;
        }
        if !self.margin.is_finite() {
            return true;
        }
        let b = if self.margin > 0.0 {
            b.expand(self.margin)
        } else {
            *b
        };
        let (mut near, mut far) = (self.tmin, self.tmax);
        for axis in 0..3 {
            if !self.usable[axis] {
                continue;
            }
            let (o_lo, o_hi) = (self.o_lo[axis], self.o_hi[axis]);
            let (i_lo, i_hi) = (self.inv_lo[axis], self.inv_hi[axis]);
            // the slab entered at `enter` and left at `leave` (swapped for negative rays)
            let (enter, leave) = if i_lo > 0.0 {
                (b.min[axis], b.max[axis])
            } else {
                (b.max[axis], b.min[axis])
            };
            let corners = |plane: f32| {
                let (a, c) = (plane - o_hi, plane - o_lo);
                [a * i_lo, a * i_hi, c * i_lo, c * i_hi]
            };
            let n = corners(enter).into_iter().fold(f32::INFINITY, f32::min);
            let f = corners(leave).into_iter().fold(f32::NEG_INFINITY, f32::max);
            near = near.max(n);
            far = far.min(f);
        }
        // a NaN keeps the box
        near.partial_cmp(&far) != Some(std::cmp::Ordering::Greater)
    }
}

/// The finite boxes of an [`AabbBvh`] that holds at most [`FEW_BOXES`] of them, by axis, in
/// leaf order.
///
/// Most scenes hold a handful of SDF objects, and every camera, shadow and mirror ray asks
/// which of them it crosses. A walk of the tree tests the root's children, stacks and sorts
/// the ones hit, then tests each box again with [`Aabb::ray_interval`] (a division per axis
/// per box): 18.6 % of a hybrid.ron frame's profile went there. A scan tests the eight boxes at
/// once with the ray's reciprocals computed once, the same operations per box as
/// [`Aabb::ray_interval`] in the same order, so the intervals are the same numbers; the boxes
/// crossed are then visited nearest entry first, as the walk's sorted children are. (The GPU
/// walks the tree: the order differs only where two boxes are entered at the same distance,
/// and shows only where two objects are hit at exactly the same distance.) The scan computes
/// its own reciprocals: one computation shared with the unbounded boxes before it measured
/// 1–2 % slower hybrid.ron frames.
#[derive(Debug, Clone)]
struct FewBoxes {
    min: [[f32; FEW_BOXES]; 3],
    max: [[f32; FEW_BOXES]; 3],
    index: [u32; FEW_BOXES],
    len: usize,
}

impl FewBoxes {
    fn of(boxes: &[(u32, Aabb)]) -> Option<Box<Self>> {
        if boxes.len() > FEW_BOXES {
            return None;
        }
        // unused lanes hold empty boxes (and are masked off anyway)
        let mut few = FewBoxes {
            min: [[f32::INFINITY; FEW_BOXES]; 3],
            max: [[f32::NEG_INFINITY; FEW_BOXES]; 3],
            index: [0; FEW_BOXES],
            len: boxes.len(),
        };
        for (lane, (i, b)) in boxes.iter().enumerate() {
            for axis in 0..3 {
                few.min[axis][lane] = b.min[axis];
                few.max[axis][lane] = b.max[axis];
            }
            few.index[lane] = *i;
        }
        Some(Box::new(few))
    }

    /// [`AabbBvh::visit_within`] over these boxes, grown by `margin` (≥ 0).
    #[inline]
    fn visit_within(
        &self,
        ray: &Ray,
        tmin: f32,
        tmax: &mut f32,
        margin: f32,
        mut visit: impl FnMut(usize, f32, f32, &mut f32) -> ControlFlow<()>,
    ) {
        if tmin.is_nan() || tmax.is_nan() || tmin > *tmax {
            return;
        }
        // Aabb::ray_interval lane by lane, its early exits turned into a mask (a lane that
        // failed keeps computing, unread), so that the loops vectorise
        let mut near = [tmin; FEW_BOXES];
        let mut far = [*tmax; FEW_BOXES];
        let mut crossed = [true; FEW_BOXES];
        for axis in 0..3 {
            let o = ray.origin[axis];
            let inv = 1.0 / ray.direction[axis];
            let (lo, hi) = (&self.min[axis], &self.max[axis]);
            if inv.is_finite() {
                // one loop per sign of the direction, so that neither chooses per lane; and
                // `max`/`min` as comparisons, which compile to single instructions (they
                // differ from f32::max and f32::min only on a NaN, which fails the lane's
                // comparisons first)
                let mut slab = |j: usize, n: f32, f: f32| {
                    crossed[j] &= n <= far[j] && f >= near[j];
                    near[j] = if n > near[j] { n } else { near[j] };
                    far[j] = if f < far[j] { f } else { far[j] };
                };
                if inv < 0.0 {
                    for j in 0..FEW_BOXES {
                        slab(j, (hi[j] + margin - o) * inv, (lo[j] - margin - o) * inv);
                    }
                } else {
                    for j in 0..FEW_BOXES {
                        slab(j, (lo[j] - margin - o) * inv, (hi[j] + margin - o) * inv);
                    }
                }
            } else {
                for j in 0..FEW_BOXES {
                    crossed[j] &= lo[j] - margin <= o && o <= hi[j] + margin;
                }
            }
        }
        // the boxes crossed, nearest entry first (ties in leaf order), by insertion: on eight
        // entries by hand, since ArrayVec::insert's shift is a call to memmove
        let mut order = [(0.0f32, 0usize); FEW_BOXES];
        let mut len = 0;
        for j in 0..self.len {
            if crossed[j] && near[j] <= far[j] {
                let mut at = len;
                while at > 0 && order[at - 1].0 > near[j] {
                    order[at] = order[at - 1];
                    at -= 1;
                }
                order[at] = (near[j], j);
                len += 1;
            }
        }
        for &(t0, j) in &order[..len] {
            // `visit` may have lowered tmax: what Aabb::ray_interval would give now
            if t0 > *tmax {
                continue;
            }
            let t1 = far[j].min(*tmax);
            if visit(self.index[j] as usize, t0, t1, tmax).is_break() {
                return;
            }
        }
    }
}

/// A BVH over arbitrary boxes, e.g. the world bounds of the SDF objects, walked nearest-first.
///
/// Finite boxes go into the tree. Boxes with an infinite or NaN coordinate cannot be bounded:
/// they are kept in a separate list ([`AabbBvh::unbounded`]) and offered to every walk before
/// the tree (an infinite box through [`ray_box_interval`], a NaN box as `[tmin, tmax]`: its
/// extent is unknown). So are finite boxes with a coordinate beyond
/// [`crate::geom::LARGEST_TREE_COORDINATE`], which the builder's arithmetic cannot take. Empty boxes
/// (min > max on an axis) contain nothing and are never visited.
#[derive(Debug, Clone)]
pub struct AabbBvh {
    nodes: HugePageArray<WideNode>,
    /// Leaf order → (original index, box).
    boxes: Vec<(u32, Aabb)>,
    /// The finite boxes again, for a scan instead of the walk, when there are few of them.
    few: Option<Box<FewBoxes>>,
    unbounded: Vec<u32>,
    unbounded_boxes: Vec<Aabb>,
    bounds: Aabb,
    stats: BuildStats,
}

impl AabbBvh {
    /// Builds with [`BuildQuality::Medium`].
    pub fn build(boxes: &[Aabb]) -> Self {
        Self::build_with_quality(boxes, BuildQuality::Medium)
    }

    /// Builds with the given quality, by obvhs at every quality (the spatial pre-splits of
    /// [`BuildQuality::pre_split`] only apply to triangles; boxes are never split).
    pub fn build_with_quality(boxes: &[Aabb], quality: BuildQuality) -> Self {
        let start = Instant::now();
        let mut stats = BuildStats {
            input: boxes.len(),
            ..Default::default()
        };
        let mut kept = Vec::with_capacity(boxes.len());
        let mut oboxes = Vec::with_capacity(boxes.len());
        let mut unbounded = Vec::new();
        for (i, b) in boxes.iter().enumerate() {
            if b.min.cmpgt(b.max).any() {
                stats.dropped_degenerate += 1;
            } else if !b.is_finite() || b.reach() > crate::geom::LARGEST_TREE_COORDINATE {
                unbounded.push(i as u32);
            } else {
                kept.push((i as u32, *b));
                oboxes.push(to_oaabb(b.min, b.max));
            }
        }
        let mut params = quality.params();
        params.pre_split = false;
        let tree = wide::build(&oboxes, &params);
        let leaf_boxes: Vec<(u32, Aabb)> = tree.order.iter().map(|&k| kept[k as usize]).collect();
        stats.kept = leaf_boxes.len();
        stats.references = leaf_boxes.len();
        stats.nodes = tree.nodes.len();
        stats.max_depth = tree.max_depth;
        stats.build_time = start.elapsed();
        AabbBvh {
            nodes: HugePageArray::from_vec(tree.nodes),
            few: FewBoxes::of(&leaf_boxes),
            boxes: leaf_boxes,
            unbounded_boxes: unbounded.iter().map(|&i| boxes[i as usize]).collect(),
            unbounded,
            bounds: geom_bounds(tree.bounds),
            stats,
        }
    }

    /// Calls `visit(index, t_enter, t_exit, tmax)` for every box the ray crosses within
    /// `[tmin, *tmax]`, where `(t_enter, t_exit)` is exactly [`ray_box_interval`] of that box
    /// (so the set of boxes visited when `visit` never shrinks `tmax` is exactly the set a
    /// linear scan with [`Aabb::ray_interval`] finds). Unbounded boxes come first, then the tree's
    /// boxes roughly front to back (children sorted by entry distance). `visit` may lower
    /// `*tmax` — boxes entered beyond it are then skipped (closest-hit) — or return
    /// `ControlFlow::Break` to stop the walk (any-hit). Same interface as
    /// [`super::SdfAccel::visit`].
    pub fn visit(
        &self,
        ray: &Ray,
        tmin: f32,
        tmax: &mut f32,
        visit: impl FnMut(usize, f32, f32, &mut f32) -> ControlFlow<()>,
    ) {
        self.visit_within(ray, tmin, tmax, 0.0, visit)
    }

    /// Like [`AabbBvh::visit`], with every box grown by `margin` (when `margin > 0`, through
    /// [`Aabb::expand`], as [`super::SdfAccel::visit_within`] does).
    pub fn visit_within(
        &self,
        ray: &Ray,
        tmin: f32,
        tmax: &mut f32,
        margin: f32,
        mut visit: impl FnMut(usize, f32, f32, &mut f32) -> ControlFlow<()>,
    ) {
        let grow = margin > 0.0;
        for (&i, b) in self.unbounded.iter().zip(&self.unbounded_boxes) {
            if tmin.is_nan() || tmax.is_nan() || tmin > *tmax {
                return;
            }
            if let Some((t0, t1)) = unbounded_interval(b, ray, tmin, *tmax, margin)
                && visit(i as usize, t0, t1, tmax).is_break()
            {
                return;
            }
        }
        if let Some(few) = &self.few {
            few.visit_within(ray, tmin, tmax, if grow { margin } else { 0.0 }, visit);
            return;
        }
        let nr = NodeRay::new(ray.origin, ray.direction);
        // the reciprocals once for every box of every leaf
        let inv = Vec3::ONE / ray.direction;
        let leaf = |first: u32, count: u32, tmax: &mut f32| {
            for (i, b) in &self.boxes[first as usize..(first + count) as usize] {
                let b = if grow { b.expand(margin) } else { *b };
                if let Some((t0, t1)) = b.ray_interval_from(ray.origin, inv, tmin, *tmax) {
                    visit(*i as usize, t0, t1, tmax)?;
                }
            }
            ControlFlow::Continue(())
        };
        if grow {
            wide::traverse::<true>(&self.nodes, &nr, tmin, tmax, margin, leaf);
        } else {
            wide::traverse::<false>(&self.nodes, &nr, tmin, tmax, 0.0, leaf);
        }
    }

    /// [`AabbBvh::visit_within`] for many rays, ray after ray: `visit(ray, index, t_enter,
    /// t_exit)` for every box ray `r` crosses within `[tmins[r], tmaxs[r]]`, grown by
    /// `margin(r)`, with the intervals [`AabbBvh::visit_within`] gives (`visit` cannot lower
    /// `tmax` here). Each ray's unbounded boxes come first, then its finite ones: nearest
    /// entry first (ties in leaf order) up to [`GROUPED_BOXES`] boxes, in the walk's order
    /// past them. The order is not [`AabbBvh::visit_within`]'s for 9 to 64 boxes: the shadow
    /// rays that take it get the same answers in any order (a closest hit's march is bounded
    /// by the hits before it, so its last bits may depend on the order).
    ///
    /// Where the tree holds more than [`FEW_BOXES`] boxes (which one ray scans at once) and
    /// at most [`GROUPED_BOXES`], runs of [`RAY_GROUP`] rays (the shadow rays of neighbouring
    /// pixels) first drop together the boxes none of them can cross ([`GroupBounds`]), and
    /// each ray then tests only the boxes left: the walk of every shadow ray through the tree
    /// was a tenth of a showcase frame, for rays of which most cross none of its fourteen
    /// boxes. (Over four boxes, the groups cost hybrid.ron 1–3 % more than the scan.)
    pub fn visit_rays_within(
        &self,
        rays: &[Ray],
        tmins: &[f32],
        tmaxs: &[f32],
        margin: impl Fn(usize) -> f32,
        mut visit: impl FnMut(usize, usize, f32, f32),
    ) {
        if self.few.is_some() || self.boxes.len() > GROUPED_BOXES {
            // ray by ray (the loop of `SdfAccel::visit_rays_within`'s linear scan: one helper
            // taking the walk as a closure called the visitor through a pointer, 1–2 % of a
            // frame of 400 spheres)
            for (r, ray) in rays.iter().enumerate() {
                let mut tmax = tmaxs[r];
                self.visit_within(ray, tmins[r], &mut tmax, margin(r), |i, t0, t1, _| {
                    visit(r, i, t0, t1);
                    ControlFlow::Continue(())
                });
            }
            return;
        }
        let mut left: ArrayVec<u32, GROUPED_BOXES> = ArrayVec::new();
        let mut crossed: ArrayVec<(f32, f32, u32), GROUPED_BOXES> = ArrayVec::new();
        for first in (0..rays.len()).step_by(RAY_GROUP) {
            let group = first..(first + RAY_GROUP).min(rays.len());
            let bounds = GroupBounds::of(
                group
                    .clone()
                    .map(|r| (&rays[r], tmins[r], tmaxs[r], margin(r))),
            );
            left.clear();
            for (k, (_, b)) in self.boxes.iter().enumerate() {
                if bounds.may_cross(b) {
                    left.push(k as u32);
                }
            }
            for r in group {
                let (ray, tmin, tmax, margin) = (&rays[r], tmins[r], tmaxs[r], margin(r));
                if tmin.is_nan() || tmax.is_nan() || tmin > tmax {
                    continue;
                }
                let grow = margin > 0.0;
                // the unbounded boxes as `visit_within` visits them
                for (&i, b) in self.unbounded.iter().zip(&self.unbounded_boxes) {
                    if let Some((t0, t1)) = unbounded_interval(b, ray, tmin, tmax, margin) {
                        visit(r, i as usize, t0, t1);
                    }
                }
                // the boxes left, each with the walk's interval, sorted by entry (insertion:
                // stable, so ties keep leaf order)
                let inv = Vec3::ONE / ray.direction;
                crossed.clear();
                for &k in &left {
                    let (i, b) = &self.boxes[k as usize];
                    let b = if grow { b.expand(margin) } else { *b };
                    if let Some((t0, t1)) = b.ray_interval_from(ray.origin, inv, tmin, tmax) {
                        let mut at = crossed.len();
                        crossed.push((t0, t1, *i));
                        while at > 0 && crossed[at - 1].0 > t0 {
                            crossed.swap(at - 1, at);
                            at -= 1;
                        }
                    }
                }
                for &(t0, t1, i) in &crossed {
                    visit(r, i as usize, t0, t1);
                }
            }
        }
    }

    /// Indices of the boxes kept out of the tree because they are not finite.
    pub fn unbounded(&self) -> &[u32] {
        &self.unbounded
    }

    /// The nodes as the walk reads them (root at 0; none without finite boxes); a leaf
    /// child's range indexes [`AabbBvh::leaf_boxes`].
    #[cfg(feature = "gpu")]
    pub(crate) fn wide_nodes(&self) -> &[WideNode] {
        &self.nodes
    }

    /// The caller's index of each box in the tree, in leaf order.
    #[cfg(feature = "gpu")]
    pub(crate) fn leaf_boxes(&self) -> impl Iterator<Item = u32> + '_ {
        self.boxes.iter().map(|b| b.0)
    }

    /// Number of nodes of the tree.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Exact bounds of the finite boxes ([`Aabb::EMPTY`] when there are none).
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// Counts and timing of the build.
    pub fn stats(&self) -> &BuildStats {
        &self.stats
    }
}
