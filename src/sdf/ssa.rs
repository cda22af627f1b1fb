//! The tape in SSA form: what lowering emits, what region specialisation rewrites, and the
//! register allocator that turns it into a runnable [`Tape`].
//!
//! Every [`SsaOp`] defines one value, numbered by its position; the first three are the
//! sample point's coordinates. [`Builder`] appends operations with constant folding (through
//! [`crate::sdf::tape::apply`], so a folded constant has the bits the interpreter would have
//! computed), exact identities (x + 0, x·1, −(−x), min(x, x)…) and hash-consing of repeated
//! subexpressions. [`SsaTape::compile`] removes dead code and assigns registers by a linear
//! scan that frees a register after its last reader (fidget and libfive do the same).

use crate::sdf::tape::{Instr, MAX_MATERIAL_REGISTERS, MAX_REGISTERS, Op, Shape, Tape, apply};
use rustc_hash::FxHashMap as HashMap;

/// A value: the number of the operation that defines it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct V(pub u32);

/// A material value (defined by `MatLoad` or `MatMix`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct M(pub u32);

/// One SSA operation. Operands name earlier values; unused ones are 0. `c` is the condition
/// of `Select` and the weight of `MatMix`; `imm` holds the immediate's bits, the axis of
/// `Input` or the material number of `MatLoad`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct SsaOp {
    /// The operation.
    pub op: Op,
    /// First operand.
    pub a: u32,
    /// Second operand.
    pub b: u32,
    /// Third operand.
    pub c: u32,
    /// Immediate bits.
    pub imm: u32,
}

impl SsaOp {
    /// The immediate as a float.
    pub fn imm(&self) -> f32 {
        f32::from_bits(self.imm)
    }

    /// Calls `f` with every value operand (materials excluded).
    #[inline]
    pub fn for_each_value_operand(&self, mut f: impl FnMut(u32)) {
        match self.op.shape() {
            Shape::Nullary | Shape::MatLoad => {}
            Shape::Unary | Shape::WithImm => f(self.a),
            Shape::Binary => {
                f(self.a);
                f(self.b);
            }
            Shape::Ternary => {
                f(self.a);
                f(self.b);
                f(self.c);
            }
            Shape::MatMix => f(self.c),
        }
    }
}

/// A program in SSA form with its results.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SsaTape {
    /// The operations; the first three are `Input` 0, 1, 2.
    pub ops: Vec<SsaOp>,
    /// The distance.
    pub result: u32,
    /// The blended material (shading programs only).
    pub material: Option<u32>,
}

/// Appends operations with folding, identities and hash-consing.
#[derive(Debug, Clone)]
pub struct Builder {
    ops: Vec<SsaOp>,
    memo: HashMap<SsaOp, u32>,
    share: bool,
}

impl Default for Builder {
    fn default() -> Self {
        Self::new()
    }
}

impl Builder {
    /// A builder holding the three inputs.
    pub fn new() -> Self {
        let mut b = Builder {
            ops: Vec::new(),
            memo: HashMap::default(),
            share: true,
        };
        for axis in 0..3 {
            b.ops.push(SsaOp {
                op: Op::Input,
                a: 0,
                b: 0,
                c: 0,
                imm: axis,
            });
        }
        b
    }

    /// A builder that folds but does not look for repeated subexpressions: what rebuilding an
    /// already shared program needs (specialisation only removes operations).
    pub fn without_sharing(capacity: usize) -> Self {
        let mut b = Self::new();
        b.share = false;
        b.ops.reserve(capacity);
        b
    }

    /// The sample point's coordinates.
    pub fn point(&self) -> [V; 3] {
        [V(0), V(1), V(2)]
    }

    /// Operations so far.
    pub fn len(&self) -> usize {
        self.ops.len()
    }

    /// Whether only the inputs are there.
    pub fn is_empty(&self) -> bool {
        self.ops.len() <= 3
    }

