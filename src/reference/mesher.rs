//! Triangle meshes of an SDF object's zero set, for the Embree referee: marching cubes over a
//! Lipschitz-pruned grid of the object's distance tape, vertices refined onto the surface, with
//! a stated bound on the distance between mesh and surface.
//!
//! # Why marching cubes, and which table
//! Marching cubes (Lorensen & Cline, SIGGRAPH 1987) puts every vertex on a grid edge, so a
//! vertex can be moved exactly onto the surface by a one-dimensional root search along its edge
//! and every triangle stays inside one cell — the two facts the tolerance below rests on.
//! Marching tetrahedra has the same properties but makes about three times the vertices and
//! triangles (seven edge directions per grid point instead of three); surface nets / dual
//! contouring put vertices inside cells, where no such simple bound holds.
//!
//! The case table is not typed in: [`case_table`] derives it from one rule applied to each
//! cube face on its own. On a face, a segment joins the crossing where the corners enter the
//! solid to the one where they leave it, around each run of inside corners; on an ambiguous
//! face (two diagonal inside corners) that separates the inside corners. Because the rule
//! looks at nothing but the face's four corner signs, the two cells sharing a face draw the
//! same segments on it, so the mesh has no cracks — the defect of the original 15-case table
//! with complementary symmetry (Dürst 1988). The face segments chain into closed loops around
//! the cube, each loop is fanned into triangles. Interior ambiguities (Chernyaev's cases
//! 4, 10, 13 tunnels) are resolved arbitrarily: they change the topology inside a cell, never
//! the watertightness or the distance bound.
//!
//! # Speed
//! The lowered fields are 1-Lipschitz (`crate::sdf::lower` step-corrects every node), so a
//! block of the grid whose centre value exceeds its half-diagonal cannot contain surface. An
//! octree descent over blocks of [`LEAF`]³ cells drops empty space; inside a leaf, blocks of
//! 2³ cells (whose centre is a grid point, reused as a corner value) are pruned the same way,
//! and only the corners of surviving cells are evaluated, each once. Leaves are meshed in
//! parallel (rayon); vertices on shared edges are welded by their global edge key. Implicit
//! surfaces may carry an *estimated* Lipschitz constant, so pruning keeps a safety factor
//! ([`PRUNE_SAFETY`]).
//!
//! # The tolerance
//! With cell size h, after refinement every vertex lies within `w` (the widest final root
//! bracket, [`REFINE_BRACKET`]·h at most) of a point of the surface on its edge. A mesh point p
//! lies in a triangle whose longest edge L is at most the cell diagonal √3·h (the triangle is
//! inside one cell); a point of a triangle is within L/√3 of one of its vertices (the
//! circumradius bound for acute triangles, L/2 for obtuse ones). So every mesh point is within
//! **h + w** of the surface. Without refinement (linear interpolation of the corner values)
//! the vertex is anywhere on its edge; then only "the triangle lies in a cell that contains a
//! zero" holds, and the bound is the cell diagonal **√3·h**. The bound is one-sided: it says
//! the mesh is near the surface, not that every part of the surface is meshed — features
//! thinner than a cell can fall between grid points and be lost (a hit/miss disagreement).
//!
//! # Unbounded objects
//! An object whose bounds are infinite on some axis is meshed only inside the caller's clip
//! box. The mesh simply stops at the grid's faces: it is open there, with no walls (no cell
//! outside the grid is triangulated, and the grid is not padded with "outside" values).
//! [`SdfMesh::region`] and [`SdfMesh::clipped`] say where the mesh is valid; a comparison must
//! ignore rays whose true hit on the object lies outside `region`.

use crate::geom::Aabb;
use crate::sdf::tape::{Registers, Tape};
use glam::Vec3;
use rayon::prelude::*;
use std::sync::OnceLock;

/// Cells per side of an octree leaf (a multiple of 2: leaves are split into 2³-cell blocks).
pub const LEAF: u32 = 8;

/// Prune a block only where |f(centre)| exceeds this many half-diagonals: the Lipschitz
/// constant of an implicit surface may be estimated by sampling rather than proven.
pub const PRUNE_SAFETY: f32 = 1.25;

/// Root brackets are narrowed to this fraction of a cell (or [`REFINE_MAX_STEPS`] evaluations).
pub const REFINE_BRACKET: f32 = 1e-3;

/// Most field evaluations spent refining one vertex.
pub const REFINE_MAX_STEPS: u32 = 24;

/// Fewest cells across the thinnest side of the meshed region (within the triangle budget):
/// with two cells across a slab, grid points fall inside it and its sign change is seen.
pub const MIN_CELLS_ACROSS: f32 = 2.0;

/// The thin-side rule raises the resolution at most this many times (the cost grows as its
/// square).
pub const MAX_RAISE: u32 = 4;

/// Most cells along the longest side, whatever the thinnest side asks for.
pub const MAX_RESOLUTION: u32 = 4096;

