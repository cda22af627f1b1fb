//! Lowering: SDF tree → tape. The one place where every SDF formula is written down.
//!
//! The tree is first emitted as SSA (every operation gets a fresh value), then dead code is
//! removed (a distance-only tape drops all material work) and registers are assigned by a
//! linear scan that reuses a register as soon as its last reader has run. Both backends run the
//! resulting [`Tape`]; nothing here is backend specific.

use crate::geom::Aabb;
use crate::sdf::expr::{self, BinaryOp, Expr, UnaryOp};
use crate::sdf::node::SdfNode;
use crate::sdf::tape::{IMM, Instr, MAX_MATERIAL_REGISTERS, MAX_REGISTERS, Op, Tape};
use glam::{Affine3A, Quat, Vec3, Vec4};

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

/// Both tapes of one SDF object.
#[derive(Debug, Clone, PartialEq)]
pub struct LoweredSdf {
    /// Distance only: what the sphere tracer, normals and shadows evaluate.
    pub distance: Tape,
    /// Distance and blended material: evaluated once per shaded hit.
    pub shading: Tape,
    /// Conservative object-space bounds of the surface (may be infinite).
    pub bounds: Aabb,
}

/// Lowers `node` with the object-to-world transform already folded in by the caller (use
/// [`SdfNode::Transform`]). `material_index` resolves material names; `default_material` paints
/// shapes that no `Material` node covers.
pub fn lower(
    node: &SdfNode,
    material_index: &dyn Fn(&str) -> Option<u32>,
    default_material: u32,
) -> Result<LoweredSdf, LowerError> {
    let mut b = Builder::default();
    let mut cx = Context {
        material_index,
        path: Vec::new(),
    };
    let point = b.input();
    let out = cx.node(&mut b, node, point, default_material)?;
    let bounds = bounds(node)?;
    let distance = b.finish(out.d, None).map_err(|m| cx.error(m))?;
    let shading = b.finish(out.d, Some(out.m)).map_err(|m| cx.error(m))?;
    Ok(LoweredSdf {
        distance,
        shading,
        bounds,
    })
}

/// Conservative bounds of a node's surface in its own space.
pub fn bounds(node: &SdfNode) -> Result<Aabb, LowerError> {
    use SdfNode::*;
    let child = |n: &SdfNode| bounds(n);
    Ok(match node {
        Sphere { radius } => Aabb::symmetric(Vec3::splat(radius.0)),
        Cuboid { half_extents } | RoundBox { half_extents, .. } => Aabb::symmetric(half_extents.0),
        Plane { .. } => Aabb::INFINITE,
        Torus { major, minor } => {
            let r = major.0 + minor.0;
            Aabb::symmetric(Vec3::new(r, minor.0, r))
        }
        Cylinder {
            half_height,
            radius,
        } => Aabb::symmetric(Vec3::new(radius.0, half_height.0, radius.0)),
        Cone {
            half_height,
            bottom_radius,
            top_radius,
        } => {
            let r = bottom_radius.0.max(top_radius.0);
            Aabb::symmetric(Vec3::new(r, half_height.0, r))
        }
        Capsule { a, b, radius } => Aabb::new(a.0.min(b.0), a.0.max(b.0)).expand(radius.0),
        Ellipsoid { radii } => Aabb::symmetric(radii.0),
        Octahedron { size } => Aabb::symmetric(Vec3::splat(size.0)),
        HexPrism {
            radius,
            half_length,
        } => {
            // circumradius of a hexagon with apothem r is 2r/√3
            let c = radius.0 * 2.0 / 3f32.sqrt();
            Aabb::symmetric(Vec3::new(c, c, half_length.0))
        }
        Union(v) => v
            .iter()
            .try_fold(Aabb::EMPTY, |acc, n| Ok(acc.union(&child(n)?)))?,
        Intersection(v) => v
            .iter()
            .try_fold(Aabb::INFINITE, |acc, n| Ok(acc.intersection(&child(n)?)))?,
        Subtraction { base, .. } | SmoothSubtraction { base, .. } => child(base)?,
        // smin(a, b) ≥ min(a, b) − k/4, so the blend grows each child by at most k/4.
        SmoothUnion { k, shapes } => shapes
            .iter()
            .try_fold(Aabb::EMPTY, |acc, n| Ok(acc.union(&child(n)?)))?
            .expand(k.0 * 0.25),
        SmoothIntersection { shapes, .. } => shapes
            .iter()
            .try_fold(Aabb::INFINITE, |acc, n| Ok(acc.intersection(&child(n)?)))?,
        Round { radius, shape } => child(shape)?.expand(radius.0),
        Onion { thickness, shape } => child(shape)?.expand(thickness.0),
        Transform { .. } => child_of_transform(node)?,
        Scale { factors, shape } => {
            let c = child(shape)?;
            Aabb::new(c.min * factors.0, c.max * factors.0)
        }
        Repeat { period, shape } => {
            let c = child(shape)?;
            let p = [period.0.0, period.1.0, period.2.0];
            let mut out = c;
            for (i, &pi) in p.iter().enumerate() {
                if pi > 0.0 {
                    out.min[i] = f32::NEG_INFINITY;
                    out.max[i] = f32::INFINITY;
                }
            }
            out
        }
        RepeatLimited {
            period,
            copies_each_side,
            shape,
        } => {
            let c = child(shape)?;
            let n = Vec3::new(
                copies_each_side.0 as f32,
                copies_each_side.1 as f32,
                copies_each_side.2 as f32,
            );
            Aabb::new(c.min - n * period.0, c.max + n * period.0)
        }
        Twist { shape, .. } => {
            let c = finite_child(shape, "Twist")?;
            let r = max_radius(&c, [0, 2]);
            Aabb::new(Vec3::new(-r, c.min.y, -r), Vec3::new(r, c.max.y, r))
        }
        Bend { shape, .. } => {
            let c = finite_child(shape, "Bend")?;
            let r = max_radius(&c, [0, 1]);
            Aabb::new(Vec3::new(-r, -r, c.min.z), Vec3::new(r, r, c.max.z))
        }
        Implicit { half_extents, .. } => Aabb::symmetric(half_extents.0),
        Material { shape, .. } => child(shape)?,
    })
}

fn child_of_transform(node: &SdfNode) -> Result<Aabb, LowerError> {
    let SdfNode::Transform { shape, .. } = node else {
        unreachable!("called on Transform nodes only")
    };
    let (m, _) = transform_of(node);
    Ok(bounds(shape)?.transformed(&m))
}

