//! The tape: the flat instruction list every backend evaluates, and the CPU interpreter for it.
//!
//! An SDF tree is lowered once (see [`crate::sdf::lower`]) into a straight-line program over
//! 4-wide float registers, in the manner of fidget's bytecode: the CPU runs it with the
//! interpreter below and the GPU will upload the very same instructions and constants. SDF
//! formulas therefore exist exactly once, as lowering code; a backend only implements the
//! handful of elementary operations listed in [`Op`].
//!
//! Layout (`#[repr(C)]`, `bytemuck::Pod`, 48 bytes per instruction):
//! `op, dst, a, b, c, aux, pad, pad: u32` then `imm: [f32; 4]`.
//! Register 0 holds the sample point (x, y, z, 0) on entry. A `b` operand equal to
//! [`IMM`] means "use `imm`" instead of a register. Material operations (`MatLoad`, `MatMix`)
//! act on a second register file of blended materials and are absent from distance-only tapes.

use bytemuck::{Pod, Zeroable};
use glam::{Vec3, Vec4};

/// Operand value meaning "the instruction's immediate" instead of a register.
pub const IMM: u32 = u32::MAX;

/// Maximum value registers a tape may use (the GPU interpreter's private array size).
pub const MAX_REGISTERS: usize = 64;

/// Maximum material registers a tape may use.
pub const MAX_MATERIAL_REGISTERS: usize = 16;

/// Number of floats in one blended material (see [`crate::shade::MaterialParams`]).
pub const MATERIAL_FLOATS: usize = 12;

