//! glTF materials against real assets: KHR_texture_transform on Khronos' test model, normal
//! mapping and MikkTSpace tangents on Avocado, metallic-roughness and emissive textures, and
//! alpha masks for camera and shadow rays on the CPU and in the Embree referee.

mod common;

use glam::{Vec3, Vec4};
use hytrace::geom::Ray;
use hytrace::scene::Scene;
use hytrace::scene::material::MaterialParams;
use hytrace::scene::mesh::{self, AlphaMode};
use hytrace::trace::{Hit, SceneTracer, Surface};
use std::path::{Path, PathBuf};

/// The material at a mesh hit, with the textures applied.
fn material(scene: &Scene, hit: &Hit) -> MaterialParams {
    match hit.surface {
        Surface::Mesh {
            material, sample, ..
        } => sample.apply(scene.materials[material as usize]),
        Surface::Sdf(_) => panic!("expected a mesh hit"),
    }
}

fn down(x: f32, y: f32) -> Ray {
    Ray {
        origin: Vec3::new(x, y, 5.0),
        direction: Vec3::NEG_Z,
    }
}

const TRANSFORM_TEST: &str =
    "/usr/share/assimp/models/glTF2/textureTransform/TextureTransformTest.gltf";

/// The colour seen looking down −z at (x, y) on the texture-transform model.
fn colour_at(scene: &Scene, tracer: &SceneTracer, x: f32, y: f32) -> Vec3 {
    let hit = tracer
        .closest_hit(&down(x, y), 0.0, 100.0)
        .unwrap_or_else(|| panic!("no hit at ({x}, {y})"));
    material(scene, &hit).color
}

#[test]
fn texture_transform_shows_what_the_test_model_calls_correct() {
    let path = Path::new(TRANSFORM_TEST);
    if !path.exists() {
        eprintln!("!!! {TRANSFORM_TEST} missing (scripts/setup.sh installs it): NOT RUN !!!");
        return;
    }
    let scene = Scene::from_model(path, None).unwrap_or_else(|e| panic!("{e}"));
    let tracer = SceneTracer::new(&scene);
    // The top row: quads of uv (0, 0)–(0.5, 0.5) over [−0.5, 0.5]², so a point near a quad's
    // top-left corner samples UV.png at offset + (0.05, 0.05): yellow (no offset), green
    // (offset u), blue (offset v) or cyan (both), as the model's README says.
    let corner = |cx: f32, cy: f32| colour_at(&scene, &tracer, cx - 0.4, cy + 0.4);
    let u = corner(-1.1, 0.55);
    assert!(
        u.y > 3.0 * u.x && u.y > 3.0 * u.z,
        "offset U: {u} is not green"
    );
    let v = corner(0.0, 0.55);
    assert!(
        v.z > 3.0 * v.x && v.z > 3.0 * v.y,
        "offset V: {v} is not blue"
    );
    let uv = corner(1.1, 0.55);
    assert!(
        uv.y > 3.0 * uv.x && uv.z > 3.0 * uv.x,
        "offset UV: {uv} is not cyan"
    );
    // Rotation (bottom left, centre (−1.1, −0.55), uv (0, 0)–(1, 1) with v down): the arrow
    // of Arrow.png runs along the image's diagonal from its top-left corner. Rotated by
    // 22.5°, it must point at the model's "Correct" marker, 22.5° below the diagonal as seen
    // from the uv origin (the quad's top-left corner): the point at radius 0.566 there shows
    // the arrow's black shaft, while the same radius 22.5° above the diagonal (towards the
    // "Error" marker, the rotation applied the wrong way) and on the diagonal itself (not
    // applied) do not.
    let at = |angle_deg: f32| {
        let a = angle_deg.to_radians();
        let (du, dv) = (0.566 * a.cos(), 0.566 * a.sin());
        colour_at(&scene, &tracer, -1.1 - 0.5 + du, -0.55 + 0.5 - dv)
    };
    let luma = |c: Vec3| c.dot(Vec3::new(0.2126, 0.7152, 0.0722));
    assert!(luma(at(67.5)) < 0.05, "correct side: {}", at(67.5));
    assert!(luma(at(22.5)) > 0.5, "wrong-way side: {}", at(22.5));
    // Scale (bottom middle): ×1.5 about the uv origin; the unscaled arrow's tip region at
    // image (0.62, 0.62) appears at uv (0.62/1.5, 0.62/1.5)
    let c = colour_at(&scene, &tracer, -0.5 + 0.62 / 1.5, -0.55 + 0.5 - 0.62 / 1.5);
    assert!(luma(c) < 0.05, "scale: {c}");
}