fn finite_child(shape: &SdfNode, what: &'static str) -> Result<Aabb, LowerError> {
    let c = bounds(shape)?;
    if c.is_finite() && !c.is_empty() {
        Ok(c)
    } else {
        Err(LowerError {
            path: Vec::new(),
            message: format!(
                "{what} needs a bounded child (its Lipschitz correction depends on the child's \
                 size), but `{}` is unbounded",
                shape.kind()
            ),
        })
    }
}

/// Largest distance from the axis orthogonal to lanes `axes` over the box corners.
fn max_radius(b: &Aabb, axes: [usize; 2]) -> f32 {
    b.corners()
        .iter()
        .map(|c| (c[axes[0]] * c[axes[0]] + c[axes[1]] * c[axes[1]]).sqrt())
        .fold(0.0, f32::max)
}

/// The object-to-parent affine map of a `Transform` node and its uniform scale.
pub fn transform_of(node: &SdfNode) -> (Affine3A, f32) {
    let SdfNode::Transform {
        translate,
        rotate,
        scale,
        ..
    } = node
    else {
        return (Affine3A::IDENTITY, 1.0);
    };
    let r = rotate.map(|r| r.0).unwrap_or(Vec3::ZERO);
    let q = Quat::from_rotation_z(r.z.to_radians())
        * Quat::from_rotation_y(r.y.to_radians())
        * Quat::from_rotation_x(r.x.to_radians());
    let s = scale.map(|s| s.0).unwrap_or(1.0);
    let t = translate.map(|t| t.0).unwrap_or(Vec3::ZERO);
    (
        Affine3A::from_scale_rotation_translation(Vec3::splat(s), q, t),
        s,
    )
}

// ---------------------------------------------------------------------------------------------
// SSA builder

/// An SSA value (value register before allocation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct V(u32);
/// An SSA material value.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct M(u32);

#[derive(Debug, Clone, Copy)]
enum B {
    V(V),
    Imm([f32; 4]),
}

#[derive(Debug, Clone, Copy)]
struct Ssa {
    op: Op,
    dst: u32,
    a: u32,
    b: Option<u32>,
    c: u32,
    aux: u32,
    imm: [f32; 4],
}

impl Ssa {
    fn is_material(&self) -> bool {
        matches!(self.op, Op::MatLoad | Op::MatMix)
    }
    /// Value operands read by this instruction.
    fn value_reads(&self) -> Vec<u32> {
        match self.op {
            Op::Const | Op::MatLoad => vec![],
            Op::MatMix => vec![self.c],
            Op::MulAdd | Op::Select | Op::Pack => {
                let mut v = vec![self.a, self.c];
                v.extend(self.b);
                v
            }
            _ => {
                let mut v = vec![self.a];
                v.extend(self.b);
                v
            }
        }
    }
    fn material_reads(&self) -> Vec<u32> {
        match self.op {
            Op::MatMix => vec![self.a, self.b.expect("MatMix has two material operands")],
            _ => vec![],
        }
    }
}

#[derive(Default)]
struct Builder {
    code: Vec<Ssa>,
    constants: Vec<[f32; 4]>,
    next_value: u32,
    next_material: u32,
}

impl Builder {
    fn input(&mut self) -> V {
        assert_eq!(self.next_value, 0, "the input point is value 0");
        self.next_value = 1;
        V(0)
    }

    fn emit(&mut self, op: Op, a: V, b: Option<B>, c: V, aux: u32, imm: [f32; 4]) -> V {
        let dst = self.next_value;
        self.next_value += 1;
        let (b, imm) = match b {
            None => (None, imm),
            Some(B::V(v)) => (Some(v.0), imm),
            Some(B::Imm(i)) => (Some(IMM), i),
        };
        self.code.push(Ssa {
            op,
            dst,
            a: a.0,
            b,
            c: c.0,
            aux,
            imm,
        });
        V(dst)
    }

