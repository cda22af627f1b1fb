// The hybrid scene queries: SceneTracer (src/trace/mod.rs) over SDF objects and mesh
// instances, mirrored function by function. This file is the contract with the shading code.
//
// CONTRACT (names and signatures as agreed; one clarification):
//   SceneHit.gradient is the raw gradient vector ∇f the normal estimator measured for an SDF
//   hit (its length is the CPU's `Hit::gradient`), and the unit normal for a mesh hit (length
//   1, as the CPU's 1.0). Materials: `Material` is generated from `MaterialParams`
//   (color, diffuse, specular, shininess, reflectivity, transparency, ior).
//   Shadow kinds are the generated SHADOW_NONE / SHADOW_HARD / SHADOW_SOFT /
//   SHADOW_SOFT_IMPROVED, hit kinds HIT_MISS / HIT_SDF / HIT_MESH.

struct SceneHit {
    t: f32,
    kind: u32,
    object: u32,
    triangle: u32,
    bary: vec2<f32>,
    normal: vec3<f32>,
    gradient: vec3<f32>,
    steps: u32,
}

// ---- walking the SDF objects (SdfAccel::visit_within): unbounded objects first, then the
// BVH over the bounded ones, every box grown by `margin` when margin > 0. WGSL has no
// closures, so the four visitors of SceneTracer are one switch (`WALK_*`) and the walk state
// is passed by value; its stack is a module-scope array (see `blas_stack`).

var<private> object_stack: array<Entry, STACK_SIZE>;

const WALK_CLOSEST: u32 = 0u;
const WALK_OCCLUDED: u32 = 1u;
const WALK_PENUMBRA: u32 = 2u;
const WALK_DISTANCE: u32 = 3u;

struct WalkState {
    // closest: a hit was found; occluded: the ray is blocked
    found: bool,
    // closest: the hit distance and object, and the steps spent
    t: f32,
    object: u32,
    steps: u32,
    // penumbra: the smallest visibility; distance: the smallest field value
    value: f32,
    // the current upper end of the interval (closest hits shorten it)
    limit: f32,
    stop: bool,
}

fn object_interval(index: u32, o: vec3<f32>, d: vec3<f32>, tmin: f32, tmax: f32, margin: f32) -> Interval {
    let obj = objects[index];
    if obj.nan_bounds != 0u {
        return Interval(true, tmin, tmax);
    }
    if margin > 0.0 {
        return ray_interval(obj.lo - vec3<f32>(margin), obj.hi + vec3<f32>(margin), o, d, tmin, tmax);
    }
    return ray_interval(obj.lo, obj.hi, o, d, tmin, tmax);
}

// One object whose (grown) bounds the ray crosses over [t0, t1]: the body of the closure
// SceneTracer passes to the walk, for each query.
fn walk_visit(query: u32, index: u32, t0: f32, t1: f32, o: vec3<f32>, d: vec3<f32>, k: f32, improved: bool, state: WalkState) -> WalkState {
    var s = state;
    switch query {
        case WALK_CLOSEST: {
            // the march stays within [t0, t1] ⊆ [tmin, limit]: any hit is the nearest so far
            let r = sdf_trace(index, o, d, t0, t1);
            s.steps = s.steps + r.steps;
            if r.hit {
                s.found = true;
                s.t = r.t;
                s.object = index;
                s.limit = r.t;
            }
        }
        case WALK_OCCLUDED: {
            if sdf_trace(index, o, d, t0, t1).hit {
                s.found = true;
                s.stop = true;
            }
        }
        case WALK_PENUMBRA: {
            s.value = min(s.value, sdf_penumbra(index, o, d, t0, t1, k, improved));
            if s.value <= 0.0 {
                s.stop = true;
            }
        }
        default: {
            s.value = min(s.value, field_eval(index, o));
        }
    }
    return s;
}

