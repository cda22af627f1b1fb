// The GPU render kernel: for each pixel of one rectangle of the image, the camera rays of
// src/render/cpu.rs (`camera_sample`, with `render::sample_offset`'s stratified, hashed
// sub-pixel positions) and src/scene/camera.rs, followed by the iterative integrator of
// src/shade/integrator.rs; adds the sample to the pixel's sums of radiance and AOVs as
// `render::progressive::PixelSums` adds them (the division is the host's).
//
// Needs, from the generated prelude: ShadeCamera, ShadeSettings, ShadeLight, RenderTile,
// RenderPixel, the bindings of groups 1 and 2 (shade_settings, shade_lights; shade_camera,
// render_tile, render_pixels) and the PROJECTION_*, MAX_BOUNCES and RENDER_STACK constants
// (src/gpu/shade.rs); from shaders/scene.wgsl: SceneHit, scene_closest_hit, scene_exit,
// scene_material; from shaders/shade.wgsl: the shading functions.

/// Paths lighter than this are not followed (integrator::MIN_WEIGHT).
const MIN_WEIGHT: f32 = 1e-3;

/// The hash of (x, y, z) that seeds sample jitter (render::hash3: pcg3d reduced to one
/// output, Jarzynski & Olano, JCGT 2020). u32 arithmetic wraps in WGSL as wrapping_* does.
fn hash3(x: u32, y: u32, z: u32) -> u32 {
    var v = vec3<u32>(x, y, z) * 1664525u + 1013904223u;
    v.x += v.y * v.z;
    v.y += v.z * v.x;
    v.z += v.x * v.y;
    v ^= v >> vec3<u32>(16u);
    return v.x + v.y * v.z;
}

/// ⌈√n⌉ in integers: the CPU computes (n as f32).sqrt().ceil(), exact for n ≤ 2²⁴ because f32
/// sqrt is correctly rounded; WGSL's sqrt need not be, so count instead.
fn ceil_sqrt(n: u32) -> u32 {
    var c = 1u;
    while c * c < n {
        c += 1u;
    }
    return c;
}

/// Sub-pixel position of sample s of n in pixel (x, y) (render::sample_offset).
fn sample_offset(x: u32, y: u32, s: u32, n: u32) -> vec2<f32> {
    if n <= 1u {
        return vec2<f32>(0.5, 0.5);
    }
    let cols = ceil_sqrt(n);
    let rows = (n + cols - 1u) / cols;
    let cx = s % cols;
    let cy = (s / cols) % rows;
    let h = hash3(x, y, s);
    let jx = f32(h & 0xffffu) / 65536.0;
    let jy = f32(h >> 16u) / 65536.0;
    return vec2<f32>((f32(cx) + jx) / f32(cols), (f32(cy) + jy) / f32(rows));
}

/// A ray: origin and unit direction.
struct CameraRay {
    origin: vec3<f32>,
    direction: vec3<f32>,
}

/// The ray through normalised image coordinates (u, v), v downwards (Camera::ray).
fn camera_ray(u: f32, v: f32, aspect: f32) -> CameraRay {
    let sx = (2.0 * u - 1.0) * aspect;
    let sy = 1.0 - 2.0 * v;
    let c = shade_camera;
    if c.projection == PROJECTION_PERSPECTIVE {
        return CameraRay(c.position, unit_vector(c.forward + c.scale * (sx * c.right + sy * c.up)));
    }
    let h = 0.5 * c.scale;
    return CameraRay(c.position + h * (sx * c.right + sy * c.up), unit_vector(c.forward));
}

/// What one camera sample sees (integrator::CameraSample); depth < 0 on a miss.
struct CameraSample {
    radiance: vec3<f32>,
    depth: f32,
    normal: vec3<f32>,
    albedo: vec3<f32>,
    steps: u32,
    gradient: f32,
}

/// One pending ray of the path (integrator::PendingRay). `inside` is 1 for a refracted ray
/// travelling inside the solid `inside_hit` belongs to, with index of refraction `ior`.
struct PendingRay {
    origin: vec3<f32>,
    direction: vec3<f32>,
    weight: vec3<f32>,
    bounces: u32,
    inside: u32,
    inside_hit: SceneHit,
    ior: f32,
}

