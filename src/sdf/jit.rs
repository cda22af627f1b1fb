//! Native code for tapes: each distance tape compiled to x86-64 AVX2 machine code that
//! evaluates it at 8 points, with the bits of the interpreter.
//!
//! The interpreter ([`crate::sdf::tape`]) decodes every instruction for every pass, and on 8
//! lanes that dispatch is most of its cost (about 3.6 ns per instruction, where the arithmetic
//! takes a cycle or two; BENCHMARKS.md, "JIT or library"). Here a tape becomes straight-line
//! code, in the manner of fidget's JIT and of Keeter's "Massively Parallel Rendering of Complex
//! Closed-Form Implicit Surfaces" (SIGGRAPH 2020), which also compiles region-specialised
//! tapes: each instruction is one to six AVX instructions on YMM registers. The tape's
//! registers (up to 256) live in YMM registers while they are used; a register allocator over
//! the straight-line program (Belady's rule: evict the value used farthest in the future,
//! which is optimal for a known sequence of uses) spills the others to a scratch area of 256
//! eight-lane slots, one per tape register. The tape stays the program: native code is a
//! derived cache of it, made when the scene's fields are built ([`compile_grouped`]), within a
//! budget of code bytes per object (`accel::field::NATIVE_CODE_BYTES`).
//!
//! Every operation performs exactly the instructions the AVX2 lanes of [`crate::sdf::simd`]
//! perform (`min`/`max` with the same NaN rule, `vroundps` for `floor`, no fused
//! multiply-adds), so native code returns the interpreter's bits (tested below on every op,
//! on spicy inputs, the conformance catalogue and random tapes). The transcendental functions
//! (`sin`, `cos`, `tan`, `exp`, `ln`, `pow`) are not written again in assembly: the code calls
//! the interpreter's own 8-lane implementation of the op (`simd::apply_avx2`), so their
//! polynomials exist once; a `sin` and a `cos` of the same value share one call and one
//! argument reduction (`simd::sin_cos_avx2`), as gyroids, twists and bends ask for.
//!
//! Why dynasmrt: code generation needs an x86-64 assembler at run time, and dynasmrt (also
//! what fidget uses) gives one with executable buffers; Cranelift would bring a whole compiler
//! and its own register allocator for straight-line tapes that a few lines here allocate.
//! Why not fidget's JIT: it compiles fidget's own tapes, with its own operations, NaN rules
//! and transcendental functions, so every leaf tape would be converted and the bits would no
//! longer be the interpreter's and the GPU's (BENCHMARKS.md, "JIT or library").

use crate::sdf::tape::Tape;

/// Whether this CPU runs native tapes (AVX2).
pub fn available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Most instructions compiled into one executable buffer: a block of tapes is compiled by one
/// thread, the blocks in parallel.
const BLOCK_INSTRUCTIONS: usize = 1 << 16;

/// Most bytes of machine code one tape instruction becomes: a call of the interpreter's lanes
/// after spilling all 14 allocatable registers (187 bytes), rounded up; an inline operation
/// takes at most 93 (three operand loads after evictions, one more eviction, `hypot3`'s six
/// instructions). Measured by `hytrace info`: 7.4 MiB for the 400 spheres' octree, 52 MiB for
/// a 1,000-box union's (4.4 M instructions counting the shading tapes, which are not
/// compiled): about 20 bytes per compiled instruction, an immediate operand taking three
/// instructions to broadcast.
const MAX_CODE_BYTES_PER_INSTRUCTION: usize = 192;

/// Most bytes of one tape's entry and exit code.
const MAX_CODE_BYTES_PER_TAPE: usize = 64;

/// Compiles the tapes of `tapes` that have no native code yet and that native code serves
/// (distance tapes: no material operations) into at most `max_bytes` bytes of machine code,
/// on the rayon pool, and attaches the code to each tape ([`Tape::is_native`]). A tape that
/// would not fit is left to the interpreter, which gives the same values. Returns the bytes
/// used. Does nothing where [`available`] is false.
pub fn compile_all(tapes: &mut [Tape], max_bytes: usize) -> usize {
    let mut grouped: Vec<(&mut Tape, usize)> = tapes.iter_mut().map(|t| (t, 0)).collect();
    compile_grouped(&mut grouped, &[max_bytes])[0]
}

/// [`compile_all`] for the tapes of many owners at once: each tape comes with the index of
/// its group in `budgets`, each group's code stays within its own budget, and the tapes of
/// all groups share executable buffers. Returns the bytes each group used.
///
/// Why together: an executable buffer is at least one page of its own mapping, made
/// executable by an `mprotect` that takes the process's memory-map lock. Compiled object by
/// object (two buffers each), a scene of 20,000 small SDF objects spent most of its build in
/// that lock (both threads queued on it, with TLB shootdowns between them), and 200,000
/// spheres of a few hundred bytes of code each held 2.1 GB, 568 MB compiled together.
pub fn compile_grouped(tapes: &mut [(&mut Tape, usize)], budgets: &[usize]) -> Vec<usize> {
    #[cfg(target_arch = "x86_64")]
    if available() {
        return x86::compile_grouped(tapes, budgets);
    }
    let _ = tapes;
    vec![0; budgets.len()]
}