fn avocado() -> Option<PathBuf> {
    let assets = common::assets_or_skip("glTF material tests on Avocado")?;
    Some(assets.join("glTF/Avocado/glTF/Avocado.gltf"))
}

/// A copy of a `.gltf` file in `dir`, edited by `edit`, whose buffers and images still point
/// at the original's (by absolute path).
fn edited_copy(original: &Path, dir: &Path, edit: impl FnOnce(&mut serde_json::Value)) -> PathBuf {
    let mut json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(original).unwrap()).unwrap();
    let base = original.parent().unwrap().canonicalize().unwrap();
    for key in ["buffers", "images"] {
        for item in json[key].as_array_mut().into_iter().flatten() {
            if let Some(uri) = item["uri"].as_str() {
                item["uri"] = base.join(uri).to_string_lossy().into_owned().into();
            }
        }
    }
    edit(&mut json);
    let out = dir.join("edited.gltf");
    std::fs::write(&out, serde_json::to_vec(&json).unwrap()).unwrap();
    out
}

#[test]
fn mikktspace_tangents_match_avocados_own() {
    let Some(path) = avocado() else { return };
    let with = mesh::load(&path).unwrap();
    let dir = common::temp_dir("avocado-tangents");
    let copy = edited_copy(&path, dir.path(), |j| {
        let attrs = j["meshes"][0]["primitives"][0]["attributes"]
            .as_object_mut()
            .unwrap();
        attrs.remove("TANGENT");
    });
    let without = mesh::load(&copy).unwrap();
    let (a, b) = (&with.meshes[0], &without.meshes[0]);
    assert_eq!(a.triangles.len(), b.triangles.len());
    assert!(!a.tangents.is_empty() && !b.tangents.is_empty());
    let (mut close, mut same_sign, mut corners) = (0usize, 0usize, 0usize);
    for (ta, tb) in a.triangles.iter().zip(&b.triangles) {
        for k in 0..3 {
            let (x, y) = (a.tangents[ta[k] as usize], b.tangents[tb[k] as usize]);
            corners += 1;
            // within 10°
            if x.truncate().dot(y.truncate()) > 10f32.to_radians().cos() {
                close += 1;
            }
            if x.w == y.w {
                same_sign += 1;
            }
        }
    }
    let (close, same_sign) = (
        close as f64 / corners as f64,
        same_sign as f64 / corners as f64,
    );
    eprintln!("Avocado: {close:.4} of corners within 10°, {same_sign:.4} with the same sign");
    assert!(close > 0.95, "{close}");
    assert!(same_sign > 0.99, "{same_sign}");
}

#[test]
fn the_normal_map_tilts_the_shading_normal_as_far_as_its_texels_say() {
    let Some(path) = avocado() else { return };
    let scene = Scene::from_model(&path, None).unwrap_or_else(|e| panic!("{e}"));
    let meshes = &scene.meshes;
    let mut flat = meshes.clone();
    for m in &mut flat.materials {
        m.textures.normal = None;
    }
    let mat = &meshes.materials[1];
    let (normal_ref, scale) = mat.textures.normal.expect("Avocado has a normal texture");
    assert_eq!(scale, 1.0);
    let texture = &meshes.textures[normal_ref.texture];
    assert!(!texture.srgb, "normal maps are linear");
    let m = &meshes.meshes[0];
    let (mut tilted, mut checked) = (0, 0);
    for tri in (0..m.triangles.len()).step_by(5) {
        let (u, v) = (0.3, 0.3);
        let mapped = meshes.surface(0, tri, u, v).normal;
        let plain = flat.surface(0, tri, u, v).normal;
        let [a, b, c] = m.triangles[tri].map(|i| m.uvs[i as usize]);
        let uv = a * 0.4 + b * 0.3 + c * 0.3;
        let d = (2.0 * texture.sample(uv).truncate() - Vec3::ONE).normalize();
        // the tilt from the interpolated normal is the texel's angle from +z (an orthonormal
        // frame turns one into the other); tangents not quite orthogonal to the normal and
        // the uniform scale of the instance change it a little
        let want = d.z.clamp(-1.0, 1.0).acos().to_degrees();
        let got = mapped.dot(plain).clamp(-1.0, 1.0).acos().to_degrees();
        assert!(
            (want - got).abs() < 4.0,
            "triangle {tri}: the texel says {want}°, the normal tilts {got}°"
        );
        checked += 1;
        if got > 5.0 {
            tilted += 1;
        }
    }
    assert!(
        checked > 100 && tilted > checked / 10,
        "{tilted} of {checked}"
    );
}

