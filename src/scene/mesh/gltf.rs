//! glTF 2.0: `.gltf` (external or base64-embedded buffers) and `.glb`.
//!
//! The `gltf` crate parses and validates the JSON; everything that touches binary data (the
//! GLB container, buffers, accessors with their sparse substitutions, images) is read here
//! with explicit bounds checks, so malformed files give errors instead of panics.

use super::texture::{self, Texture, UvTransform, Wrap};
use super::{
    AlphaMode, CameraProjection, LightKind, MeshAsset, MeshError, MeshInstance, MeshMaterial,
    NamedCamera, NamedLight, TextureRef, TriangleMesh, pbr_material, repair_normals, unit,
    vertex_normals,
};
use ::gltf::json;
use glam::{Affine3A, Mat4, Quat, Vec2, Vec3, Vec4};
use json::accessor::{ComponentType, Type};
use json::mesh::{Mode, Semantic};
use json::validation::Checked;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// The most node instances a scene may expand to (a node graph where nodes are shared by
/// several parents grows exponentially with its depth).
const MAX_NODE_INSTANCES: usize = 4_000_000;

/// The most elements an accessor without a buffer view (all zeros plus sparse values) may have.
const MAX_ZERO_ACCESSOR: usize = 1 << 26;

/// Loads a `.gltf` or `.glb` file whose bytes are `bytes`.
pub(super) fn load(file: &Path, bytes: &[u8]) -> Result<MeshAsset, MeshError> {
    let err = |place: &str, message: String| MeshError::Gltf {
        file: file.to_path_buf(),
        place: place.to_string(),
        message,
    };
    let (json_bytes, bin) = if bytes.starts_with(b"glTF") {
        split_glb(bytes).map_err(|m| err("", m))?
    } else {
        let first = bytes.iter().find(|b| !b.is_ascii_whitespace());
        let bom = bytes.starts_with(&[0xEF, 0xBB, 0xBF]);
        if first != Some(&b'{') && !bom {
            return Err(err(
                "",
                "not a glTF file: neither binary glTF (magic \"glTF\") nor a JSON object".into(),
            ));
        }
        let start = if bom { 3 } else { 0 };
        (&bytes[start..], None)
    };
    let mut root = parse_root(json_bytes).map_err(|m| err("", m))?;
    check_version(&root).map_err(|(place, m)| err(&place, m))?;
    precheck(&root).map_err(|(place, m)| err(&place, m))?;
    let relaxed = relax_bounds(&mut root);
    // Quantized attributes are read like any other accessor here.
    root.extensions_required
        .retain(|e| e != "KHR_mesh_quantization");
    let draco = root
        .extensions_used
        .iter()
        .any(|e| e == "KHR_draco_mesh_compression");
    let document = ::gltf::Document::from_json(root).map_err(|e| match e {
        ::gltf::Error::Validation(list) => {
            let describe =
                |(p, e): &(json::Path, json::validation::Error)| format!("{}: {}", p.0, e);
            let place = list.first().map(|(p, _)| p.0.clone()).unwrap_or_default();
            let mut message = match list.first() {
                Some((_, e)) => format!("invalid glTF: {e}"),
                None => "invalid glTF".to_string(),
            };
            if list.len() > 1 {
                let others: Vec<String> = list[1..].iter().take(6).map(describe).collect();
                message += &format!(" (also {}", others.join("; "));
                if list.len() > 7 {
                    message += &format!("; and {} more", list.len() - 7);
                }
                message += ")";
            }
            if draco {
                message = format!(
                    "Draco-compressed meshes (KHR_draco_mesh_compression) are not supported; \
                     {message}"
                );
            }
            err(&place, message)
        }
        other => err("", format!("invalid glTF: {other}")),
    })?;
    let root = document.as_json();
    let base = file.parent().unwrap_or(Path::new("."));
    let buffers = load_buffers(root, base, bin).map_err(|(place, m)| err(&place, m))?;
    let mut asset = MeshAsset::empty();
    asset.warnings = relaxed;
    let mut cx = Cx {
        root,
        base,
        buffers,
        asset,
        mesh_slot: HashMap::new(),
        texture_slot: HashMap::new(),
    };
    cx.run().map_err(|(place, m)| err(&place, m))?;
    Ok(cx.asset)
}

/// The JSON document. glTF 2.0 makes `scene.nodes` optional but `gltf-json` requires it, so
/// when the plain parse fails the document is retried with empty `nodes` filled in.
fn parse_root(bytes: &[u8]) -> Result<json::Root, String> {
    let first = match json::deserialize::from_slice::<json::Root>(bytes) {
        Ok(root) => return Ok(root),
        Err(e) => format!("invalid glTF JSON: {e}"),
    };
    let Ok(mut value) = json::deserialize::from_slice::<json::Value>(bytes) else {
        return Err(first);
    };
    // A glTF 1.0 document fails the 2.0 schema somewhere unrelated to its version (its
    // `scenes` are a map): say what it is instead.
    if let Some(version) = value.pointer("/asset/version").and_then(|v| v.as_str())
        && version_numbers(version).is_none_or(|(major, _)| major != 2)
    {
        return Err(unsupported_version(version));
    }
    let mut patched = false;
    if let Some(scenes) = value.get_mut("scenes").and_then(|s| s.as_array_mut()) {
        for scene in scenes.iter_mut().filter_map(|s| s.as_object_mut()) {
            if !scene.contains_key("nodes") {
                scene.insert("nodes".into(), json::Value::Array(Vec::new()));
                patched = true;
            }
        }
    }
    if !patched {
        return Err(first);
    }
    json::deserialize::from_value::<json::Root>(value).map_err(|_| first)
}

/// A place in the JSON and what is wrong there.
type Fail = (String, String);

fn fail<T>(place: impl Into<String>, message: impl Into<String>) -> Result<T, Fail> {
    Err((place.into(), message.into()))
}

