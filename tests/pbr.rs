//! glTF's metallic-roughness model and punctual lights, rendered, against the specification's
//! formulas evaluated here on their own (f64, written from the glTF 2.0 specification's
//! Appendix B and the KHR_lights_punctual text, not from the renderer's code): a sphere under
//! one directional light pixel by pixel, a spot light's cone on a plane (from a scene file and
//! from a glTF file), and the MetalRoughSpheres model's highlights. Each check runs on the CPU
//! and, with the `gpu` feature, on the GPU (Mesa's lavapipe where there is no GPU).

mod common;

use glam::{DVec3, Vec3};
use hytrace::render::{Framebuffer, RenderOptions, cpu};
use hytrace::scene::{Light, Scene};
use std::f64::consts::PI;
use std::path::Path;

/// The backends a check runs on, with their renders of `scene`.
fn renders(scene: &Scene, opts: &RenderOptions) -> Vec<(&'static str, Framebuffer)> {
    let mut out = vec![("cpu", cpu::render(scene, opts).unwrap())];
    #[cfg(feature = "gpu")]
    {
        let ctx = common::gpu::ctx();
        let renderer = hytrace::gpu::render::GpuRenderer::new(ctx);
        out.push(("gpu", renderer.render(ctx, scene, opts).unwrap()));
    }
    out
}

/// The metallic-roughness BRDF f(l, v) times π (the renderer's light scale: a white Lambert
/// surface under irradiance E shows E), from the specification's Appendix B: c_diff =
/// mix(base, 0, metallic), f₀ = mix(0.04, base, metallic), F = f₀ + (1 − f₀)(1 − |v·h|)⁵,
/// D the Trowbridge-Reitz distribution, V = G/(4|n·l||n·v|) with Smith's separable G.
fn spec_brdf_times_pi(
    base: DVec3,
    metallic: f64,
    roughness: f64,
    n: DVec3,
    l: DVec3,
    v: DVec3,
) -> DVec3 {
    let alpha = roughness * roughness;
    let a2 = alpha * alpha;
    let h = (l + v).normalize();
    let (nl, nv, nh, vh) = (n.dot(l), n.dot(v), n.dot(h), v.dot(h).abs());
    let d = a2 / (PI * ((nh * nh) * (a2 - 1.0) + 1.0).powi(2));
    let g1 = |c: f64| 2.0 * c / (c + (a2 + (1.0 - a2) * c * c).sqrt());
    let vis = g1(nl) * g1(nv) / (4.0 * nl * nv);
    let f0 = DVec3::splat(0.04).lerp(base, metallic);
    let f = f0 + (DVec3::ONE - f0) * (1.0 - vh).powi(5);
    let c_diff = base * (1.0 - metallic);
    PI * ((DVec3::ONE - f) * c_diff / PI + f * d * vis)
}

/// KHR_lights_punctual's spot falloff: smoothstep-like ramp between the cone cosines, squared.
fn spec_spot_falloff(cos_axis: f64, inner: f64, outer: f64) -> f64 {
    let scale = 1.0 / (inner.cos() - outer.cos()).max(0.001);
    let offset = -outer.cos() * scale;
    let s = (cos_axis * scale + offset).clamp(0.0, 1.0);
    s * s
}

fn scene_from(source: &str) -> Scene {
    Scene::from_source(source, Path::new("pbr-test.ron")).unwrap_or_else(|e| panic!("{e}"))
}

fn options(scene: &Scene) -> RenderOptions {
    RenderOptions {
        width: scene.image.width,
        height: scene.image.height,
        samples: 1,
        threads: None,
        progress: false,
    }
}

/// The camera ray through the centre of pixel (x, y), as the renderer casts it with one sample.
fn pixel_ray(scene: &Scene, x: u32, y: u32) -> (DVec3, DVec3) {
    let (w, h) = (scene.image.width as f32, scene.image.height as f32);
    let ray = scene
        .camera
        .ray((x as f32 + 0.5) / w, (y as f32 + 0.5) / h, w / h);
    (ray.origin.as_dvec3(), ray.direction.as_dvec3().normalize())
}

