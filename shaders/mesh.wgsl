// Mesh traversal: the CPU's wide BVHs (src/accel/bvh/wide.rs) walked with fixed-size stacks,
// the Woop–Benthin–Wald watertight triangle test of src/accel/triangle.rs on the leaves'
// blocks of eight (src/accel/bvh/leaf.rs), and instances (world → object ray mapping as
// src/accel/bvh.rs's InstanceBvh does it).

struct Interval {
    hit: bool,
    t0: f32,
    t1: f32,
}

// Aabb::ray_interval (src/geom.rs): the slab test clipped to [tmin, tmax]; an axis whose
// 1/d is not finite only checks that the origin lies within the slab.
fn ray_interval(lo: vec3<f32>, hi: vec3<f32>, o: vec3<f32>, d: vec3<f32>, tmin: f32, tmax: f32) -> Interval {
    var t_near = tmin;
    var t_far = tmax;
    for (var axis = 0u; axis < 3u; axis = axis + 1u) {
        let oa = o[axis];
        let l = lo[axis];
        let h = hi[axis];
        // 1/d is finite exactly when |d| is at least the smallest normal float (GPUs flush
        // smaller ones to zero anyway).
        if abs(d[axis]) >= 1.17549435e-38 {
            let inv = 1.0 / d[axis];
            let t_a = (l - oa) * inv;
            let t_b = (h - oa) * inv;
            var n = t_a;
            var f = t_b;
            if inv < 0.0 {
                n = t_b;
                f = t_a;
            }
            if !(n <= t_far && f >= t_near) {
                return Interval(false, 0.0, 0.0);
            }
            t_near = max(t_near, n);
            t_far = min(t_far, f);
        } else if !(l <= oa && oa <= h) {
            return Interval(false, 0.0, 0.0);
        }
    }
    return Interval(t_near <= t_far, t_near, t_far);
}

// WatertightRay::new: the shear of the ray into +z (paper, listing 1, "precalculations").
struct WatertightRay {
    o: vec3<f32>,
    d: vec3<f32>,
    kx: u32,
    ky: u32,
    kz: u32,
    sx: f32,
    sy: f32,
    sz: f32,
}

fn watertight_ray(o: vec3<f32>, d: vec3<f32>) -> WatertightRay {
    let ad = abs(d);
    var kz = 2u;
    if ad.x >= ad.y && ad.x >= ad.z {
        kz = 0u;
    } else if ad.y >= ad.z {
        kz = 1u;
    }
    var kx = (kz + 1u) % 3u;
    var ky = (kx + 1u) % 3u;
    if d[kz] < 0.0 {
        let swap = kx;
        kx = ky;
        ky = swap;
    }
    return WatertightRay(o, d, kx, ky, kz, d[kx] / d[kz], d[ky] / d[kz], 1.0 / d[kz]);
}

// Dekker's exact product a·b = hi + lo (Veltkamp's split into 12-bit halves; T. J. Dekker,
// "A floating-point technique for extending the available precision", 1971).
fn two_product(a: f32, b: f32) -> vec2<f32> {
    let p = a * b;
    let ca = 4097.0 * a;
    let a_hi = ca - (ca - a);
    let a_lo = a - a_hi;
    let cb = 4097.0 * b;
    let b_hi = cb - (cb - b);
    let b_lo = b - b_hi;
    let e = ((a_hi * b_hi - p) + a_hi * b_lo + a_lo * b_hi) + a_lo * b_lo;
    return vec2<f32>(p, e);
}

// The CPU's f64 fallback `edge_f64` for an edge function that rounded to 0: WGSL has no
// f64, but p·q − r·s rounded to 0 means the rounded products are equal, so the exact
// difference is the difference of their rounding errors, whose f32 sign is exact.
fn edge_exact(p: f32, q: f32, r: f32, s: f32) -> f32 {
    let pq = two_product(p, q);
    let rs = two_product(r, s);
    return (pq.x - rs.x) + (pq.y - rs.y);
}

struct TriHit {
    hit: bool,
    t: f32,
    u: f32,
    v: f32,
}

