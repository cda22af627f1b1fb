// Shading on the GPU: the WGSL mirror of src/shade/mod.rs (Lambert + Phong and glTF's
// metallic-roughness model under point, spot, directional and ambient lights, hard and soft
// shadows, ambient occlusion, the surface offset), src/shade/brdf.rs (the metallic-roughness
// BRDF) and src/shade/optics.rs (reflection, refraction, Schlick's Fresnel approximation).
//
// Needs, from the generated preludes: Material, ShadeLight, ShadeSettings and the LIGHT_*
// constants (src/gpu/shaders.rs, src/gpu/shade.rs); from shaders/sdf.wgsl and scene.wgsl:
// epsilon_at, scene_visibility, scene_distance; from shaders/render.wgsl: the bindings
// `shade_settings` and `shade_lights`.
// Every formula here has its explanation and source beside its Rust twin; keep them in step.

/// The ray parameter standing in for the CPU's f32::INFINITY: every scene query first clamps
/// its tmax to the scene's max_distance, so any value above that behaves the same.
const T_FAR: f32 = 3.0e38;

/// v/|v| computed as glam's `Vec3::normalize` does, v·(1/√(v·v)), rather than with WGSL's
/// normalize (which a driver may compute with an approximate inverse square root): refraction
/// magnifies the last-bit differences between the two.
fn unit_vector(v: vec3<f32>) -> vec3<f32> {
    return v * (1.0 / sqrt(dot(v, v)));
}

/// x^5 by multiplication, as Rust's powi(5) computes it.
fn pow5(x: f32) -> f32 {
    let x2 = x * x;
    return x2 * x2 * x;
}

/// base^e for base ≥ 0 as Rust's powf gives it: WGSL's pow is undefined at base 0 (it is
/// exp2(e·log2 base)), where powf gives 1 for e = 0 and 0 for e > 0.
fn pow_nonnegative(base: f32, e: f32) -> f32 {
    if base <= 0.0 {
        return select(0.0, 1.0, e == 0.0);
    }
    return pow(base, e);
}

/// Mirror reflection of direction d about the unit normal n (optics::reflect).
fn optics_reflect(d: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    return d - 2.0 * dot(d, n) * n;
}

/// Refraction of the unit direction d through a surface with unit normal n facing against d,
/// eta = n₁/n₂ (Snell's law in vector form; optics::refract). w = 0 on total internal
/// reflection, else w = 1.
fn optics_refract(d: vec3<f32>, n: vec3<f32>, eta: f32) -> vec4<f32> {
    let cos_i = -dot(d, n);
    let k = 1.0 - eta * eta * (1.0 - cos_i * cos_i);
    if k < 0.0 {
        return vec4<f32>(0.0);
    }
    return vec4<f32>(eta * d + (eta * cos_i - sqrt(k)) * n, 1.0);
}

/// Schlick's Fresnel reflectance (C. Schlick 1994; optics::schlick): R₀ + (1 − R₀)(1 − cos)⁵,
/// with the transmitted angle's cosine from the denser side and 1 beyond the critical angle.
fn optics_schlick(cos_i: f32, n1: f32, n2: f32) -> f32 {
    let q = (n1 - n2) / (n1 + n2);
    let r0 = q * q;
    var c = cos_i;
    if n1 > n2 {
        let eta = n1 / n2;
        let sin2_t = eta * eta * (1.0 - cos_i * cos_i);
        if sin2_t >= 1.0 {
            return 1.0;
        }
        c = sqrt(1.0 - sin2_t);
    }
    return r0 + (1.0 - r0) * pow5(1.0 - clamp(c, 0.0, 1.0));
}

/// The offset that moves secondary-ray origins off a surface hit at ray distance t at point p
/// (shade::surface_offset): a few ε(t), plus 2⁻¹⁶ of |p|'s largest coordinate.
fn surface_offset(t: f32, p: vec3<f32>) -> f32 {
    let a = abs(p);
    return 4.0 * epsilon_at(t) + max(max(a.x, a.y), a.z) * (1.0 / 65536.0);
}

/// Ambient occlusion from the distance field (shade::ambient_occlusion; Evans 2006).
fn ambient_occlusion(p: vec3<f32>, n: vec3<f32>) -> f32 {
    let step = shade_settings.ao_step;
    let steps = shade_settings.ao_steps;
    let reach = step * f32(steps);
    var occlusion = 0.0;
    var weight = 0.5;
    for (var i = 1u; i <= steps; i += 1u) {
        let h = step * f32(i);
        let d = scene_distance(p + n * h, reach);
        occlusion += weight * max(h - d, 0.0);
        weight *= 0.5;
    }
    return clamp(1.0 - shade_settings.ao_strength * occlusion / step, 0.0, 1.0);
}

/// scene::range_window: KHR_lights_punctual's clamp(1 − (d/range)⁴, 0, 1); range 0 = none.
fn range_window(dist: f32, range: f32) -> f32 {
    if range <= 0.0 {
        return 1.0;
    }
    let q = dist / range;
    let q2 = q * q;
    return clamp(1.0 - q2 * q2, 0.0, 1.0);
}

/// scene::spot_falloff: the specification's smooth cone falloff, squared.
fn spot_falloff(cos_axis: f32, cos_inner: f32, cos_outer: f32) -> f32 {
    let scale = 1.0 / max(cos_inner - cos_outer, 1e-3);
    let s = clamp((cos_axis - cos_outer) * scale, 0.0, 1.0);
    return s * s;
}