#[test]
fn a_metallic_roughness_sphere_shows_the_specifications_brdf() {
    // Metallic 0.4 and roughness 0.35 give both a diffuse part and a clear highlight; no
    // ambient light, no mirror reflection, no shadow ray: each pixel is π·f·E·(n·l) alone.
    let scene = scene_from(
        "Scene(
            image: (width: 96, height: 96, background: (0, 0, 0)),
            camera: Orthographic(position: (0, 0, 5), look_at: (0, 0, 0), height: 2.4),
            lights: [Directional(direction: (-0.5, -0.6, -1.0), color: (1, 0.9, 0.8),
                                 intensity: 1.3, shadow: None),
                     // from behind on the right: grazing, where Fresnel's (1 − v·h)⁵ shows
                     Directional(direction: (-0.8, -0.1, 0.6), intensity: 2.0, shadow: None)],
            materials: { \"m\": Pbr(base_color: (0.9, 0.5, 0.2), metallic: 0.4,
                                  roughness: 0.35, reflectivity: 0) },
            objects: [(shape: Sphere(radius: 1.0), material: \"m\")],
            shading: (max_bounces: 0),
        )",
    );
    let base = DVec3::new(0.9, 0.5, 0.2);
    let lights = [
        (
            -DVec3::new(-0.5, -0.6, -1.0).normalize(),
            DVec3::new(1.0, 0.9, 0.8) * 1.3,
        ),
        (-DVec3::new(-0.8, -0.1, 0.6).normalize(), DVec3::splat(2.0)),
    ];
    for (backend, fb) in renders(&scene, &options(&scene)) {
        let (mut checked, mut worst) = (0, (0.0f64, String::new()));
        let mut brightest = 0.0f64;
        for y in 0..fb.height {
            for x in 0..fb.width {
                let (o, d) = pixel_ray(&scene, x, y);
                // the unit sphere: |o + t d|² = 1
                let b = o.dot(d);
                let disc = b * b - (o.length_squared() - 1.0);
                let got = fb.get(x, y).as_dvec3();
                if disc < 0.0 {
                    assert_eq!(got, DVec3::ZERO, "{backend}: pixel ({x}, {y}) misses");
                    continue;
                }
                let n = o + d * (-b - disc.sqrt());
                let v = -d;
                // away from the silhouette and the terminators, where a pixel's hit and
                // normal are only as exact as the tracer's ε
                if n.dot(v) < 0.25 || lights.iter().any(|(l, _)| n.dot(*l).abs() < 0.05) {
                    continue;
                }
                let expected: DVec3 = lights
                    .iter()
                    .filter(|(l, _)| n.dot(*l) > 0.0)
                    .map(|&(l, e)| spec_brdf_times_pi(base, 0.4, 0.35, n, l, v) * e * n.dot(l))
                    .sum();
                brightest = brightest.max(expected.max_element());
                let error =
                    ((got - expected).abs() / (expected + DVec3::splat(1e-3))).max_element();
                if error > worst.0 {
                    worst = (error, format!("pixel ({x}, {y}): {got} vs {expected}"));
                }
                checked += 1;
            }
        }
        assert!(checked > 3000, "{backend}: only {checked} pixels checked");
        // the highlight is in the picture (the peak is several times the diffuse part)
        assert!(
            brightest > 2.0,
            "{backend}: brightest expected pixel {brightest}"
        );
        assert!(
            worst.0 < 0.01,
            "{backend}: relative error {:.4} at {}",
            worst.0,
            worst.1
        );
        println!(
            "{backend}: {checked} pixels within {:.5} of the specification",
            worst.0
        );
    }
}

/// The irradiance a white Lambert plane y = 0 gets from a spot light at (0, h, 0) pointing
/// down, at horizontal distance r from its foot.
fn spot_on_plane(intensity: f64, h: f64, r: f64, inner: f64, outer: f64) -> f64 {
    let d2 = r * r + h * h;
    let cos = h / d2.sqrt();
    intensity * spec_spot_falloff(cos, inner, outer) / d2 * cos
}