#[test]
fn metallic_roughness_and_emissive_textures_reach_the_material() {
    let Some(assets) = common::assets_or_skip("glTF emissive and metallic-roughness") else {
        return;
    };
    // Avocado: metallic-roughness texture, G → roughness, B → metalness, linear
    let scene = Scene::from_model(&assets.join("glTF/Avocado/glTF/Avocado.gltf"), None)
        .unwrap_or_else(|e| panic!("{e}"));
    let meshes = &scene.meshes;
    let mat = &meshes.materials[1];
    let mr = mat
        .textures
        .metallic_roughness
        .expect("Avocado's MR texture");
    assert!(!meshes.textures[mr.texture].srgb);
    assert!(meshes.textures[mat.textures.base_color.unwrap().texture].srgb);
    let m = &meshes.meshes[0];
    let mut varied = 0;
    for tri in (0..m.triangles.len()).step_by(31) {
        let s = meshes.surface(0, tri, 0.2, 0.5);
        let [a, b, c] = m.triangles[tri].map(|i| m.uvs[i as usize]);
        let texel = meshes.textures[mr.texture].sample(a * 0.3 + b * 0.2 + c * 0.5);
        let params = s.sample.apply(scene.materials[s.material as usize]);
        let factor = &mat.params;
        assert!((params.roughness - factor.roughness * texel.y).abs() < 1e-5);
        assert!((params.metallic - factor.metallic * texel.z).abs() < 1e-5);
        if (texel.y - 1.0).abs() > 0.05 {
            varied += 1;
        }
    }
    assert!(varied > 0, "the roughness texture varies over the avocado");

    // DepthOfFieldExample: emissive textures and KHR_materials_emissive_strength
    let path = assets.join("glTF/bevy-lights/DepthOfFieldExample.glb");
    let asset = mesh::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let json = gltf_json_of(&path);
    let mut strong = 0;
    for (i, m) in json["materials"].as_array().unwrap().iter().enumerate() {
        let ours = &asset.materials[i + 1];
        let factor = m["emissiveFactor"].as_array().map_or(Vec3::ZERO, |f| {
            Vec3::new(
                f[0].as_f64().unwrap() as f32,
                f[1].as_f64().unwrap() as f32,
                f[2].as_f64().unwrap() as f32,
            )
        });
        let strength = m["extensions"]["KHR_materials_emissive_strength"]["emissiveStrength"]
            .as_f64()
            .unwrap_or(1.0) as f32;
        let want = factor * strength;
        assert!(
            (ours.params.emissive - want).length() <= 1e-4 * want.length().max(1.0),
            "materials[{i}]: {} != {want}",
            ours.params.emissive
        );
        if strength > 1.0 && factor.max_element() > 0.0 {
            strong += 1;
        }
        if m.get("emissiveTexture").is_some() {
            let t = ours.textures.emissive.expect("emissive texture loaded");
            assert!(asset.textures[t.texture].srgb, "emissive textures are sRGB");
        }
    }
    assert!(strong > 0, "the model has emissive strengths above 1");
}

/// The JSON chunk of a `.glb`.
fn gltf_json_of(path: &Path) -> serde_json::Value {
    let bytes = std::fs::read(path).unwrap();
    let len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    serde_json::from_slice(&bytes[20..20 + len]).unwrap()
}

/// A 2 × 1 RGBA PNG: the left texel transparent red, the right opaque green.
fn two_texel_png() -> Vec<u8> {
    let mut img = image::RgbaImage::new(2, 1);
    img.put_pixel(0, 0, image::Rgba([255, 0, 0, 0]));
    img.put_pixel(1, 0, image::Rgba([0, 255, 0, 255]));
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    png
}