    fn un(&mut self, op: Op, a: V) -> V {
        self.emit(op, a, None, a, 0, [0.0; 4])
    }
    fn bin(&mut self, op: Op, a: V, b: V) -> V {
        self.emit(op, a, Some(B::V(b)), a, 0, [0.0; 4])
    }
    fn bin_s(&mut self, op: Op, a: V, s: f32) -> V {
        self.emit(op, a, Some(B::Imm([s; 4])), a, 0, [0.0; 4])
    }
    fn bin_v(&mut self, op: Op, a: V, v: Vec3) -> V {
        self.emit(
            op,
            a,
            Some(B::Imm(v.extend(0.0).to_array())),
            a,
            0,
            [0.0; 4],
        )
    }
    fn konst(&mut self, v: Vec4) -> V {
        self.emit(Op::Const, V(0), None, V(0), 0, v.to_array())
    }
    fn splat(&mut self, s: f32) -> V {
        self.konst(Vec4::splat(s))
    }
    fn add(&mut self, a: V, b: V) -> V {
        self.bin(Op::Add, a, b)
    }
    fn sub(&mut self, a: V, b: V) -> V {
        self.bin(Op::Sub, a, b)
    }
    fn mul(&mut self, a: V, b: V) -> V {
        self.bin(Op::Mul, a, b)
    }
    fn min(&mut self, a: V, b: V) -> V {
        self.bin(Op::Min, a, b)
    }
    fn max(&mut self, a: V, b: V) -> V {
        self.bin(Op::Max, a, b)
    }
    fn add_s(&mut self, a: V, s: f32) -> V {
        self.bin_s(Op::Add, a, s)
    }
    fn sub_s(&mut self, a: V, s: f32) -> V {
        self.bin_s(Op::Sub, a, s)
    }
    fn mul_s(&mut self, a: V, s: f32) -> V {
        self.bin_s(Op::Mul, a, s)
    }
    fn min_s(&mut self, a: V, s: f32) -> V {
        self.bin_s(Op::Min, a, s)
    }
    fn max_s(&mut self, a: V, s: f32) -> V {
        self.bin_s(Op::Max, a, s)
    }
    fn clamp_s(&mut self, a: V, lo: f32, hi: f32) -> V {
        let t = self.max_s(a, lo);
        self.min_s(t, hi)
    }
    fn neg(&mut self, a: V) -> V {
        self.un(Op::Neg, a)
    }
    fn abs(&mut self, a: V) -> V {
        self.un(Op::Abs, a)
    }
    fn mul_add(&mut self, a: V, b: V, c: V) -> V {
        self.emit(Op::MulAdd, a, Some(B::V(b)), c, 0, [0.0; 4])
    }
    /// (c.x > 0) ? a : b
    fn select(&mut self, c: V, a: V, b: V) -> V {
        self.emit(Op::Select, a, Some(B::V(b)), c, 0, [0.0; 4])
    }
    /// Lanes by name: "xzy", "y", "xz0"... (missing lanes are zero).
    fn swz(&mut self, a: V, lanes: &str) -> V {
        let mut pattern = 0u32;
        for i in 0..4 {
            let s = match lanes.as_bytes().get(i) {
                Some(b'x') => 0,
                Some(b'y') => 1,
                Some(b'z') => 2,
                Some(b'w') => 3,
                _ => 4,
            };
            pattern |= s << (3 * i);
        }
        self.emit(Op::Swizzle, a, None, a, pattern, [0.0; 4])
    }
    /// (a[la], b[lb], c[lc], 0) with lanes 0–3.
    fn pack(&mut self, a: V, la: u32, b: V, lb: u32, c: V, lc: u32) -> V {
        self.emit(
            Op::Pack,
            a,
            Some(B::V(b)),
            c,
            la | (lb << 2) | (lc << 4),
            [0.0; 4],
        )
    }
    fn length2(&mut self, a: V) -> V {
        self.emit(Op::Length, a, None, a, 2, [0.0; 4])
    }
    fn length3(&mut self, a: V) -> V {
        self.emit(Op::Length, a, None, a, 3, [0.0; 4])
    }
    fn max_lane2(&mut self, a: V) -> V {
        self.emit(Op::MaxLane, a, None, a, 2, [0.0; 4])
    }
    fn max_lane3(&mut self, a: V) -> V {
        self.emit(Op::MaxLane, a, None, a, 3, [0.0; 4])
    }
    fn min_lane3(&mut self, a: V) -> V {
        let n = self.neg(a);
        let m = self.max_lane3(n);
        self.neg(m)
    }
    fn dot3_v(&mut self, a: V, v: Vec3) -> V {
        self.emit(
            Op::Dot3,
            a,
            Some(B::Imm(v.extend(0.0).to_array())),
            a,
            0,
            [0.0; 4],
        )
    }
    fn affine(&mut self, a: V, m: &Affine3A) -> V {
        let k = self.constants.len() as u32;
        let cols = m.matrix3;
        for row in 0..3 {
            self.constants.push([
                cols.x_axis[row],
                cols.y_axis[row],
                cols.z_axis[row],
                m.translation[row],
            ]);
        }
        self.emit(Op::Affine, a, None, a, k, [0.0; 4])
    }
    fn mat_load(&mut self, material: u32) -> M {
        let dst = self.next_material;
        self.next_material += 1;
        self.code.push(Ssa {
            op: Op::MatLoad,
            dst,
            a: 0,
            b: None,
            c: 0,
            aux: material,
            imm: [0.0; 4],
        });
        M(dst)
    }
    fn mat_mix(&mut self, a: M, b: M, h: V) -> M {
        let dst = self.next_material;
        self.next_material += 1;
        self.code.push(Ssa {
            op: Op::MatMix,
            dst,
            a: a.0,
            b: Some(b.0),
            c: h.0,
            aux: 0,
            imm: [0.0; 4],
        });
        M(dst)
    }

    /// Dead-code elimination and linear-scan register allocation into a [`Tape`].
    fn finish(&self, result: V, material: Option<M>) -> Result<Tape, String> {
        let n = self.code.len();
        // Backward liveness over SSA: an instruction is kept if its destination is read later.
        let mut live_v = vec![false; self.next_value as usize];
        let mut live_m = vec![false; self.next_material as usize];
        live_v[result.0 as usize] = true;
        if let Some(m) = material {
            live_m[m.0 as usize] = true;
        }
        let mut keep = vec![false; n];
        for (i, ins) in self.code.iter().enumerate().rev() {
            let needed = if ins.is_material() {
                material.is_some() && live_m[ins.dst as usize]
            } else {
                live_v[ins.dst as usize]
            };
            if !needed {
                continue;
            }
            keep[i] = true;
            for r in ins.value_reads() {
                if r != IMM {
                    live_v[r as usize] = true;
                }
            }
            for r in ins.material_reads() {
                live_m[r as usize] = true;
            }
        }
        // Last reader of every SSA value among the kept instructions.
        let mut last_v = vec![usize::MAX; self.next_value as usize];
        let mut last_m = vec![usize::MAX; self.next_material as usize];
        for (i, ins) in self.code.iter().enumerate().filter(|(i, _)| keep[*i]) {
            for r in ins.value_reads() {
                if r != IMM {
                    last_v[r as usize] = i;
                }
            }
            for r in ins.material_reads() {
                last_m[r as usize] = i;
            }
        }
        last_v[result.0 as usize] = usize::MAX - 1;
        if let Some(m) = material {
            last_m[m.0 as usize] = usize::MAX - 1;
        }
        let mut reg_v = vec![u32::MAX; self.next_value as usize];
        let mut reg_m = vec![u32::MAX; self.next_material as usize];
        let mut free_v: Vec<u32> = (1..MAX_REGISTERS as u32).rev().collect();
        let mut free_m: Vec<u32> = (0..MAX_MATERIAL_REGISTERS as u32).rev().collect();
        reg_v[0] = 0; // the input point
        let (mut used_v, mut used_m) = (1usize, 0usize);
        if last_v[0] == usize::MAX {
            free_v.push(0); // the point is never read
        }
        let mut instrs = Vec::new();
        for (i, ins) in self.code.iter().enumerate().filter(|(i, _)| keep[*i]) {
            let map_v = |r: u32, reg_v: &Vec<u32>| if r == IMM { IMM } else { reg_v[r as usize] };
            let mut out = Instr {
                op: ins.op as u32,
                dst: 0,
                a: 0,
                b: 0,
                c: 0,
                aux: ins.aux,
                pad: [0; 2],
                imm: ins.imm,
            };
            if ins.is_material() {
                if ins.op == Op::MatMix {
                    out.a = reg_m[ins.a as usize];
                    out.b = reg_m[ins.b.expect("MatMix reads two materials") as usize];
                    out.c = reg_v[ins.c as usize];
                }
            } else {
                out.a = map_v(ins.a, &reg_v);
                out.b = ins.b.map(|b| map_v(b, &reg_v)).unwrap_or(out.a);
                out.c = map_v(ins.c, &reg_v);
                if matches!(ins.op, Op::Const) {
                    out.a = 0;
                    out.c = 0;
                }
            }
            // Operands whose last reader is this instruction free their registers before the
            // destination is chosen: interpreters read every operand before writing.
            for r in ins.value_reads() {
                if r != IMM && last_v[r as usize] == i && reg_v[r as usize] != u32::MAX {
                    let reg = reg_v[r as usize];
                    if !free_v.contains(&reg) {
                        free_v.push(reg);
                    }
                }
            }
            for r in ins.material_reads() {
                if last_m[r as usize] == i {
                    let reg = reg_m[r as usize];
                    if !free_m.contains(&reg) {
                        free_m.push(reg);
                    }
                }
            }
            if ins.is_material() {
                free_m.sort_unstable_by(|a, b| b.cmp(a));
                let reg = free_m.pop().ok_or_else(|| {
                    format!(
                        "too complex: needs more than {MAX_MATERIAL_REGISTERS} material registers"
                    )
                })?;
                reg_m[ins.dst as usize] = reg;
                used_m = used_m.max(reg as usize + 1);
                out.dst = reg;
            } else {
                free_v.sort_unstable_by(|a, b| b.cmp(a));
                let reg = free_v.pop().ok_or_else(|| {
                    format!("too complex: needs more than {MAX_REGISTERS} registers")
                })?;
                reg_v[ins.dst as usize] = reg;
                used_v = used_v.max(reg as usize + 1);
                out.dst = reg;
            }
            instrs.push(out);
        }
        Ok(Tape {
            instrs,
            constants: self.constants.clone(),
            result: reg_v[result.0 as usize],
            material_result: material.map(|m| reg_m[m.0 as usize]),
            registers: used_v,
            material_registers: used_m,
        })
    }
}