/// Splits a GLB container into its JSON chunk and its first BIN chunk.
fn split_glb(bytes: &[u8]) -> Result<(&[u8], Option<&[u8]>), String> {
    let u32_at = |at: usize| -> Option<u32> {
        let b = bytes.get(at..at.checked_add(4)?)?;
        Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let (Some(version), Some(length)) = (u32_at(4), u32_at(8)) else {
        return Err("binary glTF: truncated header (fewer than 12 bytes)".into());
    };
    if version != 2 {
        return Err(format!(
            "binary glTF version {version} is not supported (only glTF 2.0)"
        ));
    }
    let length = length as usize;
    if length > bytes.len() {
        return Err(format!(
            "binary glTF: the header gives a length of {length} bytes but the file has only {} \
             (truncated?)",
            bytes.len()
        ));
    }
    if length < 12 {
        return Err(format!("binary glTF: invalid total length {length}"));
    }
    let mut at = 12usize;
    let mut json = None;
    let mut bin = None;
    while at < length {
        let (Some(chunk_len), Some(kind)) = (u32_at(at), bytes.get(at + 4..at + 8)) else {
            return Err(format!("binary glTF: truncated chunk header at byte {at}"));
        };
        let start = at + 8;
        let end = start
            .checked_add(chunk_len as usize)
            .filter(|&e| e <= length)
            .ok_or_else(|| {
                format!(
                    "binary glTF: chunk at byte {at} claims {chunk_len} bytes, past the end of \
                     the file (truncated?)"
                )
            })?;
        let data = &bytes[start..end];
        match kind {
            b"JSON" if json.is_none() => json = Some(data),
            b"BIN\0" if bin.is_none() => bin = Some(data),
            _ => {}
        }
        if json.is_none() {
            return Err("binary glTF: the first chunk is not JSON".into());
        }
        at = end;
    }
    let json = json.ok_or("binary glTF: no JSON chunk")?;
    Ok((json, bin))
}

/// A glTF version string's major and minor numbers ("2.0": (2, 0)).
fn version_numbers(version: &str) -> Option<(u32, u32)> {
    let (major, minor) = version.split_once('.')?;
    Some((major.parse().ok()?, minor.parse().ok()?))
}

/// The error for a document of another major version than 2.
fn unsupported_version(version: &str) -> String {
    format!("glTF version {version} is not supported (only glTF 2.0)")
}

/// glTF 2.0 §3.2: a loader reads the major version it knows (a `minVersion`, when given, is
/// the least it must know); `gltf-json` parses any version string.
fn check_version(root: &json::Root) -> Result<(), Fail> {
    let version = &root.asset.version;
    match version_numbers(version) {
        Some((2, _)) => {}
        Some(_) => return fail("asset.version", unsupported_version(version)),
        None => {
            return fail(
                "asset.version",
                format!("{version:?} is not a glTF version (\"<major>.<minor>\", as \"2.0\")"),
            );
        }
    }
    if let Some(min) = &root.asset.min_version
        && version_numbers(min).is_none_or(|(major, minor)| (major, minor) > (2, 0))
    {
        return fail(
            "asset.minVersion",
            format!("the file needs glTF {min}; this loader reads glTF 2.0"),
        );
    }
    Ok(())
}

/// What makes a camera's projection impossible, if anything (glTF 2.0 §5.13: yfov and
/// aspectRatio are > 0, and a field of view is < π; xmag and ymag are not 0).
fn impossible_projection(cam: &json::Camera) -> Option<String> {
    use json::camera::Type;
    if let (Checked::Valid(Type::Perspective), Some(p)) = (cam.type_, &cam.perspective) {
        if !(p.yfov > 0.0 && p.yfov < std::f32::consts::PI) {
            return Some(format!(
                "perspective: yfov {} is not in (0, π) radians",
                p.yfov
            ));
        }
        if let Some(a) = p.aspect_ratio.filter(|a| !(*a > 0.0 && a.is_finite())) {
            return Some(format!("perspective: aspectRatio {a} is not positive"));
        }
    }
    if let (Checked::Valid(Type::Orthographic), Some(o)) = (cam.type_, &cam.orthographic)
        && (!(o.xmag.is_finite() && o.ymag.is_finite()) || o.xmag == 0.0 || o.ymag == 0.0)
    {
        return Some(format!(
            "orthographic: xmag {} and ymag {} must be finite and not 0",
            o.xmag, o.ymag
        ));
    }
    None
}

/// Checks what the `gltf` crate's validation would index without checking: the accessor
/// indices of mesh primitives.
fn precheck(root: &json::Root) -> Result<(), Fail> {
    let n = root.accessors.len();
    for (mi, mesh) in root.meshes.iter().enumerate() {
        for (pi, prim) in mesh.primitives.iter().enumerate() {
            for (sem, index) in &prim.attributes {
                if index.value() >= n {
                    let name = match sem {
                        Checked::Valid(s) => s.to_string(),
                        Checked::Invalid => "?".to_string(),
                    };
                    return fail(
                        format!("meshes[{mi}].primitives[{pi}].attributes.{name}"),
                        format!("accessor {} does not exist ({n} accessors)", index.value()),
                    );
                }
            }
        }
    }
    Ok(())
}

/// glTF requires POSITION accessors to give `min` and `max`, and `gltf-json` refuses files
/// without them; many exporters omit them and the loader does not use them, so missing or
/// malformed ones are replaced (with a warning) before validation.
fn relax_bounds(root: &mut json::Root) -> Vec<String> {
    let mut warnings = Vec::new();
    let mut positions: Vec<usize> = root
        .meshes
        .iter()
        .flat_map(|m| &m.primitives)
        .filter_map(|p| p.attributes.get(&Checked::Valid(Semantic::Positions)))
        .map(|i| i.value())
        .collect();
    positions.sort_unstable();
    positions.dedup();
    let valid = |v: &Option<json::Value>| {
        v.as_ref()
            .is_some_and(|v| json::deserialize::from_value::<[f32; 3]>(v.clone()).is_ok())
    };
    for i in positions {
        let Some(acc) = root.accessors.get_mut(i) else {
            continue;
        };
        if valid(&acc.min) && valid(&acc.max) {
            continue;
        }
        let zero = || Some(json::Value::Array(vec![json::Value::from(0.0); 3]));
        acc.min = zero();
        acc.max = zero();
        warnings.push(format!(
            "accessors[{i}]: a POSITION accessor without valid min and max (glTF requires \
             them); ignored, they are not used"
        ));
    }
    warnings
}

/// Reads every buffer: the GLB BIN chunk, a base64 `data:` URI or a file next to the glTF.
fn load_buffers(
    root: &json::Root,
    base: &Path,
    mut bin: Option<&[u8]>,
) -> Result<Vec<Vec<u8>>, Fail> {
    let mut out = Vec::with_capacity(root.buffers.len());
    for (i, b) in root.buffers.iter().enumerate() {
        let place = format!("buffers[{i}]");
        let data = match &b.uri {
            None => match bin.take() {
                Some(d) => d.to_vec(),
                None => {
                    return fail(
                        place,
                        "has no uri and there is no (unclaimed) GLB BIN chunk to use",
                    );
                }
            },
            Some(uri) => {
                read_uri(uri, base)
                    .map_err(|m| (format!("{place}.uri"), m))?
                    .0
            }
        };
        let want = b.byte_length.0;
        if (data.len() as u64) < want {
            return fail(
                place,
                format!(
                    "byteLength is {want} but only {} bytes could be read (truncated buffer?)",
                    data.len()
                ),
            );
        }
        // The buffer is its first byteLength bytes (a GLB chunk or a file may be padded
        // past them): a buffer view reaching beyond is refused where it is read.
        let mut data = data;
        data.truncate(want as usize);
        out.push(data);
    }
    Ok(out)
}

/// The bytes a URI names (and the MIME type of a `data:` URI): base64 data, or a file
/// relative to `base` (percent-decoded).
fn read_uri(uri: &str, base: &Path) -> Result<(Vec<u8>, Option<String>), String> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let Some((mime, data)) = rest.split_once(";base64,") else {
            return Err("only base64 data: URIs are supported".into());
        };
        let bytes = base64_decode(data).ok_or("invalid base64 data in the data: URI")?;
        return Ok((bytes, Some(mime.to_string())));
    }
    let path_part = uri
        .strip_prefix("file://")
        .or_else(|| uri.strip_prefix("file:"))
        .unwrap_or(uri);
    if path_part.contains("://") {
        return Err(format!(
            "unsupported URI {uri:?} (only relative files and data: URIs)"
        ));
    }
    let decoded = percent_decode(path_part).ok_or_else(|| format!("invalid URI {uri:?}"))?;
    let path: PathBuf = base.join(&decoded);
    crate::scene::read::read(&path)
        .map(|b| (b, None))
        .map_err(|e| format!("cannot read {}: {e}", path.display()))
}

/// `%XX` escapes decoded; `None` when an escape is malformed or the result is not UTF-8.
fn percent_decode(s: &str) -> Option<String> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' {
            let hex = std::str::from_utf8(b.get(i + 1..i + 3)?).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

/// Standard base64 (with optional padding, ignoring ASCII whitespace); `None` on bad input.
fn base64_decode(s: &str) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(s.len() / 4 * 3);
    let (mut acc, mut bits) = (0u32, 0u32);
    let mut padding = false;
    for &c in s.as_bytes() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            b'=' => {
                padding = true;
                continue;
            }
            c if c.is_ascii_whitespace() => continue,
            _ => return None,
        };
        if padding {
            return None;
        }
        acc = (acc << 6) | u32::from(v);
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    Some(out)
}