/// Cells of padding around a bounded object's box, so the grid's outer corners are outside.
const PAD_CELLS: f32 = 2.0;

/// How to mesh.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshOptions {
    /// Cells along the longest side of the meshed region; raised for thin regions so that
    /// the thinnest side has [`MIN_CELLS_ACROSS`] cells (at most [`MAX_RAISE`] times, and
    /// up to [`MAX_RESOLUTION`]).
    pub resolution: u32,
    /// Move each vertex onto the surface by a root search along its edge.
    pub refine: bool,
    /// If a mesh has more triangles, it is made again at a resolution scaled down to fit
    /// (triangle count grows as the square of the resolution).
    pub max_triangles: usize,
}

impl Default for MeshOptions {
    fn default() -> Self {
        MeshOptions {
            resolution: 256,
            refine: true,
            max_triangles: 2_000_000,
        }
    }
}

/// A triangle mesh of an SDF object's zero set, in world space.
#[derive(Debug, Clone, PartialEq)]
pub struct SdfMesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Triangles, counter-clockwise seen from outside the solid (where the field is positive).
    pub triangles: Vec<[u32; 3]>,
    /// Cells along the longest side of the meshed region (after the thin-side rise and the
    /// budget reduction).
    pub resolution: u32,
    /// Edge length h of a grid cell.
    pub cell: f32,
    /// Every mesh point is within this distance of the surface (see the module doc).
    pub tolerance: f32,
    /// The box the grid covers: the mesh represents the surface inside it.
    pub region: Aabb,
    /// Whether the object's surface extends outside `region` (it was clipped).
    pub clipped: bool,
    /// Field evaluations spent (grid corners, pruning probes and refinement).
    pub evaluations: u64,
}

/// Meshes the zero set of `tape` inside `bounds` (the object's world bounds, possibly
/// infinite) clipped to `clip`, which must be finite.
pub fn mesh_sdf(
    tape: &Tape,
    bounds: &Aabb,
    clip: &Aabb,
    options: &MeshOptions,
) -> Result<SdfMesh, String> {
    if !clip.is_finite() {
        return Err(format!("the clip box {clip:?} is not finite"));
    }
    if bounds.min.is_nan() || bounds.max.is_nan() {
        return Err(format!("the object's bounds {bounds:?} are NaN"));
    }
    if options.resolution == 0 {
        return Err("mesh resolution 0: at least one cell is needed".into());
    }
    let region = bounds.intersection(clip);
    let mut resolution = options.resolution;
    let mut total_evaluations = 0;
    if !region.is_empty() {
        // Thin objects (a ground slab) get at least MIN_CELLS_ACROSS cells across their
        // thinnest side, so that they do not fall between grid points.
        let size = region.max - region.min;
        let (longest, thinnest) = (size.max_element(), size.min_element());
        if thinnest > 0.0 {
            let needed = (MIN_CELLS_ACROSS * longest / thinnest).ceil();
            let cap = (MAX_RAISE * resolution).min(MAX_RESOLUTION);
            resolution = resolution.max(needed.min(cap as f32) as u32);
        }
        // Predict the triangle count from a pass at a quarter of the resolution (a 16th
        // of the cost), so that a mesh far over budget is not made in full first.
        if resolution >= 4 * LEAF {
            let coarse = mesh_at(tape, bounds, clip, resolution / 4, false);
            total_evaluations += coarse.evaluations;
            let predicted = 16.0 * coarse.triangles.len() as f64;
            if predicted > options.max_triangles as f64 {
                let scale = (0.9 * options.max_triangles as f64 / predicted).sqrt();
                resolution = ((resolution as f64 * scale) as u32).max(LEAF);
            }
        }
    }
    loop {
        let mut mesh = mesh_at(tape, bounds, clip, resolution, options.refine);
        total_evaluations += mesh.evaluations;
        mesh.evaluations = total_evaluations;
        let n = mesh.triangles.len();
        if n <= options.max_triangles || resolution <= LEAF {
            return Ok(mesh);
        }
        // Triangles scale as resolution²; aim 10 % under the budget.
        let scale = (0.9 * options.max_triangles as f64 / n as f64).sqrt();
        resolution = ((resolution as f64 * scale) as u32).clamp(LEAF, resolution - 1);
    }
}

/// The grid: `cells` cells of size `h` from `origin`.
#[derive(Debug, Clone, Copy)]
struct Grid {
    origin: Vec3,
    h: f32,
    cells: [u32; 3],
}

impl Grid {
    fn point(&self, i: [u32; 3]) -> Vec3 {
        self.origin + self.h * Vec3::new(i[0] as f32, i[1] as f32, i[2] as f32)
    }

    /// Global key of the grid edge from point `i` along `axis`.
    fn edge_key(&self, i: [u32; 3], axis: usize) -> u64 {
        let (sx, sy) = (self.cells[0] as u64 + 1, self.cells[1] as u64 + 1);
        ((i[2] as u64 * sy + i[1] as u64) * sx + i[0] as u64) * 3 + axis as u64
    }
}