// WatertightRay::intersect_nondegenerate: degenerate triangles were left out at upload.
fn intersect_triangle(r: WatertightRay, a: vec3<f32>, b: vec3<f32>, c: vec3<f32>, tmin: f32, tmax: f32) -> TriHit {
    let miss = TriHit(false, 0.0, 0.0, 0.0);
    let ar = a - r.o;
    let br = b - r.o;
    let cr = c - r.o;
    let ax = ar[r.kx] - r.sx * ar[r.kz];
    let ay = ar[r.ky] - r.sy * ar[r.kz];
    let bx = br[r.kx] - r.sx * br[r.kz];
    let by = br[r.ky] - r.sy * br[r.kz];
    let cx = cr[r.kx] - r.sx * cr[r.kz];
    let cy = cr[r.ky] - r.sy * cr[r.kz];
    var u = cx * by - cy * bx;
    var v = ax * cy - ay * cx;
    var w = bx * ay - by * ax;
    if u == 0.0 {
        u = edge_exact(cx, by, cy, bx);
    }
    if v == 0.0 {
        v = edge_exact(ax, cy, ay, cx);
    }
    if w == 0.0 {
        w = edge_exact(bx, ay, by, ax);
    }
    if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
        return miss;
    }
    let det = u + v + w;
    if det == 0.0 || det != det {
        return miss;
    }
    let az = r.sz * ar[r.kz];
    let bz = r.sz * br[r.kz];
    let cz = r.sz * cr[r.kz];
    let t_scaled = u * az + v * bz + w * cz;
    let rcp = 1.0 / det;
    let t = t_scaled * rcp;
    if !(t >= tmin && t <= tmax) {
        return miss;
    }
    return TriHit(true, t, v * rcp, w * rcp);
}

// ---- the wide BVH walk shared by every tree (src/accel/bvh/wide.rs: `traverse_impl`).

// NodeRay: the ray's origin, 1/d, and the axes (bit per axis) where 1/d is not finite, on
// which the node test is a containment test. 1/d is finite exactly when |d| is at least the
// smallest normal float (GPUs flush smaller ones to zero anyway).
struct NodeRay {
    o: vec3<f32>,
    inv: vec3<f32>,
    parallel: u32,
}

fn node_ray(o: vec3<f32>, d: vec3<f32>) -> NodeRay {
    var r = NodeRay(o, vec3<f32>(0.0), 0u);
    for (var axis = 0u; axis < 3u; axis = axis + 1u) {
        if abs(d[axis]) >= 1.17549435e-38 {
            r.inv[axis] = 1.0 / d[axis];
        } else {
            r.parallel = r.parallel | (1u << axis);
        }
    }
    return r;
}

// `query_tmin`: a negative tmin is taken as 0 (so entry distances are ≥ 0, which the
// widening relies on); NaN stays NaN and is turned away by the walk.
fn query_tmin(tmin: f32) -> f32 {
    if tmin < 0.0 {
        return 0.0;
    }
    return tmin;
}

struct ChildHits {
    // widened entry distance of each child, four to a vector
    t: array<vec4<f32>, 2>,
    // bit i: child i's box meets the ray within [tmin, tmax]
    mask: u32,
}

// `child_hits`: the slab test of a node's eight children, each box grown by `margin`, with
// the entry distance scaled towards 0 and the exit away from it by WIDEN (Ize, "Robust BVH
// Ray Traversal", JCGT 2013) before they are compared.
fn child_hits(n: u32, r: NodeRay, tmin: f32, tmax: f32, margin: f32) -> ChildHits {
    var out: ChildHits;
    out.mask = 0u;
    for (var h = 0u; h < 2u; h = h + 1u) {
        var tn = vec4<f32>(tmin);
        var tf = vec4<f32>(tmax);
        var inside = vec4<bool>(true);
        for (var axis = 0u; axis < 3u; axis = axis + 1u) {
            let o = vec4<f32>(r.o[axis]);
            let lo = nodes[n].bounds[4u * axis + h] - vec4<f32>(margin);
            let hi = nodes[n].bounds[4u * axis + 2u + h] + vec4<f32>(margin);
            if ((r.parallel >> axis) & 1u) != 0u {
                inside = inside & (lo <= o) & (hi >= o);
            } else {
                let inv = vec4<f32>(r.inv[axis]);
                var pn = lo;
                var pf = hi;
                if r.inv[axis] < 0.0 {
                    pn = hi;
                    pf = lo;
                }
                tn = max(tn, (pn - o) * inv);
                tf = min(tf, (pf - o) * inv);
            }
        }
        tn = tn * (1.0 - WIDEN);
        tf = tf * (1.0 + WIDEN);
        let hit = (tn <= tf) & inside;
        out.t[h] = tn;
        for (var lane = 0u; lane < 4u; lane = lane + 1u) {
            if hit[lane] {
                out.mask = out.mask | (1u << (4u * h + lane));
            }
        }
    }
    return out;
}