/// Bytes of machine code of `tapes` (each tape's own code; tapes compiled together share
/// buffers, whose pages hold the code of many objects).
pub fn code_bytes(tapes: &[Tape]) -> usize {
    tapes
        .iter()
        .filter_map(|t| t.native.as_ref())
        .map(|n| n.code_len())
        .sum()
}

#[cfg(target_arch = "x86_64")]
// dynasm's macro converts every dynamic register number with `.into()`, even a `u8` to a `u8`
#[allow(clippy::useless_conversion)]
mod x86 {
    use super::{BLOCK_INSTRUCTIONS, MAX_CODE_BYTES_PER_INSTRUCTION, MAX_CODE_BYTES_PER_TAPE};
    use crate::sdf::native::{Entry, Native};
    use crate::sdf::simd::{apply_avx2, sin_cos_avx2};
    use crate::sdf::tape::{Instr, Op, Shape, Tape};
    use dynasmrt::x64::Assembler;
    use dynasmrt::{AssemblyOffset, DynasmApi, dynasm};
    use rayon::prelude::*;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// YMM registers that hold tape values; 14 and 15 are the operations' temporaries.
    const ALLOCATABLE: usize = 14;
    const T0: u8 = 14;
    const T1: u8 = 15;
    /// Bytes of one spill slot (8 lanes).
    const SLOT: i32 = 32;
    /// "Never read again".
    const NEVER: usize = usize::MAX;

    pub(super) fn compile_grouped(
        tapes: &mut [(&mut Tape, usize)],
        budgets: &[usize],
    ) -> Vec<usize> {
        // Blocks of consecutive tapes of about BLOCK_INSTRUCTIONS each.
        let mut blocks: Vec<&mut [(&mut Tape, usize)]> = Vec::new();
        let mut rest = tapes;
        while !rest.is_empty() {
            let mut n = 0;
            let mut len = 0;
            while n < rest.len() && (n == 0 || len + rest[n].0.len() <= BLOCK_INSTRUCTIONS) {
                len += rest[n].0.len();
                n += 1;
            }
            let (block, tail) = rest.split_at_mut(n);
            blocks.push(block);
            rest = tail;
        }
        let used: Vec<AtomicUsize> = budgets.iter().map(|_| AtomicUsize::new(0)).collect();
        blocks
            .into_par_iter()
            .for_each(|block| compile_block(block, &used, budgets));
        used.into_iter().map(AtomicUsize::into_inner).collect()
    }

    fn compilable(tape: &Tape) -> bool {
        tape.native.is_none() && tape.instrs().iter().all(|i| !i.op().is_material())
    }

    /// Compiles one block of tapes into one buffer, each tape while the bytes its group has
    /// `used` (in every block) leave room for its worst case within the group's budget.
    fn compile_block(tapes: &mut [(&mut Tape, usize)], used: &[AtomicUsize], budgets: &[usize]) {
        if !tapes.iter().any(|(t, _)| compilable(t)) {
            return; // no mapping for a block with nothing to compile
        }
        let Ok(mut ops) = Assembler::new() else {
            return; // no executable memory: the tapes stay interpreted
        };
        let mut entries: Vec<Option<(AssemblyOffset, usize)>> = Vec::with_capacity(tapes.len());
        for (tape, group) in tapes.iter() {
            if !compilable(tape) {
                entries.push(None);
                continue;
            }
            let (used, max_bytes) = (&used[*group], budgets[*group]);
            let worst = MAX_CODE_BYTES_PER_TAPE + MAX_CODE_BYTES_PER_INSTRUCTION * tape.len();
            let reserved = used.fetch_add(worst, Ordering::Relaxed);
            if reserved + worst > max_bytes {
                used.fetch_sub(worst, Ordering::Relaxed);
                entries.push(None); // interpreted; a shorter tape after it may still fit
                continue;
            }
            let start = ops.offset().0;
            let at = emit_tape(&mut ops, tape);
            let bytes = ops.offset().0 - start;
            entries.push(Some((at, bytes)));
            debug_assert!(
                bytes <= worst,
                "{bytes} bytes for {} instructions",
                tape.len()
            );
            used.fetch_sub(worst - bytes.min(worst), Ordering::Relaxed);
        }
        if entries.iter().all(Option::is_none) {
            return;
        }
        let Ok(code) = ops.finalize() else {
            return;
        };
        let code = Arc::new(code);
        for ((tape, _), entry) in tapes.iter_mut().zip(entries) {
            if let Some((at, len)) = entry {
                // SAFETY: `at` is the start of a function emitted by `emit_tape` with the
                // `Entry` signature and the System V calling convention.
                let entry: Entry = unsafe { std::mem::transmute(code.ptr(at)) };
                // SAFETY: as above; `emit_tape` reads and writes only the slots of the tape's
                // registers and stashes, all below 256 (`native::SLOTS`), and the code was made
                // only where AVX2 was detected (`compile_grouped`).
                tape.native = Some(unsafe { Native::new(code.clone(), entry, len) });
            }
        }
    }

