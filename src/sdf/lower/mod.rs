//! Lowering: SDF tree → tape. The one place where every SDF formula is written down.
//!
//! The tree is emitted as SSA ([`crate::sdf::ssa`]) with constants folded and repeated
//! subexpressions shared as it goes; [`crate::sdf::ssa::SsaTape::compile`] then removes dead
//! code (a distance-only tape drops all material work) and assigns registers. Both backends run
//! the resulting [`Tape`]; nothing here is backend specific.
//!
//! - [`bounds`]: conservative bounds of every node.
//! - [`emit`]: the scalar and 3-vector shorthands the formulas are written in.
//! - [`shapes`]: primitives and the CSG combinations (Quilez's catalogue).
//! - [`domain`]: domain operators — repetition, twist, bend — and the Lipschitz clip.
//! - [`implicit`]: implicit-surface expressions and their Lipschitz estimate.

pub mod bounds;
pub mod domain;
pub mod emit;
pub mod implicit;
pub mod shapes;

pub use bounds::{bounds, transform_of};
pub use implicit::{check_defined, estimate_lipschitz};

use crate::geom::Aabb;
use crate::sdf::expr;
use crate::sdf::node::SdfNode;
use crate::sdf::ssa::{Builder, M, SsaTape, V};
use crate::sdf::tape::Tape;
use emit::{Emit, V3};
use glam::Vec3;
use shapes::Out;

/// Most operations a lowered program may have (4 Mi, about 200 MiB while lowering): a union
/// of a hundred thousand primitives takes about 1.5 Mi.
pub const MAX_OPERATIONS: usize = 4 << 20;

/// Why a tree could not be lowered, and where: `path` leads from the root to the node (and,
/// where one value is at fault, its field), so the scene loader can point at the text.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}: {message}", display_path(path))]
pub struct LowerError {
    /// Where in the tree.
    pub path: Vec<Step>,
    /// What is wrong.
    pub message: String,
}

/// One step of a path into an SDF tree as written in the scene file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Step {
    /// A node of this kind (`Union`, `Torus`...).
    Node(&'static str),
    /// A named field of the current node (`shape`, `base`, `radius`...).
    Field(&'static str),
    /// An element of the current list (`Union([…])` or `shapes: […]`).
    Index(usize),
}

fn display_path(path: &[Step]) -> String {
    if path.is_empty() {
        return "shape".to_string();
    }
    let mut s = String::new();
    for step in path {
        match step {
            Step::Node(k) => {
                if !s.is_empty() {
                    s += " > ";
                }
                s += k;
            }
            Step::Field(f) => {
                s += ".";
                s += f;
            }
            Step::Index(i) => s += &format!("[{i}]"),
        }
    }
    s
}

/// Both tapes of one SDF object, and the distance program they come from.
#[derive(Debug, Clone, PartialEq)]
pub struct LoweredSdf {
    /// Distance only: what the sphere tracer, normals and shadows evaluate.
    pub distance: Tape,
    /// Distance and blended material: evaluated once per shaded hit.
    pub shading: Tape,
    /// The shading tape in SSA form (distance and material): what region specialisation
    /// simplifies.
    pub program: SsaTape,
    /// Conservative object-space bounds of the surface (may be infinite).
    pub bounds: Aabb,
    /// Whether the distance is a convex function of the point ([`SdfNode::is_convex`]).
    pub convex: bool,
}

/// Lowers `node` with the object-to-world transform already folded in by the caller (use
/// [`SdfNode::Transform`]). `material_index` resolves material names; `default_material` paints
/// shapes that no `Material` node covers.
pub fn lower(
    node: &SdfNode,
    material_index: &dyn Fn(&str) -> Option<u32>,
    default_material: u32,
) -> Result<LoweredSdf, LowerError> {
    let mut b = Builder::new();
    let mut cx = Context {
        material_index,
        path: Vec::new(),
    };
    let point = V3(b.point());
    let out = cx.node(&mut b, node, point, default_material)?;
    let bounds = bounds(node)?;
    let program = compact(&b.finish(out.d, Some(out.m)));
    let distance = program.distance_only().compile().map_err(|m| cx.error(m))?;
    let shading = program.compile().map_err(|m| cx.error(m))?;
    Ok(LoweredSdf {
        distance,
        shading,
        program,
        bounds,
        convex: node.is_convex(),
    })
}

/// The live operations of a program only, renumbered (the distance program of a shading build
/// still holds the material operations).
pub fn compact(p: &SsaTape) -> SsaTape {
    let live = p.live();
    let mut b = Builder::new();
    let mut map = vec![0u32; p.ops.len()];
    for (i, op) in p.ops.iter().enumerate() {
        if live[i] {
            map[i] = b.rebuild(op, |v| map[v as usize]);
        }
    }
    let result = V(map[p.result as usize]);
    let material = p.material.map(|m| M(map[m as usize]));
    b.finish(result, material)
}

pub(crate) struct Context<'a> {
    material_index: &'a dyn Fn(&str) -> Option<u32>,
    path: Vec<Step>,
}