// ---------------------------------------------------------------------------------------------
// Formulas

/// A lowered subtree: its distance and its material.
#[derive(Clone, Copy)]
struct Out {
    d: V,
    m: M,
}

struct Context<'a> {
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

    fn node(&mut self, b: &mut Builder, node: &SdfNode, p: V, mat: u32) -> Result<Out, LowerError> {
        self.path.push(Step::Node(node.kind()));
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
        p: V,
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
        p: V,
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

    fn leaf(b: &mut Builder, d: V, mat: u32) -> Out {
        Out {
            d,
            m: b.mat_load(mat),
        }
    }

    fn node_inner(
        &mut self,
        b: &mut Builder,
        node: &SdfNode,
        p: V,
        mat: u32,
    ) -> Result<Out, LowerError> {
        use SdfNode::*;
        Ok(match node {
            Sphere { radius } => {
                let l = b.length3(p);
                let d = b.sub_s(l, radius.0);
                Self::leaf(b, d, mat)
            }
            Cuboid { half_extents } => {
                let d = box_distance(b, p, half_extents.0);
                Self::leaf(b, d, mat)
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
                let inner = box_distance(b, p, half_extents.0 - Vec3::splat(r));
                let d = b.sub_s(inner, r);
                Self::leaf(b, d, mat)
            }
            Plane { normal, offset } => {
                let dp = b.dot3_v(p, normal.0);
                let d = b.sub_s(dp, offset.0);
                Self::leaf(b, d, mat)
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
                let xz = b.swz(p, "xz");
                let l = b.length2(xz);
                let qx = b.sub_s(l, major.0);
                let q = b.pack(qx, 0, p, 1, qx, 0);
                let lq = b.length2(q);
                let d = b.sub_s(lq, minor.0);
                Self::leaf(b, d, mat)
            }
            Cylinder {
                half_height,
                radius,
            } => {
                let d = cylinder_y(b, p, half_height.0, radius.0);
                Self::leaf(b, d, mat)
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
                let d = capped_cone(b, p, half_height.0, bottom_radius.0, top_radius.0);
                Self::leaf(b, d, mat)
            }
            Capsule { a, b: end, radius } => {
                let (a, e) = (a.0, end.0);
                let ba = e - a;
                let pa = b.bin_v(Op::Sub, p, a);
                let d = if ba.length_squared() < 1e-12 {
                    let l = b.length3(pa);
                    b.sub_s(l, radius.0)
                } else {
                    // Quilez sdCapsule: distance to the closest point of the segment.
                    let t = b.dot3_v(pa, ba);
                    let t = b.mul_s(t, 1.0 / ba.length_squared());
                    let h = b.clamp_s(t, 0.0, 1.0);
                    let hs = b.swz(h, "xxx");
                    let bav = b.konst(ba.extend(0.0));
                    let neg_pa = b.neg(pa);
                    let diff = b.mul_add(bav, hs, neg_pa); // ba·h − pa
                    let l = b.length3(diff);
                    b.sub_s(l, radius.0)
                };
                Self::leaf(b, d, mat)
            }
            Ellipsoid { radii } => {
                // A guaranteed bound: (|p/r| − 1)·min(r) has |∇| ≤ 1 (the gradient is
                // min(r)·|p/r²|/|p/r| ≤ 1), vanishes exactly on the surface, and its max with the
                // bounding sphere's distance |p| − max(r) stays a bound while being tight far
                // away. Quilez's k0(k0−1)/k1 estimate looks better but over-estimates by up to
                // ~10% near the tips of elongated ellipsoids (the conformance suite measures it).
                let r = radii.0;
                let pr = b.bin_v(Op::Div, p, r);
                let k0 = b.length3(pr);
                let k0m = b.sub_s(k0, 1.0);
                let near = b.mul_s(k0m, r.min_element());
                let l = b.length3(p);
                let far = b.sub_s(l, r.max_element());
                let d = b.max(near, far);
                Self::leaf(b, d, mat)
            }
            Octahedron { size } => {
                let d = octahedron(b, p, size.0);
                Self::leaf(b, d, mat)
            }
            HexPrism {
                radius,
                half_length,
            } => {
                let d = hex_prism(b, p, radius.0, half_length.0);
                Self::leaf(b, d, mat)
            }
            Union(shapes) => self.fold_children(b, None, shapes, p, mat, combine_union)?,
            Intersection(shapes) => {
                self.fold_children(b, None, shapes, p, mat, combine_intersection)?
            }
            Subtraction { base, cut } => {
                let a = self.child(b, "base", base, p, mat)?;
                let c = self.child(b, "cut", cut, p, mat)?;
                let nc = b.neg(c.d);
                Out {
                    d: b.max(a.d, nc),
                    m: a.m,
                }
            }
            SmoothUnion { k, shapes } => {
                let k = k.0;
                self.fold_children(b, Some("shapes"), shapes, p, mat, |b, x, y| {
                    smooth_min(b, x, y, k)
                })?
            }
            SmoothIntersection { k, shapes } => {
                let k = k.0;
                self.fold_children(b, Some("shapes"), shapes, p, mat, |b, x, y| {
                    smooth_max(b, x, y, k)
                })?
            }
            SmoothSubtraction { k, base, cut } => {
                let a = self.child(b, "base", base, p, mat)?;
                let c = self.child(b, "cut", cut, p, mat)?;
                let nc = Out {
                    d: b.neg(c.d),
                    m: a.m,
                };
                let out = smooth_max(b, a, nc, k.0);
                Out { d: out.d, m: a.m }
            }
            Round { radius, shape } => {
                let c = self.child(b, "shape", shape, p, mat)?;
                Out {
                    d: b.sub_s(c.d, radius.0),
                    m: c.m,
                }
            }
            Onion { thickness, shape } => {
                let c = self.child(b, "shape", shape, p, mat)?;
                let a = b.abs(c.d);
                Out {
                    d: b.sub_s(a, thickness.0),
                    m: c.m,
                }
            }
            Transform { shape, .. } => {
                let (m, s) = transform_of(node);
                let q = b.affine(p, &m.inverse());
                let c = self.child(b, "shape", shape, q, mat)?;
                // Uniform scale: distances in object space are 1/s of world distances.
                let d = if s == 1.0 { c.d } else { b.mul_s(c.d, s) };
                Out { d, m: c.m }
            }
            Scale { factors, shape } => {
                let q = b.bin_v(Op::Div, p, factors.0);
                let c = self.child(b, "shape", shape, q, mat)?;
                // f(p/s) is (1/min s)-Lipschitz; multiplying by min s restores λ = 1.
                Out {
                    d: b.mul_s(c.d, factors.0.min_element()),
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
            Twist { rate, shape } => {
                let k = rate.0;
                let cb = self.bounds(shape)?;
                let region = self.bounds(node)?;
                let r = region.max.x;
                // J = [R_xz | k·r·u + e_y]: singular values of [[1, kr],[kr, 1+k²r²]]^½ give
                // σ_max = (k r + √(4 + k² r²)) / 2 (≤ 1 + k r).
                let kr = k.abs() * r;
                let lambda = 0.5 * (kr + (4.0 + kr * kr).sqrt());
                // Evaluate at the projection onto the bounding cylinder (see clip_lipschitz).
                let center = Vec3::new(0.0, 0.5 * (cb.min.y + cb.max.y), 0.0);
                let half_h = 0.5 * (cb.max.y - cb.min.y);
                let local = b.bin_v(Op::Sub, p, center);
                let region = cylinder_y(b, local, half_h, r);
                let proj = project_cylinder_y(b, local, half_h, r);
                let pp = b.bin_v(Op::Add, proj, center);
                let y = b.swz(pp, "y");
                let ang = b.mul_s(y, k);
                let (cs, sn) = (b.un(Op::Cos, ang), b.un(Op::Sin, ang));
                let px = b.swz(pp, "x");
                let pz = b.swz(pp, "z");
                let t1 = b.mul(sn, pz);
                let t1 = b.neg(t1);
                let qx = b.mul_add(cs, px, t1);
                let t2 = b.mul(sn, px);
                let qz = b.mul_add(cs, pz, t2);
                let q = b.pack(qx, 0, pp, 1, qz, 0);
                let out = self.child(b, "shape", shape, q, mat)?;
                Out {
                    d: clip_lipschitz(b, out.d, lambda, region),
                    m: out.m,
                }
            }
            Bend { rate, shape } => {
                let k = rate.0;
                let cb = self.bounds(shape)?;
                let region = self.bounds(node)?;
                let r = region.max.x;
                // J = R(kx)·(I + k·w·e_xᵀ) with |w| = r: ‖J‖ ≤ 1 + k r (triangle inequality).
                let lambda = 1.0 + k.abs() * r;
                // Evaluate at the projection onto the bounding cylinder about z.
                let center = Vec3::new(0.0, 0.0, 0.5 * (cb.min.z + cb.max.z));
                let half_h = 0.5 * (cb.max.z - cb.min.z);
                let local = b.bin_v(Op::Sub, p, center);
                let local = b.swz(local, "xzy"); // cylinder about z ↔ about y
                let region = cylinder_y(b, local, half_h, r);
                let proj = project_cylinder_y(b, local, half_h, r);
                let proj = b.swz(proj, "xzy");
                let pp = b.bin_v(Op::Add, proj, center);
                let x = b.swz(pp, "x");
                let ang = b.mul_s(x, k);
                let (cs, sn) = (b.un(Op::Cos, ang), b.un(Op::Sin, ang));
                let py = b.swz(pp, "y");
                let t1 = b.mul(sn, py);
                let t1 = b.neg(t1);
                let qx = b.mul_add(cs, x, t1);
                let t2 = b.mul(sn, x);
                let qy = b.mul_add(cs, py, t2);
                let q = b.pack(qx, 0, qy, 0, pp, 2);
                let out = self.child(b, "shape", shape, q, mat)?;
                Out {
                    d: clip_lipschitz(b, out.d, lambda, region),
                    m: out.m,
                }
            }
            Implicit {
                expr: source,
                lipschitz,
                half_extents,
            } => {
                let e = expr::parse(source)
                    .map_err(|e| {
                        self.field_error("expr", format!("in expression `{source}`: {e}"))
                    })?
                    .fold_constants();
                check_defined(&e, half_extents.0).map_err(|m| {
                    self.field_error("expr", format!("in expression `{source}`: {m}"))
                })?;
                let lambda = match lipschitz {
                    Some(l) => l.0,
                    None => estimate_lipschitz(&e, half_extents.0).map_err(|m| {
                        self.field_error("expr", format!("in expression `{source}`: {m}"))
                    })?,
                };
                let region = box_distance(b, p, half_extents.0);
                let proj = project_box(b, p, half_extents.0);
                let f = lower_expr(b, &e, proj);
                let d = clip_lipschitz(b, f, lambda, region);
                Self::leaf(b, d, mat)
            }
            Material { name, shape } => {
                let m = (self.material_index)(name).ok_or_else(|| {
                    self.field_error("name", format!("unknown material \"{name}\""))
                })?;
                self.child(b, "shape", shape, p, m)?
            }
        })
    }

    /// Domain repetition (Quilez, "domain repetition", 2023 revision): the child is evaluated
    /// in its own cell *and* in the neighbouring cell on the near side of every repeated axis
    /// (2^k cells for k repeated axes), and the minimum is taken; every copy outside that block
    /// lies beyond the own cell's far wall, at least c/2 + |q| + gap away (gap = clearance
    /// between the child's bounds and its cell wall), which caps the result. The cap never
    /// falls below c/2, so empty cell walls never look like surfaces. The distance to the slab
    /// (or box) holding all copies is a second lower bound for the far copies, which lets rays
    /// far from the pattern take long steps. Bound; λ = 1.
    #[allow(clippy::too_many_arguments)]
    fn repeat(
        &mut self,
        b: &mut Builder,
        node: &SdfNode,
        shape: &SdfNode,
        p: V,
        mat: u32,
        c: Vec3,
        limit: Option<Vec3>,
    ) -> Result<Out, LowerError> {
        const FAR: f32 = 1e30;
        let child = self.bounds(shape)?;
        let half = 0.5 * c;
        let mut gap = f32::INFINITY;
        for i in 0..3 {
            if c[i] > 0.0 {
                let g = (half[i] - child.max[i]).min(child.min[i] + half[i]);
                if g.is_nan() || g < 0.0 {
                    return Err(self.field_error(
                        "period",
                        format!(
                            "the shape (bounds {}..{}) does not fit in its cell of period {} on \
                             axis {}: copies would overlap; use a larger period",
                            fmt3(child.min),
                            fmt3(child.max),
                            c[i],
                            ["x", "y", "z"][i]
                        ),
                    ));
                }
                gap = gap.min(g);
            }
        }
        let inv = Vec3::select(c.cmpgt(Vec3::ZERO), c.recip(), Vec3::ZERO);
        let neg_c = b.konst((-c).extend(0.0));
        // own cell ⌊p/c + ½⌋ (⌊x + ½⌋ rather than round(): WGSL rounds halves to even)
        let t = b.bin_v(Op::Mul, p, inv);
        let t = b.add_s(t, 0.5);
        let mut cell = b.un(Op::Floor, t);
        if let Some(n) = limit {
            cell = b.bin_v(Op::Max, cell, -n);
            cell = b.bin_v(Op::Min, cell, n);
        }
        let q = b.mul_add(neg_c, cell, p);
        // s = sign(q) per lane (0 at the exact centre, where the own cell suffices)
        let aq = b.abs(q);
        let aq_safe = b.max_s(aq, 1e-30);
        let s = b.bin(Op::Div, q, aq_safe);
        let mut near = b.add(cell, s);
        if let Some(n) = limit {
            near = b.bin_v(Op::Max, near, -n);
            near = b.bin_v(Op::Min, near, n);
        }
        let step = b.sub(near, cell);
        let axes: Vec<usize> = (0..3).filter(|&i| c[i] > 0.0).collect();
        let mut acc: Option<Out> = None;
        for mask in 0..(1u32 << axes.len()) {
            let mut pick = Vec3::ZERO;
            for (k, &axis) in axes.iter().enumerate() {
                if mask & (1 << k) != 0 {
                    pick[axis] = 1.0;
                }
            }
            let qm = if mask == 0 {
                q
            } else {
                let pv = b.konst(pick.extend(0.0));
                let cm = b.mul_add(step, pv, cell);
                b.mul_add(neg_c, cm, p)
            };
            let out = self.child(b, "shape", shape, qm, mat)?;
            acc = Some(match acc {
                None => out,
                Some(a) => combine_union(b, a, out),
            });
        }
        let block = acc.expect("at least one cell");
        // distance to the own cell's far wall, pushed out of reach where no copy lies beyond
        let halfv = Vec3::select(c.cmpgt(Vec3::ZERO), half, Vec3::splat(FAR));
        let far_wall = b.bin_v(Op::Add, aq, halfv);
        let far_wall = match limit {
            None => far_wall,
            Some(n) => {
                let beyond = b.sub(cell, s);
                let beyond = b.abs(beyond);
                let missing = b.bin_v(Op::Sub, beyond, n);
                let missing = b.clamp_s(missing, 0.0, 1.0);
                let far = b.splat(FAR);
                b.mul_add(missing, far, far_wall)
            }
        };
        let wall = b.min_lane3(far_wall);
        let cap = b.add_s(wall, gap);
        // the region holding every copy
        let region = self.bounds(node)?;
        let centre = Vec3::select(
            region.min.is_finite_mask() & region.max.is_finite_mask(),
            region.center(),
            Vec3::ZERO,
        );
        let extent = Vec3::select(
            region.min.is_finite_mask() & region.max.is_finite_mask(),
            0.5 * (region.max - region.min),
            Vec3::splat(FAR),
        );
        let local = b.bin_v(Op::Sub, p, centre);
        let slab = box_distance(b, local, extent);
        let cap = b.max(cap, slab);
        Ok(Out {
            d: b.min(block.d, cap),
            m: block.m,
        })
    }
}

fn combine_union(b: &mut Builder, x: Out, y: Out) -> Out {
    let d = b.min(x.d, y.d);
    // Material of the nearer shape: h = 1 picks y when x is farther.
    let diff = b.sub(x.d, y.d);
    let (one, zero) = (b.splat(1.0), b.splat(0.0));
    let h = b.select(diff, one, zero);
    Out {
        d,
        m: b.mat_mix(x.m, y.m, h),
    }
}

fn combine_intersection(b: &mut Builder, x: Out, y: Out) -> Out {
    let d = b.max(x.d, y.d);
    let diff = b.sub(y.d, x.d);
    let (one, zero) = (b.splat(1.0), b.splat(0.0));
    let h = b.select(diff, one, zero);
    Out {
        d,
        m: b.mat_mix(x.m, y.m, h),
    }
}

/// Quilez's polynomial smooth minimum, f = a(1−h) + b·h − k·h(1−h) with
/// h = clamp(½ + ½(a−b)/k, 0, 1); the same h blends the materials.
fn smooth_min(b: &mut Builder, x: Out, y: Out, k: f32) -> Out {
    if k <= 0.0 {
        return combine_union(b, x, y);
    }
    let diff = b.sub(x.d, y.d);
    let t = b.mul_s(diff, 0.5 / k);
    let t = b.add_s(t, 0.5);
    let h = b.clamp_s(t, 0.0, 1.0);
    let nd = b.neg(diff); // y − x
    let mix = b.mul_add(nd, h, x.d); // x + (y − x)·h
    let nh = b.neg(h);
    let one_minus = b.add_s(nh, 1.0);
    let hh = b.mul(h, one_minus);
    let kh = b.mul_s(hh, k);
    Out {
        d: b.sub(mix, kh),
        m: b.mat_mix(x.m, y.m, h),
    }
}

/// Smooth maximum: −smin(−a, −b, k).
fn smooth_max(b: &mut Builder, x: Out, y: Out, k: f32) -> Out {
    if k <= 0.0 {
        return combine_intersection(b, x, y);
    }
    let nx = Out {
        d: b.neg(x.d),
        m: x.m,
    };
    let ny = Out {
        d: b.neg(y.d),
        m: y.m,
    };
    let s = smooth_min(b, nx, ny, k);
    Out {
        d: b.neg(s.d),
        m: s.m,
    }
}

/// Clips a λ-Lipschitz field to a convex region R and makes it 1-Lipschitz everywhere:
/// g(p) = max(f(π(p))/λ, d_R(p)), with π the projection onto R (evaluated by the caller, who
/// passes f(π(p)) as `f_projected`) and d_R the exact signed distance to R.
/// π is non-expanding and f/λ is 1-Lipschitz on R, so f∘π/λ is 1-Lipschitz on all of space,
/// and so is the max of two 1-Lipschitz functions. Inside R, g = max(f/λ, d_R) is the surface
/// clipped to R; outside, g stays ≥ f(π(p))/λ > 0 wherever the clipped surface is absent, so the
/// region's own boundary never looks like a surface.
fn clip_lipschitz(b: &mut Builder, f_projected: V, lambda: f32, region_distance: V) -> V {
    let scaled = if lambda == 1.0 {
        f_projected
    } else {
        b.mul_s(f_projected, 1.0 / lambda)
    };
    b.max(scaled, region_distance)
}

/// Projection of p onto the box [−h, h].
fn project_box(b: &mut Builder, p: V, h: Vec3) -> V {
    let q = b.bin_v(Op::Max, p, -h);
    b.bin_v(Op::Min, q, h)
}

/// Projection of p onto the cylinder about y of radius r and |y| ≤ h.
fn project_cylinder_y(b: &mut Builder, p: V, h: f32, r: f32) -> V {
    let xz = b.swz(p, "xz");
    let l = b.length2(xz);
    let l = b.max_s(l, 1e-30);
    let rr = b.splat(r);
    let s = b.bin(Op::Div, rr, l);
    let s = b.min_s(s, 1.0);
    let one = b.splat(1.0);
    let sv = b.pack(s, 0, one, 0, s, 0);
    let q = b.mul(p, sv);
    let q = b.bin_v(Op::Max, q, Vec3::new(-1e30, -h, -1e30));
    b.bin_v(Op::Min, q, Vec3::new(1e30, h, 1e30))
}

/// Quilez sdBox: exact distance to the box [−h, h].
fn box_distance(b: &mut Builder, p: V, h: Vec3) -> V {
    let a = b.abs(p);
    let q = b.bin_v(Op::Sub, a, h);
    let qp = b.max_s(q, 0.0);
    let outside = b.length3(qp);
    let m = b.max_lane3(q);
    let inside = b.min_s(m, 0.0);
    b.add(outside, inside)
}

/// Quilez sdCappedCylinder along y: exact.
fn cylinder_y(b: &mut Builder, p: V, h: f32, r: f32) -> V {
    let xz = b.swz(p, "xz");
    let l = b.length2(xz);
    let v = b.pack(l, 0, p, 1, l, 0);
    let av = b.abs(v);
    let d = b.bin_v(Op::Sub, av, Vec3::new(r, h, 0.0));
    let m = b.max_lane2(d);
    let inside = b.min_s(m, 0.0);
    let dp = b.max_s(d, 0.0);
    let outside = b.length2(dp);
    b.add(inside, outside)
}

/// Quilez sdCappedCone (exact): r1 at y = −h, r2 at y = +h.
fn capped_cone(b: &mut Builder, p: V, h: f32, r1: f32, r2: f32) -> V {
    let xz = b.swz(p, "xz");
    let l = b.length2(xz);
    let q = b.pack(l, 0, p, 1, l, 0); // (|p.xz|, p.y, ·)
    let k1 = Vec3::new(r2, h, 0.0);
    let k2 = Vec3::new(r2 - r1, 2.0 * h, 0.0);
    // ca = (q.x − min(q.x, q.y < 0 ? r1 : r2), |q.y| − h)
    let qy = b.swz(q, "y");
    let nqy = b.neg(qy);
    let (c1, c2) = (b.splat(r1), b.splat(r2));
    let rsel = b.select(nqy, c1, c2);
    let mq = b.min(q, rsel);
    let cax = b.sub(q, mq);
    let aq = b.abs(q);
    let cay = b.sub_s(aq, h);
    let ca = b.pack(cax, 0, cay, 1, cax, 0);
    // cb = q − k1 + k2·clamp(dot(k1 − q, k2)/dot(k2, k2), 0, 1)
    let kq = b.bin_v(Op::Sub, q, k1);
    let nkq = b.neg(kq);
    let dk = b.dot3_v(nkq, k2);
    let t = b.mul_s(dk, 1.0 / k2.length_squared());
    let t = b.clamp_s(t, 0.0, 1.0);
    let ts = b.swz(t, "xxx");
    let k2v = b.konst(k2.extend(0.0));
    let cb = b.mul_add(k2v, ts, kq);
    // s = (cb.x < 0 && ca.y < 0) ? −1 : 1
    let both = b.pack(cb, 0, ca, 1, cb, 0);
    let m = b.max_lane2(both);
    let (one, minus) = (b.splat(1.0), b.splat(-1.0));
    let s = b.select(m, one, minus);
    let la = b.length2(ca);
    let lb = b.length2(cb);
    let dmin = b.min(la, lb);
    b.mul(s, dmin)
}

/// Quilez sdOctahedron, exact form, with the branches turned into selects.
fn octahedron(b: &mut Builder, p: V, s: f32) -> V {
    let ap = b.abs(p);
    let sum = b.dot3_v(ap, Vec3::ONE);
    let m = b.sub_s(sum, s);
    let mv = b.swz(m, "xxx");
    let ap3 = b.mul_s(ap, 3.0);
    let cond = b.sub(mv, ap3); // lane i > 0 ⇔ 3·p_i < m
    let c1 = b.swz(cond, "x");
    let c2 = b.swz(cond, "y");
    let q1 = b.swz(ap, "xyz");
    let q2 = b.swz(ap, "yzx");
    let q3 = b.swz(ap, "zxy");
    let c2sel = b.select(c2, q2, q3);
    let q = b.select(c1, q1, c2sel);
    let qz = b.swz(q, "z");
    let qy = b.swz(q, "y");
    let dzy = b.sub(qz, qy);
    let kk = b.add_s(dzy, s);
    let kk = b.mul_s(kk, 0.5);
    let k = b.clamp_s(kk, 0.0, s);
    let ks = b.sub_s(k, s);
    let nk = b.neg(k);
    let zero = b.splat(0.0);
    let t = b.pack(zero, 0, ks, 0, nk, 0);
    let v = b.add(q, t);
    let exact = b.length3(v);
    let any = b.max_lane3(cond);
    let flat = b.mul_s(m, 0.577_350_26);
    b.select(any, exact, flat)
}

/// Quilez sdHexPrism (exact): apothem r in the xy-plane, half-length hz along z.
fn hex_prism(b: &mut Builder, p: V, r: f32, hz: f32) -> V {
    const K: Vec3 = Vec3::new(-0.866_025_4, 0.5, 0.577_350_26);
    let ap = b.abs(p);
    let dk = b.dot3_v(ap, Vec3::new(K.x, K.y, 0.0));
    let dk = b.min_s(dk, 0.0);
    let dks = b.swz(dk, "xx");
    let kv = b.konst(Vec4::new(-2.0 * K.x, -2.0 * K.y, 0.0, 0.0));
    let p2 = b.mul_add(kv, dks, ap); // p.xy −= 2·min(dot(k.xy, p.xy), 0)·k.xy
    let px = b.swz(p2, "x");
    let cx = b.clamp_s(px, -K.z * r, K.z * r);
    let rr = b.splat(r);
    let zero = b.splat(0.0);
    let off = b.pack(cx, 0, rr, 0, zero, 0);
    let w = b.sub(p2, off);
    let lw = b.length2(w);
    let wy = b.swz(w, "y");
    let (one, minus) = (b.splat(1.0), b.splat(-1.0));
    let sgn = b.select(wy, one, minus);
    let dx = b.mul(lw, sgn);
    let pz = b.swz(p2, "z");
    let dy = b.sub_s(pz, hz);
    let d = b.pack(dx, 0, dy, 0, dx, 0);
    let m = b.max_lane2(d);
    let inside = b.min_s(m, 0.0);
    let dp = b.max_s(d, 0.0);
    let outside = b.length2(dp);
    b.add(inside, outside)
}

/// Lowers an implicit-surface expression; integer powers become products so that negative
/// bases work identically on every backend (WGSL's pow is undefined for x < 0).
fn lower_expr(b: &mut Builder, e: &Expr, p: V) -> V {
    match e {
        Expr::X => b.swz(p, "x"),
        Expr::Y => b.swz(p, "y"),
        Expr::Z => b.swz(p, "z"),
        Expr::Const(c) => b.splat(*c),
        Expr::Unary(op, a) => {
            let a = lower_expr(b, a, p);
            let op = match op {
                UnaryOp::Neg => Op::Neg,
                UnaryOp::Abs => Op::Abs,
                UnaryOp::Sqrt => Op::Sqrt,
                UnaryOp::Sin => Op::Sin,
                UnaryOp::Cos => Op::Cos,
                UnaryOp::Tan => Op::Tan,
                UnaryOp::Exp => Op::Exp,
                UnaryOp::Ln => Op::Ln,
                UnaryOp::Floor => Op::Floor,
            };
            b.un(op, a)
        }
        Expr::Binary(BinaryOp::Pow, base, exp) => {
            let x = lower_expr(b, base, p);
            match **exp {
                Expr::Const(n) if n.fract() == 0.0 && n.abs() <= 64.0 => {
                    let k = n.abs() as u32;
                    let pos = int_pow(b, x, k);
                    if n < 0.0 {
                        let one = b.splat(1.0);
                        b.bin(Op::Div, one, pos)
                    } else {
                        pos
                    }
                }
                _ => {
                    let y = lower_expr(b, exp, p);
                    b.bin(Op::Pow, x, y)
                }
            }
        }
        Expr::Binary(op, l, r) => {
            let l = lower_expr(b, l, p);
            let r = lower_expr(b, r, p);
            let op = match op {
                BinaryOp::Add => Op::Add,
                BinaryOp::Sub => Op::Sub,
                BinaryOp::Mul => Op::Mul,
                BinaryOp::Div => Op::Div,
                BinaryOp::Min => Op::Min,
                BinaryOp::Max => Op::Max,
                BinaryOp::Pow => unreachable!("handled above"),
            };
            b.bin(op, l, r)
        }
    }
}

/// xᵏ by repeated squaring.
fn int_pow(b: &mut Builder, x: V, k: u32) -> V {
    if k == 0 {
        return b.splat(1.0);
    }
    let (mut result, mut base, mut k) = (None, x, k);
    while k > 0 {
        if k & 1 == 1 {
            result = Some(match result {
                None => base,
                Some(r) => b.mul(r, base),
            });
        }
        k >>= 1;
        if k > 0 {
            base = b.mul(base, base);
        }
    }
    result.expect("k > 0 sets the result")
}

/// Checks that an expression is finite over the box [−h, h] (sampled on a 21³ grid that
/// includes the faces): a NaN would silently turn part of the box into solid, since the clipped
/// field falls back to the box distance there.
pub fn check_defined(e: &Expr, h: Vec3) -> Result<(), String> {
    const N: usize = 21;
    for i in 0..N {
        for j in 0..N {
            for k in 0..N {
                let t = Vec3::new(i as f32, j as f32, k as f32) / (N - 1) as f32;
                let q = -h + 2.0 * h * t;
                let v = e.eval(q);
                if !v.is_finite() {
                    return Err(format!(
                        "the expression is {v} at {} inside its box; it must be defined \
                         everywhere in half_extents (e.g. guard sqrt and ln with abs or max)",
                        fmt3(q)
                    ));
                }
            }
        }
    }
    Ok(())
}

/// Estimates the Lipschitz constant of an expression over the box [−h, h] by the largest
/// central-difference gradient on a 25³ grid, times 1.5 for what the grid misses.
pub fn estimate_lipschitz(e: &Expr, h: Vec3) -> Result<f32, String> {
    let mut b = Builder::default();
    let p = b.input();
    let f = lower_expr(&mut b, e, p);
    let tape = b.finish(f, None)?;
    const N: usize = 25;
    let step = (2.0 * h.max_element() / N as f32) * 1e-2;
    let mut max_grad: f32 = 0.0;
    for i in 0..N {
        for j in 0..N {
            for k in 0..N {
                let t = (Vec3::new(i as f32, j as f32, k as f32) + 0.5) / N as f32;
                let q = -h + 2.0 * h * t;
                let g = tape.gradient(q, step).length();
                if g.is_finite() {
                    max_grad = max_grad.max(g);
                }
            }
        }
    }
    if max_grad > 0.0 {
        Ok(1.5 * max_grad)
    } else {
        Err(
            "could not estimate a Lipschitz constant (the gradient is zero or undefined on \
             the whole box); give `lipschitz:` explicitly"
                .to_string(),
        )
    }
}

/// `(x, y, z)` for messages.
fn fmt3(v: Vec3) -> String {
    format!("({}, {}, {})", v.x, v.y, v.z)
}