macro_rules! opcodes {
    ($( $(#[$doc:meta])* $name:ident = $val:expr, )*) => {
        /// Elementary operations of the tape. Componentwise ops act on all four lanes.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        #[repr(u32)]
        pub enum Op { $( $(#[$doc])* $name = $val, )* }

        impl Op {
            /// Every opcode, in numeric order.
            pub const ALL: &'static [Op] = &[ $( Op::$name, )* ];

            /// The opcode for a raw number read from an instruction.
            pub fn from_u32(v: u32) -> Option<Op> {
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
    /// dst = imm
    Const = 0,
    /// dst = a + b
    Add = 1,
    /// dst = a − b
    Sub = 2,
    /// dst = a · b
    Mul = 3,
    /// dst = a / b
    Div = 4,
    /// dst = min(a, b)
    Min = 5,
    /// dst = max(a, b)
    Max = 6,
    /// dst = pow(a, b), defined for a ≥ 0 only (integer powers are lowered to products)
    Pow = 7,
    /// dst = −a
    Neg = 8,
    /// dst = |a|
    Abs = 9,
    /// dst = √a
    Sqrt = 10,
    /// dst = sin a
    Sin = 11,
    /// dst = cos a
    Cos = 12,
    /// dst = tan a
    Tan = 13,
    /// dst = eᵃ
    Exp = 14,
    /// dst = ln a
    Ln = 15,
    /// dst = ⌊a⌋
    Floor = 16,
    /// dst = a · b + c
    MulAdd = 17,
    /// dst = (c.x > 0) ? a : b
    Select = 18,
    /// dst = lanes of a chosen by aux: 3 bits per output lane (0–3 = x,y,z,w, 4 = zero)
    Swizzle = 19,
    /// dst = (a[aux&3], b[(aux>>2)&3], c[(aux>>4)&3], 0)
    Pack = 20,
    /// dst.x = a.xyz · b.xyz
    Dot3 = 21,
    /// dst.x = length of the first `aux` lanes of a (aux = 2 or 3)
    Length = 22,
    /// dst.x = max of the first `aux` lanes of a (aux = 2 or 3)
    MaxLane = 23,
    /// dst = (M · (a.xyz, 1), 0) with the 3×4 matrix M in constants[aux..aux+3] (rows)
    Affine = 24,
    /// material register dst = the scene material number aux
    MatLoad = 25,
    /// material register dst = mix(material a, material b, value register c.x)
    MatMix = 26,
}

/// One tape instruction; mirrors `struct Instr` in `shaders/sdf.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct Instr {
    /// An [`Op`] as u32.
    pub op: u32,
    /// Destination register.
    pub dst: u32,
    /// First operand register.
    pub a: u32,
    /// Second operand register, or [`IMM`].
    pub b: u32,
    /// Third operand register.
    pub c: u32,
    /// Op-specific small integer (swizzle pattern, lane count, constant index, material).
    pub aux: u32,
    /// Padding to a 16-byte multiple for WGSL storage layout.
    pub pad: [u32; 2],
    /// Immediate operand.
    pub imm: [f32; 4],
}
const _: () = assert!(std::mem::size_of::<Instr>() == 48);

impl Instr {
    /// The decoded opcode.
    pub fn opcode(&self) -> Op {
        Op::from_u32(self.op).expect("tapes are built only by the lowering code")
    }
}

/// A lowered SDF: instructions, constants, and where the results end up.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Tape {
    /// The program.
    pub instrs: Vec<Instr>,
    /// Large constants (affine matrix rows), referenced by `aux`.
    pub constants: Vec<[f32; 4]>,
    /// Register holding the distance (lane x) at the end.
    pub result: u32,
    /// Material register holding the blended material at the end (shading tapes only).
    pub material_result: Option<u32>,
    /// Value registers used.
    pub registers: usize,
    /// Material registers used.
    pub material_registers: usize,
}

/// Scratch value registers for [`Tape::eval_in`].
pub struct Registers([Vec4; MAX_REGISTERS]);

impl Registers {
    /// Fresh (zeroed) registers.
    pub fn new() -> Self {
        Registers([Vec4::ZERO; MAX_REGISTERS])
    }
}

impl Default for Registers {
    fn default() -> Self {
        Self::new()
    }
}

/// A blended material as the tape carries it: see [`crate::shade::MaterialParams`] for lanes.
pub type MaterialVec = [f32; MATERIAL_FLOATS];

impl Tape {
    /// The signed distance (or bound) at `p`.
    #[inline]
    pub fn eval(&self, p: Vec3) -> f32 {
        self.eval_in(p, &mut Registers::new())
    }

    /// The signed distance at `p`, using caller-provided scratch registers (the tracer keeps
    /// one set per ray instead of clearing 1 KiB per evaluation).
    #[inline]
    pub fn eval_in(&self, p: Vec3, regs: &mut Registers) -> f32 {
        self.run(p, &mut regs.0, None);
        regs.0[self.result as usize & (MAX_REGISTERS - 1)].x
    }

    /// The distance and the blended material at `p` (`materials` is the scene's table).
    pub fn eval_material(&self, p: Vec3, materials: &[MaterialVec]) -> (f32, MaterialVec) {
        let mut regs = [Vec4::ZERO; MAX_REGISTERS];
        let mut mats = [[0.0; MATERIAL_FLOATS]; MAX_MATERIAL_REGISTERS];
        self.run(p, &mut regs, Some((&mut mats, materials)));
        let m = self
            .material_result
            .map(|r| mats[r as usize])
            .unwrap_or_else(|| materials.first().copied().unwrap_or([0.0; MATERIAL_FLOATS]));
        (regs[self.result as usize].x, m)
    }

    /// Central-difference gradient with step h (6 evaluations).
    pub fn gradient(&self, p: Vec3, h: f32) -> Vec3 {
        let dx = Vec3::new(h, 0.0, 0.0);
        let dy = Vec3::new(0.0, h, 0.0);
        let dz = Vec3::new(0.0, 0.0, h);
        Vec3::new(
            self.eval(p + dx) - self.eval(p - dx),
            self.eval(p + dy) - self.eval(p - dy),
            self.eval(p + dz) - self.eval(p - dz),
        ) / (2.0 * h)
    }

    fn run(
        &self,
        p: Vec3,
        regs: &mut [Vec4; MAX_REGISTERS],
        mut materials: Option<(&mut [MaterialVec; MAX_MATERIAL_REGISTERS], &[MaterialVec])>,
    ) {
        regs[0] = p.extend(0.0);
        for ins in &self.instrs {
            let a = regs[ins.a as usize & (MAX_REGISTERS - 1)];
            let b = if ins.b == IMM {
                Vec4::from_array(ins.imm)
            } else {
                regs[ins.b as usize & (MAX_REGISTERS - 1)]
            };
            let c = regs[ins.c as usize & (MAX_REGISTERS - 1)];
            let out = match ins.opcode() {
                Op::Const => Vec4::from_array(ins.imm),
                Op::Add => a + b,
                Op::Sub => a - b,
                Op::Mul => a * b,
                Op::Div => a / b,
                Op::Min => a.min(b),
                Op::Max => a.max(b),
                Op::Pow => a.powf_vec(b),
                Op::Neg => -a,
                Op::Abs => a.abs(),
                Op::Sqrt => a.map(f32::sqrt),
                Op::Sin => a.map(f32::sin),
                Op::Cos => a.map(f32::cos),
                Op::Tan => a.map(f32::tan),
                Op::Exp => a.map(f32::exp),
                Op::Ln => a.map(f32::ln),
                Op::Floor => a.floor(),
                Op::MulAdd => a * b + c,
                Op::Select => {
                    if c.x > 0.0 {
                        a
                    } else {
                        b
                    }
                }
                Op::Swizzle => swizzle(a, ins.aux),
                Op::Pack => Vec4::new(
                    a[(ins.aux & 3) as usize],
                    b[((ins.aux >> 2) & 3) as usize],
                    c[((ins.aux >> 4) & 3) as usize],
                    0.0,
                ),
                Op::Dot3 => Vec4::new(a.truncate().dot(b.truncate()), 0.0, 0.0, 0.0),
                Op::Length => {
                    let l = if ins.aux == 2 {
                        a.truncate().truncate().length()
                    } else {
                        a.truncate().length()
                    };
                    Vec4::new(l, 0.0, 0.0, 0.0)
                }
                Op::MaxLane => {
                    let m = if ins.aux == 2 {
                        a.x.max(a.y)
                    } else {
                        a.x.max(a.y).max(a.z)
                    };
                    Vec4::new(m, 0.0, 0.0, 0.0)
                }
                Op::Affine => {
                    let k = ins.aux as usize;
                    let q = a.truncate().extend(1.0);
                    Vec4::new(
                        Vec4::from_array(self.constants[k]).dot(q),
                        Vec4::from_array(self.constants[k + 1]).dot(q),
                        Vec4::from_array(self.constants[k + 2]).dot(q),
                        0.0,
                    )
                }
                Op::MatLoad => {
                    if let Some((mats, table)) = materials.as_mut() {
                        mats[ins.dst as usize] = table[ins.aux as usize];
                    }
                    continue;
                }
                Op::MatMix => {
                    if let Some((mats, _)) = materials.as_mut() {
                        let (ma, mb) = (mats[ins.a as usize], mats[ins.b as usize]);
                        let h = c.x;
                        mats[ins.dst as usize] =
                            std::array::from_fn(|i| ma[i] + (mb[i] - ma[i]) * h);
                    }
                    continue;
                }
            };
            regs[ins.dst as usize & (MAX_REGISTERS - 1)] = out;
        }
    }
}

/// Swizzle lane selector: 3 bits per output lane, 0–3 pick x, y, z, w and 4 gives zero.
pub fn swizzle(a: Vec4, pattern: u32) -> Vec4 {
    let lane = |i: u32| {
        let s = (pattern >> (3 * i)) & 7;
        if s < 4 { a[s as usize] } else { 0.0 }
    };
    Vec4::new(lane(0), lane(1), lane(2), lane(3))
}

trait PowVec {
    fn powf_vec(self, e: Vec4) -> Vec4;
}

impl PowVec for Vec4 {
    fn powf_vec(self, e: Vec4) -> Vec4 {
        Vec4::new(
            self.x.powf(e.x),
            self.y.powf(e.y),
            self.z.powf(e.z),
            self.w.powf(e.w),
        )
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
    s += &format!("const IMM: u32 = {}u;\n", IMM);
    s += &format!("const MAX_REGISTERS: u32 = {}u;\n", MAX_REGISTERS);
    s += &format!(
        "const MAX_MATERIAL_REGISTERS: u32 = {}u;\n",
        MAX_MATERIAL_REGISTERS
    );
    s += &format!("const MATERIAL_FLOATS: u32 = {}u;\n", MATERIAL_FLOATS);
    s
}
