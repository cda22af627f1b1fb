// The tape interpreter: `Tape::eval_in` and `Tape::eval_material` of src/sdf/tape.rs, op for
// op. Instructions of every tape of the scene sit in `instrs`, their affine rows in
// `tape_constants`; a `TapeRef` says where one tape starts. Registers live in private arrays
// of the generated sizes (MAX_REGISTERS vec4s, MAX_MATERIAL_REGISTERS materials).

var<private> regs: array<vec4<f32>, MAX_REGISTERS>;
var<private> mat_regs: array<array<vec4<f32>, 3>, MAX_MATERIAL_REGISTERS>;

// The lane of a swizzle pattern (3 bits per output lane: 0–3 pick x..w, 4 gives zero).
fn swizzle_lane(a: vec4<f32>, pattern: u32, i: u32) -> f32 {
    let s = (pattern >> (3u * i)) & 7u;
    if s < 4u {
        return a[s];
    }
    return 0.0;
}

// Runs the tape at p; with `materials`, also the material ops (MatLoad, MatMix) over the
// scene's material table.
fn tape_run(tape: TapeRef, p: vec3<f32>, materials_on: bool) {
    let mask = MAX_REGISTERS - 1u;
    regs[0] = vec4<f32>(p, 0.0);
    var out: vec4<f32>;
    var write: bool;
    for (var i = 0u; i < tape.len; i = i + 1u) {
        let ins = instrs[tape.start + i];
        let a = regs[ins.a & mask];
        var b: vec4<f32>;
        if ins.b == IMM {
            b = ins.imm;
        } else {
            b = regs[ins.b & mask];
        }
        let c = regs[ins.c & mask];
        out = vec4<f32>(0.0);
        write = true;
        switch ins.op {
            case OP_CONST: { out = ins.imm; }
            case OP_ADD: { out = a + b; }
            case OP_SUB: { out = a - b; }
            case OP_MUL: { out = a * b; }
            case OP_DIV: { out = a / b; }
            case OP_MIN: { out = min(a, b); }
            case OP_MAX: { out = max(a, b); }
            case OP_POW: { out = pow(a, b); }
            case OP_NEG: { out = -a; }
            case OP_ABS: { out = abs(a); }
            case OP_SQRT: { out = sqrt(a); }
            case OP_SIN: { out = sin(a); }
            case OP_COS: { out = cos(a); }
            case OP_TAN: { out = tan(a); }
            case OP_EXP: { out = exp(a); }
            case OP_LN: { out = log(a); }
            case OP_FLOOR: { out = floor(a); }
            case OP_MULADD: { out = a * b + c; }
            case OP_SELECT: {
                if c.x > 0.0 {
                    out = a;
                } else {
                    out = b;
                }
            }
            case OP_SWIZZLE: {
                out = vec4<f32>(
                    swizzle_lane(a, ins.aux, 0u),
                    swizzle_lane(a, ins.aux, 1u),
                    swizzle_lane(a, ins.aux, 2u),
                    swizzle_lane(a, ins.aux, 3u),
                );
            }
            case OP_PACK: {
                out = vec4<f32>(a[ins.aux & 3u], b[(ins.aux >> 2u) & 3u], c[(ins.aux >> 4u) & 3u], 0.0);
            }
            case OP_DOT3: { out = vec4<f32>(dot(a.xyz, b.xyz), 0.0, 0.0, 0.0); }
            case OP_LENGTH: {
                var l: f32;
                if ins.aux == 2u {
                    l = length(a.xy);
                } else {
                    l = length(a.xyz);
                }
                out = vec4<f32>(l, 0.0, 0.0, 0.0);
            }
            case OP_MAXLANE: {
                var m: f32;
                if ins.aux == 2u {
                    m = max(a.x, a.y);
                } else {
                    m = max(max(a.x, a.y), a.z);
                }
                out = vec4<f32>(m, 0.0, 0.0, 0.0);
            }
            case OP_AFFINE: {
                let k = tape.constants + ins.aux;
                let q = vec4<f32>(a.xyz, 1.0);
                out = vec4<f32>(
                    dot(tape_constants[k], q),
                    dot(tape_constants[k + 1u], q),
                    dot(tape_constants[k + 2u], q),
                    0.0,
                );
            }
            case OP_MATLOAD: {
                write = false;
                if materials_on {
                    mat_regs[ins.dst % MAX_MATERIAL_REGISTERS] = materials[ins.aux].lanes;
                }
            }
            case OP_MATMIX: {
                write = false;
                if materials_on {
                    let ma = mat_regs[ins.a % MAX_MATERIAL_REGISTERS];
                    let mb = mat_regs[ins.b % MAX_MATERIAL_REGISTERS];
                    let h = c.x;
                    var mixed: array<vec4<f32>, 3>;
                    for (var j = 0u; j < 3u; j = j + 1u) {
                        mixed[j] = ma[j] + (mb[j] - ma[j]) * h;
                    }
                    mat_regs[ins.dst % MAX_MATERIAL_REGISTERS] = mixed;
                }
            }
            default: { write = false; }
        }
        if write {
            regs[ins.dst & mask] = out;
        }
    }
}

// Tape::eval_in: the signed distance (or bound) at p.
fn tape_eval(tape: TapeRef, p: vec3<f32>) -> f32 {
    tape_run(tape, p, false);
    return regs[tape.result & (MAX_REGISTERS - 1u)].x;
}

// Tape::eval_material's material: the blended material lanes at p (the table's first
// material when the tape has no material result).
fn tape_material(tape: TapeRef, material_result: u32, p: vec3<f32>) -> array<vec4<f32>, 3> {
    tape_run(tape, p, true);
    if material_result == NONE {
        if globals.material_count > 0u {
            return materials[0].lanes;
        }
        return array<vec4<f32>, 3>(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
    }
    return mat_regs[material_result % MAX_MATERIAL_REGISTERS];
}