#[test]
fn a_spot_lights_cone_edge_sits_where_its_angles_say() {
    let (h, intensity, inner, outer) = (2.0f64, 4.0f64, 25.0f64, 40.0f64);
    let scene = scene_from(&format!(
        "Scene(
            image: (width: 120, height: 120, background: (0, 0, 0)),
            camera: Orthographic(position: (0, 10, 0), look_at: (0, 0, 0), up: (0, 0, -1),
                                 height: 6),
            lights: [Spot(position: (0, {h}, 0), direction: (0, -1, 0), intensity: {intensity},
                          inner_angle: {inner}, outer_angle: {outer}, shadow: None)],
            materials: {{ \"white\": (color: (1, 1, 1)) }},
            objects: [(shape: Plane(normal: (0, 1, 0), offset: 0), material: \"white\")],
        )"
    ));
    let (inner, outer) = (inner.to_radians(), outer.to_radians());
    let edge = h * outer.tan();
    for (backend, fb) in renders(&scene, &options(&scene)) {
        let mut outermost_lit = 0.0f64;
        for y in 0..fb.height {
            for x in 0..fb.width {
                let (o, d) = pixel_ray(&scene, x, y);
                let p = o + d * (-o.y / d.y);
                let r = (p.x * p.x + p.z * p.z).sqrt();
                let expected = spot_on_plane(intensity, h, r, inner, outer);
                let got = fb.get(x, y).x as f64;
                assert!(
                    (got - expected).abs() <= 1e-4 + 1e-3 * expected,
                    "{backend}: at r = {r:.4}: {got} vs {expected}"
                );
                if got > 0.0 {
                    outermost_lit = outermost_lit.max(r);
                }
            }
        }
        // lit up to the outer cone's edge, dark beyond it (one pixel is 0.05 wide)
        assert!(
            outermost_lit <= edge && outermost_lit > edge - 0.08,
            "{backend}: the light reaches r = {outermost_lit}, the cone's edge is {edge}"
        );
    }
}

/// A glTF file (JSON with an embedded buffer) holding a 6 × 6 quad at y = 0, facing up, with a
/// white rough dielectric material, and a spot light at (0, h, 0) pointing down.
fn spot_gltf(dir: &Path, h: f32, candela: f32, inner: f32, outer: f32) -> std::path::PathBuf {
    use base64::Engine;
    let positions: [[f32; 3]; 4] = [[-3., 0., -3.], [3., 0., -3.], [3., 0., 3.], [-3., 0., 3.]];
    let normals = [[0f32, 1., 0.]; 4];
    let indices: [u16; 6] = [0, 2, 1, 0, 3, 2];
    let mut bytes: Vec<u8> = Vec::new();
    for p in positions.iter().chain(normals.iter()) {
        for c in p {
            bytes.extend_from_slice(&c.to_le_bytes());
        }
    }
    for i in indices {
        bytes.extend_from_slice(&i.to_le_bytes());
    }
    let data = base64::engine::general_purpose::STANDARD.encode(&bytes);
    // the light node looks along its −Z: rotate −Z onto −Y (a quarter turn about +X)
    let s = std::f32::consts::FRAC_1_SQRT_2;
    let json = format!(
        r#"{{
  "asset": {{"version": "2.0"}},
  "extensionsUsed": ["KHR_lights_punctual"],
  "extensions": {{"KHR_lights_punctual": {{"lights": [
    {{"type": "spot", "intensity": {candela}, "color": [1, 1, 1],
      "spot": {{"innerConeAngle": {inner}, "outerConeAngle": {outer}}}}}]}}}},
  "scene": 0,
  "scenes": [{{"nodes": [0, 1]}}],
  "nodes": [
    {{"mesh": 0}},
    {{"translation": [0, {h}, 0], "rotation": [{neg_s}, 0, 0, {s}],
      "extensions": {{"KHR_lights_punctual": {{"light": 0}}}}}}
  ],
  "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0, "NORMAL": 1}}, "indices": 2,
                                "material": 0}}]}}],
  "materials": [{{"pbrMetallicRoughness": {{"baseColorFactor": [1, 1, 1, 1],
                                            "metallicFactor": 0, "roughnessFactor": 1}}}}],
  "buffers": [{{"byteLength": {len}, "uri": "data:application/octet-stream;base64,{data}"}}],
  "bufferViews": [
    {{"buffer": 0, "byteOffset": 0, "byteLength": 48}},
    {{"buffer": 0, "byteOffset": 48, "byteLength": 48}},
    {{"buffer": 0, "byteOffset": 96, "byteLength": 12}}
  ],
  "accessors": [
    {{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
      "min": [-3, 0, -3], "max": [3, 0, 3]}},
    {{"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"}},
    {{"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}}
  ]
}}"#,
        neg_s = -s,
        len = bytes.len()
    );
    let path = dir.join("spot.gltf");
    std::fs::write(&path, json).unwrap();
    path
}

