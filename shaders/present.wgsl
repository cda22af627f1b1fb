// The viewer's presentation (src/viewer/present.rs): one triangle covering the window, each
// pixel copied from the picture texture of the same size (textureLoad, no filtering).

@group(0) @binding(0) var picture: texture_2d<f32>;

@vertex
fn cover_vertex(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    // (-1, -1), (3, -1), (-1, 3): a triangle whose inside holds the whole clip square
    let x = f32((i << 1u) & 2u) * 2.0 - 1.0;
    let y = f32(i & 2u) * 2.0 - 1.0;
    return vec4<f32>(x, y, 0.0, 1.0);
}

@fragment
fn copy_fragment(@builtin(position) at: vec4<f32>) -> @location(0) vec4<f32> {
    let size = vec2<i32>(textureDimensions(picture));
    let texel = clamp(vec2<i32>(at.xy), vec2<i32>(0), size - vec2<i32>(1));
    return vec4<f32>(textureLoad(picture, texel, 0).rgb, 1.0);
}