    /// The operand registers an instruction reads, by its shape.
    fn operands(ins: &Instr) -> ([u8; 3], usize) {
        match ins.op().shape() {
            Shape::Nullary | Shape::MatLoad => ([0; 3], 0),
            Shape::Unary | Shape::WithImm => ([ins.a(), 0, 0], 1),
            Shape::Binary => ([ins.a(), ins.b(), 0], 2),
            Shape::Ternary | Shape::MatMix => ([ins.a(), ins.b(), ins.imm_bits() as u8], 3),
        }
    }

    /// Whether native code calls the interpreter's lanes for the op.
    fn is_call(op: Op) -> bool {
        matches!(
            op,
            Op::Sin | Op::Cos | Op::Tan | Op::Exp | Op::Ln | Op::Pow | Op::PowImm
        )
    }

    /// Next uses, from a backward pass: `reads[i][k]` is the index of the next instruction
    /// after `i` that reads the value operand k of instruction i reads (`NEVER` if none, or if
    /// `i` overwrites it), `written[i]` that of the value instruction i writes; `inputs[r]`
    /// the first read of input register r. The tape's result is read at `len`.
    struct Uses {
        reads: Vec<[usize; 3]>,
        written: Vec<usize>,
        inputs: [usize; 3],
    }

    fn uses(tape: &Tape) -> Uses {
        let instrs = tape.instrs();
        let n = instrs.len();
        let mut next = [NEVER; 256];
        next[tape.result() as usize] = n;
        let mut reads = vec![[NEVER; 3]; n];
        let mut written = vec![NEVER; n];
        for i in (0..n).rev() {
            let ins = &instrs[i];
            written[i] = next[ins.out() as usize];
            next[ins.out() as usize] = NEVER;
            let (regs, count) = operands(ins);
            for k in 0..count {
                reads[i][k] = next[regs[k] as usize];
            }
            for &r in &regs[..count] {
                next[r as usize] = i;
            }
        }
        Uses {
            reads,
            written,
            inputs: [next[0], next[1], next[2]],
        }
    }

    /// Where the tape's values are while code is emitted.
    struct Allocation {
        /// What each allocatable YMM register holds: (tape register, its next read).
        held: [Option<(u8, usize)>; ALLOCATABLE],
        /// The YMM register holding each tape register, if any.
        at: [Option<u8>; 256],
        /// Whether the spill slot of each tape register holds its current value.
        spilled: [bool; 256],
    }

    impl Allocation {
        fn new() -> Self {
            Allocation {
                held: [None; ALLOCATABLE],
                at: [None; 256],
                spilled: [false; 256],
            }
        }

        /// Frees YMM `y` (its value stays in its slot if it was spilled).
        fn release(&mut self, y: u8) {
            if let Some((r, _)) = self.held[y as usize].take() {
                self.at[r as usize] = None;
            }
        }

        /// A YMM register to write: a free one, else the one whose value is read farthest in
        /// the future (Belady), spilled first if its slot is stale and it is read again.
        fn take(&mut self, ops: &mut Assembler, pinned: &[u8]) -> u8 {
            if let Some(y) = (0..ALLOCATABLE as u8).find(|&y| self.held[y as usize].is_none()) {
                return y;
            }
            let y = (0..ALLOCATABLE as u8)
                .filter(|y| !pinned.contains(y))
                .max_by_key(|&y| self.held[y as usize].map_or(NEVER, |(_, next)| next))
                .expect("more registers than operands");
            let (r, next) = self.held[y as usize].expect("taken");
            if next != NEVER && !self.spilled[r as usize] {
                store(ops, r, y);
                self.spilled[r as usize] = true;
            }
            self.release(y);
            y
        }

        /// The YMM register holding tape register `r`, loaded from its slot if needed.
        fn load(&mut self, ops: &mut Assembler, r: u8, pinned: &[u8]) -> u8 {
            if let Some(y) = self.at[r as usize] {
                return y;
            }
            let y = self.take(ops, pinned);
            let off = SLOT * r as i32;
            dynasm!(ops ; .arch x64 ; vmovups Ry(y), [rbx + off]);
            self.held[y as usize] = Some((r, 0));
            self.at[r as usize] = Some(y);
            y
        }

        /// Spills every value read after instruction `i` whose slot is stale, and forgets
        /// every register: a call clobbers them all.
        fn spill_all(&mut self, ops: &mut Assembler) {
            for y in 0..ALLOCATABLE as u8 {
                if let Some((r, next)) = self.held[y as usize] {
                    if next != NEVER && !self.spilled[r as usize] {
                        store(ops, r, y);
                        self.spilled[r as usize] = true;
                    }
                    self.release(y);
                }
            }
        }
    }