fn child_code(n: u32, slot: u32) -> u32 {
    return nodes[n].children[slot / 4u][slot % 4u];
}

// The slots of node n that hold leaves.
fn leaf_slots(n: u32) -> u32 {
    var m = 0u;
    for (var slot = 0u; slot < 8u; slot = slot + 1u) {
        m = m | ((child_code(n, slot) >> 31u) << slot);
    }
    return m;
}

fn leaf_count(code: u32) -> u32 {
    return ((code >> 29u) & 3u) + 1u;
}

// A walk's pending children: (widened entry distance, child code), one stack per nesting level at
// module scope: function-local arrays are allocated once per inlined call site, and lavapipe
// (Mesa 22.3) silently corrupted private memory once a kernel had many of them (the probe
// kernel, which calls every query).
struct Entry {
    t: f32,
    code: u32,
}
var<private> blas_stack: array<Entry, STACK_SIZE>;
var<private> tlas_stack: array<Entry, STACK_SIZE>;

// Pushes the hit children of `mask` whose entry lies within tmax onto `stack` above `sp`
// and returns the new top. With `ordered` they are stacked by entry distance, the nearest on
// top (popped next); ties, and all of them without `ordered`, pop in slot order: the CPU's
// insertion sort and push order (`traverse_impl`).
fn push_children(stack: ptr<private, array<Entry, STACK_SIZE>>, sp: u32, n: u32, hits: ChildHits, mask_in: u32, tmax: f32, ordered: bool) -> u32 {
    var top = sp;
    var mask = mask_in;
    while mask != 0u {
        // highest slot first
        let i = firstLeadingBit(mask);
        mask = mask & ~(1u << i);
        let e = Entry(hits.t[i / 4u][i % 4u], child_code(n, i));
        if e.t > tmax {
            continue;
        }
        var j = top;
        while ordered && j > sp && (*stack)[j - 1u].t < e.t {
            (*stack)[j] = (*stack)[j - 1u];
            j = j - 1u;
        }
        (*stack)[j] = e;
        top = top + 1u;
    }
    return top;
}

struct MeshHit {
    hit: bool,
    t: f32,
    triangle: u32,
    u: f32,
    v: f32,
}

fn block_vertex(b: u32, k: u32, lane: u32) -> vec3<f32> {
    let h = lane / 4u;
    let l = lane % 4u;
    return vec3<f32>(
        tri_blocks[b].v[2u * (3u * k) + h][l],
        tri_blocks[b].v[2u * (3u * k + 1u) + h][l],
        tri_blocks[b].v[2u * (3u * k + 2u) + h][l],
    );
}

// ---- textures (Texture::sample) and a material's texture slots (SceneMeshes::surface).

fn rem_euclid(i: i32, n: i32) -> i32 {
    let r = i % n;
    if r < 0 {
        return r + n;
    }
    return r;
}

// texture::wrap: texel index i mapped into 0..n by the wrap mode.
fn wrap_index(i: i32, n: i32, mode: u32) -> i32 {
    if mode == WRAP_CLAMP_TO_EDGE {
        return clamp(i, 0, n - 1);
    }
    if mode == WRAP_MIRRORED_REPEAT {
        let m = rem_euclid(i, 2 * n);
        if m >= n {
            return 2 * n - 1 - m;
        }
        return m;
    }
    return rem_euclid(i, n);
}

// A float texel coordinate as an integer: NaN to 0, clamped so that +1 cannot overflow
// (the CPU's saturating `as i64` conversion, within ±2³⁰).
fn texel_floor(f: f32) -> i32 {
    if f != f {
        return 0;
    }
    return i32(clamp(f, -1073741824.0, 1073741824.0));
}

fn lerp4(a: vec4<f32>, b: vec4<f32>, t: f32) -> vec4<f32> {
    return a + (b - a) * t;
}