fn mesh_at(tape: &Tape, bounds: &Aabb, clip: &Aabb, resolution: u32, refine: bool) -> SdfMesh {
    let region = bounds.intersection(clip);
    let empty = |region: Aabb, clipped: bool| SdfMesh {
        positions: Vec::new(),
        triangles: Vec::new(),
        resolution,
        cell: 0.0,
        tolerance: 0.0,
        region,
        clipped,
        evaluations: 0,
    };
    if region.is_empty() {
        // all of the object (if it has any extent) lies outside the clip box
        return empty(region, !bounds.is_empty());
    }
    let size = region.max - region.min;
    let h = size.max_element() / resolution as f32;
    if !(h > 0.0 && h.is_finite()) {
        return empty(region, false);
    }
    // Pad by a few cells where the object's own bounds end, not past the clip box.
    let padded = region.expand(PAD_CELLS * h).intersection(clip);
    let size = padded.max - padded.min;
    let cells = size
        .to_array()
        .map(|s| ((s / h).ceil().max(1.0) as u32).div_ceil(LEAF) * LEAF);
    let span = h * Vec3::new(cells[0] as f32, cells[1] as f32, cells[2] as f32);
    let grid = Grid {
        origin: padded.center() - 0.5 * span,
        h,
        cells,
    };
    let covered = Aabb::new(grid.origin, grid.origin + span);
    let clipped = !(covered.min.cmple(bounds.min).all() && covered.max.cmpge(bounds.max).all());

    // Octree descent to the leaves that may hold surface.
    let leaves_per_axis = cells.map(|c| c / LEAF);
    let mut leaves = Vec::new();
    let mut regs = Registers::new();
    let mut evaluations = 0u64;
    descend(
        tape,
        &grid,
        [0; 3],
        leaves_per_axis,
        &mut leaves,
        &mut regs,
        &mut evaluations,
    );

    let table = case_table();
    let parts: Vec<LeafMesh> = leaves
        .par_iter()
        .map_init(Registers::new, |regs, &leaf| {
            mesh_leaf(tape, &grid, leaf, table, refine, regs)
        })
        .collect();

    // Weld vertices on shared edges by their global key.
    let mut vertices: Vec<(u64, Vec3)> = Vec::new();
    let mut keyed_triangles: Vec<[u64; 3]> = Vec::new();
    let mut widest_bracket: f32 = 0.0;
    for p in &parts {
        vertices.extend_from_slice(&p.vertices);
        keyed_triangles.extend_from_slice(&p.triangles);
        evaluations += p.evaluations;
        widest_bracket = widest_bracket.max(p.widest_bracket);
    }
    drop(parts);
    vertices.par_sort_unstable_by_key(|v| v.0);
    vertices.dedup_by_key(|v| v.0);
    let triangles: Vec<[u32; 3]> = keyed_triangles
        .par_iter()
        .map(|t| {
            t.map(|k| {
                vertices
                    .binary_search_by_key(&k, |v| v.0)
                    .expect("every edge key of a triangle has its vertex") as u32
            })
        })
        .collect();
    let positions = vertices.into_iter().map(|v| v.1).collect();
    let tolerance = if refine {
        h * (1.0 + widest_bracket)
    } else {
        3f32.sqrt() * h
    };
    SdfMesh {
        positions,
        triangles,
        resolution,
        cell: h,
        // f32 positions of world coordinates: allow a few ulps of the largest coordinate.
        tolerance: tolerance
            + 4.0 * f32::EPSILON * covered.min.abs().max(covered.max.abs()).max_element(),
        region: covered,
        clipped,
        evaluations,
    }
}

/// Collects the leaves in the block of leaves [lo, lo + n) that may contain surface.
fn descend(
    tape: &Tape,
    grid: &Grid,
    lo: [u32; 3],
    n: [u32; 3],
    leaves: &mut Vec<[u32; 3]>,
    regs: &mut Registers,
    evaluations: &mut u64,
) {
    let a = grid.point(lo.map(|l| l * LEAF));
    let b = grid.point([0, 1, 2].map(|k| (lo[k] + n[k]) * LEAF));
    let centre = 0.5 * (a + b);
    let half_diagonal = 0.5 * (b - a).length();
    *evaluations += 1;
    let f = tape.eval_in(centre, regs);
    // 1-Lipschitz: |f(centre)| > half-diagonal ⇒ f keeps its sign over the whole block.
    if f.abs() > PRUNE_SAFETY * half_diagonal {
        return;
    }
    if n == [1, 1, 1] {
        leaves.push(lo);
        return;
    }
    let halves = n.map(|m| if m > 1 { [m / 2, m - m / 2] } else { [m, 0] });
    for iz in 0..2 {
        for iy in 0..2 {
            for ix in 0..2 {
                let sub = [halves[0][ix], halves[1][iy], halves[2][iz]];
                if sub.contains(&0) {
                    continue;
                }
                let off = [
                    lo[0] + ix as u32 * halves[0][0],
                    lo[1] + iy as u32 * halves[1][0],
                    lo[2] + iz as u32 * halves[2][0],
                ];
                descend(tape, grid, off, sub, leaves, regs, evaluations);
            }
        }
    }
}