/// Writes a glTF of two quads over [−1, 1]²: at z = 0 one whose material is `mode` with the
/// two-texel texture clamped across u (so α < 0.5 for x < 0), and at z = −1 an opaque one.
/// Returns the file.
fn masked_quads(dir: &Path, material_extra: &str) -> PathBuf {
    use base64::Engine as _;
    let mut bin: Vec<u8> = Vec::new();
    let quad = |z: f32| {
        [
            [-1.0, -1.0, z],
            [1.0, -1.0, z],
            [1.0, 1.0, z],
            [-1.0, 1.0, z],
        ]
    };
    for q in [quad(0.0), quad(-1.0)] {
        for p in q {
            for c in p {
                bin.extend(f32::to_le_bytes(c));
            }
        }
    }
    // uv: u = (x + 1)/2, v = (1 − y)/2
    for (u, v) in [(0.0f32, 1.0f32), (1.0, 1.0), (1.0, 0.0), (0.0, 0.0)] {
        bin.extend(u.to_le_bytes());
        bin.extend(v.to_le_bytes());
    }
    for i in [0u16, 1, 2, 0, 2, 3] {
        bin.extend(i.to_le_bytes());
    }
    let b64 = base64::engine::general_purpose::STANDARD;
    let png = b64.encode(two_texel_png());
    let buffer = b64.encode(&bin);
    let json = format!(
        r#"{{
  "asset": {{"version": "2.0"}},
  "scene": 0,
  "scenes": [{{"nodes": [0, 1]}}],
  "nodes": [{{"mesh": 0}}, {{"mesh": 1}}],
  "meshes": [
    {{"primitives": [{{"attributes": {{"POSITION": 0, "TEXCOORD_0": 2}}, "indices": 3, "material": 0}}]}},
    {{"primitives": [{{"attributes": {{"POSITION": 1}}, "indices": 3, "material": 1}}]}}
  ],
  "materials": [
    {{"pbrMetallicRoughness": {{"baseColorTexture": {{"index": 0}}}} {material_extra}}},
    {{"pbrMetallicRoughness": {{"baseColorFactor": [0.2, 0.2, 0.8, 1]}}}}
  ],
  "textures": [{{"source": 0, "sampler": 0}}],
  "samplers": [{{"wrapS": 33071, "wrapT": 33071}}],
  "images": [{{"uri": "data:image/png;base64,{png}"}}],
  "buffers": [{{"byteLength": {len}, "uri": "data:application/octet-stream;base64,{buffer}"}}],
  "bufferViews": [{{"buffer": 0, "byteOffset": 0, "byteLength": 96}},
                  {{"buffer": 0, "byteOffset": 96, "byteLength": 32}},
                  {{"buffer": 0, "byteOffset": 128, "byteLength": 12}}],
  "accessors": [
    {{"bufferView": 0, "byteOffset": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-1, -1, 0], "max": [1, 1, 0]}},
    {{"bufferView": 0, "byteOffset": 48, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-1, -1, -1], "max": [1, 1, -1]}},
    {{"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"}},
    {{"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}}
  ]
}}"#,
        len = bin.len()
    );
    let path = dir.join("masked.gltf");
    std::fs::write(&path, json).unwrap();
    path
}

/// Where the camera rays at x stop, and whether a shadow ray up from z = −0.5 is blocked, as
/// (t of the hit, occluded).
fn probe(q: &dyn hytrace::trace::query::RayQuery, x: f32) -> (f32, bool) {
    let t = q
        .closest_hit(&down(x, 0.1), 0.0, 100.0)
        .map_or(f32::INFINITY, |h| h.t);
    let up = Ray {
        origin: Vec3::new(x, 0.1, -0.5),
        direction: Vec3::Z,
    };
    (t, q.occluded(&up, 0.0, 10.0))
}