// Texture::sample: bilinear, texel centres at ((i + ½)/w, (j + ½)/h), (0, 0) the top-left.
fn texture_sample(index: u32, uv: vec2<f32>) -> vec4<f32> {
    let tex = textures[index];
    if tex.width == 0u || tex.height == 0u {
        return vec4<f32>(1.0);
    }
    let w = i32(tex.width);
    let h = i32(tex.height);
    let x = uv.x * f32(tex.width) - 0.5;
    let y = uv.y * f32(tex.height) - 0.5;
    let fx = floor(x);
    let fy = floor(y);
    var tx = x - fx;
    var ty = y - fy;
    let x0 = texel_floor(fx);
    let y0 = texel_floor(fy);
    let wrap_u = tex.wrap & 15u;
    let wrap_v = (tex.wrap >> 4u) & 15u;
    let xa = u32(wrap_index(x0, w, wrap_u));
    let xb = u32(wrap_index(x0 + 1, w, wrap_u));
    let ya = u32(wrap_index(y0, h, wrap_v));
    let yb = u32(wrap_index(y0 + 1, h, wrap_v));
    // finite exactly when t − t == 0 (NaN and ±∞ give NaN)
    if !(tx - tx == 0.0 && ty - ty == 0.0) {
        tx = 0.0;
        ty = 0.0;
    }
    let row_a = ya * tex.width;
    let row_b = yb * tex.width;
    let top = lerp4(texel_at(tex, row_a + xa), texel_at(tex, row_a + xb), tx);
    let bottom = lerp4(texel_at(tex, row_b + xa), texel_at(tex, row_b + xb), tx);
    return lerp4(top, bottom, ty);
}

// texture::srgb_to_linear.
fn texel_srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        return c / 12.92;
    }
    return pow((c + 0.055) / 1.055, 2.4);
}

// Texel i of a texture in the texel buffer: four bytes (Texture::packed8, decoded from sRGB
// for colour textures) or four f32 words.
fn texel_at(tex: TextureRecord, i: u32) -> vec4<f32> {
    if (tex.wrap & TEXELS_PACKED8) != 0u {
        // unpack4x8unorm divides by 255 as the CPU's decoding does
        let c = unpack4x8unorm(texels[tex.texel_start + i]);
        if (tex.wrap & TEXELS_SRGB) != 0u {
            return vec4<f32>(texel_srgb_to_linear(c.x), texel_srgb_to_linear(c.y), texel_srgb_to_linear(c.z), c.w);
        }
        return c;
    }
    let k = tex.texel_start + 4u * i;
    return vec4<f32>(bitcast<f32>(texels[k]), bitcast<f32>(texels[k + 1u]), bitcast<f32>(texels[k + 2u]), bitcast<f32>(texels[k + 3u]));
}

// MaterialTextures::slots order.
const SLOT_BASE_COLOR: u32 = 0u;
const SLOT_METALLIC_ROUGHNESS: u32 = 1u;
const SLOT_NORMAL: u32 = 2u;
const SLOT_OCCLUSION: u32 = 3u;
const SLOT_EMISSIVE: u32 = 4u;

fn material_slot(m: u32, slot: u32) -> u32 {
    return materials[m].slots[slot / 4u][slot % 4u];
}

fn material_has(m: u32, slot: u32) -> bool {
    return material_slot(m, slot) != NONE;
}

// The texture of slot `slot` of material m at barycentrics `bary` of the triangle with
// vertices `corners` of `mesh`: its coordinate set interpolated, KHR_texture_transform
// applied (UvTransform::apply), sampled; white without a texture or coordinates.
fn material_texel(m: u32, slot: u32, mesh: MeshRecord, corners: vec3<u32>, bary: vec3<f32>) -> vec4<f32> {
    let code = material_slot(m, slot);
    if code == NONE || mesh.has_uvs == 0u {
        return vec4<f32>(1.0);
    }
    let va = vertices[mesh.vertex_start + corners.x];
    let vb = vertices[mesh.vertex_start + corners.y];
    let vc = vertices[mesh.vertex_start + corners.z];
    var uv: vec2<f32>;
    if (code >> 31u) == 1u {
        uv = bary.x * va.uv1.xy + bary.y * vb.uv1.xy + bary.z * vc.uv1.xy;
    } else {
        uv = bary.x * vec2<f32>(va.u, va.v) + bary.y * vec2<f32>(vb.u, vb.v) + bary.z * vec2<f32>(vc.u, vc.v);
    }
    let a = materials[m].transforms[2u * slot];
    let b = materials[m].transforms[2u * slot + 1u];
    let t = a.xy * uv.x + a.zw * uv.y + b.xy;
    return texture_sample(code & 0x7fffffffu, t);
}