/// Loader state: the validated document, its buffers and the asset being built.
struct Cx<'a> {
    root: &'a json::Root,
    base: &'a Path,
    buffers: Vec<Vec<u8>>,
    asset: MeshAsset,
    /// glTF mesh index → index in `asset.meshes`.
    mesh_slot: HashMap<usize, usize>,
    /// (glTF texture index, decoded from sRGB) → index in `asset.textures` (`None`: failed,
    /// already warned).
    texture_slot: HashMap<(usize, bool), Option<usize>>,
}

impl Cx<'_> {
    fn warn(&mut self, message: String) {
        self.asset.warnings.push(message);
    }

    fn run(&mut self) -> Result<(), Fail> {
        for i in 0..self.root.materials.len() {
            let m = self.material(i);
            self.asset.materials.push(m);
        }
        let roots = self.scene_roots()?;
        self.traverse(&roots)
    }

    /// The root nodes to draw: the default scene's, else scene 0's, else every node that is
    /// nobody's child.
    fn scene_roots(&mut self) -> Result<Vec<(usize, String)>, Fail> {
        let root = self.root;
        let scene = root.scene.map(|s| s.value()).or(if root.scenes.is_empty() {
            None
        } else {
            Some(0)
        });
        if let Some(s) = scene {
            let Some(sc) = root.scenes.get(s) else {
                return fail("scene", format!("scene {s} does not exist"));
            };
            return Ok(sc
                .nodes
                .iter()
                .enumerate()
                .map(|(k, n)| (n.value(), format!("scenes[{s}].nodes[{k}]")))
                .collect());
        }
        let mut is_child = vec![false; root.nodes.len()];
        for node in &root.nodes {
            for c in node.children.iter().flatten() {
                if let Some(f) = is_child.get_mut(c.value()) {
                    *f = true;
                }
            }
        }
        if !root.nodes.is_empty() {
            self.warn("no scene: drawing every root node".to_string());
        }
        Ok((0..root.nodes.len())
            .filter(|&i| !is_child[i])
            .map(|i| (i, format!("nodes[{i}]")))
            .collect())
    }

    /// Depth-first over the node graph from `roots`, composing transforms parent → child and
    /// emitting instances, cameras and lights. Errors on cycles.
    fn traverse(&mut self, roots: &[(usize, String)]) -> Result<(), Fail> {
        let root = self.root;
        let nodes = &root.nodes;
        let mut on_path = vec![false; nodes.len()];
        let mut visits = 0usize;
        for (r, place) in roots {
            let r = *r;
            if r >= nodes.len() {
                return fail(place.clone(), format!("node {r} does not exist"));
            }
            let world = local_transform(root, r)?;
            self.emit(r, world)?;
            on_path[r] = true;
            // (node, its world transform, next child to visit)
            let mut stack: Vec<(usize, Affine3A, usize)> = vec![(r, world, 0)];
            while let Some(top) = stack.last_mut() {
                let (node, world, k) = *top;
                let children = nodes[node].children.as_deref().unwrap_or(&[]);
                if k >= children.len() {
                    on_path[node] = false;
                    stack.pop();
                    continue;
                }
                top.2 += 1;
                let c = children[k].value();
                let place = format!("nodes[{node}].children[{k}]");
                if c >= nodes.len() {
                    return fail(place, format!("node {c} does not exist"));
                }
                if on_path[c] {
                    return fail(
                        place,
                        format!(
                            "node {c} is its own ancestor: the node hierarchy has a cycle \
                             (glTF requires a forest)"
                        ),
                    );
                }
                visits += 1;
                if visits > MAX_NODE_INSTANCES {
                    return fail(
                        place,
                        format!(
                            "the node hierarchy expands to more than {MAX_NODE_INSTANCES} node \
                             instances"
                        ),
                    );
                }
                let child_world = world * local_transform(root, c)?;
                self.emit(c, child_world)?;
                on_path[c] = true;
                stack.push((c, child_world, 0));
            }
        }
        Ok(())
    }

    /// What one node instance contributes: a mesh instance, a camera, a light.
    fn emit(&mut self, index: usize, world: Affine3A) -> Result<(), Fail> {
        let root = self.root;
        let node = &root.nodes[index];
        let node_name = node
            .name
            .clone()
            .unwrap_or_else(|| format!("nodes[{index}]"));
        if let Some(m) = node.mesh {
            let slot = match self.mesh_slot.get(&m.value()) {
                Some(&s) => s,
                None => {
                    let mesh = self.mesh(m.value())?;
                    self.asset.meshes.push(mesh);
                    let s = self.asset.meshes.len() - 1;
                    self.mesh_slot.insert(m.value(), s);
                    s
                }
            };
            self.asset.instances.push(MeshInstance {
                mesh: slot,
                transform: world,
                name: node_name.clone(),
            });
        }
        let position: Vec3 = world.translation.into();
        let minus_z = unit(Vec3::from(world.matrix3 * glam::Vec3A::NEG_Z)).unwrap_or(Vec3::NEG_Z);
        if let Some(c) = node.camera {
            let place = format!("nodes[{index}].camera");
            let Some(cam) = root.cameras.get(c.value()) else {
                return fail(place, format!("camera {} does not exist", c.value()));
            };
            if let Some(problem) = impossible_projection(cam) {
                self.warn(format!("cameras[{}].{problem}; camera skipped", c.value()));
                return Ok(());
            }
            let projection = match (cam.type_, &cam.perspective, &cam.orthographic) {
                (Checked::Valid(json::camera::Type::Perspective), Some(p), _) => {
                    CameraProjection::Perspective {
                        yfov_radians: p.yfov,
                        aspect: p.aspect_ratio,
                    }
                }
                (Checked::Valid(json::camera::Type::Orthographic), _, Some(o)) => {
                    CameraProjection::Orthographic {
                        ymag: o.ymag,
                        xmag: o.xmag,
                    }
                }
                _ => {
                    self.warn(format!(
                        "cameras[{}]: type and projection do not match; camera skipped",
                        c.value()
                    ));
                    return Ok(());
                }
            };
            let y = Vec3::from(world.matrix3 * glam::Vec3A::Y);
            let up = unit(y - minus_z * y.dot(minus_z))
                .unwrap_or_else(|| minus_z.any_orthonormal_vector());
            self.asset.cameras.push(NamedCamera {
                name: cam.name.clone().unwrap_or_else(|| node_name.clone()),
                position,
                forward: minus_z,
                up,
                projection,
            });
        }
        let light = node
            .extensions
            .as_ref()
            .and_then(|e| e.khr_lights_punctual.as_ref())
            .map(|l| l.light.value());
        if let Some(l) = light {
            use json::extensions::scene::khr_lights_punctual::Type as LightType;
            let lights = root
                .extensions
                .as_ref()
                .and_then(|e| e.khr_lights_punctual.as_ref())
                .map(|k| k.lights.as_slice())
                .unwrap_or(&[]);
            let Some(light) = lights.get(l) else {
                return fail(
                    format!("nodes[{index}].extensions.KHR_lights_punctual.light"),
                    format!("light {l} does not exist"),
                );
            };
            let kind = match light.type_ {
                Checked::Valid(LightType::Point) => LightKind::Point { position },
                Checked::Valid(LightType::Directional) => {
                    LightKind::Directional { direction: minus_z }
                }
                Checked::Valid(LightType::Spot) => {
                    // the specification's defaults and limits: 0 ≤ inner < outer ≤ π/2
                    let (inner, outer) = light
                        .spot
                        .as_ref()
                        .map_or((0.0, std::f32::consts::FRAC_PI_4), |s| {
                            (s.inner_cone_angle, s.outer_cone_angle)
                        });
                    let valid = inner.is_finite()
                        && outer.is_finite()
                        && inner >= 0.0
                        && inner < outer
                        && outer <= std::f32::consts::FRAC_PI_2 + 1e-6;
                    let (inner, outer) = if valid {
                        (inner, outer.min(std::f32::consts::FRAC_PI_2))
                    } else {
                        self.warn(format!(
                            "extensions.KHR_lights_punctual.lights[{l}].spot: cone angles \
                             {inner} and {outer} do not satisfy 0 ≤ inner < outer ≤ π/2; \
                             the defaults 0 and π/4 are used"
                        ));
                        (0.0, std::f32::consts::FRAC_PI_4)
                    };
                    LightKind::Spot {
                        position,
                        direction: minus_z,
                        inner_cone_angle: inner,
                        outer_cone_angle: outer,
                    }
                }
                Checked::Invalid => {
                    self.warn(format!(
                        "extensions.KHR_lights_punctual.lights[{l}]: unknown type; light skipped"
                    ));
                    return Ok(());
                }
            };
            let color = Vec3::from_array(light.color);
            let usable = light.intensity.is_finite()
                && light.intensity >= 0.0
                && color.is_finite()
                && color.min_element() >= 0.0;
            if !usable {
                self.warn(format!(
                    "extensions.KHR_lights_punctual.lights[{l}]: intensity {} or colour {color} \
                     is negative or not finite; light skipped",
                    light.intensity
                ));
                return Ok(());
            }
            let range = light.range.filter(|r| r.is_finite() && *r > 0.0);
            if light.range.is_some() && range.is_none() {
                self.warn(format!(
                    "extensions.KHR_lights_punctual.lights[{l}].range: must be a positive \
                     number; the light has no range"
                ));
            }
            self.asset.lights.push(NamedLight {
                name: light.name.clone().unwrap_or_else(|| node_name.clone()),
                kind,
                color,
                intensity: light.intensity,
                range,
            });
        }
        Ok(())
    }

    /// One glTF mesh: its triangle primitives merged, with per-triangle materials.
    fn mesh(&mut self, mi: usize) -> Result<TriangleMesh, Fail> {
        let root = self.root;
        let Some(mesh) = root.meshes.get(mi) else {
            return fail(format!("meshes[{mi}]"), "mesh does not exist");
        };
        let mut out = TriangleMesh {
            name: mesh.name.clone().unwrap_or_else(|| format!("meshes[{mi}]")),
            ..TriangleMesh::default()
        };
        let drawn = |p: &json::mesh::Primitive| {
            matches!(
                p.mode,
                Checked::Valid(Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan)
            )
        };
        let any = |sem: Semantic| {
            let key = Checked::Valid(sem);
            mesh.primitives
                .iter()
                .any(|p| drawn(p) && p.attributes.contains_key(&key))
        };
        let (any_uv, any_uv1, any_color) = (
            any(Semantic::TexCoords(0)),
            any(Semantic::TexCoords(1)),
            any(Semantic::Colors(0)),
        );
        // the asset material of a primitive (materials are read before meshes)
        let material_of = |p: &json::mesh::Primitive| match p.material {
            Some(m) if m.value() < root.materials.len() => m.value() as u32 + 1,
            _ => 0,
        };
        // per primitive, the texture coordinate set of its material's normal texture
        let normal_mapped: Vec<Option<u32>> = mesh
            .primitives
            .iter()
            .map(|p| {
                self.asset
                    .materials
                    .get(material_of(p) as usize)
                    .and_then(|m| m.textures.normal.as_ref())
                    .map(|(t, _)| t.tex_coord)
                    .filter(|_| drawn(p))
            })
            .collect();
        let any_tangent = normal_mapped.iter().any(Option::is_some);
        for (pi, prim) in mesh.primitives.iter().enumerate() {
            let place = format!("meshes[{mi}].primitives[{pi}]");
            if !drawn(prim) {
                let mode = match prim.mode {
                    Checked::Valid(Mode::Points) => "POINTS",
                    Checked::Valid(Mode::Lines) => "LINES",
                    Checked::Valid(Mode::LineLoop) => "LINE_LOOP",
                    Checked::Valid(Mode::LineStrip) => "LINE_STRIP",
                    _ => "an unknown mode",
                };
                self.warn(format!(
                    "{place}: mode {mode} skipped (only triangles are drawn)"
                ));
                continue;
            }
            let attr = |s: Semantic| prim.attributes.get(&Checked::Valid(s)).map(|i| i.value());
            let pos_place = format!("{place}.attributes.POSITION");
            let Some(pos_acc) = attr(Semantic::Positions) else {
                return fail(pos_place, "missing (every primitive needs POSITION)");
            };
            // glTF 2.0 §3.7.2.1: POSITION is VEC3 float; KHR_mesh_quantization allows
            // integers (read like any other accessor)
            if let Ok((_, ct)) = self.types(pos_acc, &pos_place)
                && ct != ComponentType::F32
                && !self
                    .root
                    .extensions_used
                    .iter()
                    .any(|e| e == "KHR_mesh_quantization")
            {
                return fail(
                    pos_place,
                    format!(
                        "accessors[{pos_acc}] has {} components; POSITION must be FLOAT \
                         (integer positions need KHR_mesh_quantization in extensionsUsed)",
                        component_name(ct)
                    ),
                );
            }
            let positions: Vec<[f32; 3]> = self.read_vecs(pos_acc, &pos_place)?;
            if let Some(k) = positions
                .iter()
                .position(|p| !p.iter().all(|c| c.is_finite()))
            {
                return fail(
                    pos_place,
                    format!(
                        "accessors[{pos_acc}] element {k} is {:?}: positions must be finite",
                        positions[k]
                    ),
                );
            }
            let nv = positions.len();
            let base = out.positions.len();
            if base + nv > u32::MAX as usize {
                return fail(pos_place, "the mesh has more than 2³² vertices");
            }
            let normals = match attr(Semantic::Normals) {
                None => None,
                Some(a) => {
                    let p = format!("{place}.attributes.NORMAL");
                    let n: Vec<[f32; 3]> = self.read_vecs(a, &p)?;
                    if n.len() != nv {
                        return fail(
                            p,
                            format!(
                                "accessors[{a}] has {} elements but POSITION has {nv}",
                                n.len()
                            ),
                        );
                    }
                    Some(n)
                }
            };
            let uvs =
                self.vertex_attr::<2>(attr(Semantic::TexCoords(0)), &place, "TEXCOORD_0", nv)?;
            let uvs1 =
                self.vertex_attr::<2>(attr(Semantic::TexCoords(1)), &place, "TEXCOORD_1", nv)?;
            let colors = self.vertex_colors(attr(Semantic::Colors(0)), &place, nv)?;
            let file_tangents =
                self.vertex_attr::<4>(attr(Semantic::Tangents), &place, "TANGENT", nv)?;
            let indices: Vec<u32> = match prim.indices {
                Some(a) => {
                    let a = a.value();
                    let p = format!("{place}.indices");
                    let idx = self.read_indices(a, &p)?;
                    if let Some(k) = idx.iter().position(|&i| i as usize >= nv) {
                        return fail(
                            p,
                            format!(
                                "accessors[{a}] element {k} is {} but POSITION has only {nv} \
                                 vertices",
                                idx[k]
                            ),
                        );
                    }
                    idx
                }
                None => (0..nv as u32).collect(),
            };
            let mut tris: Vec<[u32; 3]> = Vec::new();
            match prim.mode {
                Checked::Valid(Mode::TriangleStrip) => {
                    for i in 0..indices.len().saturating_sub(2) {
                        // Every other triangle is flipped to keep the winding.
                        let t = if i % 2 == 0 {
                            [indices[i], indices[i + 1], indices[i + 2]]
                        } else {
                            [indices[i + 1], indices[i], indices[i + 2]]
                        };
                        tris.push(t);
                    }
                }
                Checked::Valid(Mode::TriangleFan) => {
                    for i in 1..indices.len().saturating_sub(1) {
                        tris.push([indices[0], indices[i], indices[i + 1]]);
                    }
                }
                _ => {
                    if !indices.len().is_multiple_of(3) {
                        self.warn(format!(
                            "{place}: {} indices is not a multiple of 3; the last {} ignored",
                            indices.len(),
                            indices.len() % 3
                        ));
                    }
                    tris.extend(indices.chunks_exact(3).map(|c| [c[0], c[1], c[2]]));
                }
            }
            // glTF 2.0 §3.7.2.1: "When normals are not specified, client implementations MUST
            // calculate flat normals". Each triangle's corners become vertices of their own
            // (every attribute copied) that carry the face's normal; a smooth average over
            // shared vertices would round a box's edges.
            let flat = normals.is_none();
            let (positions, uvs, uvs1, colors, file_tangents) = if flat {
                if base + 3 * tris.len() > u32::MAX as usize {
                    return fail(pos_place, "the mesh has more than 2³² vertices");
                }
                let split = (
                    unweld(&positions, &tris),
                    uvs.map(|v| unweld(&v, &tris)),
                    uvs1.map(|v| unweld(&v, &tris)),
                    colors.map(|v| unweld(&v, &tris)),
                    file_tangents.map(|v| unweld(&v, &tris)),
                );
                for (k, t) in tris.iter_mut().enumerate() {
                    let first = 3 * k as u32;
                    *t = [first, first + 1, first + 2];
                }
                split
            } else {
                (positions, uvs, uvs1, colors, file_tangents)
            };
            let pos: Vec<Vec3> = positions.iter().map(|&p| Vec3::from_array(p)).collect();
            let nrm = match normals {
                Some(n) => {
                    let mut n: Vec<Vec3> = n.iter().map(|&v| Vec3::from_array(v)).collect();
                    let bad = repair_normals(&mut n, &pos, &tris);
                    if bad > 0 {
                        self.warn(format!(
                            "{place}: {bad} normals are zero or not finite; computed instead"
                        ));
                    }
                    n
                }
                // (the corners of a triangle share no vertex with another's: flat)
                None => vertex_normals(&pos, &tris),
            };
            let material = material_of(prim);
            let mut pos = pos;
            let mut nrm = nrm;
            let to2 = |v: Option<Vec<[f32; 2]>>| v.map(|v| v.into_iter().map(Vec2::from).collect());
            let mut uvs: Option<Vec<Vec2>> = to2(uvs);
            let mut uvs1: Option<Vec<Vec2>> = to2(uvs1);
            let mut colors = colors;
            let mut tangents: Option<Vec<Vec4>> = None;
            if any_tangent {
                let from_file = file_tangents.and_then(|t| {
                    let t: Option<Vec<Vec4>> = t
                        .into_iter()
                        .map(|t| {
                            let t = Vec4::from(t);
                            let xyz = unit(t.truncate())?;
                            t.w.is_finite()
                                .then(|| xyz.extend(if t.w < 0.0 { -1.0 } else { 1.0 }))
                        })
                        .collect();
                    if t.is_none() {
                        self.warn(format!(
                            "{place}.attributes.TANGENT: a tangent is zero or not finite; \
                             tangents generated instead"
                        ));
                    }
                    t
                });
                tangents = Some(match from_file {
                    Some(t) => t,
                    None => {
                        let set = match normal_mapped[pi] {
                            Some(1) => uvs1.as_deref(),
                            Some(_) => uvs.as_deref(),
                            None => None,
                        };
                        match set {
                            Some(set) => {
                                let (t, split) =
                                    super::tangent::generate(&pos, &nrm, set, &mut tris);
                                // the vertices MikkTSpace split, copied in every attribute
                                for &v in &split {
                                    let v = v as usize;
                                    pos.push(pos[v]);
                                    nrm.push(nrm[v]);
                                    for a in [&mut uvs, &mut uvs1].into_iter().flatten() {
                                        a.push(a[v]);
                                    }
                                    if let Some(c) = &mut colors {
                                        c.push(c[v]);
                                    }
                                }
                                t
                            }
                            // no texture coordinates to orient a tangent: any one orthogonal
                            // to the normal (the normal map's x and y then have no meaning)
                            None => nrm
                                .iter()
                                .map(|n| n.any_orthonormal_vector().extend(1.0))
                                .collect(),
                        }
                    }
                });
            }
            let nv = pos.len();
            if base + nv > u32::MAX as usize {
                return fail(pos_place, "the mesh has more than 2³² vertices");
            }
            out.positions.extend(pos);
            out.normals.extend(nrm);
            let fill = |out: &mut Vec<Vec2>, have: bool, v: Option<Vec<Vec2>>| {
                if have {
                    match v {
                        Some(t) => out.extend(t),
                        None => out.extend(std::iter::repeat_n(Vec2::ZERO, nv)),
                    }
                }
            };
            fill(&mut out.uvs, any_uv, uvs);
            fill(&mut out.uvs1, any_uv1, uvs1);
            if any_color {
                match colors {
                    Some(c) => out.colors.extend(c),
                    None => out.colors.extend(std::iter::repeat_n(Vec4::ONE, nv)),
                }
            }
            if any_tangent {
                match tangents {
                    Some(t) => out.tangents.extend(t),
                    None => out
                        .tangents
                        .extend(std::iter::repeat_n(Vec4::new(1.0, 0.0, 0.0, 1.0), nv)),
                }
            }
            let b = base as u32;
            out.triangles
                .extend(tris.iter().map(|t| [t[0] + b, t[1] + b, t[2] + b]));
            out.triangle_material
                .extend(std::iter::repeat_n(material, tris.len()));
        }
        Ok(out)
    }

    /// A per-vertex attribute of `N` components (`None` when absent), checked to have one
    /// element per vertex.
    fn vertex_attr<const N: usize>(
        &self,
        accessor: Option<usize>,
        place: &str,
        name: &str,
        nv: usize,
    ) -> Result<Option<Vec<[f32; N]>>, Fail> {
        let Some(a) = accessor else {
            return Ok(None);
        };
        let p = format!("{place}.attributes.{name}");
        let v: Vec<[f32; N]> = self.read_vecs(a, &p)?;
        if v.len() != nv {
            return fail(
                p,
                format!(
                    "accessors[{a}] has {} elements but POSITION has {nv}",
                    v.len()
                ),
            );
        }
        Ok(Some(v))
    }

    /// `COLOR_0` as linear RGBA (VEC3 or VEC4; alpha 1 for VEC3), non-finite values as white.
    fn vertex_colors(
        &self,
        accessor: Option<usize>,
        place: &str,
        nv: usize,
    ) -> Result<Option<Vec<Vec4>>, Fail> {
        let Some(a) = accessor else {
            return Ok(None);
        };
        let p = format!("{place}.attributes.COLOR_0");
        let colors: Vec<Vec4> = match self.types(a, &p)?.0 {
            Type::Vec3 => self
                .vertex_attr::<3>(Some(a), place, "COLOR_0", nv)?
                .unwrap_or_default()
                .into_iter()
                .map(|c| Vec3::from(c).extend(1.0))
                .collect(),
            _ => self
                .vertex_attr::<4>(Some(a), place, "COLOR_0", nv)?
                .unwrap_or_default()
                .into_iter()
                .map(Vec4::from)
                .collect(),
        };
        Ok(Some(
            colors
                .into_iter()
                .map(|c| if c.is_finite() { c } else { Vec4::ONE })
                .collect(),
        ))
    }

    /// Material `i` of the file (asset material i + 1).
    fn material(&mut self, i: usize) -> MeshMaterial {
        let root = self.root;
        let m = &root.materials[i];
        let at = format!("materials[{i}]");
        let pbr = &m.pbr_metallic_roughness;
        let [r, g, b, alpha] = pbr.base_color_factor.0;
        let ext = m.extensions.as_ref();
        let transmission = ext
            .and_then(|e| e.transmission.as_ref())
            .map(|t| t.transmission_factor.0)
            .unwrap_or(0.0);
        let ior = ext
            .and_then(|e| e.ior.as_ref())
            .map(|x| x.ior.0)
            .unwrap_or(1.5);
        let mut params = pbr_material(
            Vec3::new(r, g, b),
            pbr.metallic_factor.0,
            pbr.roughness_factor.0,
            transmission,
            ior,
        );
        // §3.9.2: the factor's alpha is coverage like the texture's (used by MASK and BLEND)
        let base_alpha = if alpha.is_finite() {
            alpha.clamp(0.0, 1.0)
        } else {
            1.0
        };
        // KHR_materials_emissive_strength scales emissiveFactor beyond 1
        let strength = ext
            .and_then(|e| e.emissive_strength.as_ref())
            .map(|e| e.emissive_strength.0)
            .unwrap_or(1.0);
        let strength = if strength.is_finite() && strength >= 0.0 {
            strength
        } else {
            self.warn(format!(
                "{at}.extensions.KHR_materials_emissive_strength.emissiveStrength: {strength} \
                 is not a non-negative number; 1 is used"
            ));
            1.0
        };
        let emissive = Vec3::from(m.emissive_factor.0) * strength;
        params.emissive = if emissive.is_finite() {
            emissive.max(Vec3::ZERO)
        } else {
            Vec3::ZERO
        };
        let name = m.name.clone().unwrap_or_else(|| at.clone());
        let info = |x: &json::texture::Info| {
            (
                x.index.value(),
                x.tex_coord,
                x.extensions
                    .as_ref()
                    .and_then(|e| e.texture_transform.clone()),
            )
        };
        // normalTexture and occlusionTexture are not textureInfo in gltf-json's types: their
        // KHR_texture_transform is among the other extensions
        let other_transform = |others: Option<&serde_json::Map<String, json::Value>>| {
            others
                .and_then(|o| o.get("KHR_texture_transform"))
                .and_then(|v| json::deserialize::from_value(v.clone()).ok())
        };
        let base_color = pbr.base_color_texture.as_ref().map(info);
        let metallic_roughness = pbr.metallic_roughness_texture.as_ref().map(info);
        let emissive_texture = m.emissive_texture.as_ref().map(info);
        let normal = m.normal_texture.as_ref().map(|n| {
            (
                (
                    n.index.value(),
                    n.tex_coord,
                    other_transform(n.extensions.as_ref().map(|e| &e.others)),
                ),
                n.scale,
            )
        });
        let occlusion = m.occlusion_texture.as_ref().map(|o| {
            (
                (
                    o.index.value(),
                    o.tex_coord,
                    other_transform(o.extensions.as_ref().map(|e| &e.others)),
                ),
                o.strength.0,
            )
        });
        let textures = super::MaterialTextures {
            base_color: base_color.and_then(|x| {
                self.texture_ref(
                    x,
                    true,
                    &format!("{at}.pbrMetallicRoughness.baseColorTexture"),
                )
            }),
            metallic_roughness: metallic_roughness.and_then(|x| {
                self.texture_ref(
                    x,
                    false,
                    &format!("{at}.pbrMetallicRoughness.metallicRoughnessTexture"),
                )
            }),
            normal: normal.and_then(|(x, scale)| {
                let place = format!("{at}.normalTexture");
                let scale = self.finite_or(scale, 1.0, &format!("{place}.scale"));
                Some((self.texture_ref(x, false, &place)?, scale))
            }),
            occlusion: occlusion.and_then(|(x, strength)| {
                let place = format!("{at}.occlusionTexture");
                let strength = self
                    .finite_or(strength, 1.0, &format!("{place}.strength"))
                    .clamp(0.0, 1.0);
                Some((self.texture_ref(x, false, &place)?, strength))
            }),
            emissive: emissive_texture
                .and_then(|x| self.texture_ref(x, true, &format!("{at}.emissiveTexture"))),
        };
        let alpha_mode = match m.alpha_mode {
            Checked::Valid(json::material::AlphaMode::Mask) => {
                let cutoff = m.alpha_cutoff.map_or(0.5, |c| c.0);
                let cutoff = if cutoff.is_finite() && cutoff >= 0.0 {
                    cutoff
                } else {
                    self.warn(format!(
                        "{at}.alphaCutoff: {cutoff} is not a non-negative number; 0.5 is used"
                    ));
                    0.5
                };
                AlphaMode::Mask { cutoff }
            }
            Checked::Valid(json::material::AlphaMode::Blend) => AlphaMode::Blend,
            _ => AlphaMode::Opaque,
        };
        // §3.9.6: only BLEND shades with partial coverage (OPAQUE ignores alpha, MASK keeps
        // or drops whole points)
        params.opacity = if alpha_mode == AlphaMode::Blend {
            base_alpha
        } else {
            1.0
        };
        MeshMaterial {
            name,
            params,
            textures,
            alpha_mode,
            base_alpha,
        }
    }

    /// `value`, or `fallback` with a warning naming `place` when it is not finite.
    fn finite_or(&mut self, value: f32, fallback: f32, place: &str) -> f32 {
        if value.is_finite() {
            value
        } else {
            self.warn(format!(
                "{place}: {value} is not finite; {fallback} is used"
            ));
            fallback
        }
    }

    /// A material's use of glTF texture `index` on coordinate set `tex_coord` with its
    /// `KHR_texture_transform` (whose `texCoord`, when given, overrides the set), decoded in
    /// the colour space of the use; `None`, with a warning naming `place`, when it cannot be
    /// used.
    fn texture_ref(
        &mut self,
        (index, tex_coord, transform): (
            usize,
            u32,
            Option<json::extensions::texture::TextureTransform>,
        ),
        srgb: bool,
        place: &str,
    ) -> Option<TextureRef> {
        let (tex_coord, transform) = match transform {
            None => (tex_coord, UvTransform::IDENTITY),
            Some(t) => {
                let uv = UvTransform {
                    offset: Vec2::from(t.offset.0),
                    rotation: t.rotation.0,
                    scale: Vec2::from(t.scale.0),
                };
                let uv = if uv.is_finite() {
                    uv
                } else {
                    self.warn(format!(
                        "{place}.extensions.KHR_texture_transform: offset, rotation or scale is \
                         not finite; the transform is ignored"
                    ));
                    UvTransform::IDENTITY
                };
                (t.tex_coord.unwrap_or(tex_coord), uv)
            }
        };
        if tex_coord > 1 {
            self.warn(format!(
                "{place}.texCoord: TEXCOORD_{tex_coord}; only TEXCOORD_0 and TEXCOORD_1 are \
                 supported, the texture is ignored"
            ));
            return None;
        }
        let texture = self.texture(index, srgb, place)?;
        Some(TextureRef {
            texture,
            tex_coord,
            transform,
        })
    }

    /// glTF texture `t` decoded (once per colour space), or `None` with a warning when it
    /// cannot be.
    fn texture(&mut self, t: usize, srgb: bool, used_by: &str) -> Option<usize> {
        if let Some(&slot) = self.texture_slot.get(&(t, srgb)) {
            return slot;
        }
        let slot = match self.decode_texture(t, srgb) {
            Ok(tex) => {
                self.asset.textures.push(tex);
                Some(self.asset.textures.len() - 1)
            }
            Err((place, m)) => {
                self.warn(format!(
                    "{place}: {m}; {used_by} is ignored (the material is drawn without it)"
                ));
                None
            }
        };
        self.texture_slot.insert((t, srgb), slot);
        slot
    }

    fn decode_texture(&self, t: usize, srgb: bool) -> Result<Texture, Fail> {
        let root = self.root;
        let Some(tex) = root.textures.get(t) else {
            return fail(format!("textures[{t}]"), "does not exist");
        };
        let (wrap_u, wrap_v) = match tex.sampler.and_then(|s| root.samplers.get(s.value())) {
            Some(s) => (wrap_mode(s.wrap_s), wrap_mode(s.wrap_t)),
            None => (Wrap::Repeat, Wrap::Repeat),
        };
        let ii = tex.source.value();
        let place = format!("images[{ii}]");
        let Some(img) = root.images.get(ii) else {
            return fail(
                format!("textures[{t}].source"),
                format!("image {ii} does not exist"),
            );
        };
        let mut mime = img.mime_type.as_ref().map(|m| m.0.clone());
        let (bytes, name): (Vec<u8>, String) = match (&img.uri, img.buffer_view) {
            (Some(uri), _) => {
                let (b, data_mime) =
                    read_uri(uri, self.base).map_err(|m| (format!("{place}.uri"), m))?;
                let name = if uri.starts_with("data:") {
                    img.name.clone().unwrap_or_else(|| place.clone())
                } else {
                    uri.clone()
                };
                mime = mime.or(data_mime);
                (b, name)
            }
            (None, Some(v)) => {
                let slice = self.view_bytes(v.value(), &format!("{place}.bufferView"))?;
                (
                    slice.to_vec(),
                    img.name.clone().unwrap_or_else(|| place.clone()),
                )
            }
            (None, None) => return fail(place, "has neither uri nor bufferView"),
        };
        texture::decode(&bytes, mime.as_deref(), name, wrap_u, wrap_v, srgb)
            .map_err(|m| (place, format!("cannot decode the image: {m}")))
    }

    /// The bytes of buffer view `v`, checked against its buffer.
    fn view_bytes(&self, v: usize, place: &str) -> Result<&[u8], Fail> {
        let Some(view) = self.root.buffer_views.get(v) else {
            return fail(place, format!("buffer view {v} does not exist"));
        };
        let b = view.buffer.value();
        let Some(buf) = self.buffers.get(b) else {
            return fail(
                format!("bufferViews[{v}].buffer"),
                format!("buffer {b} does not exist"),
            );
        };
        let off = view.byte_offset.map(|o| o.0).unwrap_or(0);
        let len = view.byte_length.0;
        match off.checked_add(len) {
            Some(end) if end <= buf.len() as u64 => Ok(&buf[off as usize..end as usize]),
            _ => fail(
                format!("bufferViews[{v}]"),
                format!(
                    "bytes {off}..{} lie outside buffer {b} (its byteLength is {})",
                    off.saturating_add(len),
                    buf.len()
                ),
            ),
        }
    }

    /// Accessor `a` as `N`-component float vectors (any component type; normalized integers
    /// mapped to [0, 1] or [−1, 1]), with sparse substitution applied.
    fn read_vecs<const N: usize>(&self, a: usize, place: &str) -> Result<Vec<[f32; N]>, Fail> {
        let acc = self.accessor(a, place)?;
        let want = match N {
            1 => Type::Scalar,
            2 => Type::Vec2,
            3 => Type::Vec3,
            _ => Type::Vec4,
        };
        let (ty, ct) = self.types(a, place)?;
        if ty != want {
            return fail(
                place,
                format!(
                    "accessors[{a}] has type {} {}, expected {}",
                    type_name(ty),
                    component_name(ct),
                    type_name(want)
                ),
            );
        }
        let normalized = acc.normalized;
        self.read_elements(
            a,
            place,
            ct,
            N,
            [0.0; N],
            &|bytes: &[u8], out: &mut [f32; N]| {
                let size = ct.size();
                for (c, o) in out.iter_mut().enumerate() {
                    *o = component_f32(ct, normalized, &bytes[c * size..(c + 1) * size]);
                }
            },
        )
    }

    /// Accessor `a` as vertex indices (SCALAR of unsigned bytes, shorts or ints).
    fn read_indices(&self, a: usize, place: &str) -> Result<Vec<u32>, Fail> {
        let (ty, ct) = self.types(a, place)?;
        if ty != Type::Scalar
            || !matches!(
                ct,
                ComponentType::U8 | ComponentType::U16 | ComponentType::U32
            )
        {
            return fail(
                place,
                format!(
                    "accessors[{a}] has type {} {}; indices must be SCALAR unsigned byte, \
                     short or int",
                    type_name(ty),
                    component_name(ct)
                ),
            );
        }
        self.read_elements(a, place, ct, 1, 0u32, &|bytes: &[u8], out: &mut u32| {
            *out = component_u32(ct, bytes);
        })
    }

    fn accessor(&self, a: usize, place: &str) -> Result<&json::Accessor, Fail> {
        match self.root.accessors.get(a) {
            Some(acc) => Ok(acc),
            None => fail(place, format!("accessor {a} does not exist")),
        }
    }

    fn types(&self, a: usize, place: &str) -> Result<(Type, ComponentType), Fail> {
        let acc = self.accessor(a, place)?;
        match (acc.type_, acc.component_type) {
            (Checked::Valid(t), Checked::Valid(c)) => Ok((t, c.0)),
            _ => fail(format!("accessors[{a}]"), "invalid type or componentType"),
        }
    }

    /// Reads every element of accessor `a` (`ncomp` components of type `ct` each) with
    /// `decode`, checking every byte range, then applies its sparse substitution.
    #[allow(clippy::too_many_arguments)]
    fn read_elements<T: Copy>(
        &self,
        a: usize,
        place: &str,
        ct: ComponentType,
        ncomp: usize,
        zero: T,
        decode: &dyn Fn(&[u8], &mut T),
    ) -> Result<Vec<T>, Fail> {
        let acc = self.accessor(a, place)?;
        let at = format!("accessors[{a}]");
        let count = usize::try_from(acc.count.0).unwrap_or(usize::MAX);
        let elem = ct.size() * ncomp;
        let mut out: Vec<T>;
        match acc.buffer_view {
            Some(v) => {
                let v = v.value();
                let data = self.view_bytes(v, &format!("{at}.bufferView"))?;
                let stride = self
                    .root
                    .buffer_views
                    .get(v)
                    .and_then(|bv| bv.byte_stride)
                    .map(|s| s.0)
                    .filter(|&s| s > 0)
                    .unwrap_or(elem);
                if stride < elem {
                    return fail(
                        format!("bufferViews[{v}].byteStride"),
                        format!("{stride} is smaller than an element of {at} ({elem} bytes)"),
                    );
                }
                let offset = acc.byte_offset.map(|o| o.0).unwrap_or(0);
                let need = if count == 0 {
                    Some(0)
                } else {
                    (count as u64 - 1)
                        .checked_mul(stride as u64)
                        .and_then(|x| x.checked_add(elem as u64))
                        .and_then(|x| x.checked_add(offset))
                };
                match need {
                    Some(n) if n <= data.len() as u64 => {}
                    _ => {
                        return fail(
                            at,
                            format!(
                                "{count} elements of {elem} bytes (stride {stride}) from byte \
                                 {offset} do not fit in buffer view {v} ({} bytes)",
                                data.len()
                            ),
                        );
                    }
                }
                let data = &data[offset as usize..];
                out = vec![zero; count];
                for (k, o) in out.iter_mut().enumerate() {
                    decode(&data[k * stride..k * stride + elem], o);
                }
            }
            None => {
                if acc.sparse.is_none() {
                    return fail(at, "has neither bufferView nor sparse");
                }
                if count > MAX_ZERO_ACCESSOR {
                    return fail(
                        at,
                        format!("{count} elements without a buffer view is implausibly many"),
                    );
                }
                out = vec![zero; count];
            }
        }
        if let Some(sparse) = &acc.sparse {
            let sp = format!("{at}.sparse");
            let n = usize::try_from(sparse.count.0).unwrap_or(usize::MAX);
            if n > count {
                return fail(
                    format!("{sp}.count"),
                    format!("{n} substitutions for an accessor of {count} elements"),
                );
            }
            let ict = match sparse.indices.component_type {
                Checked::Valid(c) => c.0,
                Checked::Invalid => {
                    return fail(format!("{sp}.indices.componentType"), "invalid");
                }
            };
            let iv = sparse.indices.buffer_view.value();
            let idata = self.view_bytes(iv, &format!("{sp}.indices.bufferView"))?;
            let ioff = sparse.indices.byte_offset.0;
            let isize = ict.size();
            let vv = sparse.values.buffer_view.value();
            let vdata = self.view_bytes(vv, &format!("{sp}.values.bufferView"))?;
            let voff = sparse.values.byte_offset.0;
            let fits = |off: u64, size: usize, len: usize| {
                (n as u64)
                    .checked_mul(size as u64)
                    .and_then(|x| x.checked_add(off))
                    .is_some_and(|end| end <= len as u64)
            };
            if !fits(ioff, isize, idata.len()) {
                return fail(
                    format!("{sp}.indices"),
                    format!("{n} indices from byte {ioff} do not fit in buffer view {iv}"),
                );
            }
            if !fits(voff, elem, vdata.len()) {
                return fail(
                    format!("{sp}.values"),
                    format!("{n} values from byte {voff} do not fit in buffer view {vv}"),
                );
            }
            let idata = &idata[ioff as usize..];
            let vdata = &vdata[voff as usize..];
            for k in 0..n {
                let target = component_u32(ict, &idata[k * isize..(k + 1) * isize]) as usize;
                let Some(slot) = out.get_mut(target) else {
                    return fail(
                        format!("{sp}.indices"),
                        format!(
                            "substitution {k} targets element {target} of an accessor of \
                             {count}"
                        ),
                    );
                };
                decode(&vdata[k * elem..(k + 1) * elem], slot);
            }
        }
        Ok(out)
    }
}

