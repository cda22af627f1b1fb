// What a window shows (src/gpu/display.rs): one triangle covering the target; each pixel takes
// the picture's pixel under it (the picture scaled to the window by repeating pixels), either
// 8-bit sRGB pixels uploaded by the host or the render kernel's sums of samples, tone-mapped
// here as the host's `render::output` does; the heads-up band on top is darkened and its text
// drawn over. Everything is composed in 8-bit sRGB codes, as the host composes an image file.
//
// The generated prelude before this file declares RenderPixel, DisplaySettings and the
// DISPLAY_* constants.

@group(0) @binding(0) var<uniform> display: DisplaySettings;
@group(0) @binding(1) var picture: texture_2d<f32>;
@group(0) @binding(2) var<storage, read> sums: array<RenderPixel>;
@group(0) @binding(3) var heads_up: texture_2d<f32>;

@vertex
fn cover_vertex(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    // (-1, -1), (3, -1), (-1, 3): a triangle whose inside holds the whole clip square
    let x = f32((i << 1u) & 2u) * 2.0 - 1.0;
    let y = f32(i & 2u) * 2.0 - 1.0;
    return vec4<f32>(x, y, 0.0, 1.0);
}

// `render::output::ToneMapping::apply`: exposure, then the operator.
fn tone_map(radiance: vec3<f32>) -> vec3<f32> {
    let x = max(radiance, vec3<f32>(0.0)) * display.exposure_scale;
    switch display.tone_operator {
        case DISPLAY_TONE_CLAMP: {
            return min(x, vec3<f32>(1.0));
        }
        case DISPLAY_TONE_REINHARD: {
            // Reinhard, Stark, Shirley & Ferwerda 2002
            return x / (vec3<f32>(1.0) + x);
        }
        default: {
            // Narkowicz's ACES fit, 2015
            let num = x * (2.51 * x + 0.03);
            let den = x * (2.43 * x + 0.59) + 0.14;
            return clamp(num / den, vec3<f32>(0.0), vec3<f32>(1.0));
        }
    }
}

// `render::output::to_srgb8` of one channel: the sRGB transfer function (IEC 61966-2-1),
// quantised to its 8-bit code.
fn srgb_code(v: f32) -> f32 {
    let c = clamp(v, 0.0, 1.0);
    var e = 12.92 * c;
    if c > 0.0031308 {
        e = 1.055 * pow(c, 1.0 / 2.4) - 0.055;
    }
    return floor(e * 255.0 + 0.5);
}

// The inverse transfer function, for targets that encode to sRGB on writing.
fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 {
        return v / 12.92;
    }
    return pow((v + 0.055) / 1.055, 2.4);
}

@fragment
fn display_fragment(@builtin(position) at: vec4<f32>) -> @location(0) vec4<f32> {
    let x = u32(at.x);
    let y = u32(at.y);
    let w = display.picture_width;
    let h = display.picture_height;
    // the picture's pixel under this one: floor(x·w / window width), as the host scales
    let px = min((x * w) / max(display.window_width, 1u), w - 1u);
    let py = min((y * h) / max(display.window_height, 1u), h - 1u);
    var code: vec3<f32>;
    if display.passes > 0u {
        let p = sums[py * w + px];
        let mean = p.radiance / f32(display.passes);
        let t = tone_map(mean);
        code = vec3<f32>(srgb_code(t.x), srgb_code(t.y), srgb_code(t.z));
        if p.cut != 0u {
            // a sample the driver cut short (`loops_were_cut`) is wrong: magenta says so
            code = vec3<f32>(255.0, 0.0, 255.0);
        }
    } else {
        code = round(textureLoad(picture, vec2<i32>(i32(px), i32(py)), 0).rgb * 255.0);
    }
    if y < display.band_rows {
        // darkened so the text reads on any picture
        code = floor(code * 0.35);
        let text = textureLoad(heads_up, vec2<i32>(i32(x), i32(y)), 0);
        if text.a > 0.5 {
            code = round(text.rgb * 255.0);
        }
    }
    let v = code / 255.0;
    if display.srgb_target != 0u {
        return vec4<f32>(srgb_to_linear(v.x), srgb_to_linear(v.y), srgb_to_linear(v.z), 1.0);
    }
    return vec4<f32>(v, 1.0);
}