    fn store(ops: &mut Assembler, r: u8, y: u8) {
        let off = SLOT * r as i32;
        dynasm!(ops ; .arch x64 ; vmovups [rbx + off], Ry(y));
    }

    /// An instruction's part in a sin/cos pair.
    #[derive(Clone, Copy, PartialEq)]
    pub(super) enum Pairing {
        None,
        /// A `sin` (or `cos`) whose call also computes the `cos` (or `sin`) of the same value
        /// for a later instruction, into the spill slot given (one no tape register uses).
        First(u8),
        /// That later instruction: it loads the result from the slot.
        Second(u8),
    }

    /// How far ahead a `sin` looks for the `cos` of its operand.
    const PAIR_WINDOW: usize = 64;

    /// Pairs each `sin` with a later `cos` of the same value (or the other way round): the
    /// two share one argument reduction (`math::sin_cos`, whose halves `math::sin` and
    /// `math::cos` are, so the bits are the same). Gyroids, twists and bends evaluate both
    /// of many arguments.
    pub(super) fn sin_cos_pairs(tape: &Tape) -> Vec<Pairing> {
        let instrs = tape.instrs();
        let mut pairs = vec![Pairing::None; instrs.len()];
        let mut next_slot = tape.registers();
        for i in 0..instrs.len() {
            let first = &instrs[i];
            let other = match first.op() {
                Op::Sin => Op::Cos,
                Op::Cos => Op::Sin,
                _ => continue,
            };
            let a = first.a();
            if pairs[i] != Pairing::None || first.out() == a || next_slot >= 256 {
                continue;
            }
            for j in i + 1..instrs.len().min(i + 1 + PAIR_WINDOW) {
                let later = &instrs[j];
                if later.op() == other && later.a() == a && pairs[j] == Pairing::None {
                    pairs[i] = Pairing::First(next_slot as u8);
                    pairs[j] = Pairing::Second(next_slot as u8);
                    next_slot += 1;
                    break;
                }
                if later.out() == a {
                    break; // the value is overwritten before any partner
                }
            }
        }
        pairs
    }