/// A node's own transform (matrix, or translation · rotation · scale), checked finite.
fn local_transform(root: &json::Root, index: usize) -> Result<Affine3A, Fail> {
    let node = &root.nodes[index];
    let m = match node.matrix {
        Some(m) => Mat4::from_cols_array(&m),
        None => {
            let t = Vec3::from_array(node.translation.unwrap_or([0.0; 3]));
            let r = node.rotation.map(|r| r.0).unwrap_or([0.0, 0.0, 0.0, 1.0]);
            let r = glam::Vec4::from_array(r)
                .try_normalize()
                .map(Quat::from_vec4)
                .unwrap_or(Quat::IDENTITY);
            let s = Vec3::from_array(node.scale.unwrap_or([1.0; 3]));
            Mat4::from_scale_rotation_translation(s, r, t)
        }
    };
    if !m.is_finite() {
        return fail(format!("nodes[{index}]"), "the transform is not finite");
    }
    Ok(Affine3A::from_mat4(m))
}

/// The glTF spelling of an accessor type.
fn type_name(t: Type) -> &'static str {
    match t {
        Type::Scalar => "SCALAR",
        Type::Vec2 => "VEC2",
        Type::Vec3 => "VEC3",
        Type::Vec4 => "VEC4",
        Type::Mat2 => "MAT2",
        Type::Mat3 => "MAT3",
        Type::Mat4 => "MAT4",
    }
}

