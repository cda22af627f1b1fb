//! The tape: the flat, register-allocated program every backend evaluates, and its interpreter.
//!
//! An SDF tree is lowered once (see [`crate::sdf::lower`]) into SSA ([`crate::sdf::ssa`]),
//! which is specialised to regions ([`crate::sdf::simplify`]) and register-allocated into a
//! [`Tape`]: a straight-line program over scalar `f32` registers, in the manner of fidget's
//! bytecode and libfive's tapes. The CPU runs it with the interpreter below — one point per
//! call, or 4 or 8 points per instruction on SIMD lanes ([`crate::sdf::simd`]) — and the GPU
//! uploads the very same instructions (`shaders/tape.wgsl`). SDF formulas therefore exist
//! exactly once, as lowering code; a backend only implements the elementary operations of
//! [`Op`].
//!
//! Layout (`#[repr(C)]`, `bytemuck::Pod`, 8 bytes per instruction): `op, out, a, b: u8`, then
//! `imm: u32`, an `f32` immediate for the `…Imm` ops and [`Op::Const`], the third register of
//! [`Op::Select`], [`Op::Hypot3`] and [`Op::MatMix`], or a material number. Registers 0, 1 and 2 hold the
//! sample point's x, y and z on entry. Material operations act on a second register file of
//! blended materials and are absent from distance tapes.

use crate::sdf::lanes::Lanes;
use crate::sdf::math;
use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// Value registers a tape may use: register numbers are bytes.
pub const MAX_REGISTERS: usize = 256;

// Native code spills each tape register to a slot of its own.
const _: () = assert!(MAX_REGISTERS == crate::sdf::native::SLOTS);

/// Material registers a tape may use.
pub const MAX_MATERIAL_REGISTERS: usize = 16;

/// Number of floats in one blended material (see [`crate::scene::material::MaterialParams`]).
pub const MATERIAL_FLOATS: usize = 20;

/// A blended material as the tape carries it: see [`crate::scene::material::MaterialParams`] for lanes.
pub type MaterialVec = [f32; MATERIAL_FLOATS];

