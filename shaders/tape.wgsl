// The tape interpreter: `Tape::eval_in` and `Tape::eval_material` of src/sdf/tape.rs, op for
// op (the value of each op is `sdf::tape::apply`). Instructions of every tape of the scene
// sit in `instrs`; a `TapeRef` says where one tape starts. An instruction's first word packs
// op | out << 8 | a << 16 | b << 24; the second is the immediate (a float's bits, the third
// register of SELECT and MATMIX, or a material number). Registers live in private arrays of
// the generated sizes; registers 0–2 hold the sample point on entry.

// Whether the driver ended this invocation's loops early. llvmpipe (Mesa's lavapipe) counts
// the iterations of every loop of a kernel invocation together, for its whole SIMD group, and
// once 65,535 are spent (gallivm's LP_MAX_TGSI_LOOP_ITERATIONS) every loop stops after its
// first iteration: marches, walks and the tape interpreter then answer wrongly, and nothing
// says so. A loop that has to run twice tells: called last in a kernel, it runs once only when
// the budget is gone. `zero` is 0 at run time but unknown to the compiler, so the loop cannot
// be unrolled away.
fn loops_were_cut(zero: u32) -> bool {
    var n = 0u;
    loop {
        n = n + 1u;
        if n >= 2u + zero {
            break;
        }
    }
    return n < 2u;
}

var<private> regs: array<f32, MAX_REGISTERS>;
var<private> mat_regs: array<MaterialLanes, MAX_MATERIAL_REGISTERS>;

// Runs the tape at p; with `materials_on`, also the material ops (MatLoad, MatMix) over the
// scene's material table.
fn tape_run(tape: TapeRef, p: vec3<f32>, materials_on: bool) {
    regs[0] = p.x;
    regs[1] = p.y;
    regs[2] = p.z;
    for (var i = 0u; i < tape.len; i = i + 1u) {
        let ins = instrs[tape.start + i];
        let op = (ins.code >> INSTR_OP_SHIFT) & 0xffu;
        let out = (ins.code >> INSTR_OUT_SHIFT) & 0xffu;
        let a = regs[(ins.code >> INSTR_A_SHIFT) & 0xffu];
        let b = regs[(ins.code >> INSTR_B_SHIFT) & 0xffu];
        let k = bitcast<f32>(ins.imm);
        var v = 0.0;
        var write = true;
        switch op {
            case OP_CONST: { v = k; }
            case OP_COPY: { v = a; }
            case OP_NEG: { v = -a; }
            case OP_ABS: { v = abs(a); }
            case OP_SQRT: { v = sqrt(a); }
            case OP_SQUARE: { v = a * a; }
            case OP_FLOOR: { v = floor(a); }
            case OP_SIN: { v = sin(a); }
            case OP_COS: { v = cos(a); }
            case OP_TAN: { v = tan(a); }
            case OP_EXP: { v = exp(a); }
            case OP_LN: { v = log(a); }
            case OP_ADD: { v = a + b; }
            case OP_SUB: { v = a - b; }
            case OP_MUL: { v = a * b; }
            case OP_DIV: { v = a / b; }
            case OP_MIN: { v = min(a, b); }
            case OP_MAX: { v = max(a, b); }
            case OP_POW: { v = pow(a, b); }
            case OP_HYPOT: { v = sqrt(a * a + b * b); }
            case OP_HYPOT3: {
                let c = regs[ins.imm & 0xffu];
                v = sqrt(a * a + b * b + c * c);
            }
            case OP_ADDIMM: { v = a + k; }
            case OP_SUBIMM: { v = a - k; }
            case OP_RSUBIMM: { v = k - a; }
            case OP_MULIMM: { v = a * k; }
            case OP_DIVIMM: { v = a / k; }
            case OP_RDIVIMM: { v = k / a; }
            case OP_MINIMM: { v = min(a, k); }
            case OP_MAXIMM: { v = max(a, k); }
            case OP_POWIMM: { v = pow(a, k); }
            case OP_SELECT: {
                if regs[ins.imm & 0xffu] > 0.0 {
                    v = a;
                } else {
                    v = b;
                }
            }
            case OP_MATLOAD: {
                write = false;
                if materials_on {
                    mat_regs[out % MAX_MATERIAL_REGISTERS] = materials[ins.imm].lanes;
                }
            }
            case OP_MATMIX: {
                write = false;
                if materials_on {
                    let ma = mat_regs[((ins.code >> INSTR_A_SHIFT) & 0xffu) % MAX_MATERIAL_REGISTERS];
                    let mb = mat_regs[((ins.code >> INSTR_B_SHIFT) & 0xffu) % MAX_MATERIAL_REGISTERS];
                    let h = regs[ins.imm & 0xffu];
                    var mixed: MaterialLanes;
                    for (var j = 0u; j < MATERIAL_VECS; j = j + 1u) {
                        mixed[j] = ma[j] + (mb[j] - ma[j]) * h;
                    }
                    mat_regs[out % MAX_MATERIAL_REGISTERS] = mixed;
                }
            }
            default: { write = false; }
        }
        if write {
            regs[out] = v;
        }
    }
}

// Tape::eval_in: the signed distance (or bound) at p.
fn tape_eval(tape: TapeRef, p: vec3<f32>) -> f32 {
    tape_run(tape, p, false);
    return regs[tape.result];
}

// Tape::eval_material's material: the blended material lanes at p (the table's first
// material when the tape has no material result).
fn tape_material(tape: TapeRef, p: vec3<f32>) -> MaterialLanes {
    tape_run(tape, p, true);
    if tape.material == NONE {
        if globals.material_count > 0u {
            return materials[0].lanes;
        }
        return MaterialLanes();
    }
    return mat_regs[tape.material % MAX_MATERIAL_REGISTERS];
}
