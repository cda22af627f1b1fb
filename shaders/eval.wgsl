// The tape evaluation kernel: the distance tape of object `chunk.object` at every point of one
// chunk (the GPU side of the SDF conformance suite).

@group(1) @binding(0) var<storage, read> eval_points: array<vec4<f32>>;
@group(1) @binding(1) var<storage, read_write> eval_values: array<f32>;
@group(1) @binding(2) var<uniform> chunk: ChunkParams;

@compute @workgroup_size(WORKGROUP_SIZE)
fn eval_main(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= chunk.count {
        return;
    }
    let i = chunk.first + id.x;
    eval_values[i] = tape_eval(objects[chunk.object].distance, eval_points[i].xyz);
}