    /// The constant a value holds, if it is one.
    pub fn constant(&self, v: V) -> Option<f32> {
        let o = &self.ops[v.0 as usize];
        (o.op == Op::Const).then(|| o.imm())
    }

    /// The operation defining v.
    pub fn def(&self, v: V) -> &SsaOp {
        &self.ops[v.0 as usize]
    }

    /// The finished program.
    pub fn finish(self, result: V, material: Option<M>) -> SsaTape {
        SsaTape {
            ops: self.ops,
            result: result.0,
            material: material.map(|m| m.0),
        }
    }

    fn raw(&mut self, op: SsaOp) -> u32 {
        if !self.share {
            self.ops.push(op);
            return self.ops.len() as u32 - 1;
        }
        if let Some(&v) = self.memo.get(&op) {
            return v;
        }
        let v = self.ops.len() as u32;
        self.ops.push(op);
        self.memo.insert(op, v);
        v
    }

    /// A constant.
    pub fn konst(&mut self, x: f32) -> V {
        V(self.raw(SsaOp {
            op: Op::Const,
            a: 0,
            b: 0,
            c: 0,
            imm: x.to_bits(),
        }))
    }

    /// A unary operation.
    pub fn unary(&mut self, op: Op, a: V) -> V {
        debug_assert_eq!(op.shape(), Shape::Unary);
        if let Some(x) = self.constant(a) {
            return self.konst(apply::<f32>(op, x, 0.0, 0.0, 0.0));
        }
        let da = *self.def(a);
        match (op, da.op) {
            (Op::Copy, _) => return a,
            (Op::Neg, Op::Neg) => return V(da.a),
            (Op::Abs, Op::Abs) => return a,
            (Op::Abs | Op::Square, Op::Neg) => return self.unary(op, V(da.a)),
            _ => {}
        }
        V(self.raw(SsaOp {
            op,
            a: a.0,
            b: 0,
            c: 0,
            imm: 0,
        }))
    }

    /// A binary operation on two values; a constant operand becomes an immediate.
    pub fn binary(&mut self, op: Op, a: V, b: V) -> V {
        debug_assert_eq!(op.shape(), Shape::Binary);
        match (self.constant(a), self.constant(b)) {
            (Some(x), Some(y)) => return self.konst(apply::<f32>(op, x, y, 0.0, 0.0)),
            (None, Some(k)) => {
                let imm_op = match op {
                    Op::Add => Some(Op::AddImm),
                    Op::Sub => Some(Op::SubImm),
                    Op::Mul => Some(Op::MulImm),
                    Op::Div => Some(Op::DivImm),
                    Op::Min => Some(Op::MinImm),
                    Op::Max => Some(Op::MaxImm),
                    Op::Pow => Some(Op::PowImm),
                    _ => None,
                };
                if let Some(imm_op) = imm_op {
                    return self.with_imm(imm_op, a, k);
                }
            }
            (Some(k), None) => {
                let imm_op = match op {
                    Op::Add => Some(Op::AddImm),
                    Op::Sub => Some(Op::RsubImm),
                    Op::Mul => Some(Op::MulImm),
                    Op::Div => Some(Op::RdivImm),
                    Op::Min => Some(Op::MinImm),
                    Op::Max => Some(Op::MaxImm),
                    _ => None,
                };
                if let Some(imm_op) = imm_op {
                    return self.with_imm(imm_op, b, k);
                }
            }
            (None, None) => {}
        }
        match op {
            Op::Min | Op::Max if a == b => return a,
            Op::Mul if a == b => return self.unary(Op::Square, a),
            _ => {}
        }
        // Commutative operations in a canonical order, so that hash-consing finds a + b and
        // b + a alike.
        let (a, b) = if matches!(op, Op::Add | Op::Mul | Op::Min | Op::Max | Op::Hypot) && b < a {
            (b, a)
        } else {
            (a, b)
        };
        V(self.raw(SsaOp {
            op,
            a: a.0,
            b: b.0,
            c: 0,
            imm: 0,
        }))
    }