// Walks the objects for one query; `value` starts at `initial_value`.
fn sdf_walk(query: u32, o: vec3<f32>, d: vec3<f32>, tmin: f32, tmax: f32, margin: f32, k: f32, improved: bool, initial_value: f32) -> WalkState {
    var s = WalkState(false, 0.0, 0u, 0u, initial_value, tmax, false);
    for (var u = 0u; u < globals.unbounded_count; u = u + 1u) {
        if tmin != tmin || s.limit != s.limit || tmin > s.limit {
            // AabbBvh::visit_within gives up on an empty or NaN interval
            s.stop = true;
        }
        if s.stop {
            break;
        }
        let index = refs[globals.unbounded_start + u];
        let iv = object_interval(index, o, d, tmin, s.limit, margin);
        if iv.hit {
            s = walk_visit(query, index, iv.t0, iv.t1, o, d, k, improved, s);
        }
    }
    // the tree: AabbBvh::visit_within's walk (`traverse` with the boxes grown by margin),
    // nearest child first; its leaves' boxes are tested with the caller's tmin
    let node_tmin = query_tmin(tmin);
    if s.stop || globals.object_root == NONE || !(node_tmin <= s.limit) {
        return s;
    }
    let nr = node_ray(o, d);
    object_stack[0] = Entry(node_tmin, globals.object_root);
    var sp = 1u;
    while sp > 0u && !s.stop {
        sp = sp - 1u;
        let entry = object_stack[sp];
        if entry.t > s.limit {
            continue;
        }
        if (entry.code & LEAF_BIT) != 0u {
            let first = entry.code & FIRST_MASK;
            for (var j = first; j < first + leaf_count(entry.code); j = j + 1u) {
                if s.stop {
                    break;
                }
                let index = refs[j];
                let iv = object_interval(index, o, d, tmin, s.limit, margin);
                if iv.hit {
                    s = walk_visit(query, index, iv.t0, iv.t1, o, d, k, improved, s);
                }
            }
            continue;
        }
        let hits = child_hits(entry.code, nr, node_tmin, s.limit, margin);
        sp = push_children(&object_stack, sp, entry.code, hits, hits.mask, s.limit, true);
    }
    return s;
}

// ---- mesh surfaces (SceneMeshes::surface; texture sampling is in mesh.wgsl).

struct MeshSurface {
    normal: vec3<f32>,
    material: u32,
    // SurfaceSample: multipliers of the material's colour, opacity, metallic, roughness,
    // occlusion and emission
    color: vec3<f32>,
    alpha: f32,
    metallic: f32,
    roughness: f32,
    occlusion: f32,
    emissive: vec3<f32>,
}

// meshes::normal_mapped: the texel decoded as 2t − 1, x and y scaled, in the frame (T, B, N)
// with T made orthogonal to N and B = w·(N × T); kept at least MIN_COS above the tangent
// plane of n.
fn normal_mapped(n_in: vec3<f32>, tangent: vec4<f32>, texel: vec3<f32>, scale: f32) -> vec3<f32> {
    if !(dot(n_in, n_in) > 0.0) {
        return n_in;
    }
    let n = normalize(n_in);
    let t0 = tangent.xyz - n * dot(n, tangent.xyz);
    if !(dot(t0, t0) > 0.0) {
        return n;
    }
    let t = normalize(t0);
    var sign = 1.0;
    if tangent.w < 0.0 {
        sign = -1.0;
    }
    let b = sign * cross(n, t);
    let d = 2.0 * texel - vec3<f32>(1.0);
    let mapped0 = t * (d.x * scale) + b * (d.y * scale) + n * d.z;
    if !(dot(mapped0, mapped0) > 0.0) {
        return n;
    }
    let mapped = normalize(mapped0);
    let min_cos = 0.05;
    let c = dot(mapped, n);
    if c >= min_cos {
        return mapped;
    }
    let along = mapped - n * c;
    var dir = vec3<f32>(0.0);
    if dot(along, along) > 0.0 {
        dir = normalize(along);
    }
    return normalize_or_y(dir * sqrt(1.0 - min_cos * min_cos) + n * min_cos);
}