/// One leaf's triangles, with vertices and triangles named by global edge keys.
struct LeafMesh {
    vertices: Vec<(u64, Vec3)>,
    triangles: Vec<[u64; 3]>,
    evaluations: u64,
    /// Widest final root bracket, as a fraction of h.
    widest_bracket: f32,
}

const LP: usize = LEAF as usize + 1;

/// Corner `c` of a cube (bit 0 = +x, bit 1 = +y, bit 2 = +z): the numbering of [`EDGES`] and
/// of the case table's corner bits.
fn corner_offset(c: usize) -> [u32; 3] {
    [(c & 1) as u32, ((c >> 1) & 1) as u32, ((c >> 2) & 1) as u32]
}

/// The 12 cube edges as (corner, corner), corners numbered by their bits (bit 0 = +x, bit 1 =
/// +y, bit 2 = +z): edges 0–3 run along x, 4–7 along y, 8–11 along z, from the lower corner.
pub const EDGES: [(usize, usize); 12] = [
    (0, 1),
    (2, 3),
    (4, 5),
    (6, 7),
    (0, 2),
    (1, 3),
    (4, 6),
    (5, 7),
    (0, 4),
    (1, 5),
    (2, 6),
    (3, 7),
];

fn mesh_leaf(
    tape: &Tape,
    grid: &Grid,
    leaf: [u32; 3],
    table: &[Vec<[u8; 3]>; 256],
    refine: bool,
    regs: &mut Registers,
) -> LeafMesh {
    let base = leaf.map(|l| l * LEAF);
    let mut values = [f32::NAN; LP * LP * LP];
    let mut known = [false; LP * LP * LP];
    let mut vertex_of = vec![u32::MAX; LP * LP * LP * 3];
    let mut out = LeafMesh {
        vertices: Vec::new(),
        triangles: Vec::new(),
        evaluations: 0,
        widest_bracket: 0.0,
    };
    let local = |i: [usize; 3]| (i[2] * LP + i[1]) * LP + i[0];
    let global = |i: [usize; 3]| [0, 1, 2].map(|k| base[k] + i[k] as u32);
    let mut value = |i: [usize; 3], regs: &mut Registers, evaluations: &mut u64| -> f32 {
        let k = local(i);
        if !known[k] {
            known[k] = true;
            values[k] = tape.eval_in(grid.point(global(i)), regs);
            *evaluations += 1;
        }
        values[k]
    };
    let half = LEAF as usize / 2;
    // √3·h: the half-diagonal of a 2³-cell block.
    let block_reach = PRUNE_SAFETY * 3f32.sqrt() * grid.h;
    for bz in 0..half {
        for by in 0..half {
            for bx in 0..half {
                let c = [2 * bx + 1, 2 * by + 1, 2 * bz + 1];
                if value(c, regs, &mut out.evaluations).abs() > block_reach {
                    continue;
                }
                for cz in 0..2 {
                    for cy in 0..2 {
                        for cx in 0..2 {
                            let cell = [2 * bx + cx, 2 * by + cy, 2 * bz + cz];
                            let mut f = [0f32; 8];
                            let mut case = 0usize;
                            for (k, fk) in f.iter_mut().enumerate() {
                                let o = corner_offset(k);
                                let p = [0, 1, 2].map(|a| cell[a] + o[a] as usize);
                                *fk = value(p, regs, &mut out.evaluations);
                                if *fk < 0.0 {
                                    case |= 1 << k;
                                }
                            }
                            for tri in &table[case] {
                                let keys = tri.map(|e| {
                                    let (ca, cb) = EDGES[e as usize];
                                    let axis = e as usize / 4;
                                    let oa = corner_offset(ca);
                                    let pa = [0, 1, 2].map(|a| cell[a] + oa[a] as usize);
                                    let slot = local(pa) * 3 + axis;
                                    let key = grid.edge_key(global(pa), axis);
                                    if vertex_of[slot] == u32::MAX {
                                        vertex_of[slot] = out.vertices.len() as u32;
                                        let a = grid.point(global(pa));
                                        let ob = corner_offset(cb);
                                        let pb = [0, 1, 2].map(|x| cell[x] + ob[x] as usize);
                                        let b = grid.point(global(pb));
                                        let (p, bracket) = edge_vertex(
                                            tape,
                                            a,
                                            b,
                                            f[ca],
                                            f[cb],
                                            refine,
                                            regs,
                                            &mut out.evaluations,
                                        );
                                        out.widest_bracket = out.widest_bracket.max(bracket);
                                        out.vertices.push((key, p));
                                    }
                                    key
                                });
                                out.triangles.push(keys);
                            }
                        }
                    }
                }
            }
        }
    }
    out
}