/// The depth-first stack of pending rays: each step pops one and pushes at most two, so it
/// never holds more than max_bounces + 1 (integrator::trace_camera_ray).
var<private> path_stack: array<PendingRay, RENDER_STACK>;
var<private> path_len: u32;

/// Pushes a ray spawned by `parent` when it is light enough to matter and within the bounce
/// limit (the `spawn` closure of trace_camera_ray). Ray::new normalises the direction.
fn spawn(parent: PendingRay, max_bounces: u32, origin: vec3<f32>, direction: vec3<f32>, weight: vec3<f32>, inside: u32, inside_hit: SceneHit, ior: f32) {
    if parent.bounces < max_bounces && max(max(weight.x, weight.y), weight.z) >= MIN_WEIGHT && path_len < RENDER_STACK {
        path_stack[path_len] = PendingRay(origin, unit_vector(direction), weight, parent.bounces + 1u, inside, inside_hit, ior);
        path_len += 1u;
    }
}

/// Follows the camera ray and everything it spawns (integrator::trace_camera_ray).
fn trace_camera_ray(origin: vec3<f32>, direction: vec3<f32>) -> CameraSample {
    let max_bounces = min(shade_settings.max_bounces, MAX_BOUNCES);
    var no_hit: SceneHit;
    path_stack[0] = PendingRay(origin, direction, vec3<f32>(1.0), 0u, 0u, no_hit, 1.0);
    path_len = 1u;
    var sample = CameraSample(vec3<f32>(0.0), -1.0, vec3<f32>(0.0), vec3<f32>(0.0), 0u, 0.0);
    var primary = true;
    while path_len > 0u {
        path_len -= 1u;
        let item = path_stack[path_len];
        let d = item.direction;
        if item.inside != 0u {
            // Travelling inside a transparent object: find where it leaves.
            let exit = scene_exit(item.inside_hit, item.origin, d, T_FAR);
            if exit.x < 0.0 {
                continue;
            }
            let t = exit.x;
            let n = exit.yzw;
            let p = item.origin + t * d;
            let offset = surface_offset(t, p);
            let cos_i = clamp(dot(d, n), 0.0, 1.0);
            let f = optics_schlick(cos_i, item.ior, 1.0);
            let out = optics_refract(d, -n, item.ior);
            if out.w != 0.0 {
                spawn(item, max_bounces, p + n * offset, out.xyz, item.weight * (1.0 - f), 0u, no_hit, 1.0);
            }
            spawn(item, max_bounces, p - n * offset, optics_reflect(d, -n), item.weight * f, 1u, item.inside_hit, item.ior);
            continue;
        }
        let hit = scene_closest_hit(item.origin, d, 0.0, T_FAR);
        if primary {
            sample.steps = select(0u, hit.steps, hit.kind != HIT_MISS);
        }
        if hit.kind == HIT_MISS {
            sample.radiance += item.weight * shade_settings.background;
            primary = false;
            continue;
        }
        let p = item.origin + hit.t * d;
        var m = scene_material(hit, p);
        if m.opacity < 1.0 {
            // a partly covered surface is thin: no refraction (integrator::surfaced)
            m.transparency = 0.0;
        }
        // Shade the side the ray arrives on (rays can start inside a solid).
        let n = select(hit.normal, -hit.normal, dot(hit.normal, d) > 0.0);
        if primary {
            sample.depth = hit.t;
            sample.normal = n;
            sample.albedo = m.color;
            // SceneHit.gradient is ∇f as measured; the CPU keeps its length |∇f|.
            sample.gradient = length(hit.gradient);
            primary = false;
        }
        if hit.t == 0.0 && hit.kind == HIT_SDF && m.transparency > 0.0 {
            // the ray starts inside a transparent solid: it travels inside it as a refracted
            // ray would (integrator::trace_camera_ray_from)
            spawn(item, max_bounces, item.origin, d, item.weight * m.color, 1u, hit, m.ior);
            continue;
        }
        let cos_i = clamp(-dot(d, n), 0.0, 1.0);
        // integrator::mirror_reflectance: Schlick from R₀ = r (Phong) or r·F(f₀) (PBR), and
        // the share left to local shading (1 − F_r for Phong, all of it for PBR)
        let pbr_weight = clamp(m.pbr, 0.0, 1.0);
        var f_r = vec3<f32>(0.0);
        var local_share = 1.0;
        if m.reflectivity > 0.0 {
            let grazing = pow5(1.0 - cos_i);
            let phong = m.reflectivity + (1.0 - m.reflectivity) * grazing;
            let f0 = brdf_f0(m);
            let pbr = m.reflectivity * (f0 + (1.0 - f0) * grazing);
            f_r = mix(vec3<f32>(phong), pbr, pbr_weight);
            local_share = 1.0 - (1.0 - pbr_weight) * phong;
        }
        var f_t = 0.0;
        if m.transparency > 0.0 {
            f_t = optics_schlick(cos_i, 1.0, m.ior);
        }
        let opaque = 1.0 - m.transparency;
        let coverage = clamp(m.opacity, 0.0, 1.0);
        let local_weight = coverage * opaque * local_share;
        let offset = surface_offset(hit.t, p);
        if m.opacity < 1.0 {
            // the uncovered fraction of a BLEND surface goes on straight through
            spawn(item, max_bounces, p - n * offset, d, item.weight * (1.0 - max(m.opacity, 0.0)), 0u, no_hit, 1.0);
        }
        if local_weight > 0.0 {
            sample.radiance += item.weight * local_weight * shade_local(p, n, -d, hit.t, m);
        }
        let reflect_weight = coverage * (opaque * f_r + m.transparency * f_t);
        if max(reflect_weight.x, max(reflect_weight.y, reflect_weight.z)) > 0.0 {
            spawn(item, max_bounces, p + n * offset, optics_reflect(d, n), item.weight * reflect_weight, 0u, no_hit, 1.0);
        }
        let transmit_weight = coverage * m.transparency * (1.0 - f_t);
        if transmit_weight > 0.0 {
            let t = optics_refract(d, n, 1.0 / m.ior);
            if t.w != 0.0 {
                spawn(item, max_bounces, p - n * offset, t.xyz, item.weight * transmit_weight * m.color, 1u, hit, m.ior);
            }
        }
    }
    return sample;
}