fn mesh_surface(instance: u32, triangle: u32, u: f32, v: f32) -> MeshSurface {
    let inst = instances[instance];
    let mesh = meshes[inst.mesh];
    let tri = triangle_indices[mesh.triangle_start + triangle];
    let corners = vec3<u32>(tri.a, tri.b, tri.c);
    let va = vertices[mesh.vertex_start + tri.a];
    let vb = vertices[mesh.vertex_start + tri.b];
    let vc = vertices[mesh.vertex_start + tri.c];
    let w = 1.0 - u - v;
    let bary = vec3<f32>(w, u, v);
    let geometric = cross(vb.position - va.position, vc.position - va.position);
    var n = w * va.normal + u * vb.normal + v * vc.normal;
    if !(dot(n, n) > 1e-20) {
        n = geometric;
    }
    var surface: MeshSurface;
    surface.color = vec3<f32>(1.0);
    surface.alpha = 1.0;
    surface.metallic = 1.0;
    surface.roughness = 1.0;
    surface.occlusion = 1.0;
    surface.emissive = vec3<f32>(1.0);
    if inst.material_override != NONE {
        surface.material = inst.material_override;
    } else {
        surface.material = inst.material_base + tri.material;
        let m = surface.material;
        let base = material_texel(m, SLOT_BASE_COLOR, mesh, corners, bary)
            * (w * va.color + u * vb.color + v * vc.color);
        surface.color = base.xyz;
        if materials[m].alpha_mode == ALPHA_BLEND {
            surface.alpha = base.w;
        }
        if material_has(m, SLOT_METALLIC_ROUGHNESS) {
            // glTF 2.0 §3.9.2: metalness in B, roughness in G
            let mr = material_texel(m, SLOT_METALLIC_ROUGHNESS, mesh, corners, bary);
            surface.metallic = mr.z;
            surface.roughness = mr.y;
        }
        let factors = materials[m].factors;
        if material_has(m, SLOT_OCCLUSION) {
            // §3.9.4: 1 + strength·(R − 1)
            surface.occlusion = 1.0 + factors.w * (material_texel(m, SLOT_OCCLUSION, mesh, corners, bary).x - 1.0);
        }
        if material_has(m, SLOT_EMISSIVE) {
            surface.emissive = material_texel(m, SLOT_EMISSIVE, mesh, corners, bary).xyz;
        }
        if material_has(m, SLOT_NORMAL) && mesh.has_uvs != 0u {
            let tangent = w * va.tangent + u * vb.tangent + v * vc.tangent;
            let texel = material_texel(m, SLOT_NORMAL, mesh, corners, bary).xyz;
            n = normal_mapped(n, tangent, texel, factors.z);
        }
    }
    // the normal matrix is stored as columns: x_axis·n.x + y_axis·n.y + z_axis·n.z
    let nm = inst.normal_matrix;
    let world = nm[0].xyz * n.x + nm[1].xyz * n.y + nm[2].xyz * n.z;
    surface.normal = normalize_or_y(world);
    return surface;
}

// ---- the queries.

fn scene_miss() -> SceneHit {
    return SceneHit(0.0, HIT_MISS, 0u, 0u, vec2<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0), 0u);
}

// SceneTracer::closest_hit: meshes first (their hit shortens every SDF march), then every
// SDF object whose bounds the ray crosses before the current limit.
fn scene_closest_hit(o: vec3<f32>, d: vec3<f32>, tmin: f32, tmax: f32) -> SceneHit {
    var limit = min(tmax, globals.max_distance);
    let mesh = tlas_closest(o, d, tmin, limit);
    if mesh.hit {
        limit = mesh.t;
    }
    let w = sdf_walk(WALK_CLOSEST, o, d, tmin, limit, 0.0, 0.0, false, 0.0);
    let steps = w.steps;
    if w.found {
        let p = o + d * w.t;
        let g = sdf_gradient(w.object, p, normal_step(w.t, p));
        return SceneHit(w.t, HIT_SDF, w.object, 0u, vec2<f32>(0.0), normalize_or_y(g), g, steps);
    }
    if mesh.hit {
        let s = mesh_surface(mesh.instance, mesh.triangle, mesh.u, mesh.v);
        return SceneHit(mesh.t, HIT_MESH, mesh.instance, mesh.triangle, vec2<f32>(mesh.u, mesh.v), s.normal, s.normal, steps);
    }
    var miss = scene_miss();
    miss.steps = steps;
    return miss;
}

// SceneTracer::mesh_blocks.
fn mesh_blocks(o: vec3<f32>, d: vec3<f32>, tmin: f32, tmax: f32) -> bool {
    return tlas_any(o, d, tmin, min(tmax, globals.max_distance));
}