macro_rules! opcodes {
    ($( $(#[$doc:meta])* $name:ident = $val:expr, )*) => {
        /// Elementary operations of the tape, on scalars.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
        #[repr(u8)]
        pub enum Op { $( $(#[$doc])* $name = $val, )* }

        impl Op {
            /// Every opcode, in numeric order.
            pub const ALL: &'static [Op] = &[ $( Op::$name, )* ];

            /// The opcode for a raw number read from an instruction.
            pub fn from_u8(v: u8) -> Option<Op> {
                match v { $( $val => Some(Op::$name), )* _ => None }
            }

            /// The opcode's name as used in generated WGSL constants (`OP_<NAME>`).
            pub fn name(self) -> &'static str {
                match self { $( Op::$name => stringify!($name), )* }
            }
        }
    };
}

opcodes! {
    /// out = imm
    Const = 0,
    /// out = a
    Copy = 1,
    /// out = −a
    Neg = 2,
    /// out = |a|
    Abs = 3,
    /// out = √a
    Sqrt = 4,
    /// out = a²
    Square = 5,
    /// out = ⌊a⌋
    Floor = 6,
    /// out = sin a
    Sin = 7,
    /// out = cos a
    Cos = 8,
    /// out = tan a
    Tan = 9,
    /// out = eᵃ
    Exp = 10,
    /// out = ln a
    Ln = 11,
    /// out = a + b
    Add = 12,
    /// out = a − b
    Sub = 13,
    /// out = a · b
    Mul = 14,
    /// out = a / b
    Div = 15,
    /// out = min(a, b)
    Min = 16,
    /// out = max(a, b)
    Max = 17,
    /// out = aᵇ, defined for a ≥ 0 only (integer powers are lowered to products)
    Pow = 18,
    /// out = √(a² + b²), computed as sqrt(a·a + b·b): a 2-D length as one operation, whose
    /// slope the interval evaluator bounds by Cauchy–Schwarz
    Hypot = 19,
    /// out = a + imm
    AddImm = 20,
    /// out = a − imm
    SubImm = 21,
    /// out = imm − a
    RsubImm = 22,
    /// out = a · imm
    MulImm = 23,
    /// out = a / imm
    DivImm = 24,
    /// out = imm / a
    RdivImm = 25,
    /// out = min(a, imm)
    MinImm = 26,
    /// out = max(a, imm)
    MaxImm = 27,
    /// out = a^imm, a ≥ 0
    PowImm = 28,
    /// out = (register imm > 0) ? a : b
    Select = 29,
    /// out = √(a² + b² + c²) with c the register imm, computed as sqrt((a·a + b·b) + c·c): a
    /// 3-D length as one operation (nested `Hypot`s would round once more)
    Hypot3 = 33,
    /// material out = the scene material number imm
    MatLoad = 30,
    /// material out = mix(material a, material b, value register imm)
    MatMix = 31,
    /// out = the sample point's coordinate imm (0, 1, 2); SSA only: tapes start with the
    /// point in registers 0–2
    Input = 32,
}

/// What an operation reads and writes, for liveness and register allocation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    /// No operands (`Const`, `Input`).
    Nullary,
    /// Reads `a`.
    Unary,
    /// Reads `a` and `b`.
    Binary,
    /// Reads `a` and an `f32` immediate.
    WithImm,
    /// Reads `a`, `b` and the value register in `imm`.
    Ternary,
    /// Writes a material register from the table (`MatLoad`).
    MatLoad,
    /// Reads materials `a`, `b` and the value register in `imm`, writes a material.
    MatMix,
}

impl Op {
    /// The operation's operands.
    pub fn shape(self) -> Shape {
        use Op::*;
        match self {
            Const | Input => Shape::Nullary,
            Copy | Neg | Abs | Sqrt | Square | Floor | Sin | Cos | Tan | Exp | Ln => Shape::Unary,
            Add | Sub | Mul | Div | Min | Max | Pow | Hypot => Shape::Binary,
            AddImm | SubImm | RsubImm | MulImm | DivImm | RdivImm | MinImm | MaxImm | PowImm => {
                Shape::WithImm
            }
            Select | Hypot3 => Shape::Ternary,
            MatLoad => Shape::MatLoad,
            MatMix => Shape::MatMix,
        }
    }

    /// Whether the result is a material.
    pub fn is_material(self) -> bool {
        matches!(self, Op::MatLoad | Op::MatMix)
    }
}

/// The value of one value operation, on any lanes: the single definition of what every op
/// computes, shared by the interpreters, constant folding and the tests. `c` is the third
/// operand of [`Op::Select`]; `imm` the immediate of the `…Imm` ops and [`Op::Const`].
#[inline(always)]
pub fn apply<L: Lanes>(op: Op, a: L, b: L, c: L, imm: f32) -> L {
    let k = || L::splat(imm);
    match op {
        Op::Const => k(),
        Op::Copy => a,
        Op::Neg => a.neg(),
        Op::Abs => a.abs(),
        Op::Sqrt => a.sqrt(),
        Op::Square => a.mul(a),
        Op::Floor => a.floor(),
        Op::Sin => math::sin(a),
        Op::Cos => math::cos(a),
        Op::Tan => math::tan(a),
        Op::Exp => math::exp(a),
        Op::Ln => math::ln(a),
        Op::Add => a.add(b),
        Op::Sub => a.sub(b),
        Op::Mul => a.mul(b),
        Op::Div => a.div(b),
        Op::Min => a.min(b),
        Op::Max => a.max(b),
        Op::Pow => math::pow(a, b),
        Op::Hypot => a.mul(a).add(b.mul(b)).sqrt(),
        Op::AddImm => a.add(k()),
        Op::SubImm => a.sub(k()),
        Op::RsubImm => k().sub(a),
        Op::MulImm => a.mul(k()),
        Op::DivImm => a.div(k()),
        Op::RdivImm => k().div(a),
        Op::MinImm => a.min(k()),
        Op::MaxImm => a.max(k()),
        Op::PowImm => math::pow(a, k()),
        Op::Select => L::select_pos(c, a, b),
        Op::Hypot3 => a.mul(a).add(b.mul(b)).add(c.mul(c)).sqrt(),
        // Not value operations: the interpreters handle them apart.
        Op::MatLoad | Op::MatMix | Op::Input => L::splat(0.0),
    }
}

/// One tape instruction. The GPU reads the same bytes as two `u32` words (`InstrRecord` in
/// `crate::gpu::records`): the byte fields' positions in the first word are generated from
/// this declaration ([`wgsl_constants`]: `INSTR_*_SHIFT`), so the field order is stated once.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Pod, Zeroable)]
pub struct Instr {
    op: u8,
    out: u8,
    a: u8,
    b: u8,
    imm: u32,
}
const _: () = assert!(std::mem::size_of::<Instr>() == 8);
// WGSL storage buffers are little-endian: the byte at offset k of the first word is its bits
// 8k..8k+8 only on a little-endian host.
#[cfg(not(target_endian = "little"))]
compile_error!("the GPU reads tape instructions as little-endian words");
// The byte fields fill the first word, the immediate is the second.
const _: () = assert!(
    std::mem::offset_of!(Instr, op) < 4
        && std::mem::offset_of!(Instr, out) < 4
        && std::mem::offset_of!(Instr, a) < 4
        && std::mem::offset_of!(Instr, b) < 4
);
/// Byte offset of an instruction's immediate (the GPU record's second word).
pub const INSTR_IMM_OFFSET: usize = std::mem::offset_of!(Instr, imm);

impl Instr {
    /// An instruction; only [`crate::sdf::ssa`]'s register allocator makes them, so that a
    /// tape's operation bytes are always valid [`Op`]s.
    pub(crate) fn new(op: Op, out: u8, a: u8, b: u8, imm: u32) -> Self {
        Instr {
            op: op as u8,
            out,
            a,
            b,
            imm,
        }
    }

    /// The operation.
    #[inline(always)]
    pub fn op(&self) -> Op {
        // SAFETY: `Instr::new` is the only constructor and stores `Op as u8`; `Op` is
        // `repr(u8)`, so the byte is a valid discriminant.
        unsafe { std::mem::transmute::<u8, Op>(self.op) }
    }

    /// Destination register (a material register for material ops).
    #[inline(always)]
    pub fn out(&self) -> u8 {
        self.out
    }

    /// First operand register.
    #[inline(always)]
    pub fn a(&self) -> u8 {
        self.a
    }

    /// Second operand register.
    #[inline(always)]
    pub fn b(&self) -> u8 {
        self.b
    }

    /// The immediate's raw bits.
    #[inline(always)]
    pub fn imm_bits(&self) -> u32 {
        self.imm
    }

    /// The immediate as a float.
    #[inline(always)]
    pub fn imm(&self) -> f32 {
        f32::from_bits(self.imm)
    }
}

/// A register-allocated program: instructions, and where the results end up.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Tape {
    pub(crate) instrs: Vec<Instr>,
    pub(crate) result: u8,
    pub(crate) material_result: Option<u8>,
    /// The material table entry a shading tape's material is, when it is not a blend.
    pub(crate) constant_material: Option<u32>,
    pub(crate) registers: usize,
    pub(crate) material_registers: usize,
    /// The tape compiled to native code ([`crate::sdf::jit`]), where it was.
    pub(crate) native: Option<crate::sdf::native::Native>,
}

/// Scratch value registers for [`Tape::eval_in`].
pub struct Registers(Box<[f32; MAX_REGISTERS]>);

impl Registers {
    /// Fresh (zeroed) registers.
    pub fn new() -> Self {
        Registers(Box::new([0.0; MAX_REGISTERS]))
    }
}

impl Default for Registers {
    fn default() -> Self {
        Self::new()
    }
}

thread_local! {
    /// Registers given back by [`PooledRegisters`], for the next query on this thread.
    static REGISTER_POOL: std::cell::RefCell<Vec<Registers>> = const { std::cell::RefCell::new(Vec::new()) };
}

impl Registers {
    /// Registers from this thread's pool, returned to it when dropped: a query that evaluates
    /// a few points (a reflected ray, a shadow ray, a normal) then costs no allocation and no
    /// zeroing of 1 KiB. A tape writes every register it reads, so what a previous query
    /// left in them does not matter.
    pub fn pooled() -> PooledRegisters {
        let regs = REGISTER_POOL
            .with(|pool| pool.borrow_mut().pop())
            .unwrap_or_default();
        PooledRegisters(Some(regs))
    }
}

/// [`Registers`] borrowed from the thread's pool ([`Registers::pooled`]).
pub struct PooledRegisters(Option<Registers>);

impl std::ops::Deref for PooledRegisters {
    type Target = Registers;
    fn deref(&self) -> &Registers {
        self.0.as_ref().expect("held until dropped")
    }
}

impl std::ops::DerefMut for PooledRegisters {
    fn deref_mut(&mut self) -> &mut Registers {
        self.0.as_mut().expect("held until dropped")
    }
}

impl Drop for PooledRegisters {
    fn drop(&mut self) {
        if let Some(regs) = self.0.take() {
            // `try_with`: during thread teardown the pool may be gone; the registers are freed
            let _ = REGISTER_POOL.try_with(|pool| pool.borrow_mut().push(regs));
        }
    }
}

impl Tape {
    /// Whether the tape has native code ([`crate::sdf::jit::compile_all`]).
    pub fn is_native(&self) -> bool {
        self.native.is_some()
    }

    /// The tape's native code, if it has any.
    pub fn native_code(&self) -> Option<&crate::sdf::native::Native> {
        self.native.as_ref()
    }

    /// The same program without its native code: what the interpreter runs.
    pub fn interpreted(&self) -> Tape {
        Tape {
            native: None,
            ..self.clone()
        }
    }

    /// The instructions.
    pub fn instrs(&self) -> &[Instr] {
        &self.instrs
    }

    /// Number of instructions.
    pub fn len(&self) -> usize {
        self.instrs.len()
    }

    /// Whether the tape has no instruction (the result is an input register).
    pub fn is_empty(&self) -> bool {
        self.instrs.is_empty()
    }

    /// The largest magnitude among the tape's constants (0 without any): with the point's, it
    /// sets the scale of the values the tape computes, and so of its rounding errors.
    pub fn largest_constant(&self) -> f32 {
        self.instrs
            .iter()
            .filter(|i| matches!(i.op().shape(), Shape::Nullary | Shape::WithImm))
            .filter(|i| i.op() != Op::Input)
            .map(|i| i.imm().abs())
            .filter(|v| v.is_finite())
            .fold(0.0, f32::max)
    }

    /// Register holding the distance at the end.
    pub fn result(&self) -> u8 {
        self.result
    }

    /// Material register holding the blended material at the end (shading tapes only).
    pub fn material_result(&self) -> Option<u8> {
        self.material_result
    }

    /// Value registers used.
    pub fn registers(&self) -> usize {
        self.registers
    }

    /// Material registers used.
    pub fn material_registers(&self) -> usize {
        self.material_registers
    }

    /// The signed distance (or bound) at `p`.
    #[inline]
    pub fn eval(&self, p: Vec3) -> f32 {
        self.eval_in(p, &mut Registers::new())
    }

    /// The signed distance at `p`, using caller-provided scratch registers (the tracer keeps
    /// one set per thread instead of allocating 1 KiB per evaluation).
    #[inline]
    pub fn eval_in(&self, p: Vec3, regs: &mut Registers) -> f32 {
        self.eval_lanes(p.x, p.y, p.z, &mut regs.0)
    }

    /// The tape on lanes: lane i of the result is the distance at (x[i], y[i], z[i]), with
    /// the bits a scalar evaluation at that point gives.
    #[inline(always)]
    pub fn eval_lanes<L: Lanes>(&self, x: L, y: L, z: L, r: &mut [L; MAX_REGISTERS]) -> L {
        r[0] = x;
        r[1] = y;
        r[2] = z;
        let material = self.material_registers > 0;
        for ins in &self.instrs {
            // Every operand slot is read unconditionally (a byte always names a register):
            // the compiler sinks the loads into the arms that use them, and no branch is
            // spent deciding which to read.
            let a = r[ins.a as usize];
            let b = r[ins.b as usize];
            let c = r[ins.imm as u8 as usize];
            let op = ins.op();
            // a shading tape's material operations write material registers, not these
            if material && op.is_material() {
                continue;
            }
            r[ins.out as usize] = apply(op, a, b, c, ins.imm());
        }
        r[self.result as usize]
    }

    /// The distance and the blended material at `p` (`materials` is the scene's table).
    pub fn eval_material(&self, p: Vec3, materials: &[MaterialVec]) -> (f32, MaterialVec) {
        // the value registers from the pool (zeroing 1 KiB for every hit showed in profiles)
        let mut pooled = Registers::pooled();
        self.eval_material_lanes(p.x, p.y, p.z, materials, &mut (*pooled).0)
    }

    /// [`Self::eval_material`] on lanes: lane i of the distance and of each of the
    /// [`MATERIAL_FLOATS`] material entries holds the bits a scalar evaluation at
    /// (x[i], y[i], z[i]) gives (each lane's operations are the scalar's, in the same order).
    /// `r` is scratch.
    #[inline(always)]
    pub fn eval_material_lanes<L: Lanes>(
        &self,
        x: L,
        y: L,
        z: L,
        materials: &[MaterialVec],
        r: &mut [L; MAX_REGISTERS],
    ) -> (L, [L; MATERIAL_FLOATS]) {
        let load = |k: u32| {
            materials
                .get(k as usize)
                .copied()
                .unwrap_or([0.0; MATERIAL_FLOATS])
                .map(L::splat)
        };
        let mut mats = [[L::splat(0.0); MATERIAL_FLOATS]; MAX_MATERIAL_REGISTERS];
        let mreg = |i: u8| i as usize % MAX_MATERIAL_REGISTERS;
        r[0] = x;
        r[1] = y;
        r[2] = z;
        for ins in &self.instrs {
            match ins.op() {
                Op::MatLoad => mats[mreg(ins.out)] = load(ins.imm),
                Op::MatMix => {
                    let (ma, mb) = (mats[mreg(ins.a)], mats[mreg(ins.b)]);
                    let h = r[ins.imm as u8 as usize];
                    mats[mreg(ins.out)] =
                        std::array::from_fn(|i| ma[i].add(mb[i].sub(ma[i]).mul(h)));
                }
                op => {
                    let a = r[ins.a as usize];
                    let b = r[ins.b as usize];
                    let c = r[ins.imm as u8 as usize];
                    r[ins.out as usize] = apply(op, a, b, c, ins.imm());
                }
            }
        }
        let m = match self.material_result {
            Some(m) => mats[mreg(m)],
            None => load(0),
        };
        (r[self.result as usize], m)
    }

    /// The blended material at `p`: [`Self::eval_material`]'s, without evaluating anything
    /// when the material is one table entry (an object of one material, or a leaf where one
    /// branch of every blend is decided).
    pub fn material_at(&self, p: Vec3, materials: &[MaterialVec]) -> MaterialVec {
        match self.constant_material {
            Some(k) => materials
                .get(k as usize)
                .copied()
                .unwrap_or([0.0; MATERIAL_FLOATS]),
            None => self.eval_material(p, materials).1,
        }
    }

    /// Whether [`Self::material_at`] is the same at every point.
    pub fn has_constant_material(&self) -> bool {
        self.constant_material.is_some()
    }

    /// Central-difference gradient with step h (6 evaluations).
    pub fn gradient(&self, p: Vec3, h: f32) -> Vec3 {
        let mut regs = Registers::new();
        let mut f = |q: Vec3| self.eval_in(q, &mut regs);
        Vec3::new(
            f(p + Vec3::X * h) - f(p - Vec3::X * h),
            f(p + Vec3::Y * h) - f(p - Vec3::Y * h),
            f(p + Vec3::Z * h) - f(p - Vec3::Z * h),
        ) / (2.0 * h)
    }
}

/// WGSL constant declarations for every opcode and tape limit, generated from [`Op`] so the
/// shader and the Rust side can never disagree (fidget's `opcode_constants` habit).
pub fn wgsl_constants() -> String {
    let mut s =
        String::from("// Generated from src/sdf/tape.rs by hytrace::sdf::tape::wgsl_constants.\n");
    for op in Op::ALL {
        s += &format!(
            "const OP_{}: u32 = {}u;\n",
            op.name().to_uppercase(),
            *op as u32
        );
    }
    s += &format!("const MAX_REGISTERS: u32 = {}u;\n", MAX_REGISTERS);
    s += &format!(
        "const MAX_MATERIAL_REGISTERS: u32 = {}u;\n",
        MAX_MATERIAL_REGISTERS
    );
    s += &format!("const MATERIAL_FLOATS: u32 = {}u;\n", MATERIAL_FLOATS);
    // bit positions of the byte fields in an instruction's first word
    for (name, offset) in [
        ("OP", std::mem::offset_of!(Instr, op)),
        ("OUT", std::mem::offset_of!(Instr, out)),
        ("A", std::mem::offset_of!(Instr, a)),
        ("B", std::mem::offset_of!(Instr, b)),
    ] {
        s += &format!("const INSTR_{name}_SHIFT: u32 = {}u;\n", 8 * offset);
    }
    s
}