/// One invocation per pixel of the rectangle (x0, y0, w, h) of `render_tile`, one dispatch
/// per sample: the first sample a buffer receives writes the pixel's sums, later ones
/// (`accumulate`) add to them in the order they come (as `PixelSums::add` sums); the host
/// divides by the count. One sample per dispatch also keeps each dispatch short — and a loop
/// over the samples inside one invocation made lavapipe 22.3 render glass.ron's refracting
/// objects wrongly (PSNR 26 dB against the CPU at 4 spp, 53 dB with this form).
@compute @workgroup_size(8, 8, 1)
fn render_tile_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let tile = render_tile;
    if gid.x >= tile.w || gid.y >= tile.h {
        return;
    }
    let x = tile.x0 + gid.x;
    let y = tile.y0 + gid.y;
    let width = f32(tile.width);
    let height = f32(tile.height);
    let offset = sample_offset(x, y, tile.sample, tile.samples);
    let ray = camera_ray((f32(x) + offset.x) / width, (f32(y) + offset.y) / height, width / height);
    let sample = trace_camera_ray(ray.origin, ray.direction);
    let i = (y - tile.sums_y0) * tile.sums_width + (x - tile.sums_x0);
    var sum = RenderPixel(vec3<f32>(0.0), -1.0, vec3<f32>(0.0), 0.0, vec3<f32>(0.0), 0.0, 0u, 0u, 0u, 0u);
    if tile.accumulate != 0u {
        sum = render_pixels[i];
    }
    sum.radiance += sample.radiance;
    sum.normal += sample.normal;
    sum.albedo += sample.albedo;
    sum.steps += f32(sample.steps);
    sum.gradient += sample.gradient;
    // the nearest depth; negative: every sample so far missed (∞ on the CPU side)
    if sample.depth >= 0.0 && (sum.depth < 0.0 || sample.depth < sum.depth) {
        sum.depth = sample.depth;
    }
    // (tile.w < 2³¹: the shift is 0)
    if loops_were_cut(tile.w >> 31u) {
        sum.cut += 1u;
    }
    render_pixels[i] = sum;
}