    /// An operation of a value and an immediate.
    pub fn with_imm(&mut self, op: Op, a: V, k: f32) -> V {
        debug_assert_eq!(op.shape(), Shape::WithImm);
        if let Some(x) = self.constant(a) {
            return self.konst(apply::<f32>(op, x, 0.0, 0.0, k));
        }
        match op {
            Op::AddImm | Op::SubImm if k == 0.0 => return a,
            Op::MulImm | Op::DivImm if k == 1.0 => return a,
            Op::MulImm if k == -1.0 => return self.unary(Op::Neg, a),
            _ => {}
        }
        V(self.raw(SsaOp {
            op,
            a: a.0,
            b: 0,
            c: 0,
            imm: k.to_bits(),
        }))
    }

    /// `c > 0 ? a : b`.
    pub fn select(&mut self, c: V, a: V, b: V) -> V {
        if a == b {
            return a;
        }
        if let Some(x) = self.constant(c) {
            return if x > 0.0 { a } else { b };
        }
        V(self.raw(SsaOp {
            op: Op::Select,
            a: a.0,
            b: b.0,
            c: c.0,
            imm: 0,
        }))
    }

    /// √(a² + b² + c²).
    pub fn hypot3(&mut self, a: V, b: V, c: V) -> V {
        if let (Some(x), Some(y), Some(z)) = (self.constant(a), self.constant(b), self.constant(c))
        {
            return self.konst(apply::<f32>(Op::Hypot3, x, y, z, 0.0));
        }
        V(self.raw(SsaOp {
            op: Op::Hypot3,
            a: a.0,
            b: b.0,
            c: c.0,
            imm: 0,
        }))
    }

    /// The scene material number `index`.
    pub fn mat_load(&mut self, index: u32) -> M {
        M(self.raw(SsaOp {
            op: Op::MatLoad,
            a: 0,
            b: 0,
            c: 0,
            imm: index,
        }))
    }

    /// mix(a, b, h).
    pub fn mat_mix(&mut self, a: M, b: M, h: V) -> M {
        if a == b {
            return a;
        }
        match self.constant(h) {
            Some(0.0) => return a,
            Some(1.0) => return b,
            _ => {}
        }
        M(self.raw(SsaOp {
            op: Op::MatMix,
            a: a.0,
            b: b.0,
            c: h.0,
            imm: 0,
        }))
    }

    /// Appends `op` with its operands renamed by `map` (values and materials alike), through
    /// the folding above: how a simplified program is rebuilt.
    pub fn rebuild(&mut self, op: &SsaOp, map: impl Fn(u32) -> u32) -> u32 {
        match op.op.shape() {
            Shape::Nullary => match op.op {
                Op::Input => op.imm,
                _ => self.konst(op.imm()).0,
            },
            Shape::Unary => self.unary(op.op, V(map(op.a))).0,
            Shape::Binary => self.binary(op.op, V(map(op.a)), V(map(op.b))).0,
            Shape::WithImm => self.with_imm(op.op, V(map(op.a)), op.imm()).0,
            Shape::Ternary if op.op == Op::Hypot3 => {
                self.hypot3(V(map(op.a)), V(map(op.b)), V(map(op.c))).0
            }
            Shape::Ternary => self.select(V(map(op.c)), V(map(op.a)), V(map(op.b))).0,
            Shape::MatLoad => self.mat_load(op.imm).0,
            Shape::MatMix => self.mat_mix(M(map(op.a)), M(map(op.b)), V(map(op.c))).0,
        }
    }
}

impl SsaTape {
    /// Which operations the results depend on.
    pub fn live(&self) -> Vec<bool> {
        let mut live = Vec::new();
        self.live_into(true, &mut live);
        live
    }

