//! PLY, ASCII and binary (little and big endian), read with `ply-rs-bw` straight into small
//! structs: `vertex` (x y z, optional nx ny nz and u v / s t / texture_u texture_v) and `face`
//! (`vertex_indices` or `vertex_index`, any list type). Other elements are skipped.

use super::polygon::triangulate;
use super::{MeshAsset, MeshError, MeshInstance, TriangleMesh, repair_normals, vertex_normals};
use glam::{Affine3A, Vec2, Vec3};
use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{
    BeginList, ElementDef, Encoding, Property, PropertyAccess, PropertyAccessResult, PropertyType,
    ScalarType,
};
use std::io::Cursor;
use std::path::Path;

/// A vertex as read.
#[derive(Default)]
struct PlyVertex {
    p: [f32; 3],
    n: [f32; 3],
    uv: [f32; 2],
}

impl PropertyAccess for PlyVertex {
    fn new() -> Self {
        PlyVertex::default()
    }

    fn set_property(&mut self, key: &str, property: Property) -> PropertyAccessResult {
        let Some(v) = property.to_f32_lossy() else {
            return PropertyAccessResult::Ignored;
        };
        let slot = match key {
            "x" => &mut self.p[0],
            "y" => &mut self.p[1],
            "z" => &mut self.p[2],
            "nx" => &mut self.n[0],
            "ny" => &mut self.n[1],
            "nz" => &mut self.n[2],
            k if U_NAMES.contains(&k) => &mut self.uv[0],
            k if V_NAMES.contains(&k) => &mut self.uv[1],
            _ => return PropertyAccessResult::Ignored,
        };
        *slot = v;
        PropertyAccessResult::Set
    }
}

const U_NAMES: [&str; 4] = ["u", "s", "texture_u", "texture_s"];
const V_NAMES: [&str; 4] = ["v", "t", "texture_v", "texture_t"];
const INDEX_NAMES: [&str; 2] = ["vertex_indices", "vertex_index"];

/// A face as read: its vertex indices, or `bad` when they were negative or not integers.
#[derive(Default)]
struct PlyFace {
    indices: Vec<u32>,
    bad: bool,
}

impl PropertyAccess for PlyFace {
    fn new() -> Self {
        PlyFace::default()
    }

    fn set_property(&mut self, key: &str, property: Property) -> PropertyAccessResult {
        if !INDEX_NAMES.contains(&key) {
            return PropertyAccessResult::Ignored;
        }
        match property.to_u32_list() {
            Some(list) => self.indices = list,
            None => self.bad = true,
        }
        PropertyAccessResult::Set
    }

    fn begin_list_uint(&mut self, key: &str, _len: usize) -> BeginList<'_, u32> {
        if INDEX_NAMES.contains(&key) {
            BeginList::Fill(&mut self.indices)
        } else {
            BeginList::UseSetter
        }
    }
}

/// An element that is read past and dropped.
struct Skip;

impl PropertyAccess for Skip {
    fn new() -> Self {
        Skip
    }
}

