// The probe kernel: the scene queries shading builds on (scene_material, scene_exit,
// scene_visibility, scene_distance), evaluated per ray so tests can compare them with the CPU.
// `chunk.penumbra_k` is the penumbra sharpness k, `chunk.part` the query of this pass.
// Group 1 (probe_rays, probe_results, chunk) is declared by the generated code of KernelSource::io
// (src/gpu/shaders.rs).

@compute @workgroup_size(WORKGROUP_SIZE)
fn probe_main(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= chunk.count {
        return;
    }
    let i = chunk.first + id.x;
    let ray = probe_rays[i];
    let k = chunk.penumbra_k;
    // One query per pass (chunk.part), each pass its own dispatch: see GpuQuery::probe.
    var r = probe_results[i];
    if chunk.part == 0u {
        let hit = scene_closest_hit(ray.origin, ray.direction, ray.tmin, ray.tmax);
        r.kind = hit.kind;
        r.exit = vec4<f32>(-1.0, 0.0, 0.0, 0.0);
        if hit.kind != HIT_MISS {
            let p = ray.origin + ray.direction * hit.t;
            r.material = lanes_from_material(scene_material(hit, p));
            let inside = p + ray.direction * (4.0 * epsilon_at(hit.t));
            r.exit = scene_exit(hit, inside, ray.direction, ray.tmax);
        }
    } else if chunk.part == 1u {
        r.soft = scene_visibility(ray.origin, ray.direction, ray.tmin, ray.tmax, SHADOW_SOFT, k);
    } else if chunk.part == 2u {
        r.soft_improved = scene_visibility(ray.origin, ray.direction, ray.tmin, ray.tmax, SHADOW_SOFT_IMPROVED, k);
    } else {
        r.distance = scene_distance(ray.origin, 1.0);
    }
    // (chunk.count < 2³¹: the shift is 0; the first pass starts the flag)
    let cut = select(0u, 1u, loops_were_cut(chunk.count >> 31u));
    r.cut = select(r.cut | cut, cut, chunk.part == 0u);
    probe_results[i] = r;
}