// SceneMeshes::masked_out: whether the hit at (u, v) of `triangle` of instance `instance` is
// a hole of an alpha mask (MASK material, coverage below the cutoff; glTF 2.0 §3.9.6).
fn masked_out(instance: u32, triangle: u32, u: f32, v: f32) -> bool {
    let inst = instances[instance];
    if inst.material_override != NONE {
        return false;
    }
    let mesh = meshes[inst.mesh];
    let tri = triangle_indices[mesh.triangle_start + triangle];
    let m = inst.material_base + tri.material;
    if materials[m].alpha_mode != ALPHA_MASK {
        return false;
    }
    let bary = vec3<f32>(1.0 - u - v, u, v);
    let corners = vec3<u32>(tri.a, tri.b, tri.c);
    let color = bary.x * vertices[mesh.vertex_start + tri.a].color.w
        + bary.y * vertices[mesh.vertex_start + tri.b].color.w
        + bary.z * vertices[mesh.vertex_start + tri.c].color.w;
    let factors = materials[m].factors;
    let alpha = factors.y * color * material_texel(m, SLOT_BASE_COLOR, mesh, corners, bary).w;
    return alpha < factors.x;
}

// MeshBvh::closest_hit in object space (`traverse_grouped`): at each node the hit leaf
// children's triangles are tested together (their blocks), then the inner children are
// ordered and pushed; the nearest triangle with tmin ≤ t ≤ tmax wins, ties to the smaller
// triangle index. With `any_hit` (MeshBvh::any_hit) the first triangle found, children in
// slot order.
// With `instance` not NONE, hits on the holes of its alpha masks do not count
// (HitFilter, the CPU's AlphaTest).
fn blas_walk(root: u32, o: vec3<f32>, d: vec3<f32>, tmin_in: f32, tmax_in: f32, any_hit: bool, instance: u32) -> MeshHit {
    var best = MeshHit(false, tmax_in, 0u, 0.0, 0.0);
    let tmin = query_tmin(tmin_in);
    var tmax = tmax_in;
    if root == NONE || !(tmin <= tmax) {
        return best;
    }
    let wr = watertight_ray(o, d);
    let nr = node_ray(o, d);
    blas_stack[0] = Entry(tmin, root);
    var sp = 1u;
    while sp > 0u {
        sp = sp - 1u;
        let entry = blas_stack[sp];
        if entry.t > tmax {
            continue;
        }
        let n = entry.code;
        let hits = child_hits(n, nr, tmin, tmax, 0.0);
        let leaves = hits.mask & leaf_slots(n);
        if leaves != 0u {
            let code = child_code(n, firstTrailingBit(leaves));
            let first = code & FIRST_MASK;
            for (var b = first; b < first + leaf_count(code); b = b + 1u) {
                for (var lane = 0u; lane < 8u; lane = lane + 1u) {
                    if (tri_blocks[b].slot[lane / 4u][lane % 4u] & leaves) == 0u {
                        continue;
                    }
                    let h = intersect_triangle(wr, block_vertex(b, 0u, lane), block_vertex(b, 1u, lane), block_vertex(b, 2u, lane), tmin, tmax);
                    let id = tri_blocks[b].id[lane / 4u][lane % 4u];
                    if h.hit && (!best.hit || h.t < best.t || (h.t == best.t && id < best.triangle))
                        && (instance == NONE || !masked_out(instance, id, h.u, h.v)) {
                        best = MeshHit(true, h.t, id, h.u, h.v);
                        if any_hit {
                            return best;
                        }
                        tmax = h.t;
                    }
                }
            }
        }
        sp = push_children(&blas_stack, sp, n, hits, hits.mask & ~leaves, tmax, !any_hit);
    }
    return best;
}