    /// Emits one tape as a function with the [`Entry`] signature; returns its start.
    fn emit_tape(ops: &mut Assembler, tape: &Tape) -> AssemblyOffset {
        let start = ops.offset();
        let uses = uses(tape);
        // rdi, rsi, rdx: the points' x, y and z; rcx: the spill slots; r8: the output. rbx
        // and r13 keep the slots and the output across calls; three pushes keep the stack
        // 16-byte aligned for them.
        dynasm!(ops
            ; .arch x64
            ; push rbx
            ; push r12
            ; push r13
            ; mov rbx, rcx
            ; mov r13, r8
        );
        let mut alloc = Allocation::new();
        for axis in 0..3u8 {
            if uses.inputs[axis as usize] != NEVER {
                let y = alloc.take(ops, &[]);
                match axis {
                    0 => dynasm!(ops ; .arch x64 ; vmovups Ry(y), [rdi]),
                    1 => dynasm!(ops ; .arch x64 ; vmovups Ry(y), [rsi]),
                    _ => dynasm!(ops ; .arch x64 ; vmovups Ry(y), [rdx]),
                }
                alloc.held[y as usize] = Some((axis, uses.inputs[axis as usize]));
                alloc.at[axis as usize] = Some(y);
            }
        }
        let pairs = sin_cos_pairs(tape);
        for (i, ins) in tape.instrs().iter().enumerate() {
            let op = ins.op();
            let (regs, count) = operands(ins);
            let out = ins.out();
            if let Pairing::Second(stash) = pairs[i] {
                // Computed by the first of the pair: the operand is not read again here.
                for (&r, &next) in regs[..count].iter().zip(&uses.reads[i]) {
                    if let Some(y) = alloc.at[r as usize] {
                        let held = alloc.held[y as usize].as_mut().expect("held");
                        held.1 = next;
                        if next == NEVER {
                            alloc.release(y);
                        }
                    }
                }
                if let Some(y) = alloc.at[out as usize] {
                    alloc.release(y);
                }
                alloc.spilled[out as usize] = false;
                let d = alloc.take(ops, &[]);
                let off = SLOT * stash as i32;
                dynasm!(ops ; .arch x64 ; vmovups Ry(d), [rbx + off]);
                alloc.held[d as usize] = Some((out, uses.written[i]));
                alloc.at[out as usize] = Some(d);
                continue;
            }
            if is_call(op) {
                // The interpreter's lanes read the operands from their slots.
                for &r in &regs[..count] {
                    if !alloc.spilled[r as usize] {
                        let y = alloc.at[r as usize].expect("a value not in its slot is held");
                        store(ops, r, y);
                        alloc.spilled[r as usize] = true;
                    }
                }
                for (&r, &next) in regs[..count].iter().zip(&uses.reads[i]) {
                    if let Some(y) = alloc.at[r as usize] {
                        alloc.held[y as usize].as_mut().expect("held").1 = next;
                    }
                }
                if let Some(y) = alloc.at[out as usize] {
                    alloc.release(y);
                }
                alloc.spill_all(ops);
                let slot = |r: u8| SLOT * r as i32;
                let (a, b) = (
                    slot(regs[0]),
                    slot(if count > 1 { regs[1] } else { regs[0] }),
                );
                let o = slot(out);
                if let Pairing::First(stash) = pairs[i] {
                    // sin and cos of one value in one call: the other result waits in a slot
                    // no tape register uses, for the second of the pair
                    let (sin, cos) = if op == Op::Sin {
                        (o, slot(stash))
                    } else {
                        (slot(stash), o)
                    };
                    let f = sin_cos_avx2 as *const () as i64;
                    dynasm!(ops
                        ; .arch x64
                        ; lea rdi, [rbx + a]
                        ; lea rsi, [rbx + sin]
                        ; lea rdx, [rbx + cos]
                        ; mov rax, QWORD f
                        ; call rax
                    );
                    alloc.spilled[out as usize] = true;
                    continue;
                }
                let imm = ins.imm_bits() as i32;
                let f = apply_avx2 as *const () as i64;
                dynasm!(ops
                    ; .arch x64
                    ; mov edi, op as u8 as i32
                    ; lea rsi, [rbx + a]
                    ; lea rdx, [rbx + b]
                    ; mov ecx, imm
                    ; lea r8, [rbx + o]
                    ; mov rax, QWORD f
                    ; call rax
                );
                alloc.spilled[out as usize] = true;
                continue;
            }
            let mut y = [0u8; 3];
            for k in 0..count {
                y[k] = alloc.load(ops, regs[k], &y[..k]);
            }
            // Operands read here for the last time free their registers (the code reads
            // every operand before it writes the destination, which may be one of them).
            for (&yk, &next) in y[..count].iter().zip(&uses.reads[i]) {
                if let Some(held) = alloc.held[yk as usize].as_mut() {
                    held.1 = next;
                }
            }
            for (&yk, &next) in y[..count].iter().zip(&uses.reads[i]) {
                if next == NEVER {
                    alloc.release(yk);
                }
            }
            if let Some(held) = alloc.at[out as usize] {
                alloc.release(held);
            }
            alloc.spilled[out as usize] = false;
            let live: Vec<u8> = (0..count)
                .filter(|&k| alloc.at[regs[k] as usize].is_some())
                .map(|k| y[k])
                .collect();
            let d = alloc.take(ops, &live);
            let (a, b, c) = (y[0], y[1], y[2]);
            let imm = ins.imm_bits();
            match op {
                Op::Const => broadcast(ops, d, imm),
                Op::Copy => dynasm!(ops ; .arch x64 ; vmovaps Ry(d), Ry(a)),
                Op::Neg => {
                    sign_bits(ops, T0);
                    dynasm!(ops ; .arch x64 ; vxorps Ry(d), Ry(a), Ry(T0));
                }
                Op::Abs => {
                    sign_bits(ops, T0);
                    dynasm!(ops ; .arch x64 ; vandnps Ry(d), Ry(T0), Ry(a));
                }
                Op::Sqrt => dynasm!(ops ; .arch x64 ; vsqrtps Ry(d), Ry(a)),
                Op::Square => dynasm!(ops ; .arch x64 ; vmulps Ry(d), Ry(a), Ry(a)),
                Op::Floor => dynasm!(ops ; .arch x64 ; vroundps Ry(d), Ry(a), 1),
                Op::Add => dynasm!(ops ; .arch x64 ; vaddps Ry(d), Ry(a), Ry(b)),
                Op::Sub => dynasm!(ops ; .arch x64 ; vsubps Ry(d), Ry(a), Ry(b)),
                Op::Mul => dynasm!(ops ; .arch x64 ; vmulps Ry(d), Ry(a), Ry(b)),
                Op::Div => dynasm!(ops ; .arch x64 ; vdivps Ry(d), Ry(a), Ry(b)),
                Op::Min | Op::Max => {
                    // min(a, b) as `(a < b || b is NaN) ? a : b`: vminps gives
                    // `a < b ? a : b`, and a NaN b takes a (as the AVX2 lanes do)
                    if op == Op::Min {
                        dynasm!(ops ; .arch x64 ; vminps Ry(T0), Ry(a), Ry(b));
                    } else {
                        dynasm!(ops ; .arch x64 ; vmaxps Ry(T0), Ry(a), Ry(b));
                    }
                    dynasm!(ops
                        ; .arch x64
                        ; vcmpunordps Ry(T1), Ry(b), Ry(b)
                        ; vblendvps Ry(d), Ry(T0), Ry(a), Ry(T1)
                    );
                }
                Op::Hypot | Op::Hypot3 => {
                    // sqrt((a·a + b·b) + c·c), summed in the interpreter's order
                    dynasm!(ops
                        ; .arch x64
                        ; vmulps Ry(T0), Ry(a), Ry(a)
                        ; vmulps Ry(T1), Ry(b), Ry(b)
                        ; vaddps Ry(T0), Ry(T0), Ry(T1)
                    );
                    if op == Op::Hypot3 {
                        dynasm!(ops
                            ; .arch x64
                            ; vmulps Ry(T1), Ry(c), Ry(c)
                            ; vaddps Ry(T0), Ry(T0), Ry(T1)
                        );
                    }
                    dynasm!(ops ; .arch x64 ; vsqrtps Ry(d), Ry(T0));
                }
                Op::Select => dynasm!(ops
                    ; .arch x64
                    ; vxorps Ry(T0), Ry(T0), Ry(T0)
                    // c > 0 (predicate GT_OQ: a NaN c picks b). dynasmrt 5 encodes the
                    // register operands of `vcmpps` in the reverse order (the first becomes
                    // the instruction's second source; checked by disassembly), so 0 is
                    // written first: this is c > 0
                    ; vcmpps Ry(T1), Ry(T0), Ry(c), 0x1e
                    ; vblendvps Ry(d), Ry(b), Ry(a), Ry(T1)
                ),
                Op::AddImm
                | Op::SubImm
                | Op::RsubImm
                | Op::MulImm
                | Op::DivImm
                | Op::RdivImm
                | Op::MinImm
                | Op::MaxImm => {
                    broadcast(ops, T1, imm);
                    let k = T1;
                    match op {
                        Op::AddImm => dynasm!(ops ; .arch x64 ; vaddps Ry(d), Ry(a), Ry(k)),
                        Op::SubImm => dynasm!(ops ; .arch x64 ; vsubps Ry(d), Ry(a), Ry(k)),
                        Op::RsubImm => dynasm!(ops ; .arch x64 ; vsubps Ry(d), Ry(k), Ry(a)),
                        Op::MulImm => dynasm!(ops ; .arch x64 ; vmulps Ry(d), Ry(a), Ry(k)),
                        Op::DivImm => dynasm!(ops ; .arch x64 ; vdivps Ry(d), Ry(a), Ry(k)),
                        Op::RdivImm => dynasm!(ops ; .arch x64 ; vdivps Ry(d), Ry(k), Ry(a)),
                        // a NaN immediate: min(a, NaN) is a, as the lanes give
                        _ if f32::from_bits(imm).is_nan() => {
                            dynasm!(ops ; .arch x64 ; vmovaps Ry(d), Ry(a))
                        }
                        Op::MinImm => dynasm!(ops ; .arch x64 ; vminps Ry(d), Ry(a), Ry(k)),
                        _ => dynasm!(ops ; .arch x64 ; vmaxps Ry(d), Ry(a), Ry(k)),
                    }
                }
                // calls above; material ops are never compiled (`compilable`)
                _ => unreachable!("{op:?} is not compiled inline"),
            }
            alloc.held[d as usize] = Some((out, uses.written[i]));
            alloc.at[out as usize] = Some(d);
        }
        let result = tape.result();
        let y = match alloc.at[result as usize] {
            Some(y) => y,
            None => {
                let off = SLOT * result as i32;
                dynasm!(ops ; .arch x64 ; vmovups Ry(T0), [rbx + off]);
                T0
            }
        };
        dynasm!(ops
            ; .arch x64
            ; vmovups [r13], Ry(y)
            ; vzeroupper
            ; pop r13
            ; pop r12
            ; pop rbx
            ; ret
        );
        start
    }