impl Context<'_> {
    fn error(&self, message: impl Into<String>) -> LowerError {
        LowerError {
            path: self.path.clone(),
            message: message.into(),
        }
    }

    /// An error about one field of the current node.
    fn field_error(&self, field: &'static str, message: impl Into<String>) -> LowerError {
        let mut e = self.error(message);
        e.path.push(Step::Field(field));
        e
    }

    /// Bounds of a subtree, with errors placed at the current node.
    fn bounds(&self, node: &SdfNode) -> Result<Aabb, LowerError> {
        bounds(node).map_err(|e| self.error(e.message))
    }

    fn node(
        &mut self,
        b: &mut Builder,
        node: &SdfNode,
        p: V3,
        mat: u32,
    ) -> Result<Out, LowerError> {
        self.path.push(Step::Node(node.kind()));
        // Repetition evaluates its child once per neighbouring cell, so nested repetitions
        // multiply: refuse before the program outgrows memory, at the node that overflows.
        if b.len() > MAX_OPERATIONS {
            return Err(self.error(format!(
                "too complex: the tape would exceed {MAX_OPERATIONS} operations (nested \
                 repetitions multiply their child; use fewer levels or fewer shapes)"
            )));
        }
        let out = self.node_inner(b, node, p, mat)?;
        self.path.pop();
        Ok(out)
    }

    /// Lowers the child held in field `field` of the current node.
    fn child(
        &mut self,
        b: &mut Builder,
        field: &'static str,
        node: &SdfNode,
        p: V3,
        mat: u32,
    ) -> Result<Out, LowerError> {
        self.path.push(Step::Field(field));
        let out = self.node(b, node, p, mat)?;
        self.path.pop();
        Ok(out)
    }

    /// Lowers a list of children and folds them with `combine` as it goes, so that only the
    /// running result and the newest child are live: a union of hundreds of shapes needs no
    /// more registers than a union of two.
    fn fold_children(
        &mut self,
        b: &mut Builder,
        field: Option<&'static str>,
        shapes: &[SdfNode],
        p: V3,
        mat: u32,
        combine: impl Fn(&mut Builder, Out, Out) -> Out,
    ) -> Result<Out, LowerError> {
        if shapes.is_empty() {
            return Err(self.error("needs at least one shape"));
        }
        if let Some(f) = field {
            self.path.push(Step::Field(f));
        }
        let mut acc: Option<Out> = None;
        for (i, s) in shapes.iter().enumerate() {
            self.path.push(Step::Index(i));
            let out = self.node(b, s, p, mat)?;
            self.path.pop();
            acc = Some(match acc {
                None => out,
                Some(a) => combine(b, a, out),
            });
        }
        if field.is_some() {
            self.path.pop();
        }
        Ok(acc.expect("shapes is not empty"))
    }

    /// Lowers the children of a union or an intersection as a balanced tree ordered like a
    /// BVH over their bounds (median splits along the longest axis of their centres), not as
    /// a chain: min and max are associative, so the value is the chain's, but interval
    /// evaluation over a small box can then drop whole far halves at once — a chain keeps every
    /// shape that comes before the nearest one — and region specialisation finds short tapes.
    /// Children are lowered in tree order, so at most one pending value per level is live.
    fn fold_balanced(
        &mut self,
        b: &mut Builder,
        shapes: &[SdfNode],
        p: V3,
        mat: u32,
        combine: fn(&mut Builder, Out, Out) -> Out,
    ) -> Result<Out, LowerError> {
        if shapes.is_empty() {
            return Err(self.error("needs at least one shape"));
        }
        let centres: Vec<Vec3> = shapes
            .iter()
            .map(|s| {
                let c = bounds(s).map(|a| a.center()).unwrap_or(Vec3::ZERO);
                Vec3::select(c.is_finite_mask(), c, Vec3::ZERO)
            })
            .collect();
        let mut order: Vec<usize> = (0..shapes.len()).collect();
        self.fold_range(b, shapes, &centres, &mut order, p, mat, combine)
    }

    #[allow(clippy::too_many_arguments)]
    fn fold_range(
        &mut self,
        b: &mut Builder,
        shapes: &[SdfNode],
        centres: &[Vec3],
        order: &mut [usize],
        p: V3,
        mat: u32,
        combine: fn(&mut Builder, Out, Out) -> Out,
    ) -> Result<Out, LowerError> {
        if let [i] = order {
            self.path.push(Step::Index(*i));
            let out = self.node(b, &shapes[*i], p, mat)?;
            self.path.pop();
            return Ok(out);
        }
        let (lo, hi) = order.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), &i| (lo.min(centres[i]), hi.max(centres[i])),
        );
        let extent = hi - lo;
        let axis = if extent.x >= extent.y && extent.x >= extent.z {
            0
        } else if extent.y >= extent.z {
            1
        } else {
            2
        };
        // stable: equal centres keep the file's order
        order.sort_by(|&a, &c| centres[a][axis].total_cmp(&centres[c][axis]));
        let mid = order.len() / 2;
        let (left, right) = order.split_at_mut(mid);
        let l = self.fold_range(b, shapes, centres, left, p, mat, combine)?;
        let r = self.fold_range(b, shapes, centres, right, p, mat, combine)?;
        Ok(combine(b, l, r))
    }

    fn node_inner(
        &mut self,
        b: &mut Builder,
        node: &SdfNode,
        p: V3,
        mat: u32,
    ) -> Result<Out, LowerError> {
        use SdfNode::*;
        let leaf = |b: &mut Builder, d: V| Out::leaf(b, d, mat);
        Ok(match node {
            Sphere { radius } => {
                let l = b.length(&p.0);
                let d = b.sub_k(l, radius.0);
                leaf(b, d)
            }
            Cuboid { half_extents } => {
                let d = shapes::box_distance(b, p, half_extents.0);
                leaf(b, d)
            }
            RoundBox {
                half_extents,
                radius,
            } => {
                let r = radius.0;
                if r > half_extents.0.min_element() {
                    return Err(self.field_error(
                        "radius",
                        format!(
                            "radius {r} exceeds the smallest half-extent {}",
                            half_extents.0.min_element()
                        ),
                    ));
                }
                // Quilez sdRoundBox: a box shrunk by r, inflated by r.
                let inner = shapes::box_distance(b, p, half_extents.0 - Vec3::splat(r));
                let d = b.sub_k(inner, r);
                leaf(b, d)
            }
            Plane { normal, offset } => {
                let dp = b.dot_k(p, normal.0);
                let d = b.sub_k(dp, offset.0);
                leaf(b, d)
            }
            Torus { major, minor } => {
                if minor.0 > major.0 {
                    return Err(self.field_error(
                        "minor",
                        format!(
                            "minor radius {} exceeds major radius {} (self-intersecting torus)",
                            minor.0, major.0
                        ),
                    ));
                }
                let d = shapes::torus(b, p, major.0, minor.0);
                leaf(b, d)
            }
            Cylinder {
                half_height,
                radius,
            } => {
                let d = shapes::cylinder_y(b, p, half_height.0, radius.0);
                leaf(b, d)
            }
            Cone {
                half_height,
                bottom_radius,
                top_radius,
            } => {
                if bottom_radius.0 == 0.0 && top_radius.0 == 0.0 {
                    return Err(
                        self.field_error("top_radius", "bottom_radius and top_radius are both 0")
                    );
                }
                let d = shapes::capped_cone(b, p, half_height.0, bottom_radius.0, top_radius.0);
                leaf(b, d)
            }
            Capsule { a, b: end, radius } => {
                let d = shapes::capsule(b, p, a.0, end.0, radius.0);
                leaf(b, d)
            }
            Ellipsoid { radii } => {
                let d = shapes::ellipsoid(b, p, radii.0);
                leaf(b, d)
            }
            Octahedron { size } => {
                let d = shapes::octahedron(b, p, size.0);
                leaf(b, d)
            }
            HexPrism {
                radius,
                half_length,
            } => {
                let d = shapes::hex_prism(b, p, radius.0, half_length.0);
                leaf(b, d)
            }
            Union(list) => self.fold_balanced(b, list, p, mat, shapes::union)?,
            Intersection(list) => self.fold_balanced(b, list, p, mat, shapes::intersection)?,
            Subtraction { base, cut } => {
                let a = self.child(b, "base", base, p, mat)?;
                let c = self.child(b, "cut", cut, p, mat)?;
                let nc = b.neg(c.d);
                Out {
                    d: b.max(a.d, nc),
                    m: a.m,
                }
            }
            SmoothUnion { k, shapes: list } => {
                let k = k.0;
                self.fold_children(b, Some("shapes"), list, p, mat, |b, x, y| {
                    shapes::smooth_min(b, x, y, k)
                })?
            }
            SmoothIntersection { k, shapes: list } => {
                let k = k.0;
                self.fold_children(b, Some("shapes"), list, p, mat, |b, x, y| {
                    shapes::smooth_max(b, x, y, k)
                })?
            }
            SmoothSubtraction { k, base, cut } => {
                let a = self.child(b, "base", base, p, mat)?;
                let c = self.child(b, "cut", cut, p, mat)?;
                let nc = Out {
                    d: b.neg(c.d),
                    m: a.m,
                };
                let out = shapes::smooth_max(b, a, nc, k.0);
                Out { d: out.d, m: a.m }
            }
            Round { radius, shape } => {
                let c = self.child(b, "shape", shape, p, mat)?;
                Out {
                    d: b.sub_k(c.d, radius.0),
                    m: c.m,
                }
            }
            Onion { thickness, shape } => {
                let c = self.child(b, "shape", shape, p, mat)?;
                let a = b.abs(c.d);
                Out {
                    d: b.sub_k(a, thickness.0),
                    m: c.m,
                }
            }
            Transform { shape, .. } => {
                let (m, s) = transform_of(node);
                let q = b.affine(p, &m.inverse());
                let c = self.child(b, "shape", shape, q, mat)?;
                // Uniform scale: distances in object space are 1/s of world distances.
                Out {
                    d: b.mul_k(c.d, s),
                    m: c.m,
                }
            }
            Scale { factors, shape } => {
                let q = b.v_div_k(p, factors.0);
                let c = self.child(b, "shape", shape, q, mat)?;
                // f(p/s) is (1/min s)-Lipschitz; multiplying by min s restores λ = 1.
                Out {
                    d: b.mul_k(c.d, factors.0.min_element()),
                    m: c.m,
                }
            }
            Repeat { period, shape } => {
                let c = Vec3::new(period.0.0, period.1.0, period.2.0);
                if c == Vec3::ZERO {
                    return Err(self
                        .field_error("period", "period is 0 on every axis: nothing is repeated"));
                }
                self.repeat(b, node, shape, p, mat, c, None)?
            }
            RepeatLimited {
                period,
                copies_each_side,
                shape,
            } => {
                let n = Vec3::new(
                    copies_each_side.0 as f32,
                    copies_each_side.1 as f32,
                    copies_each_side.2 as f32,
                );
                // An axis with no copies on either side is not repeated at all.
                let c = Vec3::select(n.cmpgt(Vec3::ZERO), period.0, Vec3::ZERO);
                if c == Vec3::ZERO {
                    return self.child(b, "shape", shape, p, mat);
                }
                self.repeat(b, node, shape, p, mat, c, Some(n))?
            }
            Twist { rate, shape } => self.twist(b, node, shape, p, mat, rate.0)?,
            Bend { rate, shape } => self.bend(b, node, shape, p, mat, rate.0)?,
            Implicit {
                expr: source,
                lipschitz,
                half_extents,
            } => {
                let e = expr::parse(source)
                    .map_err(|e| {
                        self.field_error("expr", format!("in expression `{}`: {e}", quoted(source)))
                    })?
                    .fold_constants();
                // (the sampling below would overflow: points of a box past f32's range are NaN)
                let limit = crate::geom::LARGEST_TREE_COORDINATE;
                if half_extents.0.max_element() > limit {
                    return Err(self.field_error(
                        "half_extents",
                        format!(
                            "({:e}, {:e}, {:e}) reaches beyond ±{limit:e}, the largest \
                             coordinate the renderer builds its trees over",
                            half_extents.0.x, half_extents.0.y, half_extents.0.z
                        ),
                    ));
                }
                check_defined(&e, half_extents.0).map_err(|m| {
                    self.field_error("expr", format!("in expression `{}`: {m}", quoted(source)))
                })?;
                let lambda = match lipschitz {
                    Some(l) => l.0,
                    None => estimate_lipschitz(&e, half_extents.0).map_err(|m| {
                        self.field_error("expr", format!("in expression `{}`: {m}", quoted(source)))
                    })?,
                };
                let d = implicit::clipped(b, &e, p, half_extents.0, lambda);
                leaf(b, d)
            }
            Material { name, shape } => {
                let m = (self.material_index)(name).ok_or_else(|| {
                    self.field_error("name", format!("unknown material \"{name}\""))
                })?;
                self.child(b, "shape", shape, p, m)?
            }
        })
    }
}

/// `(x, y, z)` for messages.
fn fmt3(v: Vec3) -> String {
    format!("({}, {}, {})", v.x, v.y, v.z)
}

/// An expression as an error quotes it: whole when short, else its first [`QUOTED`]
/// characters and an ellipsis (a generated expression made error lines of 10 KB; a parse
/// error's column still counts in the whole text).
fn quoted(source: &str) -> String {
    match source.char_indices().nth(QUOTED) {
        Some((end, _)) => format!("{}…", &source[..end]),
        None => source.to_string(),
    }
}

/// Most characters of an expression an error quotes.
const QUOTED: usize = 60;
