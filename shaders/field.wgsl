// An object's field octree (src/accel/field.rs): point location (`FieldOctree::locate`,
// `FieldCursor::eval`, `ObjectField::shading_at`) and the parametric ray walk over its leaves
// (`RayWalk`, Revelles, Ureña & Lastra 2000), step for step. Every object's octree sits in
// `field_nodes` as the CPU stores it, rebased: a node is the index of the first of its eight
// children (octant order: bit 0 x, bit 1 y, bit 2 z, set for the upper half) or
// FIELD_LEAF | an index into `field_leaves`, whose tapes are indices into `field_tapes`. An
// object's record holds its root (NONE without an octree) and the box the octree covers.

fn max3(v: vec3<f32>) -> f32 {
    return max(max(v.x, v.y), v.z);
}

fn min3(v: vec3<f32>) -> f32 {
    return min(min(v.x, v.y), v.z);
}

// FieldOctree::locate: the leaf holding p (the tree's box closed; a point on a midplane goes
// to the upper child), or NONE outside the octree's box or without one. The CPU's cursor
// resumes from its last leaf or path, whose boxes it checks half open above (Cell::owns), so
// it finds the leaf this descent from the root finds, for every point. The descent is bounded by
// the tree's depth, so a malformed tree gives NONE (the whole tape, always right) rather than
// a long loop.
fn field_locate(object: u32, p: vec3<f32>) -> u32 {
    let obj = objects[object];
    if obj.field_root == NONE {
        return NONE;
    }
    var lo = obj.field_lo;
    var hi = obj.field_hi;
    if !(all(p >= lo) && all(p <= hi)) {
        return NONE;
    }
    var node = field_nodes[obj.field_root];
    for (var depth = 0u; depth < FIELD_MAX_DEPTH && (node & FIELD_LEAF) == 0u; depth = depth + 1u) {
        let mid = 0.5 * (lo + hi);
        let up = p >= mid;
        let octant = select(0u, 1u, up.x) | select(0u, 2u, up.y) | select(0u, 4u, up.z);
        node = field_nodes[node + octant];
        lo = select(lo, mid, up);
        hi = select(mid, hi, up);
    }
    if (node & FIELD_LEAF) == 0u {
        return NONE;
    }
    return node & ~FIELD_LEAF;
}

// FieldCursor::region's tape: the distance tape of the leaf holding p, else the whole one.
fn field_tape_at(object: u32, p: vec3<f32>) -> TapeRef {
    let leaf = field_locate(object, p);
    if leaf == NONE {
        return objects[object].distance;
    }
    return field_tapes[field_leaves[leaf].tape];
}

// FieldCursor::eval: the field at p.
fn field_eval(object: u32, p: vec3<f32>) -> f32 {
    return tape_eval(field_tape_at(object, p), p);
}

// ObjectField::shading_at: the shading tape valid at p (the leaf's, or the whole one).
fn field_shading_at(object: u32, p: vec3<f32>) -> TapeRef {
    let leaf = field_locate(object, p);
    if leaf == NONE {
        return objects[object].shading;
    }
    return field_tapes[field_leaves[leaf].shading];
}

// ---- the ray walk (RayWalk). One walk is active per invocation at a time (the tracer walks
// one object's leaves while it marches them; probes locate points instead), so its state and
// stack are module-scope, as the BVH walks' stacks are.

// One level of the walk: RayWalk's Frame without the box, which only the CPU's callers use.
struct FieldFrame {
    t0: vec3<f32>,
    node: u32,
    t1: vec3<f32>,
    // the next child to visit, in the mirrored frame (8: none left)
    next: u32,
}

// The walk's state: the mirrored axes, the stack's height and the interval walked.
struct FieldWalk {
    mirror: u32,
    len: u32,
    t_from: f32,
    t_to: f32,
}

var<private> field_stack: array<FieldFrame, FIELD_MAX_DEPTH + 1u>;
var<private> field_walk: FieldWalk;

// A leaf met by the walk (Crossed): its index, NONE when the walk is over, and where the
// ray enters and leaves its box.
struct Crossed {
    leaf: u32,
    enter: f32,
    exit: f32,
}

fn crossed_none() -> Crossed {
    return Crossed(NONE, 0.0, 0.0);
}