    /// YMM `y` = the float with `bits` in every lane. Through `eax`, not from a constant
    /// after the code: dynasmrt 5 encodes `vbroadcastss ymm, DWORD [mem]` as its 128-bit form
    /// (4 lanes, the upper 4 zeroed; checked by disassembly), and a pool of 32-byte splats
    /// read as memory operands would take more bytes than it saves where, as in most leaf
    /// tapes, each constant is used once.
    fn broadcast(ops: &mut Assembler, y: u8, bits: u32) {
        dynasm!(ops
            ; .arch x64
            ; mov eax, bits as i32
            ; vmovd Rx(y), eax
            ; vbroadcastss Ry(y), Rx(y)
        );
    }

    /// YMM `y` = the sign bit alone in every lane (−0.0).
    fn sign_bits(ops: &mut Assembler, y: u8) {
        dynasm!(ops
            ; .arch x64
            ; vpcmpeqd Ry(y), Ry(y), Ry(y)
            ; vpslld Ry(y), Ry(y), 31
        );
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use crate::sdf::simd::tests::check_bits;
    use crate::sdf::simd::{PacketRegisters, SimdLevel, eval8};
    use crate::sdf::ssa::{Builder, V};
    use crate::sdf::tape::{Op, Shape};
    use glam::Vec3;

    /// Compiles `tape` and checks its native code against the interpreter at `pts`, bit for
    /// bit (NaN against NaN).
    fn check_native(name: &str, tape: &Tape, pts: &[Vec3]) {
        let mut native = tape.clone();
        let bytes = compile_all(std::slice::from_mut(&mut native), usize::MAX);
        assert!(native.is_native(), "{name}: not compiled");
        let worst = MAX_CODE_BYTES_PER_TAPE + MAX_CODE_BYTES_PER_INSTRUCTION * tape.len();
        assert!(
            bytes <= worst,
            "{name}: {bytes} bytes of code, over the bound {worst}"
        );
        // native code (eval8 at the AVX2 level runs it) and the interpreter on the same
        // tape, each against the scalar interpreter
        check_bits(SimdLevel::Avx2, name, &native, pts);
        check_bits(SimdLevel::Avx2, name, &native.interpreted(), pts);
    }

    /// Whether this CPU makes native code (AVX2). Where it does not, the renderer never
    /// makes any and these tests have nothing to compare: they say so, and fail under CI
    /// (`CI=true`), whose machines have AVX2.
    fn runs_native() -> bool {
        if available() {
            return true;
        }
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "no AVX2 on this CPU under CI: native code cannot be tested"
        );
        eprintln!("SKIPPED: no AVX2 on this CPU, so no native code to compare");
        false
    }