    /// Marks in `live` the operations the distance (and, with `material`, the material)
    /// depends on; returns how many there are, inputs excluded.
    pub fn live_into(&self, material: bool, live: &mut Vec<bool>) -> usize {
        live.clear();
        live.resize(self.ops.len(), false);
        live[self.result as usize] = true;
        if let (true, Some(m)) = (material, self.material) {
            live[m as usize] = true;
        }
        let mut count = 0;
        for i in (0..self.ops.len()).rev() {
            if !live[i] {
                continue;
            }
            let op = &self.ops[i];
            if op.op != Op::Input {
                count += 1;
            }
            op.for_each_value_operand(|v| live[v as usize] = true);
            if op.op == Op::MatMix {
                live[op.a as usize] = true;
                live[op.b as usize] = true;
            }
        }
        count
    }

    /// Number of operations the results depend on, inputs excluded.
    pub fn live_len(&self) -> usize {
        self.live()
            .iter()
            .zip(&self.ops)
            .filter(|(l, o)| **l && o.op != Op::Input)
            .count()
    }

    /// The program without its material part (what tracing evaluates).
    pub fn distance_only(&self) -> SsaTape {
        SsaTape {
            ops: self.ops.clone(),
            result: self.result,
            material: None,
        }
    }

    /// Dead-code elimination and linear-scan register allocation into a [`Tape`]. Fails when
    /// the program needs more than [`MAX_REGISTERS`] values (or [`MAX_MATERIAL_REGISTERS`]
    /// materials) alive at once.
    pub fn compile(&self) -> Result<Tape, String> {
        self.compile_or_rematerialise(true)
    }

    /// [`Self::compile`] of the distance alone (the material operations dropped).
    pub fn compile_distance(&self) -> Result<Tape, String> {
        self.compile_or_rematerialise(false)
    }

    /// Allocation as it is, or, when registers run out, once more after cheap values read far
    /// from where they are made have been recomputed near their readers (a register
    /// allocator's rematerialisation, Briggs, Cooper & Torczon 1992, instead of spilling: the
    /// interpreters have no memory beyond their registers). That is what a union of many
    /// translated primitives needs: the coordinate offsets that rows of them share would
    /// otherwise stay alive across the whole union. When that is not enough, dearer values
    /// are recomputed too (up to [`REMAT_COST_FALLBACK`] operations): under an object's
    /// rotation or scale, the rotated coordinates that members of one orientation share cost
    /// a dozen operations of the inputs, and a few hundred orientations outlive the registers.
    fn compile_or_rematerialise(&self, with_material: bool) -> Result<Tape, String> {
        let mut result = self.compile_part(with_material);
        for cost in [REMAT_COST, REMAT_COST_FALLBACK] {
            if !matches!(result, Err(OutOf::Registers)) {
                break;
            }
            result = self
                .rematerialised(with_material, cost)
                .compile_part(with_material);
        }
        result.map_err(|e| e.to_string())
    }

    /// The program with every value that takes at most `max_cost` operations of the inputs
    /// recomputed wherever its last copy is more than [`REMAT_DISTANCE`] operations old, and
    /// emitted only where first read: such a value is never alive for long. Other values keep
    /// their order; dead code is left out.
    pub fn rematerialised(&self, with_material: bool, max_cost: u32) -> SsaTape {
        let n = self.ops.len();
        let mut live = Vec::new();
        self.live_into(with_material, &mut live);
        let mut cost: Vec<Option<u32>> = vec![None; n];
        for (i, op) in self.ops.iter().enumerate() {
            let c = match op.op {
                Op::Input => Some(0),
                _ if op.op.is_material() => None,
                _ => {
                    let mut c = Some(1u32);
                    op.for_each_value_operand(|v| {
                        c = c.and_then(|c| cost[v as usize].map(|k| c + k));
                    });
                    c.filter(|&c| c <= max_cost)
                }
            };
            cost[i] = c;
        }
        let mut r = Remat {
            ops: &self.ops,
            cost: &cost,
            copy: vec![u32::MAX; n],
            out: Vec::with_capacity(n),
        };
        for (i, op) in self.ops.iter().enumerate() {
            if op.op == Op::Input {
                r.copy[i] = r.out.len() as u32;
                r.out.push(*op);
            } else if live[i] && cost[i].is_none() {
                r.emit(i);
            }
        }
        let result = r.fresh(self.result);
        let material = self
            .material
            .filter(|_| with_material)
            .map(|m| r.copy[m as usize]);
        SsaTape {
            ops: r.out,
            result,
            material,
        }
    }