#[test]
fn a_gltf_spot_light_shines_its_cone_in_candela() {
    let dir = common::temp_dir("gltf-spot");
    let (h, candela, inner, outer) = (2.0f32, 30.0f32, 0.3f32, 0.6f32);
    let path = spot_gltf(dir.path(), h, candela, inner, outer);
    let mut scene = Scene::from_model(&path, None).unwrap_or_else(|e| panic!("{e}"));
    assert!(
        matches!(scene.lights.as_slice(), [Light::Spot { .. }]),
        "{:?}",
        scene.lights
    );
    // seen from above (the file has no camera)
    scene.camera = hytrace::scene::camera::Camera::look_at(
        Vec3::new(0.0, 10.0, 0.0),
        Vec3::ZERO,
        -Vec3::Z,
        hytrace::scene::camera::Projection::Orthographic { height: 6.5 },
    )
    .unwrap();
    scene.image.width = 96;
    scene.image.height = 72;
    scene.image.background = Vec3::ZERO;
    scene.shading.max_bounces = 0;
    let base = DVec3::ONE;
    let light = DVec3::new(0.0, h as f64, 0.0);
    for (backend, fb) in renders(&scene, &options(&scene)) {
        let (mut lit, mut dark) = (0, 0);
        for y in 0..fb.height {
            for x in 0..fb.width {
                let (o, d) = pixel_ray(&scene, x, y);
                let t = -o.y / d.y;
                let p = o + d * t;
                if !(t > 0.0 && p.x.abs() < 2.95 && p.z.abs() < 2.95) {
                    continue;
                }
                let to_light = light - p;
                let dist = to_light.length();
                let l = to_light / dist;
                // candela at distance d: candela/d² lux, the renderer's unit of irradiance
                let e = candela as f64 * spec_spot_falloff(l.y, inner as f64, outer as f64)
                    / (dist * dist);
                let expected = spec_brdf_times_pi(base, 0.0, 1.0, DVec3::Y, l, -d) * e * l.y;
                let got = fb.get(x, y).as_dvec3();
                assert!(
                    (got - expected).abs().max_element() <= 1e-4 + 2e-3 * expected.max_element(),
                    "{backend}: pixel ({x}, {y}) at {p}: {got} vs {expected}"
                );
                if expected.x > 0.0 {
                    lit += 1;
                } else {
                    dark += 1;
                }
            }
        }
        assert!(lit > 500 && dark > 500, "{backend}: {lit} lit, {dark} dark");
    }
}

/// The spheres of MetalRoughSpheresNoTextures: node `m{M}%_r{R}%` (gray) or `g_m{M}%_r{R}%`
/// (golden) sits at x = 0.001·i (roughness step i), y = 0.001·j (metallic step j), z = 0 or
/// −0.003, with radius 0.00035.
fn sphere_centre(roughness_step: u32, metallic_step: u32, golden: bool) -> Vec3 {
    Vec3::new(
        0.001 * roughness_step as f32,
        0.001 * metallic_step as f32,
        if golden { -0.003 } else { 0.0 },
    )
}