    /// `op` of the operands (as many as it reads; `select` picks by the last) and the
    /// immediate `k`.
    fn build_op(b: &mut Builder, op: Op, [u, v, w]: [V; 3], k: f32) -> V {
        match op.shape() {
            Shape::Nullary => b.konst(k),
            Shape::Unary => b.unary(op, u),
            Shape::Binary => b.binary(op, u, v),
            Shape::WithImm => b.with_imm(op, u, k),
            Shape::Ternary if op == Op::Hypot3 => b.hypot3(u, v, w),
            Shape::Ternary => b.select(w, u, v),
            _ => unreachable!("{op:?} is not a value operation"),
        }
    }

    #[test]
    fn every_op_gives_the_interpreter_bits_on_spicy_inputs() {
        if !runs_native() {
            return;
        }
        let pts = crate::sdf::simd::tests::spicy_points(5);
        for &op in Op::ALL {
            if op.is_material() || op == Op::Input {
                continue;
            }
            // each op with register and with immediate operands, including a NaN immediate
            for k in [1.75f32, -0.0, f32::NAN] {
                let mut b = Builder::without_sharing(16);
                let [x, y, z] = b.point();
                let v = build_op(&mut b, op, [x, y, z], k);
                let tape = b.finish(v, None).compile().unwrap();
                check_native(&format!("{} (imm {k})", op.name()), &tape, &pts);
            }
        }
    }

    /// A random program with many values alive at once (so that the allocator spills and
    /// reloads), every op, transcendental calls between them.
    fn random_program(rng: &mut Rng, len: usize) -> Tape {
        let mut b = Builder::without_sharing(len + 8);
        let [x, y, z] = b.point();
        let mut values: Vec<V> = vec![x, y, z];
        let ops: Vec<Op> = Op::ALL
            .iter()
            .copied()
            .filter(|&op| !op.is_material() && op != Op::Input)
            .collect();
        let pick = |rng: &mut Rng, values: &[V]| values[rng.below(values.len() as u64) as usize];
        for _ in 0..len {
            let op = ops[rng.below(ops.len() as u64) as usize];
            let a = pick(rng, &values);
            let c = pick(rng, &values);
            let d = pick(rng, &values);
            let k = rng.range_f32(-3.0, 3.0);
            let v = build_op(&mut b, op, [a, c, d], k);
            values.push(v);
            // sin and cos of one value, now and then a few instructions apart (native code
            // computes them in one call)
            if matches!(op, Op::Sin | Op::Cos) && rng.chance(0.6) {
                for _ in 0..rng.below(4) {
                    let x = pick(rng, &values);
                    let y = pick(rng, &values);
                    values.push(b.binary(Op::Add, x, y));
                }
                let other = if op == Op::Sin { Op::Cos } else { Op::Sin };
                values.push(b.unary(other, a));
            }
        }
        // the result reads many values, so that they all stay alive to the end
        let mut acc = *values.last().expect("values");
        for (i, &v) in values.iter().enumerate().rev().step_by(3) {
            acc = b.binary(if i % 2 == 0 { Op::Min } else { Op::Add }, acc, v);
        }
        b.finish(acc, None).compile().unwrap()
    }

    #[test]
    fn random_programs_give_the_interpreter_bits() {
        if !runs_native() {
            return;
        }
        let mut rng = Rng::new(99);
        let pts: Vec<Vec3> = (0..64).map(|_| rng.vec3_in(-4.0, 4.0)).collect();
        let mut most_registers = 0;
        for n in 0..300 {
            let len = 4 + rng.below(120) as usize;
            let tape = random_program(&mut rng, len);
            most_registers = most_registers.max(tape.registers());
            check_native(&format!("random program {n} ({len} ops)"), &tape, &pts);
        }
        // the allocator had to spill: more tape registers alive than YMM registers
        assert!(most_registers > 20, "{most_registers}");
    }

