// The batch ray-query kernel: closest hit and/or occlusion for each ray of one chunk
// (src/gpu/query.rs dispatches a batch in chunks so that no dispatch runs long).
// Group 1 (query_rays, query_results, chunk) is declared by the generated code of KernelSource::io
// (src/gpu/shaders.rs).

@compute @workgroup_size(WORKGROUP_SIZE)
fn query_main(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= chunk.count {
        return;
    }
    let i = chunk.first + id.x;
    let ray = query_rays[i];
    var result: QueryResult;
    result.kind = HIT_MISS;
    if (chunk.queries & QUERY_CLOSEST) != 0u {
        let hit = scene_closest_hit(ray.origin, ray.direction, ray.tmin, ray.tmax);
        result.t = hit.t;
        result.kind = hit.kind;
        result.object = hit.object;
        result.normal = hit.normal;
        result.steps = hit.steps;
    }
    if (chunk.queries & QUERY_OCCLUDED) != 0u {
        result.occluded = select(0u, 1u, scene_occluded(ray.origin, ray.direction, ray.tmin, ray.tmax));
    }
    // (chunk.count < 2³¹: the shift is 0)
    result.cut = select(0u, 1u, loops_were_cut(chunk.count >> 31u));
    query_results[i] = result;
}