#[test]
fn metal_rough_spheres_widen_their_highlights_with_roughness_and_metals_tint_them() {
    let Some(assets) = common::assets_or_skip("the MetalRoughSpheres test") else {
        return;
    };
    let path =
        assets.join("glTF/MetalRoughSpheresNoTextures/glTF/MetalRoughSpheresNoTextures.gltf");
    let mut scene = Scene::from_model(&path, None).unwrap_or_else(|e| panic!("{e}"));
    // Looking along z at one row of seven spheres at a time (down −z at the gray ones in
    // front, up +z at the golden ones behind them), lit from the camera: each sphere's
    // highlight sits at its centre, and its spread is the BRDF lobe's.
    scene.image.exposure = 0.0;
    scene.image.background = Vec3::ZERO;
    scene.shading.max_bounces = 0;
    let (w, h) = (448u32, 64u32);
    scene.image.width = w;
    scene.image.height = h;
    let row = |metallic_step: u32, golden: bool| -> Vec<(f64, Vec3)> {
        let mut scene = scene.clone();
        let centre = (sphere_centre(0, metallic_step, golden)
            + sphere_centre(6, metallic_step, golden))
            * 0.5;
        let toward = if golden { Vec3::Z } else { -Vec3::Z };
        scene.lights = vec![Light::Directional {
            direction: toward,
            radiance: Vec3::ONE,
            shadow: hytrace::scene::Shadow::None,
        }];
        scene.camera = hytrace::scene::camera::Camera::look_at(
            centre - toward * 0.01,
            centre,
            Vec3::Y,
            hytrace::scene::camera::Projection::Orthographic { height: 0.001 },
        )
        .unwrap();
        let fb = cpu::render(&scene, &options(&scene)).unwrap();
        // per sphere: the radiance-weighted mean squared distance from the centre (the
        // highlight's spread), and the peak pixel's colour
        (0..7)
            .map(|i| {
                let c = sphere_centre(i, metallic_step, golden);
                let (mut sum, mut weighted, mut peak) = (0.0f64, 0.0f64, Vec3::ZERO);
                for y in 0..h {
                    for x in 0..w {
                        let (o, _) = pixel_ray(&scene, x, y);
                        let r2 = ((o.x - c.x as f64).powi(2) + (o.y - c.y as f64).powi(2))
                            / (0.00035f64 * 0.00035);
                        if r2 > 0.81 {
                            continue;
                        }
                        let v = fb.get(x, y);
                        let s = v.element_sum() as f64;
                        sum += s;
                        weighted += s * r2;
                        if v.element_sum() > peak.element_sum() {
                            peak = v;
                        }
                    }
                }
                (weighted / sum.max(1e-30), peak)
            })
            .collect()
    };
    // metals (j = 6): pure specular, so the spread grows with roughness, step by step
    let metals = row(6, false);
    let spreads: Vec<f64> = metals.iter().map(|m| m.0).collect();
    for i in 2..7 {
        assert!(
            spreads[i] > spreads[i - 1] * 1.05,
            "the highlight does not widen from roughness step {} to {i}: {spreads:?}",
            i - 1
        );
    }
    // golden spheres: a metal's highlight has the base colour (0.60, 0.44, 0.012), a
    // dielectric's is white over the base colour's diffuse part
    let golden_metal = row(6, true)[1].1;
    let golden_dielectric = row(0, true)[1].1;
    let ratio = |v: Vec3| (v.y / v.x, v.z / v.x);
    let (g, b) = ratio(golden_metal);
    assert!(
        (g - 0.728).abs() < 0.05 && b < 0.05,
        "golden metal's highlight {golden_metal}"
    );
    let (g, b) = ratio(golden_dielectric);
    assert!(
        g > 0.9 && b > 0.8,
        "golden dielectric's highlight {golden_dielectric}"
    );
}