    fn compile_part(&self, with_material: bool) -> Result<Tape, OutOf> {
        let n = self.ops.len();
        let mut live = Vec::new();
        self.live_into(with_material, &mut live);
        let material = self.material.filter(|_| with_material);
        // Last reader of every value among the live operations; results stay to the end.
        let mut last = vec![0usize; n];
        for (i, op) in self.ops.iter().enumerate() {
            if !live[i] {
                continue;
            }
            op.for_each_value_operand(|v| last[v as usize] = i);
            if op.op == Op::MatMix {
                last[op.a as usize] = i;
                last[op.b as usize] = i;
            }
        }
        last[self.result as usize] = usize::MAX;
        if let Some(m) = material {
            last[m as usize] = usize::MAX;
        }
        let mut values = FreeRegisters::new(MAX_REGISTERS);
        let mut materials = FreeRegisters::new(MAX_MATERIAL_REGISTERS);
        let mut reg = vec![0u8; n];
        let (mut used_v, mut used_m) = (3usize, 0usize);
        for axis in 0..3 {
            reg[axis] = values.take_specific(axis as u8);
            if !live[axis] || self.ops[axis].op != Op::Input {
                values.give(axis as u8);
            }
        }
        let mut instrs = Vec::new();
        for (i, op) in self.ops.iter().enumerate() {
            if !live[i] || op.op == Op::Input {
                continue;
            }
            // Operands whose last reader this is free their registers before the destination
            // is chosen: interpreters read every operand before writing.
            op.for_each_value_operand(|v| {
                if last[v as usize] == i {
                    values.give(reg[v as usize]);
                }
            });
            if op.op == Op::MatMix {
                for m in [op.a, op.b] {
                    if last[m as usize] == i {
                        materials.give(reg[m as usize]);
                    }
                }
            }
            let out = if op.op.is_material() {
                let r = materials.take().ok_or(OutOf::MaterialRegisters)?;
                used_m = used_m.max(r as usize + 1);
                r
            } else {
                let r = values.take().ok_or(OutOf::Registers)?;
                used_v = used_v.max(r as usize + 1);
                r
            };
            reg[i] = out;
            let r = |v: u32| reg[v as usize];
            let ins = match op.op.shape() {
                Shape::Nullary => Instr::new(op.op, out, 0, 0, op.imm),
                Shape::Unary => Instr::new(op.op, out, r(op.a), 0, 0),
                Shape::Binary => Instr::new(op.op, out, r(op.a), r(op.b), 0),
                Shape::WithImm => Instr::new(op.op, out, r(op.a), 0, op.imm),
                Shape::Ternary => Instr::new(op.op, out, r(op.a), r(op.b), r(op.c) as u32),
                Shape::MatLoad => Instr::new(op.op, out, 0, 0, op.imm),
                Shape::MatMix => Instr::new(op.op, out, r(op.a), r(op.b), r(op.c) as u32),
            };
            instrs.push(ins);
        }
        // a material that is one table entry, not a blend: shading needs no evaluation
        let constant_material = material
            .map(|m| &self.ops[m as usize])
            .filter(|op| op.op == Op::MatLoad)
            .map(|op| op.imm);
        Ok(Tape {
            instrs,
            result: reg[self.result as usize],
            material_result: material.map(|m| reg[m as usize]),
            constant_material,
            registers: used_v,
            material_registers: used_m,
            native: None,
        })
    }
}

