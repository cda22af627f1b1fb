// The tape evaluation kernel: the distance tape of object `chunk.object` at every point of one
// chunk (the GPU side of the SDF conformance suite).
// Group 1 (eval_points, eval_values, chunk) is declared by the generated code of KernelSource::io
// (src/gpu/shaders.rs).

@compute @workgroup_size(WORKGROUP_SIZE)
fn eval_main(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= chunk.count {
        return;
    }
    let i = chunk.first + id.x;
    eval_values[i] = tape_eval(objects[chunk.object].distance, eval_points[i].xyz);
}