    #[test]
    fn a_gyroid_computes_each_sin_and_cos_pair_in_one_call() {
        // sin(x)cos(y) + sin(y)cos(z) + sin(z)cos(x): three values, each with its sin and cos
        let mut b = Builder::without_sharing(32);
        let [x, y, z] = b.point();
        let mut terms = Vec::new();
        for (u, v) in [(x, y), (y, z), (z, x)] {
            let s = b.unary(Op::Sin, u);
            let c = b.unary(Op::Cos, v);
            terms.push(b.binary(Op::Mul, s, c));
        }
        let sum = b.binary(Op::Add, terms[0], terms[1]);
        let g = b.binary(Op::Add, sum, terms[2]);
        let tape = b.finish(g, None).compile().unwrap();
        let firsts = x86::sin_cos_pairs(&tape)
            .iter()
            .filter(|p| matches!(p, x86::Pairing::First(_)))
            .count();
        assert_eq!(firsts, 3);
        if runs_native() {
            let mut rng = Rng::new(8);
            let pts: Vec<Vec3> = (0..256).map(|_| rng.vec3_in(-40.0, 40.0)).collect();
            check_native("gyroid", &tape, &pts);
        }
    }

    /// Each of `native` (compiled or not) gives the bits of its interpreted twin in `tapes`.
    fn same_values_at_8_points(tapes: &[Tape], native: &[Tape], rng: &mut Rng) {
        let pts: Vec<Vec3> = (0..8).map(|_| rng.vec3_in(-2.0, 2.0)).collect();
        let mut regs = PacketRegisters::new();
        let xyz: [[f32; 8]; 3] = std::array::from_fn(|a| std::array::from_fn(|i| pts[i][a]));
        for (t, n) in tapes.iter().zip(native) {
            let got = eval8(SimdLevel::Avx2, n, &xyz[0], &xyz[1], &xyz[2], &mut regs);
            for (i, p) in pts.iter().enumerate() {
                let want = t.eval(*p);
                assert!(got[i].to_bits() == want.to_bits() || (got[i].is_nan() && want.is_nan()));
            }
        }
    }

    #[test]
    fn tapes_compiled_together_keep_their_own_code_within_the_budget() {
        if !runs_native() {
            return;
        }
        let mut rng = Rng::new(3);
        let tapes: Vec<Tape> = (0..40).map(|_| random_program(&mut rng, 30)).collect();
        let mut native = tapes.clone();
        // a budget too small for all of them (a tape is compiled while its worst case fits):
        // the rest stay interpreted, with the same values
        let budget: usize = tapes[..2]
            .iter()
            .map(|t| MAX_CODE_BYTES_PER_TAPE + MAX_CODE_BYTES_PER_INSTRUCTION * t.len())
            .sum();
        let used = compile_all(&mut native, budget);
        assert!(used <= budget, "{used} bytes for a budget of {budget}");
        let compiled = native.iter().filter(|t| t.is_native()).count();
        assert!((2..40).contains(&compiled), "{compiled} of 40 compiled");
        same_values_at_8_points(&tapes, &native, &mut rng);
    }

    #[test]
    fn tapes_of_many_groups_share_buffers_each_group_within_its_budget() {
        if !runs_native() {
            return;
        }
        let mut rng = Rng::new(5);
        let tapes: Vec<Tape> = (0..60).map(|_| random_program(&mut rng, 20)).collect();
        let mut native = tapes.clone();
        let worst = |t: &Tape| MAX_CODE_BYTES_PER_TAPE + MAX_CODE_BYTES_PER_INSTRUCTION * t.len();
        // group 0 (every third tape) has room for the first tape's worst case, groups 1 and 2 for all
        let budgets = [worst(&tapes[0]), usize::MAX, usize::MAX];
        let mut grouped: Vec<(&mut Tape, usize)> = native
            .iter_mut()
            .enumerate()
            .map(|(i, t)| (t, i % 3))
            .collect();
        let used = compile_grouped(&mut grouped, &budgets);
        assert!(
            used[0] <= budgets[0],
            "{} bytes for {}",
            used[0],
            budgets[0]
        );
        let compiled = |g: usize| {
            native
                .iter()
                .skip(g)
                .step_by(3)
                .filter(|t| t.is_native())
                .count()
        };
        assert!(
            (1..20).contains(&compiled(0)),
            "group 0: {} of 20",
            compiled(0)
        );
        assert_eq!((compiled(1), compiled(2)), (20, 20));
        let buffers: std::collections::HashSet<usize> = native
            .iter()
            .filter_map(|t| t.native_code().map(|n| n.buffer_address()))
            .collect();
        assert_eq!(
            buffers.len(),
            1,
            "small tapes in one block share one buffer"
        );
        same_values_at_8_points(&tapes, &native, &mut rng);
    }
}