// field::first_child: the first child the ray enters (Revelles et al., Table 1, in our bit
// order): across the entry plane, the halves whose midplane is crossed before entering.
fn field_first_child(t0: vec3<f32>, tm: vec3<f32>) -> u32 {
    let entry = max3(t0);
    return select(0u, 1u, tm.x < entry) | select(0u, 2u, tm.y < entry) | select(0u, 4u, tm.z < entry);
}

// RayWalk::push: an inner node, with the first child the ray enters.
fn field_push(node: u32, t0: vec3<f32>, t1: vec3<f32>) {
    let tm = 0.5 * (t0 + t1);
    field_stack[field_walk.len] = FieldFrame(t0, node, t1, field_first_child(t0, tm));
    field_walk.len = field_walk.len + 1u;
}

// RayWalk::new: the walk over the leaves of object's octree that the ray crosses within
// [t_from, t_to]. The ray is mirrored so that every direction component is positive (child
// numbers are mirrored with it), tiny components count as TINY_DIRECTION so that the slab
// parameters stay finite; the root is pushed when the ray crosses the box and reaches t_from.
// Without an octree the walk meets nothing.
fn field_walk_begin(object: u32, o: vec3<f32>, d: vec3<f32>, t_from: f32, t_to: f32) {
    field_walk = FieldWalk(0u, 0u, t_from, t_to);
    let obj = objects[object];
    if obj.field_root == NONE {
        return;
    }
    var mo = o;
    var md = d;
    for (var axis = 0u; axis < 3u; axis = axis + 1u) {
        if md[axis] < 0.0 {
            mo[axis] = obj.field_lo[axis] + obj.field_hi[axis] - mo[axis];
            md[axis] = -md[axis];
            field_walk.mirror = field_walk.mirror | (1u << axis);
        }
        md[axis] = max(md[axis], TINY_DIRECTION);
    }
    let inv = 1.0 / md;
    let t0 = (obj.field_lo - mo) * inv;
    let t1 = (obj.field_hi - mo) * inv;
    if max3(t0) < min3(t1) && min3(t1) >= t_from {
        field_push(field_nodes[obj.field_root], t0, t1);
    }
}

// RayWalk::next_leaf: the next leaf along the ray, or NONE past t_to or the tree. Each node's
// slab parameters are halved into its children's, and the next sibling is the one across the
// nearest exit plane of the child just taken.
fn field_next_leaf() -> Crossed {
    while field_walk.len > 0u {
        let top = field_walk.len - 1u;
        let f = field_stack[top];
        if (f.node & FIELD_LEAF) != 0u {
            field_walk.len = top;
            let enter = max3(f.t0);
            if enter > field_walk.t_to {
                field_walk.len = 0u;
                return crossed_none();
            }
            return Crossed(f.node & ~FIELD_LEAF, enter, min3(f.t1));
        }
        if f.next >= 8u {
            field_walk.len = top;
            continue;
        }
        // child c in the mirrored frame: bit 0 = x, 1 = y, 2 = z, as stored
        let c = f.next;
        let tm = 0.5 * (f.t0 + f.t1);
        let up = vec3<bool>((c & 1u) != 0u, (c & 2u) != 0u, (c & 4u) != 0u);
        let ct0 = select(f.t0, tm, up);
        let ct1 = select(tm, f.t1, up);
        // the next sibling: across the nearest exit plane of this child, if it is inside
        var exit_axis = 2u;
        if ct1.x <= ct1.y && ct1.x <= ct1.z {
            exit_axis = 0u;
        } else if ct1.y <= ct1.z {
            exit_axis = 1u;
        }
        if (c & (1u << exit_axis)) != 0u {
            field_stack[top].next = 8u;
        } else {
            field_stack[top].next = c | (1u << exit_axis);
        }
        if min3(ct1) < field_walk.t_from || max3(ct0) > field_walk.t_to {
            continue;
        }
        // the child as stored: mirrored axes take the other half
        let child = field_nodes[f.node + (c ^ field_walk.mirror)];
        if (child & FIELD_LEAF) != 0u {
            field_stack[field_walk.len] = FieldFrame(ct0, child, ct1, 0u);
            field_walk.len = field_walk.len + 1u;
        } else {
            field_push(child, ct0, ct1);
        }
    }
    return crossed_none();
}