/// The surface point on the edge a→b (fa and fb of opposite sign): linear interpolation, then,
/// if `refine`, a safeguarded Illinois regula falsi (Dowell & Jarratt 1971) that falls back
/// to bisection whenever a step fails to halve the bracket, until the bracket is
/// [`REFINE_BRACKET`] of the edge. Returns the point and the final bracket as a fraction of
/// the edge (1 without refinement).
#[allow(clippy::too_many_arguments)]
fn edge_vertex(
    tape: &Tape,
    a: Vec3,
    b: Vec3,
    fa: f32,
    fb: f32,
    refine: bool,
    regs: &mut Registers,
    evaluations: &mut u64,
) -> (Vec3, f32) {
    let interpolate = |s0: f32, f0: f32, s1: f32, f1: f32| {
        let s = s0 + (s1 - s0) * f0 / (f0 - f1);
        if s.is_finite() {
            s.clamp(s0, s1)
        } else {
            0.5 * (s0 + s1)
        }
    };
    if !refine {
        return (a.lerp(b, interpolate(0.0, fa, 1.0, fb)), 1.0);
    }
    let (mut s0, mut f0, mut s1, mut f1) = (0f32, fa, 1f32, fb);
    // Which end the last step replaced (Illinois halves the other end's value on a repeat).
    let mut last = 0i8;
    let mut bisect = false;
    for _ in 0..REFINE_MAX_STEPS {
        let width = s1 - s0;
        if width <= REFINE_BRACKET {
            break;
        }
        let s = if bisect {
            0.5 * (s0 + s1)
        } else {
            interpolate(s0, f0, s1, f1)
        };
        // A step landing on an end (rounding) makes no progress: bisect instead.
        let s = if s <= s0 || s >= s1 {
            0.5 * (s0 + s1)
        } else {
            s
        };
        let f = tape.eval_in(a.lerp(b, s), regs);
        *evaluations += 1;
        if f == 0.0 {
            return (a.lerp(b, s), 0.0);
        }
        if (f < 0.0) == (f0 < 0.0) {
            s0 = s;
            f0 = f;
            if last == -1 {
                f1 *= 0.5;
            }
            last = -1;
        } else {
            s1 = s;
            f1 = f;
            if last == 1 {
                f0 *= 0.5;
            }
            last = 1;
        }
        bisect = s1 - s0 > 0.5 * width;
    }
    (a.lerp(b, interpolate(s0, f0, s1, f1)), s1 - s0)
}

/// The marching-cubes case table: for each of the 256 inside/outside patterns of a cube's
/// corners (bit k set = corner k inside, f < 0), its triangles as triples of [`EDGES`]
/// indices, counter-clockwise seen from outside the solid. Derived, not typed: see the
/// module doc for the face rule that makes neighbouring cells agree.
pub fn case_table() -> &'static [Vec<[u8; 3]>; 256] {
    static TABLE: OnceLock<[Vec<[u8; 3]>; 256]> = OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(triangulate_case))
}

/// The six cube faces, corners in counter-clockwise order seen from outside the cube.
const FACES: [[usize; 4]; 6] = [
    [0, 4, 6, 2], // −x
    [1, 3, 7, 5], // +x
    [0, 1, 5, 4], // −y
    [2, 6, 7, 3], // +y
    [0, 2, 3, 1], // −z
    [4, 5, 7, 6], // +z
];

fn edge_between(a: usize, b: usize) -> u8 {
    EDGES
        .iter()
        .position(|&(x, y)| (x, y) == (a, b) || (x, y) == (b, a))
        .expect("face corners are joined by a cube edge") as u8
}