/// What register allocation ran out of.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum OutOf {
    /// Value registers: worth a second try after rematerialisation.
    Registers,
    /// Material registers (materials are never recomputed).
    MaterialRegisters,
}

impl std::fmt::Display for OutOf {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            OutOf::Registers => write!(f, "too complex: needs more than {MAX_REGISTERS} registers"),
            OutOf::MaterialRegisters => write!(
                f,
                "too complex: needs more than {MAX_MATERIAL_REGISTERS} material registers"
            ),
        }
    }
}

/// Most operations a value may take to compute from the inputs and still be recomputed by
/// [`SsaTape::rematerialised`].
pub const REMAT_COST: u32 = 6;

/// The larger bound of the second attempt of [`SsaTape::compile`]: a value recomputed at
/// each of its distant readers costs at most this many operations more per reader, which is
/// the price of a program that otherwise would not run at all.
pub const REMAT_COST_FALLBACK: u32 = 64;

/// How many operations old the last copy of such a value may be and still be read.
pub const REMAT_DISTANCE: usize = 24;

/// The rewriting state of [`SsaTape::rematerialised`].
struct Remat<'a> {
    ops: &'a [SsaOp],
    /// What recomputing each value costs (None: never recomputed).
    cost: &'a [Option<u32>],
    /// Index in `out` of each value's newest copy (`u32::MAX`: none yet).
    copy: Vec<u32>,
    out: Vec<SsaOp>,
}

impl Remat<'_> {
    /// A copy of value v recent enough to read now, emitting a new one if needed.
    fn fresh(&mut self, v: u32) -> u32 {
        let v = v as usize;
        let c = self.copy[v];
        let recomputable = matches!(self.cost[v], Some(k) if k > 0);
        if c != u32::MAX && (!recomputable || self.out.len() - c as usize <= REMAT_DISTANCE) {
            return c;
        }
        self.emit(v)
    }

    /// Emits value v with its operands read from fresh copies; returns its index.
    fn emit(&mut self, v: usize) -> u32 {
        let mut op = self.ops[v];
        match op.op.shape() {
            Shape::Nullary | Shape::MatLoad => {}
            Shape::Unary | Shape::WithImm => op.a = self.fresh(op.a),
            Shape::Binary => {
                op.a = self.fresh(op.a);
                op.b = self.fresh(op.b);
            }
            Shape::Ternary => {
                op.a = self.fresh(op.a);
                op.b = self.fresh(op.b);
                op.c = self.fresh(op.c);
            }
            Shape::MatMix => {
                // materials are never recomputed: their copies are the originals
                op.a = self.copy[op.a as usize];
                op.b = self.copy[op.b as usize];
                op.c = self.fresh(op.c);
            }
        }
        let at = self.out.len() as u32;
        self.copy[v] = at;
        self.out.push(op);
        at
    }
}

/// A set of free registers; the lowest is taken first, so allocation is deterministic.
struct FreeRegisters {
    words: [u64; MAX_REGISTERS / 64],
}

impl FreeRegisters {
    fn new(count: usize) -> Self {
        let mut words = [0u64; MAX_REGISTERS / 64];
        for i in 0..count {
            words[i / 64] |= 1 << (i % 64);
        }
        FreeRegisters { words }
    }

    fn take(&mut self) -> Option<u8> {
        for (w, word) in self.words.iter_mut().enumerate() {
            if *word != 0 {
                let bit = word.trailing_zeros() as usize;
                *word &= !(1 << bit);
                return Some((w * 64 + bit) as u8);
            }
        }
        None
    }

    fn take_specific(&mut self, r: u8) -> u8 {
        self.words[r as usize / 64] &= !(1 << (r % 64));
        r
    }