/// A readable name of a component type.
fn component_name(c: ComponentType) -> &'static str {
    match c {
        ComponentType::I8 => "BYTE",
        ComponentType::U8 => "UNSIGNED_BYTE",
        ComponentType::I16 => "SHORT",
        ComponentType::U16 => "UNSIGNED_SHORT",
        ComponentType::U32 => "UNSIGNED_INT",
        ComponentType::F32 => "FLOAT",
    }
}

fn wrap_mode(w: Checked<json::texture::WrappingMode>) -> Wrap {
    use json::texture::WrappingMode as W;
    match w {
        Checked::Valid(W::ClampToEdge) => Wrap::ClampToEdge,
        Checked::Valid(W::MirroredRepeat) => Wrap::MirroredRepeat,
        _ => Wrap::Repeat,
    }
}

/// One little-endian component as a float; normalized integers map to [0, 1] (unsigned) or
/// [−1, 1] (signed) as the glTF specification says.
fn component_f32(ct: ComponentType, normalized: bool, b: &[u8]) -> f32 {
    match ct {
        ComponentType::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        ComponentType::I8 => {
            let v = b[0] as i8 as f32;
            if normalized { (v / 127.0).max(-1.0) } else { v }
        }
        ComponentType::U8 => {
            let v = b[0] as f32;
            if normalized { v / 255.0 } else { v }
        }
        ComponentType::I16 => {
            let v = i16::from_le_bytes([b[0], b[1]]) as f32;
            if normalized {
                (v / 32767.0).max(-1.0)
            } else {
                v
            }
        }
        ComponentType::U16 => {
            let v = u16::from_le_bytes([b[0], b[1]]) as f32;
            if normalized { v / 65535.0 } else { v }
        }
        ComponentType::U32 => {
            let v = u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32;
            if normalized { v / 4294967295.0 } else { v }
        }
    }
}

