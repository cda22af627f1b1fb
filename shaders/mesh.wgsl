// Mesh traversal: BVH2 walks with a fixed-size stack over the flattened nodes, the
// Woop–Benthin–Wald watertight triangle test of src/accel/triangle.rs, and instances
// (world → object ray mapping as src/accel/bvh.rs's InstanceBvh does it).

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

// Traversal stacks, one per nesting level, at module scope: function-local arrays are
// allocated once per inlined call site, and lavapipe (Mesa 22.3) silently corrupted private
// memory once a kernel had many of them (the probe kernel, which calls every query).
var<private> blas_stack: array<u32, STACK_SIZE>;
var<private> tlas_stack: array<u32, STACK_SIZE>;

struct MeshHit {
    hit: bool,
    t: f32,
    triangle: u32,
    u: f32,
    v: f32,
}

// Pushes the two children of an inner node, the one whose centre lies farther along the ray
// first, so the nearer is popped first.
fn push_children(stack: ptr<private, array<u32, STACK_SIZE>>, sp: ptr<function, u32>, first: u32, o: vec3<f32>, d: vec3<f32>) {
    let c0 = nodes[first];
    let c1 = nodes[first + 1u];
    let k0 = dot(c0.lo + c0.hi - 2.0 * o, d);
    let k1 = dot(c1.lo + c1.hi - 2.0 * o, d);
    if k0 <= k1 {
        (*stack)[*sp] = first + 1u;
        (*stack)[*sp + 1u] = first;
    } else {
        (*stack)[*sp] = first;
        (*stack)[*sp + 1u] = first + 1u;
    }
    *sp = *sp + 2u;
}

// MeshBvh::closest_hit in object space: the nearest triangle with tmin ≤ t ≤ tmax, ties to
// the smaller triangle index; with `any_hit` (MeshBvh::any_hit) the first triangle found.
fn blas_walk(root: u32, o: vec3<f32>, d: vec3<f32>, tmin: f32, tmax_in: f32, any_hit: bool) -> MeshHit {
    let wr = watertight_ray(o, d);
    var best = MeshHit(false, tmax_in, 0u, 0.0, 0.0);
    var tmax = tmax_in;
    blas_stack[0] = root;
    var sp = 1u;
    while sp > 0u {
        sp = sp - 1u;
        let node = nodes[blas_stack[sp]];
        if !ray_interval(node.lo, node.hi, o, d, tmin, tmax).hit {
            continue;
        }
        if node.count == 0u {
            push_children(&blas_stack, &sp, node.first, o, d);
            continue;
        }
        for (var j = node.first; j < node.first + node.count; j = j + 1u) {
            let tri = triangles[j];
            let h = intersect_triangle(wr, tri.a, tri.b, tri.c, tmin, tmax);
            if h.hit && (!best.hit || h.t < best.t || (h.t == best.t && tri.id < best.triangle)) {
                best = MeshHit(true, h.t, tri.id, h.u, h.v);
                if any_hit {
                    return best;
                }
                tmax = h.t;
            }
        }
    }
    return best;
}

fn blas_closest(root: u32, o: vec3<f32>, d: vec3<f32>, tmin: f32, tmax: f32) -> MeshHit {
    return blas_walk(root, o, d, tmin, tmax, false);
}

fn blas_any(root: u32, o: vec3<f32>, d: vec3<f32>, tmin: f32, tmax: f32) -> bool {
    return blas_walk(root, o, d, tmin, tmax, true).hit;
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
// with `any_hit` (InstanceBvh::any_hit) the first hit found.
fn tlas_walk(o: vec3<f32>, d: vec3<f32>, tmin: f32, tmax_in: f32, any_hit: bool) -> InstanceHit {
    var best = InstanceHit(false, tmax_in, 0u, 0u, 0.0, 0.0);
    if globals.tlas_root == NONE {
        return best;
    }
    var tmax = tmax_in;
    tlas_stack[0] = globals.tlas_root;
    var sp = 1u;
    while sp > 0u {
        sp = sp - 1u;
        let node = nodes[tlas_stack[sp]];
        if !ray_interval(node.lo, node.hi, o, d, tmin, tmax).hit {
            continue;
        }
        if node.count == 0u {
            push_children(&tlas_stack, &sp, node.first, o, d);
            continue;
        }
        for (var j = node.first; j < node.first + node.count; j = j + 1u) {
            let index = refs[j];
            let inst = instances[index];
            let mesh = meshes[inst.mesh];
            let h = blas_walk(mesh.root, rows_point(inst.world_to_object, o), rows_vector(inst.world_to_object, d), tmin, tmax, any_hit);
            if h.hit && (!best.hit || h.t < best.t
                || (h.t == best.t && (index < best.instance || (index == best.instance && h.triangle < best.triangle)))) {
                best = InstanceHit(true, h.t, index, h.triangle, h.u, h.v);
                if any_hit {
                    return best;
                }
                tmax = h.t;
            }
        }
    }
    return best;
}

fn tlas_closest(o: vec3<f32>, d: vec3<f32>, tmin: f32, tmax: f32) -> InstanceHit {
    return tlas_walk(o, d, tmin, tmax, false);
}

fn tlas_any(o: vec3<f32>, d: vec3<f32>, tmin: f32, tmax: f32) -> bool {
    return tlas_walk(o, d, tmin, tmax, true).hit;
}