fn triangulate_case(case: usize) -> Vec<[u8; 3]> {
    let inside = |c: usize| case & (1 << c) != 0;
    // Face segments: from the edge where the walk (counter-clockwise seen from outside the
    // cube) enters a run of inside corners to the edge where it leaves it.
    let mut next = [u8::MAX; 12];
    for face in FACES {
        for k in 0..4 {
            let (prev, here) = (face[(k + 3) % 4], face[k]);
            if inside(here) && !inside(prev) {
                // a run of inside corners starts at `here`: find where it ends
                let mut m = k;
                while inside(face[(m + 1) % 4]) {
                    m = (m + 1) % 4;
                }
                let enter = edge_between(prev, here);
                let leave = edge_between(face[m], face[(m + 1) % 4]);
                next[enter as usize] = leave;
            }
        }
    }
    // Chain the segments into loops and fan each loop into triangles.
    let mut used = [false; 12];
    let mut triangles = Vec::new();
    for start in 0..12 {
        if next[start] == u8::MAX || used[start] {
            continue;
        }
        let mut ring = Vec::new();
        let mut e = start;
        while !used[e] {
            used[e] = true;
            ring.push(e as u8);
            e = next[e] as usize;
        }
        for i in 1..ring.len() - 1 {
            triangles.push([ring[0], ring[i], ring[i + 1]]);
        }
    }
    triangles
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sdf::conformance::parse_node;
    use crate::sdf::lower::lower;
    use std::collections::HashMap;

    fn tape_of(src: &str) -> (Tape, Aabb) {
        let node = parse_node(src);
        let l = lower(&node, &|_| Some(0), 0).unwrap_or_else(|e| panic!("{e}"));
        (l.distance, l.bounds)
    }

    /// Every undirected edge is used by exactly two triangles, once in each direction.
    fn assert_closed_and_oriented(mesh: &SdfMesh) {
        let mut count: HashMap<(u32, u32), i32> = HashMap::new();
        for t in &mesh.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *count.entry((a, b)).or_default() += 1;
            }
        }
        for (&(a, b), &n) in &count {
            assert_eq!(n, 1, "directed edge {a}→{b} used {n} times");
            assert_eq!(
                count.get(&(b, a)),
                Some(&1),
                "edge {a}→{b} has no opposite: a crack or a flipped triangle"
            );
        }
    }

    #[test]
    fn case_table_is_complete_and_closed() {
        let table = case_table();
        assert!(table[0].is_empty() && table[255].is_empty());
        for (case, tris) in table.iter().enumerate() {
            if case != 0 && case != 255 {
                assert!(!tris.is_empty(), "case {case:08b} has no triangle");
            }
            // every crossing edge appears, and only crossing edges
            let inside = |c: usize| case & (1 << c) != 0;
            for (e, &(a, b)) in EDGES.iter().enumerate() {
                let used = tris.iter().any(|t| t.contains(&(e as u8)));
                assert_eq!(used, inside(a) != inside(b), "case {case:08b} edge {e}");
            }
        }
        // one inside corner: one triangle, facing away from that corner
        assert_eq!(table[1].len(), 1);
        // the usual count: 15 topological classes, at most 5 triangles from ≤ 12 edges
        assert!(table.iter().all(|t| t.len() <= 5));
    }

    #[test]
    fn sphere_mesh_is_watertight_outward_and_within_tolerance() {
        let (tape, bounds) =
            tape_of("Transform(translate: (0.1, -0.2, 0.05), shape: Sphere(radius: 0.8))");
        let clip = bounds.expand(1.0);
        let centre = Vec3::new(0.1, -0.2, 0.05);
        let mut tolerances = Vec::new();
        let mut unrefined_vertex_error = 0f32;
        for resolution in [16, 32, 64, 128] {
            for refine in [false, true] {
                let m = mesh_sdf(
                    &tape,
                    &bounds,
                    &clip,
                    &MeshOptions {
                        resolution,
                        refine,
                        ..MeshOptions::default()
                    },
                )
                .unwrap();
                assert!(!m.clipped);
                assert_closed_and_oriented(&m);
                let vertex_error = m
                    .positions
                    .iter()
                    .map(|p| ((*p - centre).length() - 0.8).abs())
                    .fold(0f32, f32::max);
                // Triangle interiors: sample each triangle at its centroid and edge midpoints.
                let mut point_error: f32 = 0.0;
                let mut outward = 0usize;
                for t in &m.triangles {
                    let [a, b, c] = t.map(|i| m.positions[i as usize]);
                    for p in [
                        (a + b + c) / 3.0,
                        0.5 * (a + b),
                        0.5 * (b + c),
                        0.5 * (c + a),
                    ] {
                        point_error = point_error.max(((p - centre).length() - 0.8).abs());
                    }
                    let n = (b - a).cross(c - a);
                    if n.dot((a + b + c) / 3.0 - centre) >= 0.0 {
                        outward += 1;
                    }
                }
                println!(
                    "sphere r=0.8 res {resolution:>3} refine {refine:<5}: {:>6} triangles, \
                     h {:.4}, tolerance {:.4}, max vertex error {vertex_error:.2e}, \
                     max point error {point_error:.2e}, {} evaluations",
                    m.triangles.len(),
                    m.cell,
                    m.tolerance,
                    m.evaluations
                );
                assert_eq!(outward, m.triangles.len(), "all triangles face outward");
                assert!(
                    point_error <= m.tolerance,
                    "{point_error} > {}",
                    m.tolerance
                );
                if refine {
                    assert!(
                        vertex_error <= REFINE_BRACKET * m.cell + 1e-6,
                        "{vertex_error}"
                    );
                    // refinement puts the vertices at least 10× closer than interpolation
                    // (down to f32 rounding of |p − c| near 1: a few 1e-6)
                    assert!(
                        vertex_error < (0.1 * unrefined_vertex_error).max(1e-5),
                        "{vertex_error} vs {unrefined_vertex_error} unrefined"
                    );
                    tolerances.push(m.tolerance);
                } else {
                    unrefined_vertex_error = vertex_error;
                }
            }
        }
        assert!(
            tolerances.windows(2).all(|w| w[1] < 0.6 * w[0]),
            "tolerance halves as the resolution doubles: {tolerances:?}"
        );
    }

    /// A mesh extracted at a level offset by 3× the stated tolerance is caught by the same
    /// vertex check the true mesh passes.
    #[test]
    fn offset_mesh_fails_the_tolerance_check() {
        let (tape, bounds) = tape_of("Sphere(radius: 0.8)");
        let m = mesh_sdf(
            &tape,
            &bounds,
            &bounds.expand(1.0),
            &MeshOptions {
                resolution: 64,
                ..MeshOptions::default()
            },
        )
        .unwrap();
        let inflated = 0.8 + 3.0 * m.tolerance;
        let (tape2, bounds2) = tape_of(&format!("Sphere(radius: {inflated})"));
        let m2 = mesh_sdf(
            &tape2,
            &bounds2,
            &bounds2.expand(1.0),
            &MeshOptions {
                resolution: 64,
                ..MeshOptions::default()
            },
        )
        .unwrap();
        let within = |p: &Vec3| (p.length() - 0.8).abs() <= m.tolerance;
        assert!(m.positions.iter().all(within));
        assert!(!m2.positions.iter().any(within));
    }

    #[test]
    fn csg_and_smooth_meshes_are_watertight() {
        for src in [
            "Subtraction(base: Box(half_extents: (0.65, 0.65, 0.65)), cut: Union([\
             Transform(translate: (0.65, 0.65, 0.65), shape: Sphere(radius: 0.6)), \
             Transform(rotate: (90, 0, 0), shape: Cylinder(half_height: 1, radius: 0.3))]))",
            "SmoothUnion(k: 0.25, shapes: [Box(half_extents: (0.7, 0.25, 0.7)), \
             Transform(translate: (0, 0.7, 0), shape: Sphere(radius: 0.45))])",
            "Twist(rate: 1.3, shape: Box(half_extents: (0.5, 1.1, 0.14)))",
            "Onion(thickness: 0.05, shape: Sphere(radius: 0.6))",
        ] {
            let (tape, bounds) = tape_of(src);
            let m = mesh_sdf(
                &tape,
                &bounds,
                &bounds.expand(1.0),
                &MeshOptions {
                    resolution: 96,
                    ..MeshOptions::default()
                },
            )
            .unwrap();
            assert!(m.triangles.len() > 1000, "{src}: {}", m.triangles.len());
            assert_closed_and_oriented(&m);
            // every vertex is on the surface: |f| is at most the distance to it (1-Lipschitz)
            let worst = m
                .positions
                .iter()
                .map(|p| tape.eval(*p).abs())
                .fold(0f32, f32::max);
            assert!(worst <= REFINE_BRACKET * m.cell + 1e-5, "{src}: {worst}");
        }
    }

    /// A field with structure at the scale of the cells (a high-frequency gyroid, clipped to
    /// its box, at 4–8 cells per period) meets many ambiguous faces: the mesh stays closed and
    /// consistently oriented, which is what the face rule of the table guarantees.
    #[test]
    fn ambiguous_faces_do_not_crack_the_mesh() {
        let (tape, bounds) = tape_of(
            "Implicit(expr: \"sin(9*x)*cos(9*y) + sin(9*y)*cos(9*z) + sin(9*z)*cos(9*x)\", \
             lipschitz: 22.1, half_extents: (1, 1, 1))",
        );
        let table = case_table();
        // the cases with an ambiguous face (two diagonal inside corners on one face)
        let ambiguous = |case: usize| {
            FACES.iter().any(|f| {
                let inside = f.map(|c| case & (1 << c) != 0);
                inside == [true, false, true, false] || inside == [false, true, false, true]
            })
        };
        assert!(
            (0..256)
                .filter(|&c| ambiguous(c))
                .all(|c| !table[c].is_empty())
        );
        // The field does have ambiguous cells at these scales: count them on a 16³ lattice.
        let n = 16;
        let h = (bounds.max - bounds.min) / n as f32;
        let mut ambiguous_cells = 0;
        for i in 0..n * n * n {
            let cell = Vec3::new((i % n) as f32, ((i / n) % n) as f32, (i / (n * n)) as f32);
            let case = (0..8).fold(0, |case, k| {
                let o = corner_offset(k);
                let p = bounds.min + h * (cell + Vec3::new(o[0] as f32, o[1] as f32, o[2] as f32));
                case | (((tape.eval(p) < 0.0) as usize) << k)
            });
            ambiguous_cells += ambiguous(case) as usize;
        }
        println!(
            "{ambiguous_cells} of {} lattice cells have an ambiguous face",
            n * n * n
        );
        assert!(ambiguous_cells > 50, "{ambiguous_cells}");
        for resolution in [12, 16, 24, 40] {
            let m = mesh_sdf(
                &tape,
                &bounds,
                &bounds.expand(0.5),
                &MeshOptions {
                    resolution,
                    ..MeshOptions::default()
                },
            )
            .unwrap();
            assert!(m.triangles.len() > 1000, "{}", m.triangles.len());
            assert_closed_and_oriented(&m);
        }
    }

    /// On a bound field (not an exact distance) linear interpolation misplaces vertices by a
    /// sizeable fraction of a cell; refinement moves them onto the surface. Both meshes share
    /// the grid, so their vertices correspond one to one (sorted by edge key).
    #[test]
    fn refinement_moves_vertices_of_bound_fields_onto_the_surface() {
        for src in [
            "Implicit(expr: \"0.5 - exp(-6*((x - 0.5)^2 + y^2 + z^2)) - exp(-6*((x + 0.5)^2 + \
             y^2 + z^2)) - exp(-6*(x^2 + (y - 0.55)^2 + z^2))\", half_extents: (1.2, 1.1, 0.8))",
            "SmoothUnion(k: 0.5, shapes: [Box(half_extents: (0.7, 0.25, 0.7)), \
             Transform(translate: (0, 0.7, 0), shape: Sphere(radius: 0.45))])",
        ] {
            let (tape, bounds) = tape_of(src);
            let mesh = |refine| {
                let options = MeshOptions {
                    resolution: 64,
                    refine,
                    ..MeshOptions::default()
                };
                mesh_sdf(&tape, &bounds, &bounds.expand(1.0), &options).unwrap()
            };
            let (linear, refined) = (mesh(false), mesh(true));
            assert_eq!(linear.triangles, refined.triangles);
            let moved = linear
                .positions
                .iter()
                .zip(&refined.positions)
                .map(|(a, b)| (*a - *b).length())
                .fold(0f32, f32::max);
            let residual = |m: &SdfMesh| {
                m.positions
                    .iter()
                    .map(|p| tape.eval(*p).abs())
                    .fold(0f32, f32::max)
            };
            println!(
                "{}…: refinement moves vertices by up to {:.3} cells; max |f| at vertices \
                 {:.2e} interpolated, {:.2e} refined",
                &src[..20],
                moved / refined.cell,
                residual(&linear),
                residual(&refined)
            );
            assert!(moved > 10.0 * REFINE_BRACKET * refined.cell, "{moved}");
            assert!(residual(&refined) < 0.1 * residual(&linear));
        }
    }

    /// An infinite slab clipped to a box is meshed inside the box only, open at its faces:
    /// no walls where the box cuts it.
    #[test]
    fn unbounded_object_is_clipped_without_walls() {
        let (tape, bounds) = tape_of("Plane(normal: (0, 1, 0), offset: 0.3)");
        assert!(!bounds.is_finite());
        let clip = Aabb::new(Vec3::new(-2.0, -1.0, -1.5), Vec3::new(2.0, 1.0, 1.5));
        let m = mesh_sdf(
            &tape,
            &bounds,
            &clip,
            &MeshOptions {
                resolution: 32,
                ..MeshOptions::default()
            },
        )
        .unwrap();
        assert!(m.clipped);
        // all vertices on the plane y = 0.3, none on a wall
        for p in &m.positions {
            assert!((p.y - 0.3).abs() < 1e-3 * m.cell + 1e-6, "{p}");
        }
        // the sheet covers the clip box's width and depth
        let lo = m.positions.iter().fold(Vec3::INFINITY, |a, p| a.min(*p));
        let hi = m
            .positions
            .iter()
            .fold(Vec3::NEG_INFINITY, |a, p| a.max(*p));
        assert!(
            lo.x <= -2.0 && hi.x >= 2.0 && lo.z <= -1.5 && hi.z >= 1.5,
            "{lo} {hi}"
        );
        assert!(m.region.min.cmple(clip.min).all() && m.region.max.cmpge(clip.max).all());
    }

    #[test]
    fn degenerate_input_is_an_error_or_empty() {
        let (tape, bounds) = tape_of("Sphere(radius: 1)");
        assert!(mesh_sdf(&tape, &bounds, &Aabb::INFINITE, &MeshOptions::default()).is_err());
        let far = Aabb::new(Vec3::splat(10.0), Vec3::splat(11.0));
        let m = mesh_sdf(&tape, &bounds, &far, &MeshOptions::default()).unwrap();
        assert!(m.triangles.is_empty());
        let zero = MeshOptions {
            resolution: 0,
            ..MeshOptions::default()
        };
        assert!(mesh_sdf(&tape, &bounds, &bounds, &zero).is_err());
    }

    #[test]
    fn triangle_budget_lowers_the_resolution() {
        let (tape, bounds) = tape_of("Sphere(radius: 1)");
        let m = mesh_sdf(
            &tape,
            &bounds,
            &bounds.expand(1.0),
            &MeshOptions {
                resolution: 128,
                max_triangles: 20_000,
                ..MeshOptions::default()
            },
        )
        .unwrap();
        assert!(m.triangles.len() <= 20_000, "{}", m.triangles.len());
        assert!(m.resolution < 128);
        assert_closed_and_oriented(&m);
    }
}