    fn give(&mut self, r: u8) {
        self.words[r as usize / 64] |= 1 << (r % 64);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn folding_identities_and_sharing() {
        let mut b = Builder::new();
        let [x, y, _] = b.point();
        let two = b.konst(2.0);
        let three = b.konst(3.0);
        let six = b.binary(Op::Mul, two, three);
        assert_eq!(b.constant(six), Some(6.0));
        let s1 = b.binary(Op::Add, x, y);
        let s2 = b.binary(Op::Add, y, x);
        assert_eq!(s1, s2, "a + b and b + a are one value");
        let n = b.unary(Op::Neg, s1);
        assert_eq!(b.unary(Op::Neg, n), s1);
        let zero = b.konst(0.0);
        assert_eq!(b.binary(Op::Add, s1, zero), s1);
        let k = b.binary(Op::Sub, six, x);
        assert_eq!(b.def(k).op, Op::RsubImm);
        assert_eq!(b.binary(Op::Min, k, k), k);
        let prog = b.finish(k, None);
        let tape = prog.compile().unwrap();
        assert_eq!(tape.len(), 1, "{:?}", tape.instrs());
        assert_eq!(tape.eval(Vec3::new(1.5, 0.0, 0.0)), 4.5);
    }

    /// A union of `nx`·`ny` boxes of half sizes h in the xy-plane, row by row, the column
    /// offsets shared between rows (as hash-consing shares them): each offset lives from the
    /// first row to the last. Returns the program and the same formula in plain Rust.
    fn grid(nx: usize, ny: usize) -> (SsaTape, impl Fn(f32, f32) -> f32) {
        let (h, step) = (0.4f32, 1.0f32);
        let mut b = Builder::new();
        let [x, y, _] = b.point();
        let mut acc = None;
        for j in 0..ny {
            for i in 0..nx {
                let dx = b.with_imm(Op::SubImm, x, i as f32 * step);
                let dy = b.with_imm(Op::SubImm, y, j as f32 * step);
                let ax = b.unary(Op::Abs, dx);
                let ay = b.unary(Op::Abs, dy);
                let ex = b.with_imm(Op::SubImm, ax, h);
                let ey = b.with_imm(Op::SubImm, ay, h);
                let d = b.binary(Op::Max, ex, ey);
                acc = Some(acc.map_or(d, |a| b.binary(Op::Min, a, d)));
            }
        }
        let prog = b.finish(acc.unwrap(), None);
        let plain = move |px: f32, py: f32| {
            let mut m = f32::INFINITY;
            for j in 0..ny {
                for i in 0..nx {
                    let ex = (px - i as f32 * step).abs() - h;
                    let ey = (py - j as f32 * step).abs() - h;
                    m = m.min(ex.max(ey));
                }
            }
            m
        };
        (prog, plain)
    }

    #[test]
    fn rematerialisation_recomputes_long_lived_cheap_values_when_registers_run_out() {
        let (prog, plain) = grid(300, 2);
        assert!(
            prog.compile_part(false).is_err(),
            "300 shared column offsets should not fit in {MAX_REGISTERS} registers"
        );
        let tape = prog
            .compile_distance()
            .expect("fits after rematerialisation");
        let mut rng = crate::rng::Rng::new(7);
        for _ in 0..200 {
            let (px, py) = (rng.range_f32(-2.0, 302.0), rng.range_f32(-2.0, 3.0));
            let p = Vec3::new(px, py, 0.0);
            assert_eq!(tape.eval(p).to_bits(), plain(px, py).to_bits(), "at {p}");
        }
        // a program that fits is rewritten to the same values
        let (small, _) = grid(6, 3);
        let a = small.compile_part(false).unwrap();
        let b = small
            .rematerialised(false, REMAT_COST)
            .compile_part(false)
            .unwrap();
        for _ in 0..100 {
            let p = Vec3::new(rng.range_f32(-1.0, 7.0), rng.range_f32(-1.0, 4.0), 0.0);
            assert_eq!(a.eval(p).to_bits(), b.eval(p).to_bits(), "at {p}");
        }
    }

    #[test]
    fn members_of_many_orientations_under_a_rotated_object_fit_after_rematerialisation() {
        use crate::sdf::conformance::parse_node;
        use crate::sdf::lower::lower;
        // 600 boxes in 90 orientations under a rotation and a scale: each orientation's
        // rotated coordinates cost a dozen operations of the inputs and are shared by members
        // all over the union, more of them than there are registers
        let members: Vec<String> = (0..600)
            .map(|i| {
                let (x, y, z) = ((i % 25) as f32 * 0.3, (i / 25) as f32 * 0.2, (i % 7) as f32);
                format!(
                    "Transform(translate: ({x}, {y}, {z}), rotate: ({}, {}, 0), \
                     shape: Box(half_extents: (0.07, 0.05, 0.09)))",
                    i % 90,
                    i % 45
                )
            })
            .collect();
        let src = format!(
            "Transform(rotate: (0, 20, 0), scale: 0.9, shape: Union([{}]))",
            members.join(", ")
        );
        let node = parse_node(&src);
        let lowered = lower(&node, &|_| Some(0), 0).expect("fits after rematerialisation");
        // the same distances as the members' minimum, each member lowered alone
        let one = |i: usize| {
            let m = format!(
                "Transform(rotate: (0, 20, 0), scale: 0.9, shape: Union([{}]))",
                members[i]
            );
            lower(&parse_node(&m), &|_| Some(0), 0).unwrap().distance
        };
        let singles: Vec<Tape> = (0..members.len()).map(one).collect();
        let mut rng = crate::rng::Rng::new(11);
        for _ in 0..50 {
            let p = Vec3::new(
                rng.range_f32(-1.0, 8.0),
                rng.range_f32(-1.0, 5.0),
                rng.range_f32(-1.0, 7.0),
            );
            let least = singles
                .iter()
                .map(|t| t.eval(p))
                .fold(f32::INFINITY, f32::min);
            assert_eq!(
                lowered.distance.eval(p).to_bits(),
                least.to_bits(),
                "at {p}"
            );
        }
    }

    #[test]
    fn registers_are_reused_after_the_last_reader() {
        // a long chain x + 1 + 1 + … needs one register beyond the inputs
        let mut b = Builder::new();
        let [x, y, z] = b.point();
        let mut v = b.binary(Op::Add, x, y);
        for _ in 0..1000 {
            v = b.with_imm(Op::AddImm, v, 1.0);
            v = b.binary(Op::Max, v, z);
        }
        let tape = b.finish(v, None).compile().unwrap();
        assert!(tape.registers() <= 4, "{}", tape.registers());
        assert_eq!(tape.eval(Vec3::new(1.0, 2.0, 0.0)), 1003.0);
    }

    #[test]
    fn too_many_live_values_is_an_error() {
        let mut b = Builder::new();
        let [x, ..] = b.point();
        // each value costs more than REMAT_COST_FALLBACK operations, so none is recomputed
        let vals: Vec<V> = (0..300)
            .map(|i| {
                let mut v = b.with_imm(Op::AddImm, x, i as f32 + 0.5);
                for _ in 0..REMAT_COST_FALLBACK {
                    v = b.unary(Op::Sin, v);
                }
                v
            })
            .collect();
        let mut acc = vals[0];
        for v in &vals[1..] {
            acc = b.binary(Op::Mul, acc, *v);
        }
        // every value is live until the chain reaches it: more than 256 at once
        let mut acc2 = vals[299];
        for v in vals.iter().rev().skip(1) {
            acc2 = b.binary(Op::Add, acc2, *v);
        }
        let r = b.binary(Op::Add, acc, acc2);
        let e = b.finish(r, None).compile().unwrap_err();
        assert!(e.contains("256 registers"), "{e}");
    }
}