#[test]
fn alpha_masked_texels_are_holes_for_camera_and_shadow_rays() {
    let dir = common::temp_dir("alpha-mask");
    let path = masked_quads(dir.path(), r#", "alphaMode": "MASK""#);
    let scene = Scene::from_model(&path, None).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(
        scene.meshes.materials[1].alpha_mode,
        AlphaMode::Mask { cutoff: 0.5 }
    );
    let tracer = SceneTracer::new(&scene);
    // x < 0: α < 0.5 (bilinear between the texel centres at x = −0.5 and 0.5): a hole; the
    // rays go on to the opaque quad 6 units below the camera, the shadow ray escapes
    for x in [-0.9, -0.6, -0.2] {
        assert_eq!(probe(&tracer, x), (6.0, false), "CPU at x = {x}");
    }
    for x in [0.2, 0.6, 0.9] {
        assert_eq!(probe(&tracer, x), (5.0, true), "CPU at x = {x}");
    }
    // the packet paths: a row of coherent camera rays and of shadow rays
    let xs: Vec<f32> = (0..16).map(|i| -0.95 + i as f32 * 0.127).collect();
    let rays: Vec<Ray> = xs.iter().map(|&x| down(x, 0.3)).collect();
    let mut hits = vec![None; rays.len()];
    tracer.closest_hits(&rays, 0.0, 100.0, &mut hits);
    let queries: Vec<hytrace::trace::ShadowQuery> = xs
        .iter()
        .flat_map(|&x| {
            let ray = Ray {
                origin: Vec3::new(x, 0.3, -0.5),
                direction: Vec3::Z,
            };
            [
                hytrace::scene::Shadow::Hard,
                hytrace::scene::Shadow::Soft(8.0),
            ]
            .map(|shadow| hytrace::trace::ShadowQuery {
                ray,
                tmin: 0.0,
                tmax: 10.0,
                shadow,
            })
        })
        .collect();
    let mut light = vec![0.0; queries.len()];
    tracer.visibilities(&queries, &mut light);
    for (k, &x) in xs.iter().enumerate() {
        if x.abs() < 0.05 {
            continue;
        }
        let want_t = if x < 0.0 { 6.0 } else { 5.0 };
        let t = hits[k].map_or(f32::INFINITY, |h| h.t);
        assert!((t - want_t).abs() < 1e-4, "packet at x = {x}: t = {t}");
        let want_light = if x < 0.0 { 1.0 } else { 0.0 };
        assert_eq!(light[2 * k], want_light, "hard shadow at x = {x}");
        assert_eq!(light[2 * k + 1], want_light, "soft shadow at x = {x}");
    }
    // the opaque part shows the texture's green, the hole the quad below
    let h = tracer.closest_hit(&down(0.6, 0.0), 0.0, 100.0).unwrap();
    assert!(material(&scene, &h).color.y > 0.9);

    #[cfg(feature = "gpu")]
    {
        let gpu = hytrace::gpu::query::GpuQuery::new(common::gpu::ctx(), &scene).unwrap();
        for x in [-0.9, -0.6, -0.2] {
            let (t, occluded) = probe(&gpu, x);
            assert!(
                (t - 6.0).abs() < 1e-4 && !occluded,
                "GPU at x = {x}: {t} {occluded}"
            );
        }
        for x in [0.2, 0.6, 0.9] {
            let (t, occluded) = probe(&gpu, x);
            assert!(
                (t - 5.0).abs() < 1e-4 && occluded,
                "GPU at x = {x}: {t} {occluded}"
            );
        }
    }

    #[cfg(feature = "embree")]
    {
        // Embree's distance may differ from the exact one in its last bit (it did by one ulp
        // on one machine's AVX-512 path), so within the tolerance the other backends get
        let embree = hytrace::reference::embree::EmbreeScene::build(&scene).unwrap();
        for x in [-0.9, -0.6, -0.2] {
            let (t, occluded) = probe(&embree, x);
            assert!(
                (t - 6.0).abs() < 1e-4 && !occluded,
                "Embree at x = {x}: {t} {occluded}"
            );
        }
        for x in [0.2, 0.6, 0.9] {
            let (t, occluded) = probe(&embree, x);
            assert!(
                (t - 5.0).abs() < 1e-4 && occluded,
                "Embree at x = {x}: {t} {occluded}"
            );
        }
    }
}

#[test]
fn blend_coverage_and_opaque_alpha() {
    let dir = common::temp_dir("alpha-blend");
    // BLEND: the texture's alpha is the coverage; nothing is a hole
    let path = masked_quads(dir.path(), r#", "alphaMode": "BLEND""#);
    let scene = Scene::from_model(&path, None).unwrap_or_else(|e| panic!("{e}"));
    let tracer = SceneTracer::new(&scene);
    let h = tracer.closest_hit(&down(-0.9, 0.0), 0.0, 100.0).unwrap();
    assert_eq!(h.t, 5.0);
    assert!(material(&scene, &h).opacity < 0.01);
    let h = tracer.closest_hit(&down(0.9, 0.0), 0.0, 100.0).unwrap();
    assert!(material(&scene, &h).opacity > 0.99);
    // OPAQUE (the default): alpha is ignored
    let path = masked_quads(dir.path(), "");
    let scene = Scene::from_model(&path, None).unwrap_or_else(|e| panic!("{e}"));
    let tracer = SceneTracer::new(&scene);
    let h = tracer.closest_hit(&down(-0.9, 0.0), 0.0, 100.0).unwrap();
    assert_eq!((h.t, material(&scene, &h).opacity), (5.0, 1.0));
}

#[test]
fn the_occlusion_texture_applies_its_red_channel_with_the_strength() {
    let dir = common::temp_dir("occlusion");
    // the two-texel texture as occlusion: R = 1 on the left, 0 on the right
    let path = masked_quads(
        dir.path(),
        r#", "occlusionTexture": {"index": 0, "strength": 0.25}"#,
    );
    let scene = Scene::from_model(&path, None).unwrap_or_else(|e| panic!("{e}"));
    let tracer = SceneTracer::new(&scene);
    let occlusion = |x: f32| {
        let h = tracer.closest_hit(&down(x, 0.0), 0.0, 100.0).unwrap();
        material(&scene, &h).occlusion
    };
    // §3.9.4: 1 + strength·(R − 1), R linear (not sRGB-decoded)
    assert!((occlusion(-0.9) - 1.0).abs() < 1e-6);
    assert!((occlusion(0.9) - 0.75).abs() < 1e-6);
    // halfway between the texel centres R = 0.5 as stored: 1 − 0.25·0.5
    assert!((occlusion(0.0) - 0.875).abs() < 1e-3, "{}", occlusion(0.0));
}

#[test]
fn bad_material_input_is_a_warning_or_an_error_naming_the_place() {
    let dir = common::temp_dir("bad-materials");
    // a texture transform that overflows f32, a negative cutoff, a missing image
    let path = masked_quads(
        dir.path(),
        r#", "alphaMode": "MASK", "alphaCutoff": -1,
           "emissiveTexture": {"index": 0, "extensions": {"KHR_texture_transform": {"offset": [1e300, 0]}}},
           "normalTexture": {"index": 0, "texCoord": 3}"#,
    );
    let asset = mesh::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let warnings = asset.warnings.join("\n");
    for want in [
        "materials[0].emissiveTexture.extensions.KHR_texture_transform",
        "materials[0].alphaCutoff",
        "materials[0].normalTexture.texCoord",
    ] {
        assert!(
            warnings.contains(want),
            "no warning about {want} in:\n{warnings}"
        );
    }
    assert_eq!(
        asset.materials[1].alpha_mode,
        AlphaMode::Mask { cutoff: 0.5 }
    );
    // a texture index that does not exist: one line naming the file and the JSON path
    let text = std::fs::read_to_string(&path).unwrap().replace(
        r#""baseColorTexture": {"index": 0}"#,
        r#""baseColorTexture": {"index": 7}"#,
    );
    let broken = dir.path().join("broken.gltf");
    std::fs::write(&broken, text).unwrap();
    let e = mesh::load(&broken).unwrap_err().to_string();
    assert!(
        e.contains("broken.gltf") && e.contains("materials[0]") && !e.contains('\n'),
        "{e}"
    );
    // an image that cannot be read: a warning, the material without its texture
    let text = std::fs::read_to_string(&path).unwrap();
    let start = text.find("data:image/png").unwrap();
    let end = start + text[start..].find('"').unwrap();
    let missing = format!("{}missing.png{}", &text[..start], &text[end..]);
    let gone = dir.path().join("gone.gltf");
    std::fs::write(&gone, missing).unwrap();
    let asset = mesh::load(&gone).unwrap_or_else(|e| panic!("{e}"));
    assert!(asset.materials[1].textures.base_color.is_none());
    assert!(
        asset.warnings.iter().any(|w| w.contains("images[0]")),
        "{:?}",
        asset.warnings
    );
    let _ = Vec4::ONE;
}