/// One little-endian unsigned component (signed types reinterpreted).
fn component_u32(ct: ComponentType, b: &[u8]) -> u32 {
    match ct {
        ComponentType::U8 | ComponentType::I8 => u32::from(b[0]),
        ComponentType::U16 | ComponentType::I16 => u32::from(u16::from_le_bytes([b[0], b[1]])),
        ComponentType::U32 | ComponentType::F32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
    }
}

/// The values of `v` at each corner of each triangle, in order: three per triangle.
fn unweld<T: Copy>(v: &[T], tris: &[[u32; 3]]) -> Vec<T> {
    tris.iter().flat_map(|t| t.map(|i| v[i as usize])).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_round_trip() {
        assert_eq!(base64_decode("aGVsbG8=").unwrap(), b"hello");
        assert_eq!(base64_decode("aGVsbG8").unwrap(), b"hello");
        assert!(base64_decode("a$b").is_none());
        assert_eq!(percent_decode("a%20b").unwrap(), "a b");
        assert!(percent_decode("a%2").is_none());
        assert!(percent_decode("%FF").is_none());
    }

    #[test]
    fn glb_container_errors() {
        assert!(split_glb(b"glTF").is_err());
        let mut b = b"glTF".to_vec();
        b.extend(2u32.to_le_bytes());
        b.extend(1000u32.to_le_bytes());
        assert!(split_glb(&b).is_err());
        let mut b = b"glTF".to_vec();
        b.extend(2u32.to_le_bytes());
        b.extend(28u32.to_le_bytes());
        b.extend(8u32.to_le_bytes());
        b.extend(b"JSON{}      ");
        assert_eq!(split_glb(&b).unwrap().0, b"{}      ");
        let mut c = b.clone();
        c[12] = 200;
        assert!(split_glb(&c).is_err());
    }
}