// SceneTracer::occluded: meshes, then any SDF hit stops the walk.
fn scene_occluded(o: vec3<f32>, d: vec3<f32>, tmin: f32, tmax: f32) -> bool {
    if mesh_blocks(o, d, tmin, tmax) {
        return true;
    }
    let limit = min(tmax, globals.max_distance);
    return sdf_walk(WALK_OCCLUDED, o, d, tmin, limit, 0.0, 0.0, false, 0.0).found;
}

// SceneTracer::visibility: 1 or 0 for hard shadows; for soft ones the smallest penumbra over
// the objects near the ray (bounds grown by limit/k), smoothed with smoothstep.
fn scene_visibility(o: vec3<f32>, d: vec3<f32>, tmin: f32, tmax: f32, shadow_kind: u32, k: f32) -> f32 {
    if shadow_kind == SHADOW_NONE {
        return 1.0;
    }
    if shadow_kind == SHADOW_HARD {
        if scene_occluded(o, d, tmin, tmax) {
            return 0.0;
        }
        return 1.0;
    }
    if mesh_blocks(o, d, tmin, tmax) {
        return 0.0;
    }
    let improved = shadow_kind == SHADOW_SOFT_IMPROVED;
    let limit = min(tmax, globals.max_distance);
    // k·h/t < 1 only where h < t/k ≤ limit/k: objects farther than that from the ray cannot
    // darken it
    let margin = limit / k;
    let res = sdf_walk(WALK_PENUMBRA, o, d, tmin, limit, margin, k, improved, 1.0).value;
    return res * res * (3.0 - 2.0 * res);
}

// SceneTracer::distance: the minimum field over objects whose bounds grown by `reach`
// contain p, clamped to reach.
fn scene_distance(p: vec3<f32>, reach: f32) -> f32 {
    // a zero-length probe ray along +y, as the CPU's
    return sdf_walk(WALK_DISTANCE, p, vec3<f32>(0.0, 1.0, 0.0), 0.0, 0.0, reach, 0.0, false, reach).value;
}

// SceneTracer::exit: where a ray that starts inside the solid of `hit` leaves it, with the
// outward normal there, as (t, normal); t < 0 when it does not.
fn scene_exit(hit: SceneHit, o: vec3<f32>, d: vec3<f32>, tmax: f32) -> vec4<f32> {
    let limit = min(tmax, globals.max_distance);
    if hit.kind == HIT_MESH {
        let h = tlas_closest(o, d, 0.0, limit);
        if !h.hit {
            return vec4<f32>(-1.0, 0.0, 0.0, 0.0);
        }
        var n = mesh_surface(h.instance, h.triangle, h.u, h.v).normal;
        if dot(n, d) < 0.0 {
            n = -n;
        }
        return vec4<f32>(h.t, n);
    }
    let t = sdf_exit(hit.object, o, d, 0.0, limit);
    if t < 0.0 {
        return vec4<f32>(-1.0, 0.0, 0.0, 0.0);
    }
    let p = o + d * t;
    let n = normalize_or_y(sdf_gradient(hit.object, p, normal_step(t, p)));
    return vec4<f32>(t, n);
}

// SceneTracer::material_at: the SDF's blended material from the shading tape valid at p (the
// leaf's, or the whole one), or the mesh triangle's material with its textures applied.
fn scene_material(hit: SceneHit, p: vec3<f32>) -> Material {
    if hit.kind == HIT_MESH {
        let s = mesh_surface(hit.object, hit.triangle, hit.bary.x, hit.bary.y);
        var m = material_from_lanes(materials[s.material].lanes);
        // SurfaceSample::apply
        m.color = m.color * s.color;
        m.opacity = m.opacity * s.alpha;
        m.occlusion = m.occlusion * s.occlusion;
        m.emissive = m.emissive * s.emissive;
        if s.metallic != 1.0 || s.roughness != 1.0 {
            let before = m.metallic * (1.0 - m.roughness) * (1.0 - m.roughness);
            m.metallic = m.metallic * s.metallic;
            m.roughness = m.roughness * s.roughness;
            if m.pbr > 0.0 && abs(m.reflectivity - before) < 1e-6 {
                m.reflectivity = m.metallic * (1.0 - m.roughness) * (1.0 - m.roughness);
            }
        }
        return m;
    }
    return material_from_lanes(tape_material(field_shading_at(hit.object, p), p));
}