/// brdf::MetallicRoughness::f0: mix(0.04, base, metallic).
fn brdf_f0(m: Material) -> vec3<f32> {
    return mix(vec3<f32>(0.04), m.color, m.metallic);
}

/// brdf::MetallicRoughness::ambient_albedo: (1 − f₀)·c_diff + f₀.
fn brdf_ambient_albedo(m: Material) -> vec3<f32> {
    let f0 = brdf_f0(m);
    return (vec3<f32>(1.0) - f0) * (m.color * (1.0 - m.metallic)) + f0;
}

/// brdf::MetallicRoughness::reflected: π·f(l, v)·(n·l) of glTF's metallic-roughness BRDF
/// (GGX distribution, Smith's separable visibility, Schlick's Fresnel).
fn brdf_reflected(m: Material, n: vec3<f32>, v: vec3<f32>, l: vec3<f32>) -> vec3<f32> {
    let PI = 3.14159265358979323846;
    let n_l = dot(n, l);
    let n_v = dot(n, v);
    if n_l <= 0.0 || n_v <= 0.0 {
        return vec3<f32>(0.0);
    }
    let hv = l + v;
    let hl = dot(hv, hv);
    var h = vec3<f32>(0.0);
    if hl > 0.0 {
        h = hv * (1.0 / sqrt(hl));
    }
    let n_h = max(dot(n, h), 0.0);
    let v_h = abs(dot(v, h));
    let alpha = max(m.roughness * m.roughness, 1e-3);
    let a2 = alpha * alpha;
    let d_denominator = n_h * n_h * (a2 - 1.0) + 1.0;
    let distribution = a2 / (PI * d_denominator * d_denominator);
    let smith_l = n_l + sqrt(a2 + (1.0 - a2) * n_l * n_l);
    let smith_v = n_v + sqrt(a2 + (1.0 - a2) * n_v * n_v);
    let visibility = 1.0 / (smith_l * smith_v);
    let f0 = brdf_f0(m);
    let fresnel = f0 + (vec3<f32>(1.0) - f0) * pow5(1.0 - v_h);
    let diffuse = (vec3<f32>(1.0) - fresnel) * (m.color * (1.0 - m.metallic)) / PI;
    let specular = fresnel * (distribution * visibility);
    return PI * (diffuse + specular) * n_l;
}

/// Local (direct) radiance leaving p toward the eye (shade::shade): p on a surface found at
/// ray distance t, with unit normal n facing the viewer and unit direction to_eye.
fn shade_local(p: vec3<f32>, n: vec3<f32>, to_eye: vec3<f32>, t: f32, m: Material) -> vec3<f32> {
    let offset = surface_offset(t, p);
    let origin = p + n * offset;
    let pbr = clamp(m.pbr, 0.0, 1.0);
    // shade_with: the PBR ambient less the traced reflection's share r·f₀
    let pbr_ambient = brdf_ambient_albedo(m) - clamp(m.reflectivity, 0.0, 1.0) * brdf_f0(m);
    let ambient_reflectance = mix(m.color * m.diffuse, pbr_ambient, pbr) * m.occlusion;
    var out = m.emissive;
    for (var i = 0u; i < shade_settings.light_count; i += 1u) {
        let light = shade_lights[i];
        var l: vec3<f32>;
        var dist: f32;
        var irradiance: vec3<f32>;
        if light.kind == LIGHT_AMBIENT {
            var ao = 1.0;
            if shade_settings.ao_steps > 0u {
                ao = ambient_occlusion(p, n);
            }
            out += ambient_reflectance * light.radiance * ao;
            continue;
        } else if light.kind == LIGHT_POINT || light.kind == LIGHT_SPOT {
            let to_light = light.vector - p;
            dist = sqrt(dot(to_light, to_light));
            if dist <= 0.0 {
                continue;
            }
            l = to_light / dist;
            var falloff = range_window(dist, light.range);
            if light.kind == LIGHT_SPOT {
                falloff = spot_falloff(-dot(l, light.axis), light.cos_inner, light.cos_outer) * falloff;
            }
            if falloff <= 0.0 {
                continue;
            }
            irradiance = light.radiance * (falloff / (dist * dist));
        } else {
            // directional: `vector` is the direction the light travels
            l = -light.vector;
            dist = T_FAR;
            irradiance = light.radiance;
        }
        let ndl = dot(n, l);
        if ndl <= 0.0 {
            continue;
        }
        var visibility = 1.0;
        if shade_settings.shadows != 0u {
            visibility = scene_visibility(origin, unit_vector(l), 0.0, dist - offset, light.shadow, light.shadow_k);
        }
        if visibility <= 0.0 {
            continue;
        }
        var reflected = vec3<f32>(0.0);
        if pbr < 1.0 {
            let diffuse = m.color * m.diffuse * ndl;
            let r = (2.0 * ndl) * n - l;
            let spec = m.specular * pow_nonnegative(max(dot(r, to_eye), 0.0), m.shininess);
            reflected += (1.0 - pbr) * (diffuse + spec);
        }
        if pbr > 0.0 {
            reflected += pbr * brdf_reflected(m, n, to_eye, l);
        }
        out += visibility * irradiance * reflected;
    }
    return out;
}