// An affine map stored as three rows (x, y, z, translation) applied to a point, summed in
// glam's order (x_axis·x + y_axis·y + z_axis·z + translation).
fn rows_point(m: array<vec4<f32>, 3>, p: vec3<f32>) -> vec3<f32> {
    let x_axis = vec3<f32>(m[0].x, m[1].x, m[2].x);
    let y_axis = vec3<f32>(m[0].y, m[1].y, m[2].y);
    let z_axis = vec3<f32>(m[0].z, m[1].z, m[2].z);
    let translation = vec3<f32>(m[0].w, m[1].w, m[2].w);
    return x_axis * p.x + y_axis * p.y + z_axis * p.z + translation;
}

// The same map applied to a vector (no translation).
fn rows_vector(m: array<vec4<f32>, 3>, v: vec3<f32>) -> vec3<f32> {
    let x_axis = vec3<f32>(m[0].x, m[1].x, m[2].x);
    let y_axis = vec3<f32>(m[0].y, m[1].y, m[2].y);
    let z_axis = vec3<f32>(m[0].z, m[1].z, m[2].z);
    return x_axis * v.x + y_axis * v.y + z_axis * v.z;
}

struct InstanceHit {
    hit: bool,
    t: f32,
    instance: u32,
    triangle: u32,
    u: f32,
    v: f32,
}

// InstanceBvh::closest_hit: the world ray mapped into each instance's object space (not
// renormalised, so t stays the world parameter), ties to the smaller instance, then triangle;
// with `any_hit` (InstanceBvh::any_hit) the first hit found. The node test grows the boxes by
// the CPU's per-ray margin (the rounding of mapping the ray, `origin_margin` × max |o|).
fn tlas_walk(o: vec3<f32>, d: vec3<f32>, tmin_in: f32, tmax_in: f32, any_hit: bool) -> InstanceHit {
    var best = InstanceHit(false, tmax_in, 0u, 0u, 0.0, 0.0);
    let tmin = query_tmin(tmin_in);
    var tmax = tmax_in;
    if globals.tlas_root == NONE || !(tmin <= tmax) {
        return best;
    }
    let nr = node_ray(o, d);
    let margin = globals.tlas_origin_margin * max(max(abs(o.x), abs(o.y)), abs(o.z));
    tlas_stack[0] = Entry(tmin, globals.tlas_root);
    var sp = 1u;
    while sp > 0u {
        sp = sp - 1u;
        let entry = tlas_stack[sp];
        if entry.t > tmax {
            continue;
        }
        if (entry.code & LEAF_BIT) != 0u {
            let first = entry.code & FIRST_MASK;
            for (var j = first; j < first + leaf_count(entry.code); j = j + 1u) {
                let index = refs[j];
                let inst = instances[index];
                let mesh = meshes[inst.mesh];
                var tested = NONE;
                if inst.alpha_tested != 0u {
                    tested = index;
                }
                let h = blas_walk(mesh.root, rows_point(inst.world_to_object, o), rows_vector(inst.world_to_object, d), tmin, tmax, any_hit, tested);
                // The merged mesh (InstanceBvh::scene_ids): its triangle stands for an
                // instance's own.
                var instance = index;
                var triangle = h.triangle;
                if index == globals.instance_count {
                    let k = globals.merged_origin_start + 2u * h.triangle;
                    instance = refs[k];
                    triangle = refs[k + 1u];
                }
                if h.hit && (!best.hit || h.t < best.t
                    || (h.t == best.t && (instance < best.instance || (instance == best.instance && triangle < best.triangle)))) {
                    best = InstanceHit(true, h.t, instance, triangle, h.u, h.v);
                    if any_hit {
                        return best;
                    }
                    tmax = h.t;
                }
            }
            continue;
        }
        let hits = child_hits(entry.code, nr, tmin, tmax, margin);
        sp = push_children(&tlas_stack, sp, entry.code, hits, hits.mask, tmax, !any_hit);
    }
    return best;
}

fn tlas_closest(o: vec3<f32>, d: vec3<f32>, tmin: f32, tmax: f32) -> InstanceHit {
    return tlas_walk(o, d, tmin, tmax, false);
}

fn tlas_any(o: vec3<f32>, d: vec3<f32>, tmin: f32, tmax: f32) -> bool {
    return tlas_walk(o, d, tmin, tmax, true).hit;
}