/// Loads a PLY file whose bytes are `bytes`.
pub(super) fn load(file: &Path, bytes: &[u8]) -> Result<MeshAsset, MeshError> {
    let err = |line: Option<usize>, message: String| MeshError::Ply {
        file: file.to_path_buf(),
        line,
        message,
    };
    if !bytes.starts_with(b"ply") {
        return Err(err(
            Some(1),
            "not a PLY file (it must start with `ply`)".into(),
        ));
    }
    let patched = lenient_header(bytes);
    let mut warnings = Vec::new();
    if let Some((_, line)) = &patched {
        warnings.push(format!(
            "{}:{line}: header lines without a keyword read as comments",
            file.display()
        ));
    }
    let bytes: &[u8] = match &patched {
        Some((b, _)) => b,
        None => bytes,
    };
    let mut reader = Reader::new(Cursor::new(bytes));
    let header = Parser::<Skip>::new()
        .read_header(&mut reader)
        .map_err(|e| {
            err(
                e.line(),
                format!("invalid header: {}", strip_line(&e.to_string())),
            )
        })?;
    let header_end = reader.get_ref().position() as usize;
    let header_lines = bytes[..header_end.min(bytes.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count();
    let remaining = bytes.len().saturating_sub(header_end);
    let binary = !matches!(header.encoding, Encoding::Ascii);

    // Every element needs at least one byte (ASCII: a line) or its fixed part (binary), so a
    // header announcing more than the file can hold is refused before anything is allocated.
    let mut need = 0usize;
    for e in header.elements.values() {
        let min = if binary { min_binary_size(e).max(1) } else { 1 };
        need = e
            .count
            .checked_mul(min)
            .and_then(|n| n.checked_add(need))
            .unwrap_or(usize::MAX);
        if need > remaining {
            return Err(err(
                None,
                format!(
                    "the header announces {} `{}` elements, which with the elements before \
                     them need at least {} bytes, but only {} bytes follow the header \
                     (truncated file?)",
                    e.count, e.name, need, remaining
                ),
            ));
        }
    }
    let Some(vdef) = header.elements.values().find(|e| e.name == "vertex") else {
        return Err(err(None, "no `vertex` element".into()));
    };
    for c in ["x", "y", "z"] {
        if !vdef.properties.contains_key(c) {
            return Err(err(
                None,
                format!("the `vertex` element has no `{c}` property"),
            ));
        }
    }
    let has = |names: &[&str]| names.iter().any(|n| vdef.properties.contains_key(*n));
    let has_normals = ["nx", "ny", "nz"]
        .iter()
        .all(|n| vdef.properties.contains_key(*n));
    let has_uv = has(&U_NAMES) && has(&V_NAMES);
    let fdef = header.elements.values().find(|e| e.name == "face");
    if let Some(f) = fdef {
        let list = f
            .properties
            .values()
            .find(|p| INDEX_NAMES.contains(&p.name.as_str()));
        match list.map(|p| &p.data_type) {
            Some(PropertyType::List(_, t))
                if !matches!(t, ScalarType::Float | ScalarType::Double) => {}
            Some(_) => {
                return Err(err(
                    None,
                    "the `face` element's vertex_indices is not a list of integers".into(),
                ));
            }
            None => {
                return Err(err(
                    None,
                    "the `face` element has no `vertex_indices` (or `vertex_index`) list".into(),
                ));
            }
        }
    }

    let mut vertices: Vec<PlyVertex> = Vec::new();
    let mut faces: Vec<PlyFace> = Vec::new();
    let mut face_first_line = None;
    let mut lines_before = header_lines;
    let (mut got_v, mut got_f) = (false, false);
    let payload_err = |e: ply_rs_bw::parser::ParseError, what: &str| {
        err(e.line(), format!("{what}: {}", strip_line(&e.to_string())))
    };
    // Every element is read, even after the vertices and faces, so that a truncated file is
    // reported as such.
    for e in header.elements.values() {
        match e.name.as_str() {
            "vertex" if !got_v => {
                vertices = Parser::<PlyVertex>::new()
                    .read_payload_for_element(&mut reader, e, &header)
                    .map_err(|x| payload_err(x, "reading vertices"))?;
                got_v = true;
            }
            "face" if !got_f => {
                face_first_line = Some(lines_before + 1);
                faces = Parser::<PlyFace>::new()
                    .read_payload_for_element(&mut reader, e, &header)
                    .map_err(|x| payload_err(x, "reading faces"))?;
                got_f = true;
            }
            _ => {
                Parser::<Skip>::new()
                    .read_payload_for_element(&mut reader, e, &header)
                    .map_err(|x| payload_err(x, &format!("reading `{}` elements", e.name)))?;
            }
        }
        lines_before += e.count;
    }

    let nv = vertices.len();
    if nv > u32::MAX as usize {
        return Err(err(None, "more than 2³² vertices".into()));
    }
    let positions: Vec<Vec3> = vertices.iter().map(|v| Vec3::from_array(v.p)).collect();
    if let Some(k) = positions.iter().position(|p| !p.is_finite()) {
        let line = (!binary).then(|| header_lines + 1 + k);
        return Err(err(
            line,
            format!("vertex {k} is {:?}: positions must be finite", positions[k]),
        ));
    }
    let mut mesh = TriangleMesh {
        name: file
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
        positions,
        ..TriangleMesh::default()
    };
    let mut small = 0usize;
    let mut local = Vec::new();
    let mut pts = Vec::new();
    for (k, f) in faces.iter().enumerate() {
        let place = || match (binary, face_first_line) {
            (false, Some(l)) => (Some(l + k), format!("face {k}")),
            _ => (None, format!("face {k}")),
        };
        if f.bad {
            let (line, what) = place();
            return Err(err(
                line,
                format!("{what}: vertex indices must be non-negative integers"),
            ));
        }
        if let Some(&i) = f.indices.iter().find(|&&i| i as usize >= nv) {
            let (line, what) = place();
            return Err(err(
                line,
                format!("{what}: vertex index {i} is out of range ({nv} vertices)"),
            ));
        }
        if f.indices.len() < 3 {
            small += 1;
            continue;
        }
        pts.clear();
        pts.extend(f.indices.iter().map(|&i| mesh.positions[i as usize]));
        local.clear();
        triangulate(&pts, &mut local);
        mesh.triangles
            .extend(local.iter().map(|t| t.map(|c| f.indices[c])));
    }
    mesh.triangle_material = vec![0; mesh.triangles.len()];
    let mut asset = MeshAsset::empty();
    asset.warnings = warnings;
    if has_normals {
        mesh.normals = vertices.iter().map(|v| Vec3::from_array(v.n)).collect();
        let bad = repair_normals(&mut mesh.normals, &mesh.positions, &mesh.triangles);
        if bad > 0 {
            asset.warnings.push(format!(
                "{}: {bad} normals are zero or not finite; computed instead",
                file.display()
            ));
        }
    } else {
        mesh.normals = vertex_normals(&mesh.positions, &mesh.triangles);
    }
    if has_uv {
        mesh.uvs = vertices
            .iter()
            .map(|v| Vec2::new(v.uv[0], 1.0 - v.uv[1]))
            .collect();
    }
    if small > 0 {
        asset.warnings.push(format!(
            "{}: {small} faces with fewer than 3 vertices skipped",
            file.display()
        ));
    }
    if fdef.is_none() {
        asset.warnings.push(format!(
            "{}: no `face` element (a point cloud?): nothing to draw",
            file.display()
        ));
    }
    if !mesh.triangles.is_empty() {
        asset.instances.push(MeshInstance {
            mesh: 0,
            transform: Affine3A::IDENTITY,
            name: mesh.name.clone(),
        });
        asset.meshes.push(mesh);
    } else if fdef.is_some() {
        asset
            .warnings
            .push(format!("{}: no faces: nothing to draw", file.display()));
    }
    Ok(asset)
}

/// The file with header lines that start with no PLY keyword (some exporters write free
/// text there) turned into comments, and the first such line; `None` when there are none.
fn lenient_header(bytes: &[u8]) -> Option<(Vec<u8>, usize)> {
    const KEYWORDS: [&str; 7] = [
        "ply",
        "format",
        "comment",
        "element",
        "property",
        "end_header",
        "obj_info",
    ];
    let mut out = Vec::new();
    let mut first = None;
    let mut at = 0;
    for (i, raw) in bytes.split(|&b| b == b'\n').enumerate() {
        let text = String::from_utf8_lossy(raw);
        let word = text.split_whitespace().next().unwrap_or("");
        if KEYWORDS.contains(&word) {
            out.extend_from_slice(raw);
        } else {
            first.get_or_insert(i + 1);
            out.extend_from_slice(b"comment ");
            out.extend_from_slice(text.trim().as_bytes());
        }
        at += raw.len() + 1;
        if word == "end_header" || at >= bytes.len() {
            break;
        }
        out.push(b'\n');
    }
    let first = first?;
    out.push(b'\n');
    out.extend_from_slice(bytes.get(at..).unwrap_or(&[]));
    Some((out, first))
}

/// The parser's message without its own `Line N:` prefix (the error carries the line).
fn strip_line(s: &str) -> String {
    let s = match s.strip_prefix("Line ").and_then(|r| r.split_once(": ")) {
        Some((n, rest)) if n.chars().all(|c| c.is_ascii_digit()) => rest,
        _ => s,
    };
    // ply-rs follows its first line with the offending text and its parser's state (tabs,
    // newlines, Rust debug output): an error stays one line, the first.
    s.lines().next().unwrap_or("").trim().to_string()
}

/// The fewest bytes one element takes in a binary file (lists counted empty).
fn min_binary_size(e: &ElementDef) -> usize {
    e.properties
        .values()
        .map(|p| match &p.data_type {
            PropertyType::Scalar(t) => scalar_size(t),
            PropertyType::List(count, _) => scalar_size(count),
        })
        .sum()
}

fn scalar_size(t: &ScalarType) -> usize {
    match t {
        ScalarType::Char | ScalarType::UChar => 1,
        ScalarType::Short | ScalarType::UShort => 2,
        ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
        ScalarType::Double => 8,
    }
}
