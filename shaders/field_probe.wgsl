// The field probe kernel: for the object `chunk.object`, the field and the leaf at each ray's
// origin (field_eval, field_locate) and the leaves the octree walk meets over the ray's
// interval (field_walk_begin, field_next_leaf), so that tests can compare them with
// FieldOctree::locate, the CPU's leaf tapes and RayWalk.
// Group 1 (field_probe_rays, field_probe_results, chunk) is declared by the generated code of KernelSource::io
// (src/gpu/shaders.rs).

@compute @workgroup_size(WORKGROUP_SIZE)
fn field_probe_main(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= chunk.count {
        return;
    }
    let i = chunk.first + id.x;
    let ray = field_probe_rays[i];
    let object = chunk.object;
    var r: FieldProbeResult;
    r.value = field_eval(object, ray.origin);
    r.leaf = field_locate(object, ray.origin);
    r.first_surface = NONE;
    field_walk_begin(object, ray.origin, ray.direction, ray.tmin, ray.tmax);
    loop {
        let c = field_next_leaf();
        if c.leaf == NONE {
            break;
        }
        if r.count < FIELD_PROBE_LEAVES {
            r.leaves[r.count / 4u][r.count % 4u] = c.leaf;
        }
        if r.first_surface == NONE && field_leaves[c.leaf].verdict != VERDICT_EMPTY {
            r.first_surface = c.leaf;
            r.first_enter = c.enter;
            r.first_exit = c.exit;
        }
        r.count = r.count + 1u;
    }
    field_probe_results[i] = r;
}
